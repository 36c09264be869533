"""The uncached ways of running the same model, measured side by side with :meth:`SceneRenderer.render`.

- ``uncached``: :meth:`AVGSModel.masks` with no caches: F's point features, B's frequency
  features and C_S computed on every call, under ``inference_mode``.
- ``training-mode``: the same with autograd on, as a training step runs it.

Both run the renderer's own model code and synthesis, so they give the same waveform as
the cached path (to float rounding); only time differs.
"""

from __future__ import annotations

import numpy as np
import torch



class UncachedPath:
    """:meth:`SceneRenderer.render` without any of its caches."""

    name = "uncached"
    grad = False

    def __init__(self, renderer):
        self.r = renderer

    def render(self, listener, yaw: float, mono: np.ndarray) -> np.ndarray:
        r = self.r
        peak = float(np.max(np.abs(mono))) or 1.0  # at unit peak, as render() runs
        with torch.inference_mode(not self.grad), torch.set_grad_enabled(self.grad):
            lis, theta, src = r.pose(listener, yaw)
            masks = r.model.masks(lis, theta, src)
        with torch.inference_mode():
            y, _, _ = r.task_model.synthesise(masks, np.asarray(mono, dtype=np.float32) / np.float32(peak), r.synthesis)
            return y * np.float32(peak)


class TrainingModePath(UncachedPath):
    """No caches, autograd on: what a training step pays for the same masks."""

    name = "training-mode (no caches, autograd)"
    grad = True

    def __init__(self, renderer):
        super().__init__(renderer)
        self._params = list(renderer.model.parameters())

    def render(self, listener, yaw: float, mono: np.ndarray) -> np.ndarray:
        for p in self._params:
            p.requires_grad_(True)
        try:
            return super().render(listener, yaw, mono)
        finally:
            for p in self._params:
                p.requires_grad_(False)
