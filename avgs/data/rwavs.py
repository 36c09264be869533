"""Reader of one scene in the RWAVS layout (the real dataset's, and our generator's).

Layout (docs/design.md, "Data layout (RWAVS)")::

    DATA_ROOT/position.json                {"<scene>": {"source_position": [x, y, z]}}  normalised
    DATA_ROOT/<scene>/binaural_syn_re.wav  2 channels, 22050 Hz
    DATA_ROOT/<scene>/source_syn_re.wav    1 channel, 22050 Hz
    DATA_ROOT/<scene>/frames/00001.png     key frame at t = 1 s
    DATA_ROOT/<scene>/transforms_{train,val}.json        {"camera_path": [{"camera_to_world": [16], "file_path"}]}
    DATA_ROOT/<scene>/transforms_scale_{train,val}.json  the same poses, normalised
    DATA_ROOT/<scene>/scene.json           our generator only (geometry, "to_normalised", ...)

Poses come from the scaled files when present (as AV-NeRF trains), so every position a
clip carries is in the normalised frame. The reader only reads: it never writes into the
scene folder and never unpickles anything (``feats_*.pkl`` is ignored).

The sample for frame ``t`` (file ``00042.png`` -> t = 42 s) is the 1 s clip centred on
``t``: samples ``round((t - 0.5) sr)`` to ``+ sr``, zero-padded past either end of the
recording; a clip with less than 0.5 s of recorded audio is skipped, as is a
camera-path entry without a pose.

Everything read is validated, and an invalid scene is refused with a ValueError (or a
FileNotFoundError for a missing file) whose message names the file and the field, never
loaded silently nor left to crash deeper down: JSON is read as strict UTF-8, at most
:data:`MAX_JSON_BYTES` and :data:`MAX_JSON_DEPTH` levels, with no NaN / Infinity and no key
twice in one object; numbers are JSON numbers (not booleans or strings), finite, and
coordinates within :data:`MAX_COORDINATE`; every pose is a rigid transform
(:func:`avgs.data.frame.rigid_transform_problem`); a split lists each frame once, train and
val share no frame, and ``file_path`` stays inside the scene folder (no ``..``, not
absolute); the scaled and unscaled poses agree through one uniform scale + translation (or,
per split, a rotated copy of that: loaded with a warning, as before), and with
scene.json's ``to_normalised``, ``source`` and ``poses`` where it has them; WAVs have a
sample rate in :data:`MIN_SAMPLE_RATE` .. :data:`MAX_SAMPLE_RATE`, at most
:data:`MAX_AUDIO_SECONDS` of audio and finite samples of magnitude at most
:data:`MAX_SAMPLE_MAGNITUDE`. A path that is a folder, a symbolic-link loop or not a
regular file is refused by name.
"""

from __future__ import annotations

import math
import posixpath
import re
import warnings
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

import numpy as np
import soundfile as sf
import torch

from avgs import dsp
from avgs.config import STFT, STFTConfig
from avgs.data.files import (
    describe_json,
    file_present,
    finite_number,
    is_regular_file,
    json_matrix4,
    json_vector,
    read_json,
    require_file,
)
from avgs.data.frame import (
    RIGID_TOLERANCE,
    SceneFrame,
    frame_from_json,
    rigid_transform_problem,
    signed_direction,
    similarity_fit_residual,
    yaw_from_c2w,
)

BINAURAL_FILE = "binaural_syn_re.wav"
SOURCE_FILE = "source_syn_re.wav"
POSITION_FILE = "position.json"
METADATA_FILE = "scene.json"
SPLITS = ("train", "val")
FIT_TOLERANCE = 1e-3
"RMS residual (normalised units) above which the fitted world <-> normalised map is reported as inexact."

# -- limits of what a valid scene holds (see the module docstring) -------------------------
MIN_SAMPLE_RATE, MAX_SAMPLE_RATE = 8_000, 192_000
"Sample rates (Hz) a WAV may declare at all, checked before the exact rate the model expects."
MAX_AUDIO_SECONDS = 3600.0
"""Longest recording read (1 h; RWAVS scenes are minutes long): 1 h of 2-channel float32 at
22050 Hz is already 635 MB in memory."""
MAX_SAMPLE_MAGNITUDE = 1e3
"""Largest |sample| accepted: audio is read scaled to full scale = 1; beyond this it is
garbage, and spectrogram magnitudes of it could overflow float32."""
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
YAW_TOLERANCE_DEG = 0.1
"How far (degrees) scene.json's ``yaw_deg`` of a pose may be from the transforms file's."


