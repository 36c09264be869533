"""Reader of one scene in the RWAVS layout (the real dataset's, and our generator's).

Layout (DESIGN.md §2)::

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
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import soundfile as sf
import torch

from avgs import dsp
from avgs.config import STFT, STFTConfig
from avgs.data.frame import SceneFrame, signed_direction, yaw_from_c2w

BINAURAL_FILE = "binaural_syn_re.wav"
SOURCE_FILE = "source_syn_re.wav"
POSITION_FILE = "position.json"
METADATA_FILE = "scene.json"
SPLITS = ("train", "val")
FIT_TOLERANCE = 1e-3
"RMS residual (normalised units) above which the fitted world <-> normalised map is reported as inexact."


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


def _read_json(path: Path, what: str):
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: missing; expected {what}") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc}); expected {what}") from None


def read_camera_path(path: Path) -> list[_PoseEntry]:
    """Posed entries of one transforms file, in file order (entries without a pose are skipped).

    Reads nerfstudio's camera-path format (``{"camera_path": [{"camera_to_world": [16],
    "file_path"}]}``, RWAVS's) and, as some RWAVS copies store the unscaled poses that
    way, its transforms format (``{"frames": [{"transform_matrix": [[4] x 4], "file_path"}]}``).
    """
    meta = _read_json(path, 'a camera path {"camera_path": [{"camera_to_world", "file_path"}, ...]}')
    if isinstance(meta, dict) and isinstance(meta.get("camera_path"), list):
        key, pose_key = "camera_path", "camera_to_world"
    elif isinstance(meta, dict) and isinstance(meta.get("frames"), list):
        key, pose_key = "frames", "transform_matrix"
    else:
        raise ValueError(f"{path}: expected a 'camera_path' (or nerfstudio 'frames') list of poses")
    out: list[_PoseEntry] = []
    for i, entry in enumerate(meta[key]):
        if not isinstance(entry, dict) or "file_path" not in entry:
            raise ValueError(f"{path}: {key}[{i}] has no 'file_path'")
        file_path = str(entry["file_path"])
        stem = Path(file_path.replace("\\", "/")).stem
        try:
            frame_number = int(stem)
        except ValueError:
            raise ValueError(
                f"{path}: {key}[{i}] file_path {file_path!r} is not a numbered frame like '00042.png'"
            ) from None
        pose = entry.get(pose_key)
        if pose is None:
            continue  # a frame without a pose: skipped, as in RWAVS
        try:
            c2w = np.asarray(pose, dtype=np.float64).reshape(4, 4)
        except (ValueError, TypeError):
            raise ValueError(
                f"{path}: {key}[{i}] ({file_path}) {pose_key} must be 16 numbers (row-major 4x4)"
            ) from None
        if not np.all(np.isfinite(c2w)):
            raise ValueError(f"{path}: {key}[{i}] ({file_path}) {pose_key} holds NaN or Inf")
        out.append(_PoseEntry(frame_number, file_path, c2w))
    return out


def read_wav(path: Path, channels: int, sample_rate: int = STFT.sample_rate) -> np.ndarray:
    """A WAV file as ``[channels, T]`` float32, validated (sample rate, channel count, finite)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: missing; expected a {channels}-channel {sample_rate} Hz WAV")
    try:
        info = sf.info(str(path))
    except RuntimeError as exc:
        raise ValueError(f"{path}: not a readable audio file ({exc})") from None
    if info.samplerate != sample_rate:
        raise ValueError(f"{path}: sample rate {info.samplerate} Hz, expected {sample_rate} Hz")
    if info.channels != channels:
        raise ValueError(f"{path}: {info.channels} channel(s), expected {channels}")
    data, _ = sf.read(str(path), dtype="float32", always_2d=True)  # [T, C]
    audio = np.ascontiguousarray(data.T)  # [C, T]
    if not np.all(np.isfinite(audio)):
        raise ValueError(f"{path}: holds NaN or Inf samples")
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
    if not path.is_file():
        return None
    meta = _read_json(path, "the scene description written by avgs synth")
    if not isinstance(meta, dict):
        raise ValueError(f"{path}: expected a JSON object")
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

    def __init__(self, scene_dir: str | Path, stft: STFTConfig = STFT):
        self.root = Path(scene_dir).resolve()
        if not self.root.is_dir():
            raise FileNotFoundError(f"{self.root}: scene folder missing")
        self.name = self.root.name
        self.sample_rate = stft.sample_rate
        self._stft = stft
        self.metadata: dict | None = self._read_metadata()
        poses = self._read_poses()  # {(split, scaled): [entries]}
        self.frame = self._choose_frame(poses)
        self.source = self._read_source()
        binaural = read_wav(self.root / BINAURAL_FILE, 2, self.sample_rate)  # [2, L]
        mono = read_wav(self.root / SOURCE_FILE, 1, self.sample_rate)[0]  # [L]
        self.train = self._clips(self._split_entries(poses, "train"), mono, binaural)
        self.val = self._clips(self._split_entries(poses, "val"), mono, binaural)

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
                if path.is_file():
                    poses[(split, scaled)] = read_camera_path(path)
            if (split, True) not in poses and (split, False) not in poses:
                raise FileNotFoundError(
                    f"{transforms_path(self.root, split, True)}: missing; expected it or "
                    f"{transforms_path(self.root, split, False).name} with the {split} poses"
                )
        return poses

    def _choose_frame(self, poses) -> SceneFrame:
        if self.metadata is not None and "to_normalised" in self.metadata:
            try:
                return SceneFrame.from_dict(self.metadata["to_normalised"])
            except ValueError as exc:
                raise ValueError(f"{self.root / METADATA_FILE}: bad 'to_normalised' ({exc})") from None
        world, normalised = [], []
        for split in SPLITS:
            if (split, True) in poses and (split, False) in poses:
                scaled = {e.frame_number: e.c2w[:3, 3] for e in poses[(split, True)]}
                for e in poses[(split, False)]:
                    if e.frame_number in scaled:
                        world.append(e.c2w[:3, 3])
                        normalised.append(scaled[e.frame_number])
        if not world:
            return SceneFrame.identity()
        try:
            frame, rms = SceneFrame.fit(np.array(world), np.array(normalised))
        except ValueError as exc:
            raise ValueError(f"{self.root}: cannot relate transforms_*.json to transforms_scale_*.json: {exc}") from None
        if rms > FIT_TOLERANCE:
            warnings.warn(
                f"{self.root}: the scaled poses are not a uniformly scaled and shifted copy of the "
                f"unscaled ones (RMS residual {rms:.3g}); world coordinates are approximate",
                stacklevel=3,
            )
        return frame

    def _read_source(self) -> np.ndarray:
        path = self.root.parent / POSITION_FILE
        table = _read_json(path, '{"<scene>": {"source_position": [x, y, z]}}')
        entry = table.get(self.name) if isinstance(table, dict) else None
        if entry is None:
            raise ValueError(f"{path}: no entry for scene {self.name!r}")
        try:
            source = np.asarray(entry["source_position"], dtype=np.float64).reshape(3)
        except (KeyError, TypeError, ValueError):
            raise ValueError(f"{path}: {self.name!r} needs 'source_position' as 3 numbers") from None
        if not np.all(np.isfinite(source)):
            raise ValueError(f"{path}: source_position of {self.name!r} holds NaN or Inf")
        return source

    def _split_entries(self, poses, split: str) -> list[tuple[_PoseEntry, np.ndarray]]:
        """(entry, normalised c2w) pairs of one split, from the scaled file when present."""
        if (split, True) in poses:
            return [(e, e.c2w) for e in poses[(split, True)]]
        return [(e, self.frame.pose_to_normalised(e.c2w)) for e in poses[(split, False)]]

    def _frame_path(self, file_path: str) -> Path:
        candidate = self.root / file_path
        if candidate.is_file():
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
