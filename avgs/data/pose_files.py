"""The camera poses of a scene in the RWAVS layout: every ``transforms_*.json`` read,
validated and checked against the others, and the world <-> normalised frame they imply
(docs/design.md, "Data layout (RWAVS)", "Coordinates and poses").

Both loaders read poses through :func:`read_scene_poses`: the audio clips
(:mod:`avgs.data.rwavs`) and the camera views (:mod:`avgs.data.views`), so a scene one
accepts the other does not refuse for its poses.

Checked, with a ValueError (or FileNotFoundError for a missing file) naming the file and
the field: each entry's ``file_path`` a numbered frame inside the scene folder, listed once
per split; each pose 16 finite numbers forming a rigid transform, coordinates within
:data:`MAX_COORDINATE`; train and val share no frame; the scaled and unscaled files of a
split pose the same frames, related by one uniform scale + translation (or, per split, a
rotated copy of that: loaded with a warning), and by scene.json's ``to_normalised`` where
it has one. Warned (:mod:`avgs.data.consistency`): poses used unnormalised because nothing
says how to normalise them, and normalised poses far outside [-1, 1]^3.
"""

from __future__ import annotations

import posixpath
import re
import warnings
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

import numpy as np

from avgs.data.consistency import check_same_frames, warn_outside_normalised, warn_unnormalised
from avgs.data.files import describe_json, file_present, json_matrix4, read_json
from avgs.data.frame import (
    RIGID_TOLERANCE,
    SceneFrame,
    frame_from_json,
    rigid_transform_problem,
    similarity_fit_residual,
)


METADATA_FILE = "scene.json"
SPLITS = ("train", "val")
FIT_TOLERANCE = 1e-3
"RMS residual (normalised units) above which the fitted world <-> normalised map is reported as inexact."
MAX_COORDINATE = 1e6
"""Largest |coordinate| of a pose or source, read and normalised (1000 km in metres; the
model computes in float32)."""
MIN_SCALE, MAX_SCALE = 1e-6, 1e6
"""Range of a world -> normalised ``scale`` accepted (a scene of half-extent 1 um .. 1000 km
mapped into [-1, 1]); with :data:`MAX_COORDINATE` it keeps every mapped coordinate finite."""
MAX_FRAME_NUMBER = 10**6
"Largest frame number (= time in seconds) a file_path may carry."
POSE_TOLERANCE = 1e-3
"""How far (normalised units, times max(1, the largest |normalised coordinate|)) two files'
positions of one frame may disagree: float rounding is ~1e-7 and 6-decimal copies ~1e-6."""


def transforms_path(scene_dir: Path, split: str, scaled: bool) -> Path:
    """``transforms_{split}.json`` or ``transforms_scale_{split}.json`` in ``scene_dir``."""
    return Path(scene_dir) / (f"transforms_scale_{split}.json" if scaled else f"transforms_{split}.json")


def is_scene_dir(path: Path) -> bool:
    """True for a folder holding at least one RWAVS transforms file."""
    path = Path(path)
    return path.is_dir() and any(
        transforms_path(path, split, scaled).is_file() for split in SPLITS for scaled in (True, False)
    )



@dataclass(frozen=True)
class PoseEntry:
    """One posed camera-path entry of a transforms file."""

    frame_number: int
    file_path: str
    c2w: np.ndarray  # [4, 4] in the frame of the file it was read from
    field: str = ""  # where in its file, e.g. "camera_path[3].camera_to_world"



# -- validated reading: files, JSON, numbers -------------------------------------------------


def check_coordinates(points, where: str) -> None:
    """ValueError unless every coordinate in ``points`` is finite and within :data:`MAX_COORDINATE`."""
    p = np.asarray(points, dtype=np.float64)
    if not np.all(np.isfinite(p)) or (p.size and float(np.max(np.abs(p))) > MAX_COORDINATE):
        worst = float(np.max(np.abs(np.nan_to_num(p, nan=np.inf)))) if p.size else 0.0
        raise ValueError(f"{where}: coordinate of magnitude {worst:.3g}, beyond the {MAX_COORDINATE:g} a scene may span")


def scene_frame_from_json(value) -> SceneFrame:
    """:func:`avgs.data.frame.frame_from_json` with the center within :data:`MAX_COORDINATE`
    and the scale within :data:`MIN_SCALE` .. :data:`MAX_SCALE` (ValueError naming the field)."""
    frame = frame_from_json(value)
    if float(np.max(np.abs(frame.center))) > MAX_COORDINATE:
        raise ValueError(f"'center' {[float(v) for v in frame.center]} is beyond the {MAX_COORDINATE:g} a scene may span")
    if not MIN_SCALE <= frame.scale <= MAX_SCALE:
        raise ValueError(f"'scale' {frame.scale:g} is outside {MIN_SCALE:g}..{MAX_SCALE:g}")
    return frame


