"""G_a: the audio points. Positions ``X [N, 3]`` (normalised frame) and audio-guidance
parameters ``alpha [N, D]``, both learned.

alpha is initialised from parameters of the warmed-up 3D-GS scene G, chosen by a
'+'-joined spec (paper's ablation; best ``sh+r``, 52 dims):

====  ====  =========================================
kind  dims  what
====  ====  =========================================
sh    48    spherical-harmonics colour coefficients
r     4     rotation quaternion, normalised
s     3     log-scales
o     1     opacity (logit)
====  ====  =========================================
"""

from __future__ import annotations

import torch
from torch import nn

from avgs.gaussians.sh import rgb_to_sh

ALPHA_KINDS: dict[str, int] = {"sh": 48, "r": 4, "s": 3, "o": 1}
"Parameters of G usable for alpha, with their widths."


def parse_alpha_spec(spec: str) -> list[str]:
    """``"sh+r"`` -> ``["sh", "r"]``; rejects unknown or repeated kinds."""
    kinds = [k.strip() for k in str(spec).split("+") if k.strip()]
    bad = [k for k in kinds if k not in ALPHA_KINDS]
    if not kinds or bad or len(set(kinds)) != len(kinds):
        raise ValueError(
            f"alpha-init must be a '+'-joined subset of {'/'.join(ALPHA_KINDS)} without repeats "
            f"(e.g. 'sh+r'), got {spec!r}"
        )
    return kinds


def alpha_dim(spec: str) -> int:
    """Width D of alpha for a spec (``sh+r`` -> 52)."""
    return sum(ALPHA_KINDS[k] for k in parse_alpha_spec(spec))


def alpha_from_features(features: dict[str, torch.Tensor], spec: str) -> torch.Tensor:
    """Concatenate per-point features ``{kind: [N, d]}`` in spec order -> ``[N, D]``.

    Quaternions ('r') are normalised to unit length, robustly at any magnitude (a zero
    quaternion stays zero). Non-finite features are rejected.
    """
    parts = []
    for kind in parse_alpha_spec(spec):
        if kind not in features:
            raise ValueError(f"alpha-init {spec!r} needs G's {kind!r} parameters, which were not given")
        f = torch.as_tensor(features[kind]).detach().float().reshape(len(features[kind]), -1)  # [N, d]
        if f.shape[1] != ALPHA_KINDS[kind]:
            raise ValueError(f"G's {kind!r} parameters have {f.shape[1]} dims, expected {ALPHA_KINDS[kind]}")
        if not torch.isfinite(f).all():
            bad = int((~torch.isfinite(f)).any(-1).sum())
            raise ValueError(f"G's {kind!r} parameters hold NaN or Inf in {bad} of {len(f)} Gaussians; expected finite values")
        if kind == "r":
            # Divide by the largest entry first: the norm of a tiny (1e-30) or huge (1e20)
            # quaternion under- or overflows float32. A zero quaternion stays zero.
            big = f.abs().amax(dim=-1, keepdim=True)  # [N, 1]
            f = torch.where(big > 0, f / big.clamp_min(torch.finfo(f.dtype).tiny), f)
            f = f / f.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        parts.append(f)
    return torch.cat(parts, dim=-1)


def alpha_from_gaussians(gaussians, spec: str) -> torch.Tensor:
    """alpha ``[N, D]`` from a :class:`avgs.gaussians.GaussianModel` (``.features(kind)``)."""
    return alpha_from_features({k: gaussians.features(k) for k in parse_alpha_spec(spec)}, spec)


def alpha_from_colors(colors: torch.Tensor, spec: str) -> torch.Tensor:
    """alpha ``[N, D]`` for points that have only an RGB colour (the ``--init sfm`` path).

    What a freshly initialised 3D-GS would hold: SH DC from the colour (rest zero),
    identity rotation, zero log-scale, zero opacity logit.
    """
    colors = torch.as_tensor(colors).float().reshape(-1, 3)  # [N, 3] in [0, 1]
    n = len(colors)
    sh = torch.zeros(n, 16, 3)
    sh[:, 0] = rgb_to_sh(colors)  # RGB -> SH degree-0 coefficient
    quat = torch.zeros(n, 4)
    quat[:, 0] = 1.0
    feats = {"sh": sh.reshape(n, 48), "r": quat, "s": torch.zeros(n, 3), "o": torch.zeros(n, 1)}
    return alpha_from_features(feats, spec)


class AudioPoints(nn.Module):
    """Learned audio points: ``X [N, 3]`` (normalised) and ``alpha [N, D]``.

    Point management replaces the two parameters wholesale (:meth:`set_points`); an
    optimizer holding them must be updated at the same time (see
    :mod:`avgs.train.point_management`).
    """

    def __init__(self, X: torch.Tensor, alpha: torch.Tensor):
        super().__init__()
        X = torch.as_tensor(X).float()
        alpha = torch.as_tensor(alpha).float()
        if X.dim() != 2 or X.shape[1] != 3 or len(X) < 1:
            raise ValueError(f"audio point positions must be [N >= 1, 3], got {tuple(X.shape)}")
        if alpha.dim() != 2 or alpha.shape[0] != X.shape[0]:
            raise ValueError(f"alpha must be [N={len(X)}, D], got {tuple(alpha.shape)}")
        if not (torch.isfinite(X).all() and torch.isfinite(alpha).all()):
            raise ValueError("audio points hold NaN or Inf")
        self.X = nn.Parameter(X.clone())  # [N, 3]
        self.alpha = nn.Parameter(alpha.clone())  # [N, D]

    @property
    def num_points(self) -> int:
        return int(self.X.shape[0])

    @property
    def alpha_dim(self) -> int:
        return int(self.alpha.shape[1])

    def set_points(self, X: nn.Parameter, alpha: nn.Parameter) -> None:
        """Swap in new parameters (same D); used by point management."""
        if X.shape[0] != alpha.shape[0] or alpha.shape[1] != self.alpha_dim:
            raise ValueError(f"set_points: X {tuple(X.shape)} and alpha {tuple(alpha.shape)} do not match")
        self.X = X
        self.alpha = alpha