def transforms_path(scene_dir: Path, split: str, scaled: bool) -> Path:
    """``transforms_{split}.json`` or ``transforms_scale_{split}.json`` in ``scene_dir``."""
    return Path(scene_dir) / (f"transforms_scale_{split}.json" if scaled else f"transforms_{split}.json")


def is_scene_dir(path: Path) -> bool:
    """True for a folder holding at least one RWAVS transforms file."""
    path = Path(path)
    return path.is_dir() and any(
        transforms_path(path, split, scaled).is_file() for split in SPLITS for scaled in (True, False)
    )


@dataclass(frozen=True, eq=False)
class AudioClip:
    """One 1 s training or evaluation sample: a listener pose and what it heard."""

    time: float  # s, centre of the clip (the frame number)
    frame_path: Path  # the key frame image (may be absent on disk for audio-only data)
    c2w: np.ndarray  # [4, 4] float64, OpenGL camera-to-world, normalised frame
    listener: np.ndarray  # [3] float64, normalised frame
    yaw: float  # radians, counter-clockwise from +x
    mono: np.ndarray  # [T] float32, the source signal
    binaural: np.ndarray  # [2, T] float32, channel 0 = left ear


@dataclass(frozen=True)
class _PoseEntry:
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


def read_camera_path(path: Path) -> list[_PoseEntry]:
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
    out: list[_PoseEntry] = []
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
        out.append(_PoseEntry(frame_number, file_path, c2w, field))
    return out


def read_wav(path: Path, channels: int, sample_rate: int = STFT.sample_rate) -> np.ndarray:
    """A WAV file as ``[channels, T]`` float32, validated (a sample rate in
    :data:`MIN_SAMPLE_RATE` .. :data:`MAX_SAMPLE_RATE` and equal to ``sample_rate``, the
    channel count, at most :data:`MAX_AUDIO_SECONDS`, finite samples within
    :data:`MAX_SAMPLE_MAGNITUDE`)."""
    path = Path(path)
    require_file(path, f"a {channels}-channel {sample_rate} Hz WAV")
    try:
        info = sf.info(str(path))
    except Exception as exc:  # libsndfile's errors, and whatever a malformed header provokes
        raise ValueError(f"{path}: not a readable audio file ({type(exc).__name__}: {str(exc)[:200]})") from None
    if not MIN_SAMPLE_RATE <= info.samplerate <= MAX_SAMPLE_RATE:
        raise ValueError(
            f"{path}: sample rate {info.samplerate} Hz is outside {MIN_SAMPLE_RATE}..{MAX_SAMPLE_RATE} Hz; "
            f"expected {sample_rate} Hz"
        )
    if info.samplerate != sample_rate:
        raise ValueError(f"{path}: sample rate {info.samplerate} Hz, expected {sample_rate} Hz")
    if info.channels != channels:
        raise ValueError(f"{path}: {info.channels} channel(s), expected {channels}")
    if not 0 <= info.frames <= MAX_AUDIO_SECONDS * info.samplerate:
        raise ValueError(
            f"{path}: declares {info.frames} samples ({info.frames / info.samplerate:.0f} s), more than the "
            f"{MAX_AUDIO_SECONDS:.0f} s a scene's recording may last"
        )
    try:
        data, _ = sf.read(str(path), dtype="float32", always_2d=True)  # [T, C]
    except Exception as exc:
        raise ValueError(f"{path}: not a readable audio file ({type(exc).__name__}: {str(exc)[:200]})") from None
    if data.ndim != 2 or data.shape[1] != channels or data.shape[0] > MAX_AUDIO_SECONDS * sample_rate:
        raise ValueError(f"{path}: read {list(data.shape)} samples x channels, expected at most {MAX_AUDIO_SECONDS:.0f} s of {channels} channel(s)")
    audio = np.ascontiguousarray(data.T)  # [C, T]
    if not np.all(np.isfinite(audio)):
        raise ValueError(f"{path}: holds NaN or Inf samples")
    if audio.size and float(np.max(np.abs(audio))) > MAX_SAMPLE_MAGNITUDE:
        raise ValueError(
            f"{path}: holds samples of magnitude {float(np.max(np.abs(audio))):.3g}; "
            f"audio is expected at full scale 1 (at most {MAX_SAMPLE_MAGNITUDE:g})"
        )
    return audio


