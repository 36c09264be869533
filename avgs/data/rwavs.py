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
loaded silently nor left to crash deeper down. The poses are read and checked against each
other by :mod:`avgs.data.pose_files` (shared with the view loader), the files' other
contradictions by :mod:`avgs.data.consistency` and :mod:`avgs.data.recordings` (silent
WAVs refused; a source and binaural track out of sync, or named key frames missing while
others exist, warned). JSON is read as strict UTF-8, at most
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
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import soundfile as sf
import torch

from avgs import dsp
from avgs.config import STFT, STFTConfig
from avgs.data.consistency import warn_missing_key_frames
from avgs.data.files import describe_json, finite_number, is_regular_file, json_vector, read_json, require_file
from avgs.data.frame import SceneFrame, signed_direction, yaw_from_c2w
from avgs.data.pose_files import (  # re-exported: the readers of other layouts take them from here
    FIT_TOLERANCE,
    MAX_COORDINATE,
    MAX_FRAME_NUMBER,
    MAX_SCALE,
    METADATA_FILE,
    MIN_SCALE,
    POSE_TOLERANCE,
    SPLITS,
    PoseEntry,
    check_coordinates,
    frame_number_of,
    is_scene_dir,
    pose_tolerance,
    read_camera_path,
    read_scene_metadata,
    read_scene_poses,
    scene_frame_from_json,
    transforms_path,
)
from avgs.data.recordings import check_not_silent, warn_if_out_of_sync


BINAURAL_FILE = "binaural_syn_re.wav"
SOURCE_FILE = "source_syn_re.wav"
POSITION_FILE = "position.json"

# -- limits of what a valid scene holds (see the module docstring) -------------------------
MIN_SAMPLE_RATE, MAX_SAMPLE_RATE = 8_000, 192_000
"Sample rates (Hz) a WAV may declare at all, checked before the exact rate the model expects."
MAX_AUDIO_SECONDS = 3600.0
"""Longest recording read (1 h; RWAVS scenes are minutes long): 1 h of 2-channel float32 at
22050 Hz is already 635 MB in memory."""
MAX_SAMPLE_MAGNITUDE = 1e3
"""Largest |sample| accepted: audio is read scaled to full scale = 1; beyond this it is
garbage, and spectrogram magnitudes of it could overflow float32."""
YAW_TOLERANCE_DEG = 0.1
"How far (degrees) scene.json's ``yaw_deg`` of a pose may be from the transforms file's."



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
        poses = read_scene_poses(self.root, self.metadata)
        self.frame = poses.frame
        self.source = self._read_source()
        entries = poses.entries
        self._check_metadata_agrees(entries)
        warn_missing_key_frames([(poses.files[s], e, self._frame_path(e.file_path)) for s in SPLITS for e, _ in entries[s]])
        self.train: list[AudioClip] = []
        self.val: list[AudioClip] = []
        if not audio:
            return
        binaural = read_wav(self.root / BINAURAL_FILE, 2, self.sample_rate)  # [2, L]
        check_not_silent(self.root / BINAURAL_FILE, binaural)
        mono = read_wav(self.root / SOURCE_FILE, 1, self.sample_rate)  # [1, L]
        check_not_silent(self.root / SOURCE_FILE, mono)
        mono = mono[0]  # [L]
        self.train = self._clips(entries["train"], mono, binaural)
        self.val = self._clips(entries["val"], mono, binaural)
        warn_if_out_of_sync(self.root / BINAURAL_FILE, self.root / SOURCE_FILE, mono, binaural, self.sample_rate)

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
        tol = pose_tolerance(np.concatenate([self.source[None]] + [[c[:3, 3] for _, c in v] for v in entries.values() if v]))
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
