"""A scene's geometry from its scene.json: points on its surfaces (for initialising Gaussians and
audio points) and the room outline's edges (for drawing).

Reads only the scene.json dict (``metadata["surfaces"]``: ``{"name", "material",
"color", "corners": [[x, y, z], ...]}`` in metres, and ``metadata["to_normalised"]``),
so it works on any scene written by ``avgs synth`` without the generator's other modules.
"""

from __future__ import annotations

import numpy as np

from avgs.data.frame import SceneFrame

DEFAULT_COLOR = (0.5, 0.5, 0.5)


def _surface_color(surface: dict, materials: dict) -> np.ndarray:
    color = surface.get("color")
    if color is None:
        color = (materials.get(surface.get("material"), {}) or {}).get("color", DEFAULT_COLOR)
    c = np.asarray(color, dtype=np.float64).reshape(3)
    return np.clip(c, 0.0, 1.0)


def _triangles(metadata: dict) -> tuple[np.ndarray, np.ndarray]:
    """Fan triangles ``[T, 3, 3]`` (world) of every surface polygon and their colours ``[T, 3]``."""
    surfaces = metadata.get("surfaces")
    if not isinstance(surfaces, list) or not surfaces:
        raise ValueError("scene.json has no 'surfaces' list; expected one written by `avgs synth`")
    materials = metadata.get("materials") or {}
    tris, colors = [], []
    for i, s in enumerate(surfaces):
        try:
            corners = np.asarray(s["corners"], dtype=np.float64)
        except (KeyError, TypeError, ValueError):
            raise ValueError(f"scene.json surfaces[{i}] needs 'corners' as [[x, y, z], ...]") from None
        if corners.ndim != 2 or corners.shape[1] != 3 or len(corners) < 3:
            raise ValueError(f"scene.json surfaces[{i}] corners must be [K >= 3, 3], got {corners.shape}")
        color = _surface_color(s, materials)
        for k in range(1, len(corners) - 1):
            tris.append(np.stack([corners[0], corners[k], corners[k + 1]]))
            colors.append(color)
    return np.stack(tris), np.stack(colors)


def surface_points(metadata: dict, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``n`` points drawn uniformly by area over the scene's surfaces (walls, floor,
    ceiling, furniture) and their material colours.

    Returns ``points [n, 3]`` float32 in the **normalised** frame
    (``(world - center) * scale``) and ``colors [n, 3]`` float32 RGB in [0, 1].
    """
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}")
    if "to_normalised" not in metadata:
        raise ValueError("scene.json has no 'to_normalised'; expected one written by `avgs synth`")
    frame = SceneFrame.from_dict(metadata["to_normalised"])
    tris, tri_colors = _triangles(metadata)  # [T, 3, 3], [T, 3]
    areas = 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=-1)  # [T]
    if not np.sum(areas) > 0:
        raise ValueError("scene.json surfaces have zero total area")
    pick = rng.choice(len(tris), size=n, p=areas / np.sum(areas))  # [n]
    u, v = rng.random(n), rng.random(n)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    t = tris[pick]  # [n, 3, 3]
    world = t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])  # [n, 3]
    return frame.to_normalised(world).astype(np.float32), tri_colors[pick].astype(np.float32)


# -- the room outline ------------------------------------------------------------------

_POLYGON_KEYS = ("corners", "vertices", "points", "polygon", "quad")


def outline_from_metadata(metadata: dict | None) -> np.ndarray | None:
    """Edges ``[K, 2, 3]`` (world, metres) of the room surfaces listed in scene.json, or None.

    Reads ``metadata["surfaces"]``: a list whose items are polygons (a list of [x, y, z]
    corners) or dicts holding one under ``corners`` / ``vertices`` / ``points`` /
    ``polygon`` / ``quad``. Each closed polygon contributes its edges; edges shared by
    two surfaces are kept once.
    """
    if not isinstance(metadata, dict):
        return None
    surfaces = metadata.get("surfaces")
    if surfaces is None and isinstance(metadata.get("room"), dict):
        surfaces = metadata["room"].get("surfaces")
    if not isinstance(surfaces, (list, tuple)):
        return None
    segments: dict[tuple, np.ndarray] = {}
    for s in surfaces:
        poly = s
        if isinstance(s, dict):
            poly = next((s[k] for k in _POLYGON_KEYS if k in s), None)
        try:
            corners = np.asarray(poly, dtype=np.float64)
        except (TypeError, ValueError):
            continue
        if corners.ndim != 2 or corners.shape[1] != 3 or len(corners) < 2 or not np.all(np.isfinite(corners)):
            continue
        for a, b in zip(corners, np.roll(corners, -1, axis=0)):
            key = tuple(sorted((tuple(np.round(a, 6)), tuple(np.round(b, 6)))))
            segments.setdefault(key, np.stack([a, b]))
    if not segments:
        return None
    return np.stack(list(segments.values()))  # [K, 2, 3]