def clip_window(time: float, sample_rate: int) -> tuple[int, int]:
    """Sample range ``[start, start + sr)`` of the 1 s clip centred on ``time`` seconds."""
    start = int(round((time - 0.5) * sample_rate))
    return start, start + sample_rate


def slice_padded(audio: np.ndarray, start: int, stop: int) -> np.ndarray:
    """``audio[..., start:stop]`` with zeros where the range leaves the recording (a copy)."""
    out = np.zeros((*audio.shape[:-1], stop - start), dtype=audio.dtype)
    lo, hi = max(start, 0), min(stop, audio.shape[-1])
    if hi > lo:
        out[..., lo - start : hi - start] = audio[..., lo:hi]
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


class RWAVSScene:
    """One scene folder in the RWAVS layout; everything positional is in the normalised frame.

    Attributes: ``name`` (folder name), ``root`` (the folder), ``frame``
    (:class:`SceneFrame`, world <-> normalised), ``source`` ([3] normalised),
    ``train`` / ``val`` (lists of :class:`AudioClip`), ``metadata`` (scene.json as a dict
    or None), ``sample_rate``.

    The frame is, in order of preference: scene.json's ``to_normalised``; a least-squares
    fit of the unscaled to the scaled camera positions when both kinds of transforms file
    exist; the identity.
    """

    def __init__(self, scene_dir: str | Path, stft: STFTConfig = STFT, audio: bool = True):
        """``audio=False``: the poses, frame, source and metadata only, checked as always; no WAV is
        read and ``train`` / ``val`` are empty (for tasks whose targets are other files)."""
        try:
            self.root = Path(scene_dir).resolve()
        except (OSError, RuntimeError, ValueError) as exc:  # a symbolic-link loop, an embedded NUL
            raise ValueError(f"{str(scene_dir)[:200]}: cannot resolve the scene folder ({exc})") from None
        if not self.root.is_dir():
            raise FileNotFoundError(f"{self.root}: scene folder missing")
        self.name = self.root.name
        self.sample_rate = stft.sample_rate
        self._stft = stft
        self.metadata: dict | None = self._read_metadata()
        poses = self._read_poses()  # {(split, scaled): [entries]}
        self._check_splits_disjoint(poses)
        self.frame = self._choose_frame(poses)
        self.source = self._read_source()
        entries = {split: self._split_entries(poses, split) for split in SPLITS}
        self._check_metadata_agrees(entries)
        self.train: list[AudioClip] = []
        self.val: list[AudioClip] = []
        if not audio:
            return
        binaural = read_wav(self.root / BINAURAL_FILE, 2, self.sample_rate)  # [2, L]
        mono = read_wav(self.root / SOURCE_FILE, 1, self.sample_rate)[0]  # [L]
        self.train = self._clips(entries["train"], mono, binaural)
        self.val = self._clips(entries["val"], mono, binaural)

    def __repr__(self) -> str:
        return f"RWAVSScene({self.name!r}: {len(self.train)} train / {len(self.val)} val clips)"

    def clips(self, split: str) -> list[AudioClip]:
        """``train`` or ``val``."""
        if split not in SPLITS:
            raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
        return self.train if split == "train" else self.val

    def dataset(self, split: str, stft: STFTConfig | None = None) -> "ClipDataset":
        """The split's clips as batched tensors with precomputed STFTs."""
        return ClipDataset(self.clips(split), self.source, stft or self._stft)

    # -- reading -----------------------------------------------------------------------

    def _read_metadata(self) -> dict | None:
        return read_scene_metadata(self.root)

    def _read_poses(self) -> dict[tuple[str, bool], list[_PoseEntry]]:
        poses = {}
        for split in SPLITS:
            for scaled in (True, False):
                path = transforms_path(self.root, split, scaled)
                if file_present(path, f"the {split} camera poses"):
                    poses[(split, scaled)] = read_camera_path(path)
            if (split, True) not in poses and (split, False) not in poses:
                raise FileNotFoundError(
                    f"{transforms_path(self.root, split, True)}: missing; expected it or "
                    f"{transforms_path(self.root, split, False).name} with the {split} poses"
                )
        return poses

    def _check_splits_disjoint(self, poses) -> None:
        """A frame (a time) belongs to train or to val, never to both."""
        where: dict[str, dict[int, Path]] = {split: {} for split in SPLITS}
        for (split, scaled), entries in poses.items():
            for e in entries:
                where[split].setdefault(e.frame_number, transforms_path(self.root, split, scaled))
        both = sorted(set(where["train"]) & set(where["val"]))
        if both:
            k = both[0]
            raise ValueError(
                f"{where['val'][k]}: frame {k} is also a train frame ({where['train'][k].name})"
                + (f", as are {len(both) - 1} more" if len(both) > 1 else "")
                + "; the train and val splits must be disjoint"
            )

    def _pose_pairs(self, poses) -> list[tuple[_PoseEntry, _PoseEntry, Path, Path]]:
        """(scaled entry, unscaled entry, scaled file, unscaled file) of every frame posed in both kinds of file."""
        pairs = []
        for split in SPLITS:
            if (split, True) in poses and (split, False) in poses:
                unscaled = {e.frame_number: e for e in poses[(split, False)]}
                for e in poses[(split, True)]:
                    if e.frame_number in unscaled:
                        pairs.append((e, unscaled[e.frame_number], transforms_path(self.root, split, True), transforms_path(self.root, split, False)))
        return pairs

    @staticmethod
    def _tolerance(normalised) -> float:
        n = np.asarray(normalised, dtype=np.float64)
        return POSE_TOLERANCE * max(1.0, float(np.max(np.abs(n))) if n.size else 1.0)

    def _check_pairs(self, pairs, frame: SceneFrame, how: str) -> None:
        """Every scaled pose equals its unscaled pose mapped by ``frame`` (position and rotation)."""
        if not pairs:
            return
        tol = self._tolerance([s.c2w[:3, 3] for s, _, _, _ in pairs])
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

    def _choose_frame(self, poses) -> SceneFrame:
        pairs = self._pose_pairs(poses)
        if self.metadata is not None and "to_normalised" in self.metadata:
            try:
                frame = scene_frame_from_json(self.metadata["to_normalised"])
            except ValueError as exc:
                raise ValueError(f"{self.root / METADATA_FILE}: bad 'to_normalised' ({exc})") from None
            self._check_pairs(pairs, frame, f"{METADATA_FILE}'s to_normalised")
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
            raise ValueError(f"{self.root}: cannot relate transforms_*.json to transforms_scale_*.json: {exc}") from None
        residual = np.linalg.norm(frame.to_normalised(world) - normalised, axis=-1)
        tol = self._tolerance(normalised)
        if float(np.max(residual)) <= tol:
            self._check_pairs(pairs, frame, "the fitted uniform scale + translation")
        else:
            # Not a uniformly scaled and shifted copy. A rotated copy (per split: a normalisation
            # that also turned the scene) loads with a warning, as it always did; anything else is
            # an inconsistent pair of files.
            for split in SPLITS:
                idx = [i for i, (_, _, s_path, _) in enumerate(pairs) if s_path == transforms_path(self.root, split, True)]
                if idx and similarity_fit_residual(world[idx], normalised[idx]) > self._tolerance(normalised[idx]):
                    worst = max(idx, key=lambda i: residual[i])
                    s, u, s_path, u_path = pairs[worst]
                    raise ValueError(
                        f"{s_path}: {s.field} (frame {s.frame_number}) disagrees with {u_path.name} {u.field}: "
                        f"the scaled poses are no uniformly scaled and shifted (or rotated) copy of the unscaled "
                        f"ones (this pose is {residual[worst]:.3g} normalised units off the best fit, tolerance {tol:.3g})"
                    )
        if rms > FIT_TOLERANCE:
            warnings.warn(
                f"{self.root}: the scaled poses are not a uniformly scaled and shifted copy of the "
                f"unscaled ones (RMS residual {rms:.3g}); world coordinates are approximate",
                stacklevel=3,
            )
        return frame

    def _read_source(self) -> np.ndarray:
        path = self.root.parent / POSITION_FILE
        table = read_json(path, '{"<scene>": {"source_position": [x, y, z]}}')
        if not isinstance(table, dict):
            raise ValueError(f'{path}: expected a JSON object {{"<scene>": {{"source_position": [x, y, z]}}}}, got {describe_json(table)}')
        entry = table.get(self.name)
        if entry is None:
            raise ValueError(f"{path}: no entry for scene {self.name!r}")
        if not isinstance(entry, dict) or "source_position" not in entry:
            raise ValueError(f"{path}: {self.name!r} needs 'source_position' as 3 numbers, got {describe_json(entry)}")
        source = json_vector(entry["source_position"], 3, f"{path}: {self.name}.source_position")
        check_coordinates(source, f"{path}: {self.name}.source_position")
        return source

    def _check_metadata_agrees(self, entries) -> None:
        """scene.json's ``source`` and ``poses`` (where it has them) against position.json and the transforms."""
        meta = self.metadata
        if meta is None:
            return
        path = self.root / METADATA_FILE
        has_frame = "to_normalised" in meta
        tol = self._tolerance(np.concatenate([self.source[None]] + [[c[:3, 3] for _, c in v] for v in entries.values() if v]))
        position_file = self.root.parent / POSITION_FILE
        if "source" in meta:
            src = meta["source"]
            if not isinstance(src, dict):
                raise ValueError(f"{path}: source must be an object {{'position', 'normalised'}}, got {describe_json(src)}")
            checks = []
            if "normalised" in src:
                checks.append(("source.normalised", json_vector(src["normalised"], 3, f"{path}: source.normalised")))
            if "position" in src and has_frame:
                world = json_vector(src["position"], 3, f"{path}: source.position")
                check_coordinates(world, f"{path}: source.position")
                checks.append(("source.position (through to_normalised)", self.frame.to_normalised(world)))
            for name, value in checks:
                off = float(np.linalg.norm(value - self.source))
                if not off <= tol:
                    raise ValueError(
                        f"{path}: {name} is {off:.3g} normalised units from {position_file.name}'s source_position "
                        f"of {self.name!r} (tolerance {tol:.3g})"
                    )
        if "poses" in meta and has_frame:
            listed = meta["poses"]
            if not isinstance(listed, list):
                raise ValueError(f"{path}: poses must be a list of {{'frame', 'position', 'yaw_deg'}}, got {describe_json(listed)}")
            loaded = {e.frame_number: (e, c2w, split) for split, v in entries.items() for e, c2w in v}
            for i, p in enumerate(listed):
                where = f"{path}: poses[{i}]"
                if not isinstance(p, dict) or not {"frame", "position", "yaw_deg"} <= p.keys():
                    raise ValueError(f"{where} must be an object {{'frame', 'position', 'yaw_deg'}}, got {describe_json(p)}")
                k = p["frame"]
                if isinstance(k, bool) or not isinstance(k, int):
                    raise ValueError(f"{where}.frame must be an integer frame number, got {describe_json(k)}")
                position = json_vector(p["position"], 3, f"{where}.position")
                check_coordinates(position, f"{where}.position")
                yaw_deg = finite_number(p["yaw_deg"], f"{where}.yaw_deg")
                if k not in loaded:
                    continue  # a pose the transforms files leave out (a subset scene)
                e, c2w, split = loaded[k]
                off = float(np.linalg.norm(self.frame.to_normalised(position) - c2w[:3, 3]))
                turn = abs((yaw_deg - math.degrees(yaw_from_c2w(c2w)) + 180.0) % 360.0 - 180.0)
                if not (off <= tol and turn <= YAW_TOLERANCE_DEG):
                    raise ValueError(
                        f"{where} (frame {k}) disagrees with the {split} transforms' {e.field}: position off by "
                        f"{off:.3g} normalised units (tolerance {tol:.3g}), yaw by {turn:.3g} degrees "
                        f"(tolerance {YAW_TOLERANCE_DEG:g})"
                    )

    def _split_entries(self, poses, split: str) -> list[tuple[_PoseEntry, np.ndarray]]:
        """(entry, normalised c2w) pairs of one split, from the scaled file when present."""
        if (split, True) in poses:
            return [(e, e.c2w) for e in poses[(split, True)]]
        out = [(e, self.frame.pose_to_normalised(e.c2w)) for e in poses[(split, False)]]
        for e, c2w in out:
            check_coordinates(c2w[:3, 3], f"{transforms_path(self.root, split, False)}: {e.field} mapped to the normalised frame")
        return out

    def _frame_path(self, file_path: str) -> Path:
        candidate = self.root / file_path
        if is_regular_file(candidate):
            return candidate
        return self.root / "frames" / Path(file_path.replace("\\", "/")).name

    def _clips(self, entries, mono: np.ndarray, binaural: np.ndarray) -> list[AudioClip]:
        sr = self.sample_rate
        if entries:
            last = max(e.frame_number for e, _ in entries)
            for path, length in ((self.root / BINAURAL_FILE, binaural.shape[-1]), (self.root / SOURCE_FILE, mono.shape[-1])):
                if length < last * sr:
                    raise ValueError(
                        f"{path}: {length / sr:.2f} s of audio is shorter than the last posed frame "
                        f"(t = {last} s); expected at least {last * sr} samples"
                    )
        recorded = min(mono.shape[-1], binaural.shape[-1])
        clips = []
        for entry, c2w in entries:
            start, stop = clip_window(entry.frame_number, sr)
            if min(stop, recorded) - max(start, 0) < sr / 2:
                continue  # less than 0.5 s of real audio
            clips.append(
                AudioClip(
                    time=float(entry.frame_number),
                    frame_path=self._frame_path(entry.file_path),
                    c2w=c2w,
                    listener=c2w[:3, 3].copy(),
                    yaw=yaw_from_c2w(c2w),
                    mono=slice_padded(mono, start, stop),
                    binaural=slice_padded(binaural, start, stop),
                )
            )
        return clips


