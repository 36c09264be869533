"""AVGSModel: G_a + F + B, from listener poses to masks and binaural magnitudes.

All inputs are in the normalised frame, angles in radians. Shapes: B poses, N audio
points, k vicinity points, F = 257 frequency bins, N_t STFT frames.

Training and inference run the same code. Inference adds caches only: the parts of F
and B that depend on the points and on the frequency (:meth:`AVGSModel.precompute`),
and the source's context C_S, which depends only on the source (:meth:`AVGSModel.source_context`).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from avgs.acoustics.binauralizer import Binauralizer
from avgs.acoustics.field import AcousticField
from avgs.acoustics.points import AudioPoints
from avgs.acoustics.synthesis import Masks, ear_magnitudes
from avgs.acoustics.vicinity import nearest_indices, vicinity_size
from avgs.config import STFT, AcousticConfig, STFTConfig, TrainConfig


@dataclass(frozen=True)
class ModelCache:
    """The pose-independent parts of F and B, computed once for inference (:meth:`AVGSModel.precompute`)."""

    frequency: torch.Tensor  # [F, W] B's query projection of the frequency encodings
    points: torch.Tensor | None  # [N, w] F's first layer on each point's alpha; None without context
    coordinates: torch.Tensor  # [3, N] the audio points axis by axis, for the vicinity search


SourceContext = tuple  # (C_S [context_dim] or None without context, source vicinity [k] int64)


class AVGSModel(nn.Module):
    """Audio points G_a, acoustic field F and binauralizer B."""

    def __init__(self, points: AudioPoints, cfg: AcousticConfig, stft: STFTConfig = STFT, vicinity_k: int | None = None):
        super().__init__()
        self.cfg = cfg
        self.points = points
        if vicinity_k is not None and int(vicinity_k) < 1:
            raise ValueError(f"vicinity_k must be a positive number of points, got {vicinity_k!r}")
        self.fixed_k = None if vicinity_k is None else int(vicinity_k)
        "An explicit k (a pruned checkpoint keeps its original k); None: k from the percentile."
        self.field = (
            AcousticField(points.alpha_dim, cfg.field_width, cfg.field_layers, cfg.context_dim) if cfg.use_context else None
        )
        self.binauralizer = Binauralizer(
            cfg, 2 * cfg.context_dim if cfg.use_context else None, stft.n_freq, stft.hop_length / stft.sample_rate
        )

    # -- what the task registry asks of a task's model (avgs.tasks) ------------------------

    @classmethod
    def build(cls, points: AudioPoints, cfg: TrainConfig, stft: STFTConfig = STFT, vicinity_k: int | None = None):
        """This task's model for the training configuration ``cfg``."""
        return cls(points, cfg.acoustic, stft, vicinity_k=vicinity_k)

    @staticmethod
    def build_binauralizer(cfg: TrainConfig, stft: STFTConfig, context_dim: int | None) -> nn.Module:
        """This task's B alone (the checkpoint's validation builds it on the ``meta`` device)."""
        return Binauralizer(cfg.acoustic, context_dim, stft.n_freq, stft.hop_length / stft.sample_rate)

    @staticmethod
    def config_problem(cfg: TrainConfig, stft: STFTConfig) -> str | None:
        """What in ``cfg`` this task cannot run with, or None."""
        return None

    # -- vicinity and context ------------------------------------------------------------

    @property
    def vicinity_k(self) -> int:
        """k = ceil(percentile % of N) (or the explicit ``vicinity_k``, capped at N), listener and source each."""
        if self.fixed_k is not None:
            return min(self.fixed_k, self.points.num_points)
        return vicinity_size(self.points.num_points, self.cfg.vicinity_percentile)

    def vicinity(self, positions: torch.Tensor, cache: ModelCache | None = None) -> torch.Tensor:
        """positions [B, 3] (or [3]) -> indices of the k nearest audio points [B, k] (or [k]), unordered."""
        with torch.no_grad():
            coords = self.points.X.detach().t().contiguous() if cache is None else cache.coordinates  # [3, N]
            return nearest_indices(coords, positions, self.vicinity_k)

    @torch.no_grad()
    def precompute(self) -> ModelCache:
        """The parts of F and B that no pose changes; valid until the weights or points change."""
        points = None if self.field is None else self.field.point_features(self.points.alpha).contiguous()
        return ModelCache(self.binauralizer.frequency_features().contiguous(), points, self.points.X.t().contiguous())

    def context_at(self, positions: torch.Tensor, indices: torch.Tensor, cache: ModelCache | None = None) -> torch.Tensor:
        """C_i [B, context_dim] of positions [B, 3] from their vicinities [B, k]."""
        if self.field is None:
            raise ValueError("this model was trained without scene context (--no-context)")
        return self.field(self.points.X, self.points.alpha, positions, indices, None if cache is None else cache.points)

    def source_context(self, source: torch.Tensor, cache: ModelCache | None = None) -> SourceContext:
        """(C_S [context_dim] or None without context, source vicinity [k]) for source [3]: cacheable."""
        idx = self.vicinity(source, cache)  # [k]
        if self.field is None:
            return None, idx
        return self.context_at(source[None], idx[None], cache)[0], idx

    # -- masks -------------------------------------------------------------------------

    def masks(
        self, listener: torch.Tensor, theta: torch.Tensor, source: torch.Tensor,
        cached_source: SourceContext | None = None, cache: ModelCache | None = None,
    ) -> Masks:
        """listener [B, 3], theta [B] radians, source [3] -> :class:`Masks` with both vicinity sets.

        ``cached_source``: :meth:`source_context` of the same source, reused as is;
        ``cache``: :meth:`precompute`, at inference.
        """
        B = listener.shape[0]
        listener_idx = self.vicinity(listener, cache)  # [B, k]
        c_s, source_idx = cached_source if cached_source is not None else self.source_context(source, cache)
        context = None
        if self.field is not None:
            c_l = self.context_at(listener, listener_idx, cache)  # [B, c]
            context = torch.cat([c_s[None].expand(B, -1), c_l], dim=-1)  # [B, 2c] = C_S (+) C_L
        out = self.binauralizer(listener[:, :2], theta, context, None if cache is None else cache.frequency)
        return out.with_vicinity(listener_idx, source_idx)

    def forward(self, listener: torch.Tensor, theta: torch.Tensor, source: torch.Tensor, mono_mag: torch.Tensor):
        """Training: predicted magnitudes (s_m, s_l, s_r), each [B, F, N_t], of the source's
        ``mono_mag`` [B, F, N_t], and the :class:`Masks`."""
        m = self.masks(listener, theta, source)
        s_m, s_l, s_r = ear_magnitudes(mono_mag, m)
        post = self.binauralizer.post_conv
        if post is not None:
            s_l, s_r = post(mono_mag, m.mixture, m.difference, s_l, s_r)
        return (s_m, s_l, s_r), m
