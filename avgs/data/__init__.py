"""Scene data, read (never written): the RWAVS-layout reader (:mod:`.rwavs`), the
impulse-response layout's (:mod:`.rir`), the world <-> normalised frame (:mod:`.frame`), camera
views (:mod:`.views`), scene.json's geometry (:mod:`.scene_geometry`) and checked file reading
(:mod:`.files`). Both RWAVS loaders read the poses through :mod:`.pose_files`; contradictions
between a scene's files are checked in :mod:`.consistency`, and the recordings' own
(silence, a source and binaural track out of sync) in :mod:`.recordings`. The generator that
writes such scenes is :mod:`avgs.synth`.

Kept import-light on purpose: import the submodule you need
(``from avgs.data.rwavs import RWAVSScene``).
"""
