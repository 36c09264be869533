"""Reference methods of the RIR task: the training responses, interpolated, plain or through a codec.

A method of the RIR task is a callable ``(train: RIRSet, query: RIRSet) -> [N, 2, L]``
(:mod:`avgs.evaluation.impulse_response`): given the training responses of a scene, predict the response
of each query (source, receiver, yaw). These baselines read only the query's positions and
yaw, never its responses. Every query is answered from training responses of the same
orientation (the same yaw, to :data:`YAW_TOL_DEG`); a yaw no training response has is an
error.

- **nearest**: the training response whose (source, receiver) pair is nearest to the
  query's in the 6-D concatenated space (normalised frame, Euclidean).
- **linear**: linear interpolation, per source then across sources. A grid of
  receivers times a few sources is degenerate for a Delaunay triangulation of the
  6-D (or 4-D) pairs (a product of point sets is full of co-spherical subsets), so the
  interpolation is done in two stages, each a barycentric interpolation in its own
  space:

  1. across sources: the query's source in the Delaunay triangulation of the training
     sources (of that yaw) gives weights ``w_s`` on up to ``k + 1`` of them;
  2. for each of those sources, the query's receiver in the triangulation of that
     source's training receivers gives weights ``w_r``;

  the prediction is ``sum_s w_s sum_r w_r h(s, r)`` on the time-domain responses. Each
  stage works in the affine span of its points (the receivers at one height are 2-D; two
  points are a segment) and projects the query onto it; a query outside a stage's hull
  takes the nearest point of that stage (weight 1) instead, so outside both hulls linear
  is nearest per stage. Exact at training pairs, the mean of two responses at their
  midpoint.
- **opus-** / **aac-** *nearest* / *linear*: the same on the training responses after an
  Opus or AAC round trip (:mod:`avgs.evaluation.codecs`, bitrates in :data:`avgs.evaluation.codecs.CODECS`): what
  storing the measured responses compressed, and interpolating them, would give.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import Delaunay, QhullError, cKDTree

from avgs.evaluation import codecs
from avgs.config import STFT

if TYPE_CHECKING:
    from avgs.data.rir import RIRSet

YAW_TOL_DEG = 1e-6
"Two yaws are the same orientation when they differ by less than this (modulo 360)."
SNAP = 1e-9
"Barycentric weights below this are dropped (and the rest renormalised): a query on a training point gets its response exactly."


def _yaw_groups(yaw: np.ndarray) -> dict[float, np.ndarray]:
    """Rows of each orientation: ``{yaw in [0, 360): indices}``."""
    wrapped = np.mod(np.asarray(yaw, dtype=np.float64), 360.0)
    groups: dict[float, list[int]] = {}
    keys: list[float] = []
    for i, y in enumerate(wrapped):
        key = next((k for k in keys if min(abs(k - y), 360.0 - abs(k - y)) < YAW_TOL_DEG), None)
        if key is None:
            keys.append(float(y))
            key = float(y)
        groups.setdefault(key, []).append(i)
    return {k: np.asarray(v, dtype=np.int64) for k, v in groups.items()}


def _match_yaw(key: float, train_groups: dict[float, np.ndarray]) -> float:
    """The training set's key for the orientation ``key``."""
    for k in train_groups:
        if min(abs(k - key), 360.0 - abs(k - key)) < YAW_TOL_DEG:
            return k
    have = ", ".join(f"{k:g}" for k in sorted(train_groups))
    raise ValueError(f"no training responses at yaw {key:g} degrees (the training set has yaws {have})")