class ClipDataset(torch.utils.data.Dataset):
    """Clips as tensors, with every STFT computed once.

    Per clip (``__getitem__``) or batched (:meth:`batch`, leading ``B``):
    ``listener [3]``, ``yaw []`` (radians), ``theta []`` (direction to the source,
    positive = left), ``source [3]``, ``mono [T]``, ``binaural [2, T]``,
    ``mono_stft [F, N]`` complex, ``mono_mag [F, N]``, ``binaural_mag [2, F, N]``.
    Positions are normalised; all real tensors float32.
    """

    def __init__(self, clips: list[AudioClip], source, stft: STFTConfig = STFT, chunk: int = 64):
        if not clips:
            raise ValueError("ClipDataset needs at least one clip")
        self.stft_config = stft
        self.source = torch.as_tensor(np.asarray(source), dtype=torch.float32)  # [3]
        self.listener = torch.from_numpy(np.stack([c.listener for c in clips])).float()  # [B, 3]
        self.yaw = torch.tensor([c.yaw for c in clips], dtype=torch.float32)  # [B]
        self.theta = signed_direction(
            torch.from_numpy(np.stack([c.listener for c in clips]).astype(np.float64)),
            torch.tensor([c.yaw for c in clips], dtype=torch.float64),
            torch.as_tensor(np.asarray(source, dtype=np.float64)),
        ).float()  # [B], computed in float64
        self.time = torch.tensor([c.time for c in clips], dtype=torch.float32)  # [B]
        self.mono = torch.from_numpy(np.stack([c.mono for c in clips]))  # [B, T]
        self.binaural = torch.from_numpy(np.stack([c.binaural for c in clips]))  # [B, 2, T]
        with torch.no_grad():
            self.mono_stft = torch.cat(
                [dsp.stft(self.mono[i : i + chunk], stft) for i in range(0, len(clips), chunk)]
            )  # [B, F, N] complex64
            self.binaural_mag = torch.cat(
                [dsp.magnitude(self.binaural[i : i + chunk], stft) for i in range(0, len(clips), chunk)]
            )  # [B, 2, F, N]

    def __len__(self) -> int:
        return int(self.listener.shape[0])

    def __getitem__(self, index: int) -> dict[str, torch.Tensor]:
        return self.batch(index)

    def batch(self, index) -> dict[str, torch.Tensor]:
        """Tensors for one clip (an int) or a batch (a list / tensor of indices)."""
        if isinstance(index, torch.Tensor):
            index = index.long()
        single = isinstance(index, (int, np.integer))
        mono_stft = self.mono_stft[index]
        return {
            "listener": self.listener[index],
            "yaw": self.yaw[index],
            "theta": self.theta[index],
            "source": self.source if single else self.source.expand(len(mono_stft), 3),
            "time": self.time[index],
            "mono": self.mono[index],
            "binaural": self.binaural[index],
            "mono_stft": mono_stft,
            "mono_mag": mono_stft.abs(),
            "binaural_mag": self.binaural_mag[index],
        }
