"""Contradictions between a scene's files that each file alone cannot show: the scaled and
unscaled transforms of a split pose different frames, poses lie far outside the
normalised frame, nothing says how to normalise, some key frames are missing, or the
intrinsics describe no real camera. (The recordings' own: :mod:`avgs.data.recordings`.)

The rule for each: an **error** (ValueError naming the file and the value, the loaders'
error type) where no real recording can look like that; a **warning** (one line) where a
real one can, so the scene still loads. Each check says which, and why, where it is made.
Every function takes plain values (paths, arrays, entries with ``frame_number`` and
``field``), so both loaders call them. The pose warnings point at
:func:`avgs.data.pose_files.read_scene_poses`, which both loaders call: Python's default
warning filter then shows one of them once per process, not once per loader.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np

NORMALISED_EXTENT = 1.5
"""Largest |coordinate| of a listener pose in the normalised frame before a warning: the
layout scales poses into [-1, 1]^3; 1.5 leaves room for a normalisation made from part of
the poses (e.g. the training ones only) or rounded."""
SQUARE_PIXELS = 1.1
"""Largest ratio of the two focal lengths (in pixels, at the frame's real size) loaded
silently: calibrated cameras give equal ones to a few per cent."""
MAX_PIXEL_ASPECT = 2.0
"""Largest ratio of the focal lengths accepted at all (an anamorphic 2x lens); beyond it the
intrinsics describe no camera."""
FOV_AGREEMENT = 1.25
"""Largest ratio of tan(fov / 2) between transforms.json's focal length and a camera-path
entry's ``fov`` loaded silently: the two describe one camera, but a camera path may carry a
nominal fov (a lens's rated one, rounded) rather than the calibrated one."""


def check_same_frames(scaled_path: Path, scaled: list, unscaled_path: Path, unscaled: list) -> None:
    """The scaled and unscaled transforms of one split pose the same frames (ValueError).

    An error: the layout defines ``transforms_scale_*`` as the same poses, scaled; a frame
    posed in one file only means one of them was edited or belongs to another scene, and
    the reader would take the scaled pose of a frame nothing else vouches for."""
    a = {e.frame_number: e for e in scaled}
    b = {e.frame_number: e for e in unscaled}
    if a.keys() == b.keys():
        return
    only_scaled, only_unscaled = sorted(a.keys() - b.keys()), sorted(b.keys() - a.keys())
    span = f"frames {min(b)}..{max(b)}" if b else "no frame"
    if only_scaled:
        k = only_scaled[0]
        more = f" (and {len(only_scaled) - 1} more)" if len(only_scaled) > 1 else ""
        raise ValueError(
            f"{scaled_path}: {a[k].field} poses frame {k}{more}, which {unscaled_path.name} does not pose "
            f"(it poses {len(b)}: {span}); expected the same frames in both, the scaled file being the same poses scaled"
        )
    k = only_unscaled[0]
    more = f" (and {len(only_unscaled) - 1} more)" if len(only_unscaled) > 1 else ""
    raise ValueError(
        f"{scaled_path}: does not pose frame {k}{more}, which {unscaled_path.name} {b[k].field} poses; "
        "expected the same frames in both, the scaled file being the same poses scaled"
    )


def warn_unnormalised(root: Path, unscaled_files: list[Path], positions: np.ndarray) -> None:
    """Poses read from unscaled files with nothing saying how to normalise them.

    A warning: a real RWAVS copy stripped of its ``transforms_scale_*.json`` looks just like
    this; it is read with the identity map, but position.json's source is in the
    normalised frame, so listener and source may well be in different frames."""
    reach = float(np.max(np.abs(positions))) if positions.size else 0.0
    names = ", ".join(p.name for p in unscaled_files)
    warnings.warn(
        f"{root}: poses read from {names} with no transforms_scale_*.json and no scene.json 'to_normalised', "
        f"so they are used unnormalised (|coordinate| up to {reach:.3g}); expected normalised poses, "
        "like position.json's source",
        UserWarning,
        stacklevel=2,
    )


def warn_outside_normalised(files: list[tuple[Path, list, np.ndarray]]) -> None:
    """Normalised listener positions far outside [-1, 1]^3 (one warning, the worst pose).

    ``files``: (file, its entries, their normalised positions [N, 3]). A warning: the frame
    the layout promises is [-1, 1]^3, but a real dataset normalised by other means (its own
    metres, or a subset of the poses) can put poses outside it and still be a recording."""
    worst = None
    for path, entries, positions in files:
        if len(entries) == 0:
            continue
        reach = np.max(np.abs(np.asarray(positions, dtype=np.float64)), axis=-1)  # [N]
        i = int(np.argmax(reach))
        if reach[i] > NORMALISED_EXTENT and (worst is None or reach[i] > worst[0]):
            worst = (float(reach[i]), path, entries[i], np.asarray(positions)[i], int(np.sum(reach > NORMALISED_EXTENT)))
    if worst is None:
        return
    reach, path, entry, position, count = worst
    warnings.warn(
        f"{path}: {entry.field} (frame {entry.frame_number}) puts the listener at "
        f"[{', '.join(f'{v:.3g}' for v in position)}] ({count} pose(s) beyond {NORMALISED_EXTENT:g}); "
        "expected normalised poses within [-1, 1]^3, the frame transforms_scale_*.json are scaled into",
        UserWarning,
        stacklevel=2,
    )


def warn_missing_key_frames(named: list[tuple[Path, object, Path]]) -> None:
    """Some key frames exist and some named ones do not (one warning, the first missing).

    ``named``: (transforms file, entry, the image path it resolves to). A scene without
    any key frame is audio-only data (loaded silently); a partial set means a file_path
    names a frame that was never written. A warning: the audio loader does not need the
    images, and a real copy with a few frames lost still holds its recordings (the view
    loader refuses the scene)."""
    exists = [(path, entry, image, image.is_file()) for path, entry, image in named]
    missing = [m for m in exists if not m[3]]
    if not missing or len(missing) == len(exists):
        return
    path, entry, image, _ = missing[0]
    warnings.warn(
        f"{path}: {entry.field.split('.')[0]}.file_path names {image.name}, which does not exist, while "
        f"{len(exists) - len(missing)} of the {len(exists)} key frames named do ({len(missing)} missing); "
        "expected every named frame in the scene's frames folder",
        UserWarning,
        stacklevel=3,
    )


def check_intrinsics(path: Path, K: list[list[float]], width: int, height: int, entry_fov: tuple[Path, str, float] | None) -> None:
    """The pinhole ``K`` (pixels, at the frame's real ``width`` x ``height``) from ``path``
    (transforms.json) describes a real camera, and agrees with a camera-path entry's
    vertical ``fov`` (degrees) where one is given as ``(file, field, fov)``."""
    fx, fy, cx, cy = K[0][0], K[1][1], K[0][2], K[1][2]
    aspect = max(fx / fy, fy / fx)
    stated = f"fl_x {fx:.4g} and fl_y {fy:.4g} (in pixels of the {width}x{height} frames)"
    # An error beyond 2: no camera has pixels twice as wide as high (an anamorphic lens is the
    # most there is); a warning above 1.1: a real calibration may be off, or the lens anamorphic.
    if aspect > MAX_PIXEL_ASPECT:
        raise ValueError(
            f"{path}: {stated} make pixels {aspect:.3g} times as wide as high; expected square pixels "
            f"(a ratio near 1, at most {MAX_PIXEL_ASPECT:g})"
        )
    if aspect > SQUARE_PIXELS:
        warnings.warn(
            f"{path}: {stated} make pixels {aspect:.3g} times as wide as high; expected square pixels "
            f"(a ratio within {SQUARE_PIXELS:g})",
            UserWarning,
            stacklevel=3,
        )
    # An error: a principal point outside the frame cannot come from a camera that took it.
    if not (0.0 <= cx <= width and 0.0 <= cy <= height):
        raise ValueError(
            f"{path}: principal point cx {cx:.4g}, cy {cy:.4g} (in pixels of the {width}x{height} frames) "
            "lies outside the frame; expected it inside, near the centre"
        )
    if entry_fov is None:
        return
    file, field, fov = entry_fov
    from_k = math.degrees(2 * math.atan(0.5 * height / fy))
    ratio = math.tan(math.radians(fov) / 2) / (0.5 * height / fy)
    # A warning: a camera path's fov may be a nominal viewer setting, not the calibration.
    if max(ratio, 1 / ratio) > FOV_AGREEMENT:
        warnings.warn(
            f"{path}: fl_y {fy:.4g} gives a vertical field of view of {from_k:.3g} degrees, but {file.name} "
            f"{field} says {fov:.3g}; expected the two to describe one camera (within {FOV_AGREEMENT - 1:.0%} in focal length)",
            UserWarning,
            stacklevel=3,
        )
