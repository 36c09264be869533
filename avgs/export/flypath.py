"""A listener path: keyframes in a small JSON file, and the pose at any time between them.

The file is a JSON list of keyframes, ``t`` strictly increasing from 0::

    [
      {"t": 0.0, "listener": [1.0, 2.0, 1.5], "yaw": 90.0, "source": [3.0, 3.0, 1.5]},
      {"t": 2.5, "listener": [4.0, 2.0, 1.5], "yaw": 45.0}
    ]

``t`` seconds, ``listener`` world coordinates, ``yaw`` degrees counter-clockwise from +x;
``source`` (world) is optional: a keyframe without one keeps the previous keyframe's (the
first's default: the checkpoint's trained source). Between keyframes positions move in a
straight line and the yaw turns the shorter way round, both linearly in time; the path ends
at the last keyframe's ``t``. The explorer records such a file from a drag (File > Record path).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from avgs.io import atomic


@dataclass(frozen=True)
class Keyframe:
    t: float  # seconds from the path's start
    listener: tuple[float, float, float]  # world
    yaw: float  # degrees ccw from +x
    source: tuple[float, float, float] | None = None  # world; None: the previous keyframe's (or the trained one)

    def as_dict(self) -> dict:
        d = {"t": self.t, "listener": list(self.listener), "yaw": self.yaw}
        if self.source is not None:
            d["source"] = list(self.source)
        return d


@dataclass(frozen=True)
class PathPose:
    """The pose at one time of a path (world, degrees; ``source`` None: the trained one)."""

    listener: np.ndarray  # [3]
    yaw: float
    source: np.ndarray | None  # [3]


def _vec3(value, where: str) -> tuple[float, float, float]:
    try:
        v = [float(x) for x in value]
    except (TypeError, ValueError):
        v = []
    if len(v) != 3 or not all(math.isfinite(x) for x in v):
        raise ValueError(f"{where} must be 3 finite numbers [x, y, z], got {value!r}")
    return (v[0], v[1], v[2])


def _number(value, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{where} must be a finite number, got {value!r}")
    return float(value)


def check_keyframes(items, where: str = "path") -> list[Keyframe]:
    """Keyframes from plain data (a list of dicts) or :class:`Keyframe` s; one ValueError naming ``where``,
    the keyframe and what was expected otherwise."""
    if not isinstance(items, (list, tuple)) or len(items) < 2:
        raise ValueError(f"{where}: expected a list of at least 2 keyframes "
                         '[{"t": seconds, "listener": [x, y, z], "yaw": degrees}, ...]')
    frames: list[Keyframe] = []
    for i, item in enumerate(items):
        at = f"{where}: keyframe {i}"
        if isinstance(item, Keyframe):
            item = item.as_dict()
        if not isinstance(item, dict) or not {"t", "listener", "yaw"} <= set(item):
            raise ValueError(f'{at}: expected {{"t": seconds, "listener": [x, y, z], "yaw": degrees}}, got {item!r}')
        unknown = set(item) - {"t", "listener", "yaw", "source"}
        if unknown:
            raise ValueError(f"{at}: unknown keys {sorted(unknown)} (expected t, listener, yaw, source)")
        t = _number(item["t"], f"{at}: t")
        if (not frames and t != 0.0) or (frames and t <= frames[-1].t):
            raise ValueError(f"{at}: t must start at 0 and increase strictly, got {t:g}"
                             + (f" after {frames[-1].t:g}" if frames else ""))
        source = item.get("source")
        frames.append(Keyframe(t, _vec3(item["listener"], f"{at}: listener"), _number(item["yaw"], f"{at}: yaw"),
                               None if source is None else _vec3(source, f"{at}: source")))
    return frames


def read_path(path: str | Path) -> list[Keyframe]:
    """The keyframes of a path file (format: the module's docstring)."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not JSON ({exc.msg} at line {exc.lineno})") from None
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a text file") from None
    return check_keyframes(data, str(path))


def write_path(path: str | Path, keyframes, inputs=()) -> Path:
    """Keyframes as a path file (atomically; never over one of ``inputs``)."""
    frames = check_keyframes(list(keyframes), str(path))
    atomic.check_output(path, inputs=inputs, what="path file")
    return atomic.write_json(path, [k.as_dict() for k in frames])


def duration(keyframes: list[Keyframe]) -> float:
    return keyframes[-1].t


def pose_at(keyframes: list[Keyframe], t: float) -> PathPose:
    """The pose at time ``t`` (clamped to the path): linear between keyframes, the yaw the shorter way."""
    times = np.array([k.t for k in keyframes])
    t = float(np.clip(t, 0.0, times[-1]))
    i = int(np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(keyframes) - 2))
    a, b = keyframes[i], keyframes[i + 1]
    w = (t - a.t) / (b.t - a.t)
    listener = (1.0 - w) * np.asarray(a.listener) + w * np.asarray(b.listener)
    turn = (b.yaw - a.yaw + 180.0) % 360.0 - 180.0  # the shorter way, in (-180, 180]
    src_a, src_b = _source_at(keyframes, i), _source_at(keyframes, i + 1)
    source = None if src_a is None else (1.0 - w) * src_a + w * (src_a if src_b is None else src_b)
    return PathPose(listener, float((a.yaw + w * turn) % 360.0), source)


def _source_at(keyframes: list[Keyframe], i: int) -> np.ndarray | None:
    """The source in force at keyframe ``i``: its own or the last one given before it."""
    for k in keyframes[i::-1]:
        if k.source is not None:
            return np.asarray(k.source, dtype=np.float64)
    return None
