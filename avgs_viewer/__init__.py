"""``avgs-viewer``: the desktop explorer of a trained AV-GS scene.

Qt lives in :mod:`avgs_viewer.window` (composition only) and the parts it is made of: the side
panel (``control_panel``, ``pose_panel``), the menus (``menus``), the file actions and their
dialogs (``file_actions``), the checkpoint loader (``loading``), the audio path's glue
(``audio_path``), the 3D view's mouse (``mouse``) and canvas (``canvas``), the response panel
and the map's controls; and in :mod:`avgs_viewer.app`. The state, drag, colour, audio engine,
sound output, worker and export modules import no Qt and are tested without a window.
Importing this package imports nothing heavy.
"""
