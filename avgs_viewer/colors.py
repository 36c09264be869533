"""Point colours: learned alpha -> RGB, G's colours, vicinity sets; and their legends.

All colours are uint8 RGB [N, 3]. The alpha projection is fitted once per checkpoint
and is deterministic (fixed subsample, fixed sign convention), so the same scene always
looks the same and a point keeps its colour while the listener moves.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Vicinity labels and their colours. The spheres are blue (listener) and yellow (source);
# their sets are lighter/warmer relatives so a set reads as belonging to its sphere.
NEITHER, LISTENER, SOURCE, BOTH = 0, 1, 2, 3
VICINITY_COLOURS = np.array([
    [128, 128, 138],   # neither: grey
    [70, 170, 255],    # listener's vicinity: sky blue
    [255, 140, 20],    # source's vicinity: orange
    [225, 40, 200],    # both: magenta
], dtype=np.uint8)
VICINITY_NAMES = ("neither", "listener's vicinity", "source's vicinity", "both vicinities")
# Sphere colours, float RGB for VTK. No colour can differ from every point colour (alpha and
# G's RGB take any), so the spheres also differ by shape: shaded, drawn over the points and
# ringed white then black (scene_view.HALO), which shows on any background.
LISTENER_COLOUR = (0.15, 0.35, 1.00)
SOURCE_COLOUR = (1.00, 0.88, 0.05)
NO_RGB_COLOUR = np.array([180, 180, 180], dtype=np.uint8)


def vicinity_labels(n: int, listener_idx: np.ndarray, source_idx: np.ndarray) -> np.ndarray:
    """[n] int8 labels: NEITHER, LISTENER, SOURCE or BOTH for each point."""
    labels = np.zeros(n, dtype=np.int8)
    listener_idx = np.asarray(listener_idx, dtype=np.int64).reshape(-1)
    source_idx = np.asarray(source_idx, dtype=np.int64).reshape(-1)
    for name, idx in (("listener", listener_idx), ("source", source_idx)):
        if idx.size and (idx.min() < 0 or idx.max() >= n):
            raise ValueError(f"{name} vicinity indices must lie in [0, {n}), got range "
                             f"[{idx.min()}, {idx.max()}]")
    labels[listener_idx] |= LISTENER
    labels[source_idx] |= SOURCE
    return labels


def vicinity_colours(labels: np.ndarray) -> np.ndarray:
    """[N] labels -> [N, 3] uint8 colours."""
    return VICINITY_COLOURS[np.asarray(labels, dtype=np.int64)]


@dataclass(frozen=True)
class AlphaProjection:
    """PCA of the audio-guidance parameters alpha [N, D] to three colour channels.

    Red, green and blue are the first three principal components, each mapped from its
    1st..99th percentile to 0..255. Sign convention (as sklearn's ``svd_flip``): each
    component's largest-magnitude loading is positive.
    """

    mean: np.ndarray        # [D]
    components: np.ndarray  # [3, D] (zero rows when D < 3)
    lo: np.ndarray          # [3] score mapped to 0
    hi: np.ndarray          # [3] score mapped to 255
    explained: np.ndarray   # [3] fraction of alpha's variance per component

    @classmethod
    def fit(cls, alpha: np.ndarray, max_rows: int = 20_000, seed: int = 0) -> "AlphaProjection":
        alpha = np.asarray(alpha, dtype=np.float64)
        if alpha.ndim != 2 or alpha.shape[0] < 1 or alpha.shape[1] < 1:
            raise ValueError(f"alpha must be [N, D] with N, D >= 1, got shape {alpha.shape}")
        if not np.all(np.isfinite(alpha)):
            raise ValueError("alpha has non-finite values; the checkpoint is damaged")
        rows = alpha
        if len(alpha) > max_rows:
            rows = alpha[np.sort(np.random.default_rng(seed).choice(len(alpha), max_rows, replace=False))]
        mean = rows.mean(axis=0)
        _, s, vt = np.linalg.svd(rows - mean, full_matrices=False)
        k = min(3, vt.shape[0])
        components = np.zeros((3, alpha.shape[1]))
        components[:k] = vt[:k]
        # Deterministic signs: the largest-magnitude loading of each component is positive.
        signs = np.sign(components[np.arange(3), np.argmax(np.abs(components), axis=1)])
        components *= np.where(signs == 0, 1.0, signs)[:, None]
        var = s**2
        explained = np.zeros(3)
        if var.sum() > 0:
            explained[:k] = var[:k] / var.sum()
        scores = (rows - mean) @ components.T  # [n, 3]
        lo = np.percentile(scores, 1, axis=0)
        hi = np.percentile(scores, 99, axis=0)
        return cls(mean, components, lo, hi, explained)

    def __call__(self, alpha: np.ndarray) -> np.ndarray:
        """alpha [N, D] -> [N, 3] uint8 colours."""
        scores = (np.asarray(alpha, dtype=np.float64) - self.mean) @ self.components.T
        span = np.where(self.hi - self.lo > 1e-12, self.hi - self.lo, 1.0)
        unit = np.clip((scores - self.lo) / span, 0.0, 1.0)
        unit[:, self.hi - self.lo <= 1e-12] = 0.5  # a constant component shows as mid-level
        return np.round(unit * 255).astype(np.uint8)

    def legend(self) -> list[tuple[str, tuple[int, int, int]]]:
        """(text, colour) rows: which colour channel shows which principal component."""
        rows = []
        for i, (name, colour) in enumerate((("red", (230, 40, 40)), ("green", (40, 200, 40)),
                                             ("blue", (60, 90, 255)))):
            rows.append((f"{name} = alpha PC{i + 1} ({100 * self.explained[i]:.0f}% of variance)", colour))
        return rows


def gaussian_arrays(gaussians) -> tuple[np.ndarray, np.ndarray]:
    """(means [M, 3], rgb [M, 3]) of ``SceneRenderer.gaussians`` (an object with ``means``
    and ``rgb``, or a (means, rgb) pair)."""
    if hasattr(gaussians, "means") and hasattr(gaussians, "rgb"):
        return np.asarray(gaussians.means), np.asarray(gaussians.rgb)
    means, rgb = gaussians
    return np.asarray(means), np.asarray(rgb)


def rgb_from_gaussians(points: np.ndarray, means: np.ndarray, rgb: np.ndarray) -> np.ndarray:
    """Each audio point [N, 3] takes the colour of its nearest Gaussian of G -> [N, 3] uint8.

    ``rgb`` [M, 3] may be floats in [0, 1] or uint8.
    """
    from scipy.spatial import cKDTree

    means = np.asarray(means, dtype=np.float64)
    rgb = np.asarray(rgb)
    if means.ndim != 2 or means.shape[1] != 3 or rgb.shape != means.shape:
        raise ValueError(f"gaussians must be means [M, 3] and rgb [M, 3], got {means.shape} and {rgb.shape}")
    if len(means) == 0:
        return np.tile(NO_RGB_COLOUR, (len(points), 1))
    if rgb.dtype != np.uint8:
        rgb = np.round(np.clip(rgb.astype(np.float64), 0.0, 1.0) * 255).astype(np.uint8)
    _, nearest = cKDTree(means).query(np.asarray(points, dtype=np.float64), k=1)
    return rgb[nearest]


def vicinity_legend() -> list[tuple[str, tuple[int, int, int]]]:
    return [(name, tuple(int(c) for c in colour)) for name, colour in zip(VICINITY_NAMES, VICINITY_COLOURS)]


def rgb_legend() -> list[tuple[str, tuple[int, int, int]]]:
    return [("G's colour (nearest Gaussian)", (200, 200, 200))]