_FRAME_STEM = re.compile(r"[0-9]{1,12}")
_DRIVE = re.compile(r"[A-Za-z]:")


def frame_number_of(file_path, where: str) -> int:
    """The frame number of a ``file_path`` like ``frames/00042.png`` (42); ValueError naming
    ``where`` when it is no string, no numbered frame, or leaves the scene folder."""
    if not isinstance(file_path, str):
        raise ValueError(f"{where} file_path must be a string like 'frames/00042.png', got {describe_json(file_path)}")
    shown = file_path if len(file_path) <= 80 else file_path[:80] + "..."
    name = file_path.replace("\\", "/")
    stem = PurePosixPath(name).stem if "\x00" not in name else ""
    if not _FRAME_STEM.fullmatch(stem) or int(stem) > MAX_FRAME_NUMBER:
        raise ValueError(f"{where} file_path {shown!r} is not a numbered frame like '00042.png'")
    norm = posixpath.normpath(name)
    if name.startswith("/") or _DRIVE.match(name) or norm == ".." or norm.startswith("../"):
        raise ValueError(
            f"{where} file_path {shown!r} leaves the scene folder; paths must stay inside it (relative, no '..' out of it)"
        )
    return int(stem)


def read_camera_path(path: Path) -> list[PoseEntry]:
    """Posed entries of one transforms file, in file order (entries without a pose are skipped).

    Reads nerfstudio's camera-path format (``{"camera_path": [{"camera_to_world": [16],
    "file_path"}]}``, RWAVS's) and, as some RWAVS copies store the unscaled poses that
    way, its transforms format (``{"frames": [{"transform_matrix": [[4] x 4], "file_path"}]}``).
    Validated: each entry's ``file_path`` a numbered frame inside the scene folder, listed
    once; each pose 16 finite numbers forming a rigid transform, coordinates within
    :data:`MAX_COORDINATE`.
    """
    path = Path(path)
    meta = read_json(path, 'a camera path {"camera_path": [{"camera_to_world", "file_path"}, ...]}')
    if isinstance(meta, dict) and isinstance(meta.get("camera_path"), list):
        key, pose_key = "camera_path", "camera_to_world"
    elif isinstance(meta, dict) and isinstance(meta.get("frames"), list):
        key, pose_key = "frames", "transform_matrix"
    else:
        raise ValueError(f"{path}: expected a 'camera_path' (or nerfstudio 'frames') list of poses")
    out: list[PoseEntry] = []
    seen: dict[int, int] = {}
    for i, entry in enumerate(meta[key]):
        if not isinstance(entry, dict) or "file_path" not in entry:
            raise ValueError(f"{path}: {key}[{i}] has no 'file_path'")
        frame_number = frame_number_of(entry["file_path"], f"{path}: {key}[{i}]")
        file_path = entry["file_path"]
        if frame_number in seen:
            raise ValueError(
                f"{path}: {key}[{i}].file_path {file_path[:80]!r} is frame {frame_number} again "
                f"(already {key}[{seen[frame_number]}]); a split lists each frame once"
            )
        seen[frame_number] = i
        pose = entry.get(pose_key)
        if pose is None:
            continue  # a frame without a pose: skipped, as in RWAVS
        field = f"{key}[{i}].{pose_key}"
        c2w = json_matrix4(pose, f"{path}: {field}")
        problem = rigid_transform_problem(c2w, RIGID_TOLERANCE)
        if problem is not None:
            raise ValueError(f"{path}: {field} is not a rigid transform ({problem})")
        check_coordinates(c2w[:3, 3], f"{path}: {field}")
        out.append(PoseEntry(frame_number, file_path, c2w, field))
    return out



def read_scene_metadata(scene_dir: str | Path) -> dict | None:
    """``scene.json`` of a scene folder as a dict (our generator's), or None (real RWAVS scenes)."""
    path = Path(scene_dir) / METADATA_FILE
    what = "the scene description written by avgs synth"
    if not file_present(path, what):
        return None
    meta = read_json(path, what)
    if not isinstance(meta, dict):
        raise ValueError(f"{path}: expected a JSON object")
    if "to_normalised" in meta:
        try:
            scene_frame_from_json(meta["to_normalised"])
        except ValueError as exc:
            raise ValueError(f"{path}: bad 'to_normalised' ({exc})") from None
    return meta


