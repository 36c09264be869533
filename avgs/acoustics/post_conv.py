"""AV-NeRF's optional time-frequency post-processing head ("conv head") of the binauralizer.

The masks of B are per frequency and time-invariant: they can colour the source and set
the interaural level per frequency, but not smear it in time as a room does. AV-NeRF's
code (``ANeRF(conv=True)``) adds a small 2-D convolution over the spectrogram that
predicts a residual per time-frequency bin, for each ear from
``(|S|, m_m, +-m_d, s_ear)``, and ends in a ReLU::

    s_l' = ReLU(s_l + Conv([|S|, m_m,  m_d, s_l]))
    s_r' = ReLU(s_r + Conv([|S|, m_m, -m_d, s_r]))        one Conv, shared by both ears

Conv: 7x7 (4 -> 16), ReLU, 3x3 (16 -> 16), ReLU, 3x3 (16 -> 1). Its receptive field is
5 STFT frames either side (about 29 ms), so a long signal can be processed in blocks that
overlap by that much (:data:`CONTEXT_FRAMES`). The mixture output ``s_m`` is not
post-processed (AV-NeRF's mono loss sees the plain mask).
"""

from __future__ import annotations

import torch
from torch import nn

CONTEXT_FRAMES = 5
"Frames either side that one output frame depends on: (7 - 1) / 2 + 1 + 1."


class PostConv(nn.Module):
    """Residual magnitude correction per ear: ``[B, F, N_t]`` in, ``[B, F, N_t]`` out (>= 0)."""

    def __init__(self, channels: int = 16):
        super().__init__()
        self.net = nn.Sequential(
            nn.Conv2d(4, channels, 7, 1, 3),
            nn.ReLU(inplace=True),
            nn.Conv2d(channels, channels, 3, 1, 1),
            nn.ReLU(inplace=True),
            nn.Conv2d(channels, 1, 3, 1, 1),
        )

    def forward(
        self, mono_mag: torch.Tensor, mixture: torch.Tensor, difference: torch.Tensor, s_l: torch.Tensor, s_r: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """mono_mag, s_l, s_r: [B, F, N_t]; masks [B, F] -> post-processed (s_l, s_r) [B, F, N_t]."""
        B, F, N = mono_mag.shape
        m = mixture[..., None].expand(B, F, N)  # [B, F, N_t]
        d = difference[..., None].expand(B, F, N)  # [B, F, N_t]
        x = torch.cat(
            [torch.stack([mono_mag, m, d, s_l], dim=1), torch.stack([mono_mag, m, -d, s_r], dim=1)], dim=0
        )  # [2B, 4, F, N_t]: both ears through the shared conv in one batch
        res = self.net(x)[:, 0]  # [2B, F, N_t]
        return torch.relu(s_l + res[:B]), torch.relu(s_r + res[B:])
