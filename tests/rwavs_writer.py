"""A small, independent writer of RWAVS-layout scenes, for testing the reader.

Deliberately minimal and separate from ``avgs`` (it imports nothing from it): its own
pose convention code, its own clip timing, its own audio. A scene is a box room with a
fixed source; for frame k (at t = k s) the listener stands still for the second
[k - 0.5, k + 0.5) and hears the source through free-field propagation: 1/r gain, a
distance delay, an interaural time and level difference and a head-shadow low-pass on
the far ear. So the louder ear is the one facing the source, which pins channel order
and the left/right convention end to end.
"""

from __future__ import annotations

import json
import math
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import soundfile as sf
from scipy.signal import lfilter

SR = 22050
SPEED_OF_SOUND = 343.0
HEAD_RADIUS = 0.0875
ROOM = np.array([[0.0, 0.0, 0.0], [6.0, 4.0, 3.0]])  # world bounds, metres
EAR_HEIGHT = 1.6


@dataclass
class Pose:
    frame: int  # frame number = time in seconds
    position: np.ndarray  # [3] world
    yaw: float  # radians, ccw from +x


@dataclass
class WrittenScene:
    data_root: Path
    scene_dir: Path
    name: str
    center: np.ndarray  # [3] world
    scale: float
    source_world: np.ndarray  # [3]
    train: list[Pose]
    val: list[Pose]
    mono: np.ndarray  # [L] as written
    binaural: np.ndarray  # [2, L] as written
    sample_rate: int = SR
    extra: dict = field(default_factory=dict)

    def normalised(self, world) -> np.ndarray:
        return (np.asarray(world, dtype=np.float64) - self.center) * self.scale

    @property
    def source(self) -> np.ndarray:
        return self.normalised(self.source_world)


def opengl_c2w(position, yaw: float) -> np.ndarray:
    """Camera looking along its -Z at ``yaw``, +Y up (world +z), +X to its right."""
    c, s = math.cos(yaw), math.sin(yaw)
    c2w = np.eye(4)
    c2w[:3, 0] = [s, -c, 0.0]  # right of a listener facing (c, s)
    c2w[:3, 1] = [0.0, 0.0, 1.0]  # up
    c2w[:3, 2] = [-c, -s, 0.0]  # back (the camera looks along -Z)
    c2w[:3, 3] = position
    return c2w


def write_png(path: Path, rgb: np.ndarray) -> None:
    """A tiny 8-bit RGB PNG with nothing but zlib."""
    h, w, _ = rgb.shape
    raw = b"".join(b"\x00" + rgb[y].astype(np.uint8).tobytes() for y in range(h))

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")
    path.write_bytes(png)


def source_signal(n: int, rng: np.random.Generator) -> np.ndarray:
    """Speech-like test source: a few drifting tones and noise under a syllable-rate envelope."""
    t = np.arange(n) / SR
    x = 0.3 * rng.standard_normal(n)
    for f0 in rng.uniform(150.0, 3000.0, size=4):
        x += np.sin(2 * np.pi * f0 * t + 3 * np.sin(2 * np.pi * 0.7 * t))
    envelope = 0.55 + 0.45 * np.sin(2 * np.pi * 3.0 * t + rng.uniform(0, 2 * np.pi))
    return x * envelope


def one_pole_lowpass(x: np.ndarray, a: float = 0.85) -> np.ndarray:
    return lfilter([1.0 - a], [1.0, -a], x)


def ear_signals(x: np.ndarray, x_lp: np.ndarray, position, yaw, source, start: int, stop: int) -> np.ndarray:
    """[2, stop - start]: what the left and right ear receive during samples [start, stop)."""
    d = np.asarray(source)[:2] - np.asarray(position)[:2]
    r = float(np.linalg.norm(np.asarray(source) - np.asarray(position)))
    fx, fy = math.cos(yaw), math.sin(yaw)
    sin_left = (fx * d[1] - fy * d[0]) / max(float(np.hypot(*d)), 1e-9)  # +1 source on the left
    out = np.zeros((2, stop - start))
    n = np.arange(start, stop)
    for ch, side in ((0, +1.0), (1, -1.0)):
        facing = side * sin_left  # +1: this ear faces the source
        gain = (1.0 + 0.5 * facing) / max(r, 0.3)
        delay = int(round((r - HEAD_RADIUS * facing) / SPEED_OF_SOUND * SR))
        shadow = max(0.0, -facing)  # the far ear is low-passed
        idx = n - delay
        ok = (idx >= 0) & (idx < len(x))
        out[ch, ok] = gain * ((1 - shadow) * x[idx[ok]] + shadow * x_lp[idx[ok]])
    return out


