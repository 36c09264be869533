"""The inference paths we compare the fast one against, measured side by side in one run.

- ``previous``: what :meth:`SceneRenderer.render` did before the fast path (commit
  c4b219a): :meth:`AVGSModel.masks` on ``[1, ...]`` tensors under ``inference_mode``,
  C_S cached, ``torch.topk`` with a sorted result, tensors built per call.
- ``naive``: the straightforward way: autograd on, C_S recomputed every call, a full
  ``argsort`` for the vicinity.

Both give the same waveform as the fast path (to float rounding); only time differs.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from avgs import dsp
from avgs.acoustics.model import binaural_waveform, signed_direction


def _decay(model):
    """The tail's power decay per frame [F], or None for a mask-only model."""
    tail = model.binauralizer.reverb
    return None if tail is None else tail.decay().detach()


def _inputs(renderer, listener, yaw: float):
    dev = renderer.device
    lis = torch.tensor(renderer.frame.to_normalised(np.asarray(listener, dtype=np.float64))[None], dtype=torch.float32, device=dev)
    src = torch.tensor(renderer._source_n, dtype=torch.float32, device=dev)  # [3]
    theta = signed_direction(lis, torch.tensor([math.radians(float(yaw))], device=dev), src)  # [1]
    return lis, src, theta


class PreviousPath:
    """The renderer's pre-fast-path implementation (C_S cached, topk, inference mode)."""

    name = "previous (c4b219a)"

    def __init__(self, renderer):
        self.r = renderer
        self.model = renderer._model
        with torch.inference_mode():
            src = torch.tensor(renderer._source_n, dtype=torch.float32, device=renderer.device)
            self.cached = self.model.source_context(src)

    def render(self, listener, yaw: float, mono: np.ndarray) -> np.ndarray:
        with torch.inference_mode():
            lis, src, theta = _inputs(self.r, listener, yaw)
            m = self.model.masks(lis, theta, src, cached_source=self.cached)
            spec = dsp.stft(torch.from_numpy(mono).to(self.r.device)[None], self.r.stft)
            y = binaural_waveform(spec, m.mixture, m.difference, mono.size, self.r.stft,
                                  reverb=m.reverb, decay=_decay(self.model), synthesis=self.r.synthesis)[0]
            return y.float().cpu().numpy()


class NaivePath:
    """No cache, autograd on, full sort for the vicinity."""

    name = "naive (no cache, autograd, full sort)"

    def __init__(self, renderer):
        import copy

        self.r = renderer
        self.model = copy.deepcopy(renderer._model).requires_grad_(True)  # a training-mode model's graph

    def _masks(self, lis, theta, src):
        model = self.model
        k = model.vicinity_k
        X = model.points.X
        idx_l = torch.argsort(((X[None] - lis[:, None]) ** 2).sum(-1), dim=-1)[:, :k]  # [1, k]
        idx_s = torch.argsort(((X - src) ** 2).sum(-1))[:k]  # [k]
        context = None
        if model.field is not None:
            c_s = model.context_at(src[None], idx_s[None])  # [1, c]
            c_l = model.context_at(lis, idx_l)  # [1, c]
            context = torch.cat([c_s, c_l], dim=-1)
        return model.binauralizer(lis[:, :2], theta, context)

    def render(self, listener, yaw: float, mono: np.ndarray) -> np.ndarray:
        with torch.enable_grad():
            lis, src, theta = _inputs(self.r, listener, yaw)
            out = self._masks(lis, theta, src)
        with torch.no_grad():
            reverb = None if out.reverb is None else out.reverb.detach()
            spec = dsp.stft(torch.from_numpy(mono).to(self.r.device)[None], self.r.stft)
            y = binaural_waveform(spec, out.mixture.detach(), out.difference.detach(), mono.size, self.r.stft,
                                  reverb=reverb, decay=_decay(self.model), synthesis=self.r.synthesis)[0]
            return y.detach().float().cpu().numpy()
