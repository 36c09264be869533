"""A grid of binaural responses as a SOFA file (AES69), and one pose's response as a WAV.

The convention is ``SingleRoomSRIR`` 1.0 (SOFA 2.1): spatial room impulse responses in one
room, measured with one source and one listener of R omnidirectional receivers, both of
which may move from measurement to measurement (ListenerPosition, ListenerView and
SourcePosition per measurement, M x C); ``Data.IR`` is M x R x N. Our grid is exactly that:
M = sources x listener positions x yaws (the yaw is the listener's view), R = 2 receivers
(the ears, left then right), N samples. The others do not fit: SimpleFreeFieldHRIR is for
HRTFs (free field, the source around a fixed head); SingleRoomDRIR and MultiSpeakerBRIR are
deprecated in sofar's conventions (SingleRoomSRIR replaces SingleRoomDRIR; MultiSpeakerBRIR is
per emitter of a loudspeaker array, E, which we have not); GeneralFIR would take the data but
names no room, listener view or source per measurement.

Measurements are ordered source-major, then listener position, then yaw
(``m = (s * P + p) * Y + y``); the file's ``GLOBAL:Comment`` says so and ``GLOBAL:GridShape``
holds ``S P Y``, so :func:`read_grid` gives back the very grid. Positions are the scene's
world coordinates (metres for generated scenes), z up. The ears are nominal points on a
head of radius :data:`EAR_OFFSET` (the model's head is implicit in its responses).
``RoomType`` is ``shoebox`` with the scene's bounding box as its corners (the box the
renderer keeps listener and source inside, not necessarily the room's shape).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from avgs.export.grid import ResponseGrid
from avgs.io import atomic

CONVENTION = "SingleRoomSRIR"
EAR_OFFSET = 0.0875
"Distance of each ear from the head's centre, metres (along the listener's left, +y of its view)."


def _views(yaws: np.ndarray) -> np.ndarray:
    """Unit view vectors ``[Y, 3]`` of yaws (degrees ccw from +x), level."""
    r = np.radians(yaws)
    return np.stack([np.cos(r), np.sin(r), np.zeros_like(r)], axis=1)


def to_sofa(grid: ResponseGrid, title: str = "", comment: str = ""):
    """The grid as a ``sofar.Sofa`` of :data:`CONVENTION`, verified."""
    import sofar

    S, P, Y = grid.shape
    si, pi, yi = (a.ravel() for a in np.meshgrid(np.arange(S), np.arange(P), np.arange(Y), indexing="ij"))  # [M]
    sofa = sofar.Sofa(CONVENTION)
    sofa.GLOBAL_Title = title or "AV-GS binaural responses"
    sofa.GLOBAL_DatabaseName = "AV-GS explorer"
    sofa.GLOBAL_AuthorContact = "avgs export"
    sofa.GLOBAL_Organization = "AV-GS explorer"
    sofa.GLOBAL_ListenerShortName = "binaural head"
    sofa.GLOBAL_Comment = ((comment + " ") if comment else "") + (
        f"Predicted binaural room impulse responses: measurement m = (s * {P} + p) * {Y} + y of {S} sources x "
        f"{P} listener positions x {Y} yaws (ListenerView); receiver 0 = left ear, 1 = right ear.")
    sofa.add_attribute("GLOBAL_GridShape", f"{S} {P} {Y}")
    sofa.GLOBAL_RoomType = "shoebox"
    sofa.RoomCornerA = grid.bounds[0][None]  # [1, 3]
    sofa.RoomCornerB = grid.bounds[1][None]
    sofa.ListenerPosition = grid.listeners[pi]  # [M, 3] cartesian, metres
    sofa.ListenerView = _views(grid.yaws)[yi]  # [M, 3]
    sofa.ListenerUp = np.array([[0.0, 0.0, 1.0]])
    sofa.ReceiverPosition = np.array([[0.0, EAR_OFFSET, 0.0], [0.0, -EAR_OFFSET, 0.0]])[..., None]  # [R, C, I]
    sofa.ReceiverPosition_Type = "cartesian"
    sofa.ReceiverPosition_Units = "metre"
    sofa.delete("ReceiverDescriptions")  # string variables fail to write (netCDF4 with numpy 2); the comment names the ears
    sofa.delete("EmitterDescriptions")
    sofa.ReceiverView = np.tile(np.array([1.0, 0.0, 0.0])[None, :, None], (2, 1, 1))  # [R, C, I]: facing the view
    sofa.ReceiverUp = np.tile(np.array([0.0, 0.0, 1.0])[None, :, None], (2, 1, 1))
    sofa.delete("MeasurementDate")  # optional, and these are predictions
    sofa.SourcePosition = grid.sources[si]  # [M, 3]
    sofa.Data_IR = grid.ir.reshape(S * P * Y, 2, -1)  # [M, R, N]
    sofa.Data_SamplingRate = float(grid.sample_rate)
    sofa.Data_Delay = np.zeros((1, 2))
    sofa.verify(issue_handling="raise")
    return sofa


def write_grid(path: str | Path, grid: ResponseGrid, title: str = "", inputs=()) -> Path:
    """``grid`` as a ``.sofa`` file (atomically; never over one of ``inputs``)."""
    import sofar

    path = Path(path)
    if path.suffix.lower() != ".sofa":
        raise ValueError(f"a response grid must be written to a .sofa file, got {path}")
    atomic.check_output(path, inputs=inputs, what="SOFA output")
    sofa = to_sofa(grid, title)
    with atomic.atomic_path(path) as tmp:
        sofar.write_sofa(str(tmp), sofa)
    return path


def read_grid(path: str | Path) -> ResponseGrid:
    """A grid written by :func:`write_grid` (verified by sofar on reading)."""
    import sofar

    sofa = sofar.read_sofa(str(path), verify=True, verbose=False)
    if sofa.GLOBAL_SOFAConventions != CONVENTION or not hasattr(sofa, "GLOBAL_GridShape"):
        raise ValueError(f"{path}: not a response grid of 'avgs export' (convention {sofa.GLOBAL_SOFAConventions})")
    S, P, Y = (int(v) for v in str(sofa.GLOBAL_GridShape).split())
    ir = np.asarray(sofa.Data_IR, dtype=np.float32)  # [M, R, N]
    listeners = np.asarray(sofa.ListenerPosition, dtype=np.float64).reshape(S, P, Y, 3)[0, :, 0]
    views = np.asarray(sofa.ListenerView, dtype=np.float64).reshape(S, P, Y, 3)[0, 0]
    sources = np.asarray(sofa.SourcePosition, dtype=np.float64).reshape(S, P, Y, 3)[:, 0, 0]
    bounds = np.concatenate([np.asarray(sofa.RoomCornerA).reshape(1, 3), np.asarray(sofa.RoomCornerB).reshape(1, 3)])
    return ResponseGrid(sources, listeners, np.degrees(np.arctan2(views[:, 1], views[:, 0])) % 360.0,
                        ir.reshape(S, P, Y, 2, -1), int(round(float(np.asarray(sofa.Data_SamplingRate).ravel()[0]))),
                        bounds.astype(np.float64))


def write_impulse_wav(path: str | Path, impulse: np.ndarray, sample_rate: int, inputs=()) -> Path:
    """One pose's binaural response ``[2, L]`` as a 2-channel float32 WAV (channel 0 = left)."""
    return atomic.write_binaural_wav(path, impulse, sample_rate, inputs, what="impulse-response output")