def write_scene(
    data_root: Path,
    name: str = "office_1",
    *,
    n_train: int = 12,
    n_val: int = 4,
    seed: int = 0,
    first_frame: int = 1,
    tail_s: float = 0.5,
    sample_rate: int = SR,
    scaled: bool = True,
    unscaled: bool = True,
    metadata: dict | None = None,
    poseless_frames: tuple[int, ...] = (),
    unlisted_frames: tuple[int, ...] = (),
    source_world=(4.5, 2.5, 1.2),
    unscaled_as_frames: bool = False,
    poses: list[tuple[float, float, float]] | None = None,
) -> WrittenScene:
    """Write one scene under ``data_root/name`` and (merge) its source into ``data_root/position.json``.

    Frames ``first_frame .. first_frame + n_train + n_val - 1``; every 4th one (from the
    third) is a val frame. ``poses`` optionally fixes (x, y, yaw) per frame in order.
    ``poseless_frames`` are listed without ``camera_to_world``; ``unlisted_frames``
    have an image but no transforms entry. ``metadata`` (a dict) is written as scene.json.
    ``unscaled_as_frames`` writes the unscaled poses in nerfstudio's transforms format
    (``frames`` / nested ``transform_matrix``), as some RWAVS copies have them.
    """
    rng = np.random.default_rng(seed)
    data_root = Path(data_root)
    scene_dir = data_root / name
    (scene_dir / "frames").mkdir(parents=True, exist_ok=True)
    center = ROOM.mean(axis=0)
    scale = 1.0 / float(np.max(ROOM[1] - center))
    source_world = np.asarray(source_world, dtype=np.float64)

    frames = list(range(first_frame, first_frame + n_train + n_val))
    all_poses = []
    for i, k in enumerate(frames):
        if poses is not None:
            x, y, yaw = poses[i]
            pos = np.array([x, y, EAR_HEIGHT])
        else:
            while True:
                pos = np.array([rng.uniform(0.4, 5.6), rng.uniform(0.4, 3.6), EAR_HEIGHT])
                if np.linalg.norm(pos[:2] - source_world[:2]) > 0.8:
                    break
            yaw = float(rng.uniform(-np.pi, np.pi))
        all_poses.append(Pose(k, pos, float(yaw)))
    val_idx = set(range(2, len(frames), 4)) if n_val else set()
    val_idx = set(sorted(val_idx)[:n_val])
    while len(val_idx) < n_val:
        val_idx.add(max(set(range(len(frames))) - val_idx))
    train = [p for i, p in enumerate(all_poses) if i not in val_idx]
    val = [p for i, p in enumerate(all_poses) if i in val_idx]

    # Audio: the listener stands at pose k for samples [round((k - 0.5) sr), +sr).
    length = int(round((frames[-1] + tail_s) * sample_rate))
    x = source_signal(length, rng)
    x_lp = one_pole_lowpass(x)
    binaural = np.zeros((2, length))
    for i, p in enumerate(all_poses):
        start = 0 if i == 0 else int(round((p.frame - 0.5) * sample_rate))
        stop = length if i == len(all_poses) - 1 else int(round((p.frame + 0.5) * sample_rate))
        binaural[:, start:stop] = ear_signals(x, x_lp, p.position, p.yaw, source_world, start, stop)
    mono = (x / np.max(np.abs(x))).astype(np.float32)
    binaural = (binaural / np.max(np.abs(binaural))).astype(np.float32)
    sf.write(scene_dir / "source_syn_re.wav", mono, sample_rate, subtype="FLOAT")
    sf.write(scene_dir / "binaural_syn_re.wav", binaural.T, sample_rate, subtype="FLOAT")

    for p in all_poses:
        write_png(scene_dir / "frames" / f"{p.frame:05d}.png", rng.integers(0, 255, size=(4, 6, 3)))

    def camera_path(split_poses: list[Pose], normalise: bool) -> dict:
        entries = []
        for p in split_poses:
            if p.frame in unlisted_frames:
                continue
            entry = {"file_path": f"frames/{p.frame:05d}.png", "fov": 60.0, "aspect": 1.5}
            if p.frame not in poseless_frames:
                c2w = opengl_c2w(p.position, p.yaw)
                if normalise:
                    c2w[:3, 3] = (c2w[:3, 3] - center) * scale
                entry["camera_to_world"] = [float(v) for v in c2w.reshape(-1)]
            entries.append(entry)
        return {"camera_type": "perspective", "render_height": 4, "render_width": 6, "camera_path": entries}

    for split, split_poses in (("train", train), ("val", val)):
        if unscaled:
            meta = camera_path(split_poses, False)
            if unscaled_as_frames:
                frames_list = [
                    {"file_path": e["file_path"], "transform_matrix": np.reshape(e["camera_to_world"], (4, 4)).tolist()}
                    for e in meta["camera_path"]
                    if "camera_to_world" in e
                ]
                meta = {"fl_x": 5.0, "fl_y": 5.0, "cx": 3.0, "cy": 2.0, "w": 6, "h": 4, "frames": frames_list}
            (scene_dir / f"transforms_{split}.json").write_text(json.dumps(meta))
        if scaled:
            (scene_dir / f"transforms_scale_{split}.json").write_text(json.dumps(camera_path(split_poses, True)))
    if metadata is not None:
        (scene_dir / "scene.json").write_text(json.dumps(metadata))

    position_file = data_root / "position.json"
    table = json.loads(position_file.read_text()) if position_file.is_file() else {}
    src = (source_world - center) * scale if scaled else source_world
    table[name] = {"source_position": [float(v) for v in src]}
    position_file.write_text(json.dumps(table, indent=1))

    return WrittenScene(data_root, scene_dir, name, center, scale, source_world, train, val, mono, binaural, sample_rate)
