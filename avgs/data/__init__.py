"""Scene data: the RWAVS-layout reader, the world <-> normalised frame, camera views and
the synthetic generator.

Kept import-light on purpose: import the submodule you need
(``from avgs.data.rwavs import RWAVSScene``).
"""
