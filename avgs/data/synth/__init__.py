"""Synthetic scenes with physical ground truth, written in the RWAVS layout.

One job per module:

- :mod:`.materials`  acoustic materials (pyroomacoustics table) and their display colours
- :mod:`.presets`    scene specs (office, house, apartment, outdoor), randomised mildly by seed
- :mod:`.poses`      walkable area and listener pose sampling
- :mod:`.hrtf`       the MIT KEMAR head (read from the ``slab`` package's data file)
- :mod:`.simulate`   pyroomacoustics rooms and binaural room impulse responses, RT60
- :mod:`.signals`    deterministic mono source signals
- :mod:`.render`     RGB key frames with PyVista off-screen
- :mod:`.geometry`   points sampled on a written scene's surfaces (normalised frame)
- :mod:`.writer`     one scene folder, atomically, in the RWAVS layout

Import the submodule you need; importing this package loads nothing heavy.
"""

GENERATOR_VERSION = 1
"Bumped whenever the same seed would give a different scene."
