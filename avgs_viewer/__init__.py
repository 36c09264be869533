"""``avgs-viewer``: the desktop explorer of a trained AV-GS scene.

Qt lives only in :mod:`avgs_viewer.window` and :mod:`avgs_viewer.app`; the state, drag,
colour, audio, worker, scene-view and export modules import no Qt and are tested
without a window. Importing this package imports nothing heavy.
"""