# -- a scene's pose files, against each other ---------------------------------------------


def _read_poses(root: Path, every_split: bool) -> dict[tuple[str, bool], list[PoseEntry]]:
    poses = {}
    for split in SPLITS:
        for scaled in (True, False):
            path = transforms_path(root, split, scaled)
            if file_present(path, f"the {split} camera poses"):
                poses[(split, scaled)] = read_camera_path(path)
        if every_split and (split, True) not in poses and (split, False) not in poses:
            raise FileNotFoundError(
                f"{transforms_path(root, split, True)}: missing; expected it or "
                f"{transforms_path(root, split, False).name} with the {split} poses"
            )
    return poses


def _check_splits_disjoint(root: Path, poses) -> None:
    """A frame (a time) belongs to train or to val, never to both. An error: one second of one
    recording cannot be held out and trained on, and the layout's split is disjoint."""
    where: dict[str, dict[int, Path]] = {split: {} for split in SPLITS}
    for (split, scaled), entries in poses.items():
        for e in entries:
            where[split].setdefault(e.frame_number, transforms_path(root, split, scaled))
    both = sorted(set(where["train"]) & set(where["val"]))
    if both:
        k = both[0]
        raise ValueError(
            f"{where['val'][k]}: frame {k} is also a train frame ({where['train'][k].name})"
            + (f", as are {len(both) - 1} more" if len(both) > 1 else "")
            + "; the train and val splits must be disjoint"
        )


def _pose_pairs(root: Path, poses) -> list[tuple[PoseEntry, PoseEntry, Path, Path]]:
    """(scaled entry, unscaled entry, scaled file, unscaled file) of every frame posed in both kinds of file."""
    pairs = []
    for split in SPLITS:
        if (split, True) in poses and (split, False) in poses:
            unscaled = {e.frame_number: e for e in poses[(split, False)]}
            for e in poses[(split, True)]:
                if e.frame_number in unscaled:
                    pairs.append((e, unscaled[e.frame_number], transforms_path(root, split, True), transforms_path(root, split, False)))
    return pairs


def pose_tolerance(normalised) -> float:
    """How far two positions of one pose may be apart: :data:`POSE_TOLERANCE` x max(1, the largest |coordinate|)."""
    n = np.asarray(normalised, dtype=np.float64)
    return POSE_TOLERANCE * max(1.0, float(np.max(np.abs(n))) if n.size else 1.0)


def _check_pairs(pairs, frame: SceneFrame, how: str) -> None:
    """Every scaled pose equals its unscaled pose mapped by ``frame`` (position and rotation).
    An error: the layout's scaled file is the same poses, scaled; a real recording has one pose per frame."""
    if not pairs:
        return
    tol = pose_tolerance([s.c2w[:3, 3] for s, _, _, _ in pairs])
    for s, u, s_path, u_path in pairs:
        expected = frame.pose_to_normalised(u.c2w)
        off = float(np.linalg.norm(expected[:3, 3] - s.c2w[:3, 3]))
        turn = float(np.max(np.abs(expected[:3, :3] - s.c2w[:3, :3])))
        if not (off <= tol and turn <= RIGID_TOLERANCE):
            raise ValueError(
                f"{s_path}: {s.field} (frame {s.frame_number}) disagrees with {u_path.name} {u.field} "
                f"through {how}: position off by {off:.3g} normalised units (tolerance {tol:.3g}), "
                f"rotation by {turn:.3g} (tolerance {RIGID_TOLERANCE:g})"
            )


