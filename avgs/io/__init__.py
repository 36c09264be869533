"""Files in and out.

- :mod:`.checkpoint`: the versioned, checksummed ``scene.ckpt`` (build, save, load);
  :mod:`.checkpoint_format` checks every key of one before anything uses it.
- :mod:`.atomic`: the one way every file is written (temporary file, then rename); a failed
  write (a full disk) is an ``OSError`` naming the file, and leaves nothing behind.
- :mod:`.audio_input`: the one reader of users' audio files.
"""
