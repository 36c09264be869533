"""The map between a scene's world frame and the normalised frame the model computes in.

``normalised = (world - center) * scale`` (a uniform scale and a translation, no
rotation), so directions and yaw are the same in both frames. RWAVS stores poses in both
frames (``transforms_*.json`` and ``transforms_scale_*.json``); :meth:`SceneFrame.fit`
recovers the map from the pairs by least squares.

Also here: the listener's signed direction to the source (:func:`signed_direction`),
the one place the "positive = source on the listener's left" convention is computed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from avgs.data.files import describe_json, finite_number


@dataclass(frozen=True)
class SceneFrame:
    """World <-> normalised map: ``normalised = (world - center) * scale``."""

    center: np.ndarray  # [3] world
    scale: float  # normalised units per world unit, > 0

    def __post_init__(self) -> None:
        center = np.asarray(self.center, dtype=np.float64).reshape(-1)
        if center.shape != (3,) or not np.all(np.isfinite(center)):
            raise ValueError(f"SceneFrame center must be 3 finite numbers, got {self.center!r}")
        scale = float(self.scale)
        if not (math.isfinite(scale) and scale > 0):
            raise ValueError(f"SceneFrame scale must be a finite number > 0, got {self.scale!r}")
        center.setflags(write=False)
        object.__setattr__(self, "center", center)
        object.__setattr__(self, "scale", scale)

    @classmethod
    def identity(cls) -> "SceneFrame":
        """World and normalised frames coincide."""
        return cls(np.zeros(3), 1.0)

    def to_normalised(self, points) -> np.ndarray:
        """World points ``[..., 3]`` -> normalised ``[..., 3]`` (float64)."""
        return (np.asarray(points, dtype=np.float64) - self.center) * self.scale

    def to_world(self, points) -> np.ndarray:
        """Normalised points ``[..., 3]`` -> world ``[..., 3]`` (float64)."""
        return np.asarray(points, dtype=np.float64) / self.scale + self.center

    def pose_to_normalised(self, c2w) -> np.ndarray:
        """A world camera-to-world ``[4, 4]`` -> the same pose in the normalised frame."""
        out = np.array(c2w, dtype=np.float64)
        out[:3, 3] = self.to_normalised(out[:3, 3])
        return out

    def to_dict(self) -> dict:
        """Plain values: ``{"center": [x, y, z], "scale": s}`` (JSON and checkpoint safe)."""
        return {"center": [float(v) for v in self.center], "scale": float(self.scale)}

    @classmethod
    def from_dict(cls, d: dict) -> "SceneFrame":
        """Inverse of :meth:`to_dict`; accepts lists, arrays or tensors as values."""
        try:
            center, scale = d["center"], d["scale"]
        except (KeyError, TypeError) as exc:
            raise ValueError(f"a scene frame needs keys 'center' and 'scale', got {d!r}") from exc
        if hasattr(center, "tolist"):
            center = center.tolist()
        if hasattr(scale, "item"):
            scale = scale.item()
        return cls(np.asarray(center, dtype=np.float64), float(scale))

    @classmethod
    def fit(cls, world, normalised) -> tuple["SceneFrame", float]:
        """Least-squares uniform scale + translation taking ``world [N, 3]`` to ``normalised [N, 3]``.

        Returns the frame and the RMS residual in normalised units (0 for an exact map;
        large when the normalisation also rotated the scene, which this frame cannot hold).
        """
        w = np.asarray(world, dtype=np.float64).reshape(-1, 3)  # [N, 3]
        n = np.asarray(normalised, dtype=np.float64).reshape(-1, 3)  # [N, 3]
        if w.shape != n.shape:
            raise ValueError(f"fit needs matching point sets, got {w.shape} and {n.shape}")
        w_mean, n_mean = w.mean(axis=0), n.mean(axis=0)
        dw, dn = w - w_mean, n - n_mean
        spread = float(np.sum(dw * dw))
        if len(w) < 2 or spread <= 1e-18:
            raise ValueError(f"fit needs at least two distinct positions, got {len(w)} point(s) with no spread")
        scale = float(np.sum(dw * dn)) / spread
        if scale <= 0:
            raise ValueError(f"the scaled positions are not a positively scaled copy (fitted scale {scale:.3g})")
        # normalised = scale * world + t  with  t = n_mean - scale * w_mean = -scale * center
        center = w_mean - n_mean / scale
        frame = cls(center, scale)
        rms = float(np.sqrt(np.mean(np.sum((frame.to_normalised(w) - n) ** 2, axis=-1))))
        return frame, rms


def facing_from_c2w(c2w) -> np.ndarray:
    """Unit facing direction ``[3]`` of an OpenGL camera-to-world (looks along its -Z)."""
    f = -np.asarray(c2w, dtype=np.float64)[:3, 2]
    return f / max(float(np.linalg.norm(f)), 1e-12)


def yaw_from_c2w(c2w) -> float:
    """Listener yaw in radians, counter-clockwise from +x in the xy plane: ``atan2(f_y, f_x)``."""
    f = facing_from_c2w(c2w)
    return math.atan2(f[1], f[0])


def c2w_from_yaw(position, yaw: float) -> np.ndarray:
    """OpenGL camera-to-world ``[4, 4]`` at ``position`` facing ``yaw`` radians (level, +z up)."""
    facing = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    up = np.array([0.0, 0.0, 1.0])
    back = -facing  # camera +Z
    right = np.cross(up, back)  # camera +X
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2] = right, up, back
    c2w[:3, 3] = np.asarray(position, dtype=np.float64)
    return c2w


def signed_direction(listener: torch.Tensor, yaw: torch.Tensor, source: torch.Tensor) -> torch.Tensor:
    """Signed angle theta [B] in radians from the listener's facing to the source, in the xy plane.

    ``theta = atan2(cross(f, d), dot(f, d))`` with ``f = (cos yaw, sin yaw)`` and
    ``d = source - listener``: in ``(-pi, pi]``, 0 straight ahead, **positive when the
    source is on the listener's left**, negative on the right. listener: [B, 3] (or [B, 2]);
    yaw: [B] radians, counter-clockwise from +x; source: [B, 3] or [3]. The one place this
    convention is computed: the loader, training and rendering all call it.
    """
    d = source[..., :2] - listener[..., :2]  # [B, 2]
    fx, fy = torch.cos(yaw), torch.sin(yaw)
    return torch.atan2(fx * d[..., 1] - fy * d[..., 0], fx * d[..., 0] + fy * d[..., 1])


# -- validation helpers (for the loaders: they name the file; these name the problem) --------

RIGID_TOLERANCE = 1e-3
"""How far a pose's rotation part may be from orthonormal: ``max |R^T R - I| < 1e-3``.

