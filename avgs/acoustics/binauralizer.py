"""B: the audio binauralizer (AV-NeRF's A-NeRF with the scene context C in place of its
visual feature; paper appendix "Binauralizer").

Per listener pose and for each of the F = 257 frequency bins it predicts a mixture mask
``m_m`` and a difference mask ``m_d`` (time-invariant, broadcast over STFT frames)::

    q   = ReLU(Linear(PE(x, y) (+) PE(f)))             18 + 21 -> width (42 + 21 in AV-NeRF)
    q  += Linear(C)                                      scene context (if used)
    h   = MLP_mix(q) + q                                 4 x (Linear + ReLU), residual
    m_m = act(Linear(h))                                 act: relu (AV-NeRF) or sigmoid (paper)
    e   = direction feature of theta / (1.01 pi)
    g   = MLP_diff(h, e) + h                             4 x (Linear + ReLU), residual; e enters every layer
    m_d = 2 sigmoid(Linear(g)) - 1                       in (-1, 1)
    r   = softplus(Linear(g))                            reverberant gains per ear (optional)

The reverberant gains ``r [B, 2, F]`` exist only with ``reverb_tail`` (our addition, see
:mod:`avgs.acoustics.reverb_tail`); the module then also holds the scene's learned RT60.

The frequency index is mapped linearly onto [-0.99, 0.99] before encoding. Positional
encodings use log-spaced frequencies (:mod:`avgs.acoustics.encodings`): 10, up to 2^9,
for the frequency query as in AV-NeRF; ``position_frequencies`` (default 4, up to 2^3)
for the listener's (x, y) in the normalised frame. AV-NeRF's 10 resolve far finer
than a few hundred training poses can pin down (2^9 per normalised unit: wavelengths of
about 0.01 units), and B memorised them (measured, see
:data:`avgs.config.AcousticConfig.position_frequencies`).

Direction feature (``direction_encoding``): ``"embedding"`` follows AV-NeRF's code, a learned,
circularly interpolated table of ``direction_embedding`` vectors added after each layer of
the difference MLP (AV-NeRF's table is coarser: 4 entries, with its own vector per layer);
``"fourier"`` is the paper's text, a high-frequency transform of theta concatenated with
the mixture feature; ``"harmonic"`` (default) concatenates ``cos(n theta), sin(n theta)``,
n = 1 .. ``direction_harmonics``: smooth, periodic across the listener's back, with the
source's lateral offset sin(theta) as an input. Chosen by measurement, see
:data:`avgs.config.AcousticConfig.direction_encoding`.

A concatenated feature enters the input of every layer of the difference MLP
(``direction_every_layer``), as AV-NeRF's embedding is added after every layer. Given to
the first layer only (the paper's text), it must survive three more layers, and with the
scene context B could settle on a difference mask that ignores theta (raw-head scenes,
2000 iterations: 8 runs of 12; see :data:`avgs.config.AcousticConfig.direction_every_layer`).

AV-NeRF leaves ``m_m`` linear and applies the ReLU to the ear magnitudes, so a bin with a
negative mask still gets gradient from the mixture loss; with ``relu`` on the mask itself,
as here, such a bin would get none, hence the mixture head's initialisation at gain 0.5.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
from torch import nn

from avgs.acoustics.encodings import encoded_dim, positional_encoding
from avgs.acoustics.post_conv import PostConv
from avgs.acoustics.reverb_tail import ReverbTail
from avgs.config import DIRECTION_ENCODINGS

THETA_SCALE = 1.0 / (1.01 * math.pi)
"theta (radians, in (-pi, pi]) times this lies strictly inside (-1, 1)."


class CircularEmbedding(nn.Module):
    """A learned table of ``n`` vectors on the circle, linearly interpolated.

    Input ``t`` in [-1, 1] (theta / (1.01 pi)); ``t = -1`` and ``t = 1`` meet, so the
    feature is continuous across the listener's back.
    """

    def __init__(self, n: int, dim: int):
        super().__init__()
        if n < 2:
            raise ValueError(f"a circular embedding needs >= 2 entries, got {n}")
        self.table = nn.Parameter(torch.randn(n, dim) * 0.1)  # [n, dim]
        self.n = n

    def forward(self, t: torch.Tensor) -> torch.Tensor:
        """t: [B] -> [B, dim]."""
        pos = (t.clamp(-1.0, 1.0) + 1.0) * 0.5 * self.n  # [B] in [0, n]
        lo = torch.floor(pos)
        w = (pos - lo)[:, None]  # [B, 1]
        i0 = lo.long() % self.n
        i1 = (i0 + 1) % self.n
        return (1.0 - w) * self.table[i0] + w * self.table[i1]


class BinauralMasks(NamedTuple):
    """What B predicts for a batch of poses."""

    mixture: torch.Tensor  # [B, F] >= 0 (relu) or in (0, 1) (sigmoid)
    difference: torch.Tensor  # [B, F] in (-1, 1)
    reverb: torch.Tensor | None  # [B, 2, F] >= 0, or None without a reverberant tail


def _linear_relu_stack(width: int, n: int, in_dim: int | None = None) -> nn.ModuleList:
    dims = [in_dim or width] + [width] * n
    return nn.ModuleList(nn.Linear(a, b) for a, b in zip(dims, dims[1:]))


class Binauralizer(nn.Module):
    """Masks ``m_m, m_d [B, F]`` from listener (x, y), theta and the scene context."""

    def __init__(
        self,
        context_dim: int | None,
        n_freq: int = 257,
        width: int = 128,
        pe_frequencies: int = 10,
        mixture_activation: str = "relu",
        direction_encoding: str = "embedding",
        direction_embedding: int = 180,
        position_frequencies: int | None = None,
        direction_harmonics: int = 4,
        direction_every_layer: bool = True,
        mlp_layers: int = 4,
        post_conv: bool = False,
        reverb_tail: bool = False,
        hop_seconds: float = 128 / 22050,
    ):
        super().__init__()
        if mixture_activation not in ("relu", "sigmoid"):
            raise ValueError(f"mixture_activation must be 'relu' or 'sigmoid', got {mixture_activation!r}")
        if direction_encoding not in DIRECTION_ENCODINGS:
            raise ValueError(f"direction_encoding must be one of {DIRECTION_ENCODINGS}, got {direction_encoding!r}")
        if direction_encoding == "harmonic" and direction_harmonics < 1:
            raise ValueError(f"direction_harmonics must be >= 1, got {direction_harmonics}")
        self.n_freq = n_freq
        self.pe_frequencies = pe_frequencies
        self.position_frequencies = pe_frequencies if position_frequencies is None else int(position_frequencies)
        self.direction_harmonics = int(direction_harmonics)
        self.direction_every_layer = bool(direction_every_layer)
        self.mixture_activation = mixture_activation
        self.direction_encoding = direction_encoding
        self.register_buffer(
            "freq_query", torch.linspace(-0.99, 0.99, n_freq)[:, None], persistent=False
        )  # [F, 1]
        query_dim = encoded_dim(2, self.position_frequencies) + encoded_dim(1, pe_frequencies)  # 18 + 21 by default
        self.query_proj = nn.Linear(query_dim, width)
        self.context_proj = nn.Linear(context_dim, width) if context_dim else None
        self.mix_mlp = _linear_relu_stack(width, mlp_layers)
        self.mix_head = nn.Linear(width, 1)
        # Every bin starts at gain 0.5 and receives gradient. With the default init a relu
        # mixture started dead (m_m = 0, no gradient) in 5-80 % of the bins, depending on
        # the seed, and such bins could stay silent for the whole run.
        nn.init.zeros_(self.mix_head.weight)
        nn.init.constant_(self.mix_head.bias, 0.5 if mixture_activation == "relu" else 0.0)
        if direction_encoding == "embedding":
            self.direction = CircularEmbedding(direction_embedding, width)
            self.diff_mlp = _linear_relu_stack(width, mlp_layers)
        else:
            self.direction = None
            D = self.direction_dim
            if self.direction_every_layer:
                self.diff_mlp = nn.ModuleList(nn.Linear(width + D, width) for _ in range(mlp_layers))
            else:
                self.diff_mlp = _linear_relu_stack(width, mlp_layers, in_dim=width + D)
        self.diff_head = nn.Linear(width, 1)
        self.post_conv = PostConv() if post_conv else None  # applied to magnitudes, see AVGSModel
        self.reverb = ReverbTail(n_freq, width, hop_seconds) if reverb_tail else None

    @property
    def direction_dim(self) -> int:
        """Width of :meth:`direction_feature` (Fourier and harmonic encodings)."""
        if self.direction_encoding == "harmonic":
            return 2 * self.direction_harmonics
        return encoded_dim(1, self.pe_frequencies)

    def direction_feature(self, theta: torch.Tensor) -> torch.Tensor:
        """theta [B] radians -> the concatenated direction feature e [B, direction_dim].

        ``fourier``: positional encoding of theta / (1.01 pi). ``harmonic``: cos(n theta),
        sin(n theta) for n = 1 .. direction_harmonics, periodic across the listener's back,
        and sin(theta), the source's lateral offset, is one of its inputs.
        """
        if self.direction_encoding == "harmonic":
            n = torch.arange(1, self.direction_harmonics + 1, device=theta.device, dtype=theta.dtype)  # [K]
            nt = theta[:, None] * n  # [B, K]
            return torch.cat([torch.cos(nt), torch.sin(nt)], dim=-1)
        return positional_encoding((theta * THETA_SCALE)[:, None], self.pe_frequencies)

    def forward(
        self, listener_xy: torch.Tensor, theta: torch.Tensor, context: torch.Tensor | None = None
    ) -> BinauralMasks:
        """listener_xy: [B, 2] normalised; theta: [B] radians (positive = source on the left);
        context: [B, C] or None -> :class:`BinauralMasks` (m_m [B, F], m_d [B, F], r [B, 2, F] or None)."""
        B, F = listener_xy.shape[0], self.n_freq
        pos = positional_encoding(listener_xy, self.position_frequencies)  # [B, P] (P = 18 by default)
        freq = positional_encoding(self.freq_query, self.pe_frequencies)  # [F, 21]
        query = torch.cat([pos[:, None, :].expand(B, F, -1), freq[None].expand(B, F, -1)], dim=-1)  # [B, F, P + 21]
        q = torch.relu(self.query_proj(query))  # [B, F, W]
        if self.context_proj is not None:
            if context is None:
                raise ValueError("this binauralizer was built with scene context; pass context [B, C]")
            q = q + self.context_proj(context)[:, None, :]  # [B, F, W]
        h = q
        for layer in self.mix_mlp:
            h = torch.relu(layer(h))
        h = h + q  # [B, F, W] residual
        m = self.mix_head(h)[..., 0]  # [B, F]
        mixture = torch.relu(m) if self.mixture_activation == "relu" else torch.sigmoid(m)

        if self.direction is not None:
            e = self.direction(theta * THETA_SCALE)[:, None, :]  # [B, 1, W]
            g = h
            for layer in self.diff_mlp:
                g = torch.relu(layer(g)) + e
        else:
            e = self.direction_feature(theta)[:, None, :].expand(B, F, -1)  # [B, F, D]
            g = h
            for i, layer in enumerate(self.diff_mlp):
                g = torch.relu(layer(torch.cat([g, e], dim=-1) if i == 0 or self.direction_every_layer else g))
        g = g + h  # [B, F, W] residual
        difference = 2.0 * torch.sigmoid(self.diff_head(g)[..., 0]) - 1.0  # [B, F]
        reverb = self.reverb.gains(g) if self.reverb is not None else None  # [B, 2, F]
        return BinauralMasks(mixture, difference, reverb)
