"""Files in and out.

- :mod:`.checkpoint`: the versioned, checksummed ``scene.ckpt`` (build, save, load);
  :mod:`.checkpoint_validation` checks every key of one before anything uses it.
- :mod:`.atomic`: the one way every file is written (temporary file, then rename).
- :mod:`.audio_input`: the one reader of users' audio files.
"""