RWAVS and our generator store poses as float64 JSON (orthonormal to ~1e-15); copies
rounded to 6 decimals stay below 1e-5. A normalised pose is as rigid as the world one:
the scale applies to its translation only."""


def rigid_transform_problem(c2w, tolerance: float = RIGID_TOLERANCE) -> str | None:
    """Why ``c2w`` is not a rigid camera-to-world ``[4, 4]``, or None when it is one.

    Rigid: finite, bottom row ``[0, 0, 0, 1]``, rotation part ``R`` orthonormal
    (``max |R^T R - I| < tolerance``) with ``det R > 0`` (no reflection)."""
    m = np.asarray(c2w, dtype=np.float64)
    if m.shape != (4, 4):
        return f"not a 4x4 matrix (shape {list(m.shape)})"
    if not np.all(np.isfinite(m)):
        return "holds NaN or Inf"
    if float(np.max(np.abs(m[3] - [0.0, 0.0, 0.0, 1.0]))) >= tolerance:
        return f"bottom row is {[float(v) for v in m[3]]}, not [0, 0, 0, 1]"
    R = m[:3, :3]
    big = float(np.max(np.abs(R)))
    if big > 1.0 + tolerance:  # no entry of a rotation exceeds 1 (and R^T R could overflow)
        return f"rotation part not orthonormal (an entry of magnitude {big:.3g})"
    err = float(np.max(np.abs(R.T @ R - np.eye(3))))
    if not err < tolerance:
        return f"rotation part not orthonormal (max |R^T R - I| = {err:.3g}, tolerance {tolerance:g})"
    if not float(np.linalg.det(R)) > 0:
        return "rotation part is a reflection (det < 0)"
    return None


def frame_from_json(value) -> SceneFrame:
    """A :class:`SceneFrame` from parsed JSON (``{"center": [3 numbers], "scale": number > 0}``),
    strictly: booleans, strings, lists where a number belongs and huge or non-finite numbers
    are refused with a ValueError naming the field (``from_dict`` is lenient: it also takes
    arrays and tensors)."""
    if not isinstance(value, dict):
        raise ValueError(f"expected an object {{'center': [x, y, z], 'scale': s}}, got {describe_json(value)}")
    for key in ("center", "scale"):
        if key not in value:
            raise ValueError(f"'{key}' missing; expected {{'center': [x, y, z], 'scale': s}}")
    center = value["center"]
    if not isinstance(center, list) or len(center) != 3:
        raise ValueError(f"'center' must be a list of 3 numbers, got {describe_json(center)}")
    xyz = [finite_number(v, f"'center'[{i}]") for i, v in enumerate(center)]
    scale = finite_number(value["scale"], "'scale'")
    if not scale > 0:
        raise ValueError(f"'scale' must be > 0, got {scale!r}")
    return SceneFrame(np.array(xyz), scale)


def similarity_fit_residual(world, normalised) -> float:
    """Largest per-point distance left after the best similarity (rotation, uniform scale,
    translation; Umeyama's least squares) maps ``world [N, 3]`` onto ``normalised [N, 3]``.

    :meth:`SceneFrame.fit` holds no rotation; this tells a rotated but otherwise exact copy
    (small residual here, large there) from positions that no similarity relates."""
    w = np.asarray(world, dtype=np.float64).reshape(-1, 3)
    n = np.asarray(normalised, dtype=np.float64).reshape(-1, 3)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        dw, dn = w - w.mean(axis=0), n - n.mean(axis=0)
        var_w = float(np.mean(np.sum(dw * dw, axis=-1)))
        if len(w) < 2 or not var_w > 1e-18:
            return float(np.max(np.linalg.norm(dn, axis=-1))) if len(n) else 0.0
        U, S, Vt = np.linalg.svd(dn.T @ dw / len(w))
        D = np.eye(3)
        if np.linalg.det(U) * np.linalg.det(Vt) < 0:
            D[2, 2] = -1.0
        R = U @ D @ Vt
        s = float(np.trace(np.diag(S) @ D)) / var_w
        out = float(np.max(np.linalg.norm(s * dw @ R.T - dn, axis=-1)))
    return out if math.isfinite(out) else math.inf