class SimplexInterpolator:
    """Barycentric (piecewise-linear) weights over points ``[n, d]`` in their affine span.

    ``weights(q [m, d]) -> (index [m, k+1], weight [m, k+1])``, index -1 with weight 0 for
    unused slots; a query outside the hull gets its nearest point with weight 1.
    """

    def __init__(self, points: np.ndarray):
        points = np.asarray(points, dtype=np.float64)  # [n, d]
        if points.ndim != 2 or len(points) == 0:
            raise ValueError(f"interpolation needs points [n, d], got {points.shape}")
        self.points = points
        self.center = points.mean(axis=0)  # [d]
        _, sv, vt = np.linalg.svd(points - self.center, full_matrices=False)
        scale = max(float(sv[0]) if sv.size else 0.0, 1e-300)
        self.rank = int(np.sum(sv > 1e-9 * scale)) if scale > 1e-300 else 0
        self.basis = vt[: self.rank]  # [k, d]
        self.coords = (points - self.center) @ self.basis.T  # [n, k]
        self.tree = cKDTree(points)
        self.tri = None
        if self.rank >= 2:
            try:
                self.tri = Delaunay(self.coords)
            except QhullError:  # cospherical / nearly flat subsets: joggle (exact positions keep their weights)
                self.tri = Delaunay(self.coords, qhull_options="QJ Qbb Qc")
        elif self.rank == 1:
            self.order = np.argsort(self.coords[:, 0])
            self.sorted = self.coords[self.order, 0]

    def weights(self, queries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        q = np.atleast_2d(np.asarray(queries, dtype=np.float64))  # [m, d]
        m, k = len(q), self.rank
        index = np.full((m, k + 1), -1, dtype=np.int64)
        weight = np.zeros((m, k + 1))
        inside = np.zeros(m, dtype=bool)
        if k == 0:
            index[:, 0], weight[:, 0] = 0, 1.0
            return index, weight
        c = (q - self.center) @ self.basis.T  # [m, k] projected onto the span
        if k == 1:
            x = c[:, 0]
            lo, hi = self.sorted[0], self.sorted[-1]
            eps = 1e-12 * max(hi - lo, 1.0)
            inside = (x >= lo - eps) & (x <= hi + eps)
            j = np.clip(np.searchsorted(self.sorted, x, side="right") - 1, 0, len(self.sorted) - 2)  # segment [j, j+1]
            span = self.sorted[j + 1] - self.sorted[j]
            t = np.clip((x - self.sorted[j]) / np.where(span > 0, span, 1.0), 0.0, 1.0)
            index[:, 0], index[:, 1] = self.order[j], self.order[j + 1]
            weight[:, 0], weight[:, 1] = 1.0 - t, t
        else:
            simplex = self.tri.find_simplex(c)  # [m], -1 outside
            inside = simplex >= 0
            s = np.where(inside, simplex, 0)
            trans = self.tri.transform[s]  # [m, k+1, k]
            bary = np.einsum("mij,mj->mi", trans[:, :k], c - trans[:, k])  # [m, k]
            inside &= np.all(np.isfinite(bary), axis=1)  # a flat simplex (scipy's NaN transform): take the nearest
            bary = np.where(np.isfinite(bary), bary, 0.0)
            index[:] = self.tri.simplices[s]
            weight[:, :k] = bary
            weight[:, k] = 1.0 - bary.sum(axis=1)
        # Snap: a query on a vertex gets exactly that vertex; weights sum to one.
        weight = np.where(np.abs(weight) < SNAP, 0.0, weight)
        weight /= np.where(weight.sum(axis=1, keepdims=True) != 0, weight.sum(axis=1, keepdims=True), 1.0)
        outside = ~inside
        if np.any(outside):
            _, nearest = self.tree.query(q[outside])
            index[outside] = -1
            weight[outside] = 0.0
            index[outside, 0] = nearest
            weight[outside, 0] = 1.0
        index = np.where(weight == 0.0, -1, index)
        return index, weight


class _TrainIndex:
    """Per-orientation lookup structures of one training set (built once, cached)."""

    def __init__(self, train: "RIRSet"):
        if len(train) == 0:
            raise ValueError("the training set is empty: nothing to interpolate")
        self.groups = _yaw_groups(train.yaw)
        self.pairs = np.concatenate([train.source, train.receiver], axis=1)  # [N, 6]
        self.trees = {k: cKDTree(self.pairs[rows]) for k, rows in self.groups.items()}
        self.train = train
        self._linear: dict[float, tuple] = {}

    def linear(self, key: float):
        """(interpolator over the sources, [(interpolator over that source's receivers, its rows)] per source)."""
        if key not in self._linear:
            rows = self.groups[key]
            ids = self.train.source_index[rows]
            sources = np.unique(ids)
            positions = np.stack([self.train.source[rows[ids == s][0]] for s in sources])  # [S, 3]
            per_source = []
            for s in sources:
                r = rows[ids == s]
                per_source.append((SimplexInterpolator(self.train.receiver[r]), r))
            self._linear[key] = (SimplexInterpolator(positions), per_source)
        return self._linear[key]


class _Cache:
    """The value computed for the last few training sets (kept by identity: RIRSets hold arrays)."""

    def __init__(self, size: int = 2):
        self.size = size
        self.items: list[tuple[object, object]] = []

    def get(self, train, make):
        for obj, value in self.items:
            if obj is train:
                return value
        value = make(train)
        self.items = [(train, value), *self.items][: self.size]
        return value


_INDEX = _Cache()


def _index(train: "RIRSet") -> _TrainIndex:
    return _INDEX.get(train, _TrainIndex)


def nearest(train: "RIRSet", query: "RIRSet") -> np.ndarray:
    """The training response of the nearest (source, receiver) pair of the same yaw: ``[N, 2, L]``."""
    idx = _index(train)
    out = np.empty((len(query), *train.rir.shape[1:]), np.float32)
    pairs = np.concatenate([query.source, query.receiver], axis=1)  # [N, 6]
    for key, rows in _yaw_groups(query.yaw).items():
        group = _match_yaw(key, idx.groups)
        _, j = idx.trees[group].query(pairs[rows])
        out[rows] = train.rir[idx.groups[group][j]]
    return out


def linear(train: "RIRSet", query: "RIRSet") -> np.ndarray:
    """Linear interpolation per source, then across sources (module docstring): ``[N, 2, L]``."""
    idx = _index(train)
    out = np.zeros((len(query), *train.rir.shape[1:]), np.float64)
    for key, rows in _yaw_groups(query.yaw).items():
        by_source, per_source = idx.linear(_match_yaw(key, idx.groups))
        s_index, s_weight = by_source.weights(query.source[rows])  # [m, ks+1]
        for slot in range(s_index.shape[1]):
            for s in np.unique(s_index[:, slot][s_index[:, slot] >= 0]):
                use = np.nonzero(s_index[:, slot] == s)[0]  # queries weighting source s in this slot
                interp, r_rows = per_source[s]
                r_index, r_weight = interp.weights(query.receiver[rows[use]])  # [u, kr+1]
                for rslot in range(r_index.shape[1]):
                    ok = r_index[:, rslot] >= 0
                    w = s_weight[use[ok], slot] * r_weight[ok, rslot]  # [u']
                    out[rows[use[ok]]] += w[:, None, None] * train.rir[r_rows[r_index[ok, rslot]]]
    return out.astype(np.float32)


_DECODED: dict[tuple[str, int], _Cache] = {}


def decoded(train: "RIRSet", codec: str, sample_rate: int = STFT.sample_rate, progress: bool = False) -> "RIRSet":
    """``train`` with every response through a round trip of ``codec`` (cached for the last training set)."""
    config = codecs.CODECS[codec]

    def make(t):
        return dataclasses.replace(t, rir=codecs.roundtrip_many(t.rir, sample_rate, config, progress=progress).audio)

    return _DECODED.setdefault((codec, sample_rate), _Cache(size=1)).get(train, make)


class CodecMethod:
    """A codec round trip of the training responses, then ``nearest`` or ``linear``.

    The responses' sample rate is the scene's (:meth:`for_scene`), else 22050 Hz.
    """

    def __init__(self, codec: str, interpolation: str, progress: bool = False, sample_rate: int = STFT.sample_rate):
        if codec not in codecs.CODECS:
            raise ValueError(f"unknown codec {codec!r}; expected one of {', '.join(codecs.CODECS)}")
        if interpolation not in INTERPOLATIONS:
            raise ValueError(f"unknown interpolation {interpolation!r}; expected one of {', '.join(INTERPOLATIONS)}")
        self.codec, self.interpolation = codec, interpolation
        self.progress, self.sample_rate = progress, sample_rate

    def for_scene(self, scene) -> "CodecMethod":
        """This method at the scene's sample rate."""
        return CodecMethod(self.codec, self.interpolation, self.progress, int(scene.sample_rate))

    def __call__(self, train: "RIRSet", query: "RIRSet") -> np.ndarray:
        return INTERPOLATIONS[self.interpolation](decoded(train, self.codec, self.sample_rate, self.progress), query)

    def __repr__(self) -> str:
        return f"{self.codec}-{self.interpolation}"


INTERPOLATIONS = {"nearest": nearest, "linear": linear}

RIR_BASELINES = {
    "nearest": nearest,
    "linear": linear,
    **{f"{c}-{i}": CodecMethod(c, i) for c in codecs.CODECS for i in INTERPOLATIONS},
}
"The RIR task's baselines by their command-line names."