def _choose_frame(root: Path, poses, metadata: dict | None) -> SceneFrame:
    pairs = _pose_pairs(root, poses)
    if metadata is not None and "to_normalised" in metadata:
        try:
            frame = scene_frame_from_json(metadata["to_normalised"])
        except ValueError as exc:
            raise ValueError(f"{root / METADATA_FILE}: bad 'to_normalised' ({exc})") from None
        _check_pairs(pairs, frame, f"{METADATA_FILE}'s to_normalised")
        return frame
    if not pairs:
        return SceneFrame.identity()
    world = np.array([u.c2w[:3, 3] for _, u, _, _ in pairs])
    normalised = np.array([s.c2w[:3, 3] for s, _, _, _ in pairs])
    try:
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            frame, rms = SceneFrame.fit(world, normalised)
        if not MIN_SCALE <= frame.scale <= MAX_SCALE:
            raise ValueError(f"fitted scale {frame.scale:.3g} is outside {MIN_SCALE:g}..{MAX_SCALE:g}")
        if float(np.max(np.abs(frame.center))) > MAX_COORDINATE:
            raise ValueError(f"fitted center {[float(v) for v in frame.center]} is beyond {MAX_COORDINATE:g}")
    except ValueError as exc:
        raise ValueError(f"{root}: cannot relate transforms_*.json to transforms_scale_*.json: {exc}") from None
    residual = np.linalg.norm(frame.to_normalised(world) - normalised, axis=-1)
    tol = pose_tolerance(normalised)
    if float(np.max(residual)) <= tol:
        _check_pairs(pairs, frame, "the fitted uniform scale + translation")
    else:
        # Not a uniformly scaled and shifted copy. A rotated copy (per split: a normalisation
        # that also turned the scene) loads with a warning, as it always did; anything else is
        # an inconsistent pair of files.
        for split in SPLITS:
            idx = [i for i, (_, _, s_path, _) in enumerate(pairs) if s_path == transforms_path(root, split, True)]
            if idx and similarity_fit_residual(world[idx], normalised[idx]) > pose_tolerance(normalised[idx]):
                worst = max(idx, key=lambda i: residual[i])
                s, u, s_path, u_path = pairs[worst]
                raise ValueError(
                    f"{s_path}: {s.field} (frame {s.frame_number}) disagrees with {u_path.name} {u.field}: "
                    f"the scaled poses are no uniformly scaled and shifted (or rotated) copy of the unscaled "
                    f"ones (this pose is {residual[worst]:.3g} normalised units off the best fit, tolerance {tol:.3g})"
                )
    if rms > FIT_TOLERANCE:
        warnings.warn(
            f"{root}: the scaled poses are not a uniformly scaled and shifted copy of the "
            f"unscaled ones (RMS residual {rms:.3g}); world coordinates are approximate",
            stacklevel=4,
        )
    return frame


def _split_entries(root: Path, poses, frame: SceneFrame, split: str) -> list[tuple[PoseEntry, np.ndarray]]:
    """(entry, normalised c2w) pairs of one split, from the scaled file when present."""
    if (split, True) in poses:
        return [(e, e.c2w) for e in poses[(split, True)]]
    out = [(e, frame.pose_to_normalised(e.c2w)) for e in poses[(split, False)]]
    for e, c2w in out:
        check_coordinates(c2w[:3, 3], f"{transforms_path(root, split, False)}: {e.field} mapped to the normalised frame")
    return out


@dataclass(frozen=True, eq=False)
class ScenePoses:
    """Every transforms file of a scene, read and checked against the others."""

    frame: SceneFrame  # world <-> normalised
    entries: dict[str, list[tuple[PoseEntry, np.ndarray]]]  # split -> (entry, normalised c2w [4, 4]); splits found
    files: dict[str, Path]  # split -> the file its entries come from
    frame_stated: bool  # False when nothing gave a normalisation and the identity was assumed


def read_scene_poses(root: Path, metadata: dict | None, every_split: bool = True) -> ScenePoses:
    """The poses of both splits of the scene folder ``root`` (only those present when not
    ``every_split``), in the normalised frame, from the scaled files when present.
    ``metadata``: its scene.json (:func:`read_scene_metadata`) or None."""
    root = Path(root)
    poses = _read_poses(root, every_split)  # {(split, scaled): [entries]}
    _check_splits_disjoint(root, poses)
    for split in SPLITS:
        if (split, True) in poses and (split, False) in poses:
            check_same_frames(transforms_path(root, split, True), poses[(split, True)], transforms_path(root, split, False), poses[(split, False)])
    frame = _choose_frame(root, poses, metadata)
    found = [split for split in SPLITS if (split, True) in poses or (split, False) in poses]
    entries = {split: _split_entries(root, poses, frame, split) for split in found}
    files = {split: transforms_path(root, split, (split, True) in poses) for split in found}
    stated = (metadata is not None and "to_normalised" in metadata) or bool(_pose_pairs(root, poses))
    unscaled = [files[split] for split in found if (split, True) not in poses]
    if unscaled and not stated:
        positions = np.array([c[:3, 3] for split in found for _, c in entries[split]]).reshape(-1, 3)
        warn_unnormalised(root, unscaled, positions)
    else:
        warn_outside_normalised([(files[s], [e for e, _ in entries[s]], np.array([c[:3, 3] for _, c in entries[s]]).reshape(-1, 3)) for s in found])
    return ScenePoses(frame, entries, files, stated)
