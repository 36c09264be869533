"""Synthetic scenes with physical ground truth, written in the RWAVS layout.

One job per module:

- :mod:`.materials`  acoustic materials (pyroomacoustics table) and their display colours
- :mod:`.presets`    scene specs (office, house, apartment, outdoor, and the six impulse-response
  layouts), randomised mildly by seed
- :mod:`.poses`      walkable area and listener pose sampling
- :mod:`.hrtf`       the MIT KEMAR head (read from the ``slab`` package's data file)
- :mod:`.simulate`   pyroomacoustics rooms and binaural room impulse responses, RT60
- :mod:`.signals`    deterministic mono source signals
- :mod:`.render`     RGB key frames with PyVista off-screen
- :mod:`.writer`     one scene folder, atomically, in the RWAVS layout
- :mod:`.grid`       source and receiver grids of an impulse-response scene, its split by pair
- :mod:`.rir_writer` an impulse-response scene (``avgs synth --task rir``): the RWAVS files for
  source 0 plus ``rir/`` (docs/rir-layout.md; read by :mod:`avgs.data.rir`)

Import the submodule you need; importing this package loads nothing heavy.
"""

GENERATOR_VERSION = 1
"Bumped whenever the same seed would give a different scene."
