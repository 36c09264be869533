"""B: the audio binauralizer (AV-NeRF's A-NeRF with the scene context C in place of its
visual feature; paper appendix "Binauralizer").

Per listener pose and for each of the F = 257 frequency bins it predicts a mixture mask
``m_m`` and a difference mask ``m_d`` (time-invariant, broadcast over STFT frames)::

    q   = ReLU(W_xy PE(x, y) + W_f PE(f) + b)             query projection
    q  += Linear(C)                                        scene context (if used)
    h   = MLP_mix(q) + q                                   4 x (Linear + ReLU), residual
    m_m = act(Linear(h))                                   act: relu (AV-NeRF) or sigmoid (paper)
    e   = direction feature of theta                       (avgs.acoustics.direction)
    g   = MLP_diff(h, e) + h                               4 x (Linear + ReLU), residual; e enters every layer
    m_d = 2 sigmoid(Linear(g)) - 1                         in (-1, 1)
    r   = softplus(Linear(g))                              reverberant gains per ear (with the tail)

The forward pass has two parts. ``W_f PE(f) + b`` depends only on the frequency:
:meth:`Binauralizer.frequency_features` computes it ``[F, width]``, and inference caches
it. Everything else depends on the pose. A layer that takes the direction feature is
split the same way, ``W [g (+) e] + b = W_g g + (W_e e + b)``: ``e`` is one vector per pose.

The frequency index is mapped linearly onto [-0.99, 0.99] before encoding, with
``pe_frequencies`` log-spaced frequencies (AV-NeRF's 10); the listener's (x, y) in the
normalised frame with ``position_frequencies`` (default 4). With ``direction_every_layer``
off the direction feature enters the first difference layer only (the paper's text; the
bundled demo was trained so). Choices and their measurements: docs/paper-deviations.md.

The mixture head starts at gain 0.5 with zero weights: with ``relu`` on the mask, a bin
that started at a negative value would get no gradient and could stay silent.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn.functional import linear

from avgs.acoustics.direction import DIRECTION_ENCODINGS, direction_dim, direction_feature
from avgs.acoustics.encodings import encoded_dim, positional_encoding
from avgs.acoustics.post_conv import PostConv
from avgs.acoustics.interaural import DEFAULT_SCALE, ear_delays
from avgs.acoustics.reverb_tail import ReverbTail
from avgs.acoustics.synthesis import Masks
from avgs.config import AcousticConfig

MLP_LAYERS = 4
"Linear + ReLU layers of each of B's two MLPs (AV-NeRF)."


class Binauralizer(nn.Module):
    """Masks ``m_m, m_d [B, F]`` (and tail gains) from listener (x, y), theta and the scene context."""

    def __init__(self, cfg: AcousticConfig, context_dim: int | None, n_freq: int, hop_seconds: float):
        super().__init__()
        if cfg.mixture_activation not in ("relu", "sigmoid"):
            raise ValueError(f"mixture_activation must be 'relu' or 'sigmoid', got {cfg.mixture_activation!r}")
        if cfg.direction_encoding not in DIRECTION_ENCODINGS:
            raise ValueError(f"direction_encoding must be one of {DIRECTION_ENCODINGS}, got {cfg.direction_encoding!r}")
        if cfg.direction_harmonics < 1 or cfg.position_frequencies < 0:
            raise ValueError(
                f"direction_harmonics must be >= 1 and position_frequencies >= 0, "
                f"got {cfg.direction_harmonics} and {cfg.position_frequencies}"
            )
        width = cfg.binauralizer_width
        self.cfg = cfg
        self.n_freq = n_freq
        self.width = width
        # On the CPU even under a meta device (checkpoint validation builds B there): a meta linspace
        # imports sympy, a second of every process that reads a checkpoint.
        self.register_buffer("freq_query", torch.linspace(-0.99, 0.99, n_freq, device="cpu")[:, None],
                             persistent=False)  # [F, 1]
        self.position_dim = encoded_dim(2, cfg.position_frequencies)  # 18 by default
        self.query_proj = nn.Linear(self.position_dim + encoded_dim(1, cfg.pe_frequencies), width)
        self.context_proj = nn.Linear(context_dim, width) if context_dim else None
        self.mix_mlp = nn.ModuleList(nn.Linear(width, width) for _ in range(MLP_LAYERS))
        self.mix_head = nn.Linear(width, 1)
        nn.init.zeros_(self.mix_head.weight)
        nn.init.constant_(self.mix_head.bias, 0.5 if cfg.mixture_activation == "relu" else 0.0)
        self.direction_dim = direction_dim(cfg.direction_encoding, cfg.direction_harmonics, cfg.pe_frequencies)
        takes = MLP_LAYERS if cfg.direction_every_layer else 1
        self.diff_mlp = nn.ModuleList(
            nn.Linear(width + (self.direction_dim if i < takes else 0), width) for i in range(MLP_LAYERS)
        )
        self.diff_head = nn.Linear(width, 1)
        self.post_conv = PostConv() if cfg.post_conv else None  # on the ear magnitudes: avgs.acoustics.synthesis
        self.reverb = ReverbTail(n_freq, width, hop_seconds) if cfg.reverb_tail else None
        if cfg.interaural_delay:  # a / c of Woodworth's head, seconds: set from the recordings (avgs.train.binaural)
            self.register_buffer("itd_scale", torch.tensor(DEFAULT_SCALE))
        else:
            self.itd_scale = None

    def direction_feature(self, theta: torch.Tensor) -> torch.Tensor:
        """theta [B] radians -> e [B, direction_dim]."""
        c = self.cfg
        return direction_feature(theta, c.direction_encoding, c.direction_harmonics, c.pe_frequencies)

    def frequency_features(self) -> torch.Tensor:
        """The frequency part of the query projection, ``W_f PE(f) + b`` [F, width]: cacheable."""
        freq = positional_encoding(self.freq_query, self.cfg.pe_frequencies)  # [F, 21]
        return linear(freq, self.query_proj.weight[:, self.position_dim :], self.query_proj.bias)

    def forward(
        self, listener_xy: torch.Tensor, theta: torch.Tensor, context: torch.Tensor | None = None,
        frequency_features: torch.Tensor | None = None, bins: torch.Tensor | None = None,
    ) -> Masks:
        """listener_xy: [B, 2] normalised; theta: [B] radians (positive = source on the left);
        context: [B, C] or None; ``frequency_features``: :meth:`frequency_features`, cached at inference.
        ``bins`` [f] (int64 indices; None: all): evaluate only those bins (each bin's rows are
        independent: the same numbers as those entries of the whole output), masks and decay [.., f].
        Returns :class:`~avgs.acoustics.synthesis.Masks` without vicinity sets."""
        q_f = self.frequency_features() if frequency_features is None else frequency_features  # [F, W]
        if bins is not None:
            q_f = q_f[bins]  # [f, W]
        B, F, W = listener_xy.shape[0], q_f.shape[0], self.width
        pos = positional_encoding(listener_xy, self.cfg.position_frequencies)  # [B, P]
        row = pos @ self.query_proj.weight[:, : self.position_dim].t()  # [B, W]
        q = (q_f + row[:, None, :]).relu_()  # [B, F, W]
        if self.context_proj is not None:
            if context is None:
                raise ValueError("this binauralizer was built with scene context; pass context [B, C]")
            q = q + self.context_proj(context)[:, None, :]  # [B, F, W]
        q = q.view(B * F, W)  # all poses and frequencies as one batch of rows
        h = q
        for layer in self.mix_mlp:
            h = torch.addmm(layer.bias, h, layer.weight.t()).relu_()
        h = h + q  # [B F, W] residual
        m = (h @ self.mix_head.weight.t()).view(B, F) + self.mix_head.bias  # [B, F]
        mixture = torch.relu(m) if self.cfg.mixture_activation == "relu" else torch.sigmoid(m)

        e = self.direction_feature(theta)  # [B, D]
        g = h
        for layer in self.diff_mlp:
            if layer.in_features > W:  # W_g g + (W_e e + b): the direction's part is one vector per pose
                ge = torch.addmm(layer.bias, e, layer.weight[:, W:].t())  # [B, W]
                g = (g @ layer.weight[:, :W].t()).view(B, F, W).add_(ge[:, None, :]).relu_().view(B * F, W)
            else:
                g = torch.addmm(layer.bias, g, layer.weight.t()).relu_()
        g = g + h  # [B F, W] residual
        difference = 2.0 * torch.sigmoid((g @ self.diff_head.weight.t()).view(B, F) + self.diff_head.bias) - 1.0  # [B, F]
        delay = None if self.itd_scale is None else ear_delays(theta, self.itd_scale)  # [B, 2] seconds
        if self.reverb is None:
            return Masks(mixture, difference, delay=delay)
        gains = self.reverb.gains(g.view(B, F, W))  # [B, 2, F]
        decay = self.reverb.decay()  # [F]
        return Masks(mixture, difference, gains, decay if bins is None else decay[bins], delay=delay)
