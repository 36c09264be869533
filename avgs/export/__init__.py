"""What you hear, exported in the formats the field uses.

- :mod:`avgs.export.grid`: a grid of binaural responses (listener positions x yaws x sources).
- :mod:`avgs.export.sofa`: a grid as a SOFA file (AES69, convention ``SingleRoomSRIR``, by
  ``sofar``), and one pose's response as a WAV.
- :mod:`avgs.export.flypath`: a listener path as keyframes (a small JSON file) and the pose at any time.
- :mod:`avgs.export.video`: an MP4 (H.264 + AAC) written frame by frame through PyAV.
- :mod:`avgs.export.flythrough`: a path into that MP4: the binaural track along it (the
  renderer's stream, its pose moved every audio block) and a picture per video frame.

Everything goes through :class:`~avgs.render.renderer.SceneRenderer`; nothing here knows
which task a checkpoint was trained for.
"""
