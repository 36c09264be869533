"""Inference-only evaluation of :meth:`AVGSModel.masks` for one pose at a time.

Same numbers as the model (to float rounding; ``tests/test_acoustics_fast.py``), less
work per pose, by exact rewrites of the network and caches kept between calls:

- **Vicinity**: squared distances from per-axis contiguous copies of X, then a partial
  selection (``numpy.argpartition``, O(N)) instead of a sort. The k indices come back in
  no particular order; the context is a mean, so order does not matter.
- **F**: its first layer is linear in ``alpha (+) G_i``, so ``W alpha + b`` is computed
  once for all points (``A [N, width]``) and each pose only adds ``W_g G_i`` (3 inputs
  instead of 55). Its last layer is linear too and commutes with the mean over the
  vicinity: it is applied once to the mean instead of k times.
- **B**: the 257 frequency queries share their positional encoding; its projection
  ``W_f PE(f) + b`` is precomputed (``[F, width]``), a pose adds ``W_xy PE(x, y)``
  and the projected context (one vector each). With concatenated direction features the
  difference layers that take it are split the same way. All 257 queries go through the MLPs
  as one ``[F, width]`` batch, into work buffers kept between calls.
- C_S is computed by :meth:`source_context` and cached by the caller until the source
  moves; everything runs without autograd.

``dtype`` picks the precision of the network weights (float32 by default; bfloat16 and
float16 are for measurement: on CPUs without native support they are slower).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import torch
from torch import nn

from avgs.acoustics.binauralizer import THETA_SCALE
from avgs.acoustics.encodings import positional_encoding
from avgs.acoustics.field import DIRECTION_EPS


class PoseMasks(NamedTuple):
    """B's output for one pose, and the listener's vicinity."""

    mixture: torch.Tensor  # [F]
    difference: torch.Tensor  # [F] in (-1, 1)
    listener_vicinity: torch.Tensor  # [k] int64, unordered
    reverb: torch.Tensor | None  # [2, F] reverberant gains, None without a tail


def _linears(seq: nn.Module) -> list[nn.Linear]:
    layers = [m for m in seq.modules() if isinstance(m, nn.Linear)]
    others = [m for m in seq.modules() if not isinstance(m, (nn.Linear, nn.ReLU, nn.Sequential, nn.ModuleList))]
    if others:
        raise ValueError(f"fast path supports Linear/ReLU stacks only, found {type(others[0]).__name__}")
    return layers


class FastMasks:
    """Precomputed, allocation-light masks of a trained :class:`AVGSModel`; one pose per call.

    All positions are in the model's normalised frame, angles in radians. Not
    thread-safe (work buffers are shared); :class:`avgs.inference.SceneRenderer` locks.
    """

    @torch.no_grad()
    def __init__(self, model, dtype: torch.dtype = torch.float32):
        device = model.points.X.device
        self.device = device
        self.dtype = dtype
        self.k = int(model.vicinity_k)
        X = model.points.X.detach().float()  # [N, 3]
        self.n_points = int(X.shape[0])
        # Per-axis contiguous coordinates: distances without a [N, 3] temporary.
        self._axes = [X[:, i].contiguous() for i in range(3)]  # 3 x [N]
        self._X = X.to(dtype).contiguous()  # [N, 3]
        self._d2 = torch.empty(self.n_points, device=device)  # [N] work buffer
        self._tmp = torch.empty(self.n_points, device=device)  # [N] work buffer

        self.use_context = model.field is not None
        if self.use_context:
            lin = _linears(model.field.mlp)
            alpha = model.points.alpha.detach().float()  # [N, D]
            W1 = lin[0].weight.float()  # [w, D + 3]
            d = alpha.shape[1]
            self._A = torch.addmm(lin[0].bias.float(), alpha, W1[:, :d].T).to(dtype)  # [N, w] = W_alpha alpha + b
            self._Wg = W1[:, d:].T.contiguous().to(dtype)  # [3, w]
            self._mid = [(m.weight.T.contiguous().to(dtype), m.bias.to(dtype)) for m in lin[1:-1]]
            last = lin[-1] if len(lin) > 1 else None
            self._last = None if last is None else (last.weight.T.contiguous().to(dtype), last.bias.to(dtype))

        b = model.binauralizer
        self.n_freq = int(b.n_freq)
        self.pe = int(b.pe_frequencies)
        self.pos_pe = int(b.position_frequencies)
        self._direction_feature = b.direction_feature
        self.relu_mixture = b.mixture_activation == "relu"
        Wq = b.query_proj.weight.float()  # [W, P + 21]
        pos_dim = 2 * (2 * self.pos_pe + 1)
        freq_pe = positional_encoding(b.freq_query.float(), self.pe)  # [F, 21]
        self._q_freq = torch.addmm(b.query_proj.bias.float(), freq_pe, Wq[:, pos_dim:].T).to(dtype)  # [F, W]
        self._Wq_pos = Wq[:, :pos_dim].T.contiguous().to(dtype)  # [P, W]
        self._ctx = None if b.context_proj is None else (b.context_proj.weight.T.contiguous().to(dtype), b.context_proj.bias.to(dtype))
        self._mix = [(m.weight.T.contiguous().to(dtype), m.bias.to(dtype)) for m in b.mix_mlp]
        self._mix_head = (b.mix_head.weight.T.contiguous().to(dtype), b.mix_head.bias.to(dtype))  # [W, 1], [1]
        self._embedding = b.direction
        diff = [(m.weight.T.contiguous().to(dtype), m.bias.to(dtype)) for m in b.diff_mlp]
        W = self._q_freq.shape[1]
        self._diff_split = []  # fourier or harmonic: the layers that take e, split into h and e parts
        if self._embedding is None:
            n_split = len(diff) if b.direction_every_layer else 1
            for Wl, bl in diff[:n_split]:  # [W + D, W], [W]
                self._diff_split.append((Wl[:W].contiguous(), Wl[W:].contiguous(), bl))
            diff = diff[n_split:]
        self._diff = diff
        self._diff_head = (b.diff_head.weight.T.contiguous().to(dtype), b.diff_head.bias.to(dtype))
        tail = b.reverb
        self._reverb_head = None if tail is None else (tail.head.weight.T.contiguous().to(dtype), tail.head.bias.to(dtype))
        self.decay = None if tail is None else tail.decay().detach().float()  # [F] tail power decay per frame
        F = self.n_freq
        self._q = torch.empty(F, W, device=device, dtype=dtype)  # work buffers [F, W]
        self._h = torch.empty(F, W, device=device, dtype=dtype)
        self._g = torch.empty(F, W, device=device, dtype=dtype)

    # -- the three stages (public so that benchmarks can time them one by one) ---------

    def vicinity(self, position) -> torch.Tensor:
        """Indices [k] (int64, unordered) of the k audio points nearest ``position`` (3 floats)."""
        d2, tmp = self._d2, self._tmp
        d2.zero_()
        for axis, v in zip(self._axes, position):
            torch.sub(axis, float(v), out=tmp)
            d2.addcmul_(tmp, tmp)
        if self.k >= self.n_points:
            return torch.arange(self.n_points, device=self.device)
        if d2.device.type == "cpu":
            return torch.from_numpy(np.argpartition(d2.numpy(), self.k - 1)[: self.k].astype(np.int64))
        return torch.topk(d2, self.k, largest=False, sorted=False).indices

    def context(self, position, indices: torch.Tensor) -> torch.Tensor:
        """C_i [context_dim] of ``position`` from its vicinity ``indices`` [k]."""
        origin = torch.tensor([float(v) for v in position], device=self.device, dtype=self.dtype)  # [3]
        diff = self._X.index_select(0, indices) - origin  # [k, 3]
        norm = torch.sqrt((diff * diff).sum(-1, keepdim=True).clamp_min(DIRECTION_EPS**2))  # [k, 1]
        g = diff / norm  # [k, 3] unit directions (zero for a point on the origin)
        h = torch.addmm(self._A.index_select(0, indices), g, self._Wg)  # [k, w]
        if self._last is None:  # F is a single linear map
            return h.mean(0)
        h.relu_()
        for W, b in self._mid:
            h = torch.addmm(b, h, W).relu_()  # [k, w]
        W, b = self._last
        return torch.addmv(b, W.T, h.mean(0))  # [c]: the last layer applied to the mean

    def binauralize(self, listener_xy, theta: float, context: torch.Tensor | None):
        """(m_m [F], m_d [F], r [2, F] or None) for a listener at ``listener_xy`` (2 floats), ``theta`` radians."""
        xy = torch.tensor([[float(listener_xy[0]), float(listener_xy[1])]], device=self.device, dtype=self.dtype)
        row = positional_encoding(xy, self.pos_pe)[0] @ self._Wq_pos  # [W]
        q = torch.add(self._q_freq, row, out=self._q).relu_()  # [F, W] = relu(query_proj(PE(xy) (+) PE(f)))
        if self._ctx is not None:
            if context is None:
                raise ValueError("this binauralizer was built with scene context; pass a context vector")
            W, b = self._ctx
            q.add_(torch.addmv(b, W.T, context.to(self.dtype)))  # + context_proj(C), after the ReLU as in B
        h = q
        for i, (W, b) in enumerate(self._mix):
            h = torch.addmm(b, h, W, out=self._h if i % 2 == 0 else self._g).relu_()
        h = torch.add(h, q, out=self._h if h is not self._h else self._g)  # [F, W] residual
        Wm, bm = self._mix_head
        m = torch.addmm(bm, h, Wm)[:, 0]  # [F]
        mixture = m.relu() if self.relu_mixture else m.sigmoid()

        if self._embedding is not None:
            t = max(-1.0, min(1.0, float(theta) * THETA_SCALE))
            e = self._embedding(torch.tensor([t], device=self.device)).to(self.dtype)[0]  # [W]
            g = h
            for W, b in self._diff:
                g = torch.addmm(b, g, W).relu_().add_(e)
        else:
            e = self._direction_feature(torch.tensor([float(theta)], device=self.device)).to(self.dtype)[0]  # [D]
            g = h
            for Wh, We, bl in self._diff_split:  # W [g (+) e] + b = W_h g + (W_e e + b): e's part is one vector
                g = torch.addmm(torch.addmv(bl, We.T, e), g, Wh).relu_()  # [F, W]
            for W, b in self._diff:
                g = torch.addmm(b, g, W).relu_()
        g = g + h  # [F, W] residual
        Wd, bd = self._diff_head
        difference = torch.addmm(bd, g, Wd)[:, 0].sigmoid().mul_(2.0).sub_(1.0)  # [F] in (-1, 1)
        reverb = None
        if self._reverb_head is not None:
            Wr, br = self._reverb_head
            reverb = torch.nn.functional.softplus(torch.addmm(br, g, Wr)).T.float()  # [2, F]
        return mixture.float(), difference.float(), reverb

    # -- whole poses -------------------------------------------------------------------

    @torch.no_grad()
    def source_context(self, source) -> tuple[torch.Tensor | None, torch.Tensor]:
        """(C_S [c] or None without context, source vicinity [k]) for ``source`` (3 floats): cache it."""
        idx = self.vicinity(source)
        return (self.context(source, idx) if self.use_context else None), idx

    @torch.no_grad()
    def masks(self, listener, theta: float, cached_source: tuple) -> "PoseMasks":
        """:class:`PoseMasks` for ``listener`` (3 floats) and ``theta`` radians."""
        idx = self.vicinity(listener)
        context = None
        if self.use_context:
            c_s = cached_source[0]
            c_l = self.context(listener, idx)
            context = torch.cat([c_s, c_l])  # [2c] = C_S (+) C_L
        mixture, difference, reverb = self.binauralize(listener[:2], theta, context)
        return PoseMasks(mixture, difference, idx, reverb)


def signed_direction(listener, yaw: float, source) -> float:
    """theta (radians) = atan2(cross(f, d), dot(f, d)) in xy; positive = source on the left.

    Plain-float twin of :func:`avgs.acoustics.model.signed_direction` for one pose.
    """
    dx, dy = float(source[0]) - float(listener[0]), float(source[1]) - float(listener[1])
    fx, fy = math.cos(yaw), math.sin(yaw)
    return math.atan2(fx * dy - fy * dx, fx * dx + fy * dy)
