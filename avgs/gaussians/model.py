"""``GaussianModel``: the 3D-GS scene G (normalised frame).

Parameters (``nn.ParameterDict`` ``params``, one optimizer group each)::

    means           [N, 3]   centres
    quats           [N, 4]   rotations (w, x, y, z), unnormalised
    log_scales      [N, 3]   log standard deviations
    opacity_logits  [N]      logit of the opacity
    sh0             [N, 1, 3] SH DC coefficient (learning rate of its own, as in 3D-GS)
    shN             [N, 15, 3] SH coefficients of degrees 1..3

The stored form (:meth:`to_dict`, the checkpoint's ``gaussians``) joins the SH into
``sh [N, 16, 3]``.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from avgs.gaussians.sh import MAX_DEGREE, num_coeffs, rgb_to_sh, sh_colors, sh_to_rgb

STORED_KEYS = ("means", "quats", "log_scales", "opacity_logits", "sh")
"Keys of :meth:`GaussianModel.to_dict` (the checkpoint's ``gaussians``)."
INIT_OPACITY = 0.1
"Opacity of freshly initialised Gaussians (3D-GS)."


def knn_scale(points: np.ndarray, k: int = 3, floor: float = 1e-4) -> np.ndarray:
    """Mean distance ``[n]`` to each point's ``k`` nearest neighbours (3D-GS's initial scale),
    at least ``floor`` (duplicated points would otherwise give a zero scale)."""
    from scipy.spatial import cKDTree

    n = len(points)
    if n < 2:
        return np.full(n, 0.01)
    k = min(k, n - 1)
    d, _ = cKDTree(points).query(points, k=k + 1)  # [n, k + 1], column 0 is the point itself
    return np.maximum(np.sqrt((d[:, 1:] ** 2).mean(axis=1)), floor)


class GaussianModel(nn.Module):
    """3D Gaussians with SH colour of degree ``sh_degree`` (3: 48 coefficients)."""

    def __init__(
        self,
        means: torch.Tensor,
        quats: torch.Tensor,
        log_scales: torch.Tensor,
        opacity_logits: torch.Tensor,
        sh: torch.Tensor,
        sh_degree: int = MAX_DEGREE,
    ):
        super().__init__()
        means = torch.as_tensor(means, dtype=torch.float32)
        n = means.shape[0] if means.dim() == 2 else -1
        sh = torch.as_tensor(sh, dtype=torch.float32)
        checks = {
            "means": (means, (n, 3)),
            "quats": (torch.as_tensor(quats), (n, 4)),
            "log_scales": (torch.as_tensor(log_scales), (n, 3)),
            "opacity_logits": (torch.as_tensor(opacity_logits), (n,)),
            "sh": (sh, (n, 16, 3)),
        }
        for name, (t, shape) in checks.items():
            if tuple(t.shape) != shape or n < 0:
                raise ValueError(f"GaussianModel: {name} must be {list(shape)} (N = {n}), got {list(t.shape)}")
            if not torch.isfinite(t).all():
                raise ValueError(f"GaussianModel: {name} holds NaN or Inf")
        if not 0 <= sh_degree <= MAX_DEGREE:
            raise ValueError(f"GaussianModel: sh_degree must be in 0..{MAX_DEGREE}, got {sh_degree}")
        self.sh_degree = int(sh_degree)
        self.params = nn.ParameterDict(
            {
                "means": nn.Parameter(means.clone()),
                "quats": nn.Parameter(torch.as_tensor(quats, dtype=torch.float32).clone()),
                "log_scales": nn.Parameter(torch.as_tensor(log_scales, dtype=torch.float32).clone()),
                "opacity_logits": nn.Parameter(torch.as_tensor(opacity_logits, dtype=torch.float32).clone()),
                "sh0": nn.Parameter(sh[:, :1].clone()),
                "shN": nn.Parameter(sh[:, 1:].clone()),
            }
        )

    # -- construction -------------------------------------------------------------------

    @classmethod
    def from_points(
        cls,
        points,
        colors=None,
        sh_degree: int = MAX_DEGREE,
        opacity: float = INIT_OPACITY,
    ) -> "GaussianModel":
        """3D-GS initialisation: isotropic scales from the 3 nearest neighbours, identity
        rotations, opacity 0.1, SH DC from ``colors [n, 3]`` in [0, 1] (grey when None)."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if len(pts) == 0 or not np.all(np.isfinite(pts)):
            raise ValueError(f"GaussianModel.from_points: need >= 1 finite point [n, 3], got {np.shape(points)}")
        n = len(pts)
        if colors is None:
            rgb = torch.full((n, 3), 0.5)
        else:
            rgb = torch.as_tensor(np.asarray(colors, dtype=np.float32).reshape(-1, 3))
            if len(rgb) != n:
                raise ValueError(f"GaussianModel.from_points: {len(rgb)} colours for {n} points")
            rgb = rgb.clamp(0.0, 1.0)
        sh = torch.zeros(n, 16, 3)
        sh[:, 0] = rgb_to_sh(rgb)
        quats = torch.zeros(n, 4)
        quats[:, 0] = 1.0
        log_scales = torch.from_numpy(np.log(knn_scale(pts))).float()[:, None].repeat(1, 3)
        logit = math.log(opacity / (1.0 - opacity))
        return cls(torch.from_numpy(pts).float(), quats, log_scales, torch.full((n,), logit), sh, sh_degree)

    @classmethod
    def from_dict(cls, d: dict, sh_degree: int = MAX_DEGREE) -> "GaussianModel":
        """Inverse of :meth:`to_dict` (e.g. a checkpoint's ``gaussians``)."""
        missing = [k for k in STORED_KEYS if k not in d]
        if missing:
            raise ValueError(f"GaussianModel.from_dict: missing {missing}; expected keys {list(STORED_KEYS)}")
        sh = torch.as_tensor(d["sh"]).float()
        n = sh.shape[0]
        return cls(d["means"], d["quats"], d["log_scales"], torch.as_tensor(d["opacity_logits"]).reshape(n), sh, sh_degree)

    def to_dict(self) -> dict[str, torch.Tensor]:
        """Detached CPU tensors: ``means [N,3], quats [N,4], log_scales [N,3], opacity_logits [N], sh [N,16,3]``."""
        p = {k: v.detach().float().cpu().clone() for k, v in self.params.items()}
        return {
            "means": p["means"],
            "quats": p["quats"],
            "log_scales": p["log_scales"],
            "opacity_logits": p["opacity_logits"],
            "sh": torch.cat([p["sh0"], p["shN"]], dim=1),
        }

    # -- views of the parameters ---------------------------------------------------------

    def __len__(self) -> int:
        return int(self.params["means"].shape[0])

    @property
    def num_gaussians(self) -> int:
        return len(self)

    @property
    def means(self) -> torch.Tensor:
        """``[N, 3]`` centres (the parameter itself)."""
        return self.params["means"]

    @property
    def quats(self) -> torch.Tensor:
        """``[N, 4]`` unnormalised quaternions (w, x, y, z)."""
        return self.params["quats"]

    @property
    def scales(self) -> torch.Tensor:
        """``[N, 3]`` standard deviations (exp of the log-scales)."""
        return torch.exp(self.params["log_scales"])

    @property
    def opacities(self) -> torch.Tensor:
        """``[N]`` in (0, 1)."""
        return torch.sigmoid(self.params["opacity_logits"])

    @property
    def sh(self) -> torch.Tensor:
        """``[N, 16, 3]`` SH coefficients."""
        return torch.cat([self.params["sh0"], self.params["shN"]], dim=1)

    def features(self, kind: str) -> torch.Tensor:
        """Per-Gaussian parameters ``[N, d]`` (detached) for the audio-guidance alpha:
        ``sh`` 48 (coefficient-major, as ``sh.reshape(N, 48)``), ``r`` 4 (unit quaternion;
        zero stays zero), ``s`` 3 (log-scales), ``o`` 1 (opacity logit)."""
        n = len(self)
        with torch.no_grad():
            if kind == "sh":
                return self.sh.reshape(n, 48).clone()
            if kind == "r":
                q = self.params["quats"]
                return q / q.norm(dim=-1, keepdim=True).clamp_min(1e-12)
            if kind == "s":
                return self.params["log_scales"].clone()
            if kind == "o":
                return self.params["opacity_logits"].reshape(n, 1).clone()
        raise ValueError(f"GaussianModel.features: unknown kind {kind!r}; expected one of sh, r, s, o")

    def colors(self, campos: torch.Tensor, sh_degree: int | None = None) -> torch.Tensor:
        """RGB ``[N, 3]`` (>= 0) seen from the world point ``campos [3]``."""
        degree = self.sh_degree if sh_degree is None else sh_degree
        campos = torch.as_tensor(campos, dtype=self.means.dtype, device=self.means.device).reshape(3)
        return sh_colors(degree, self.sh[:, : num_coeffs(degree)], self.means, campos)

    def rgb(self) -> torch.Tensor:
        """View-independent colour ``[N, 3]`` in [0, 1] from the DC term (for drawing points)."""
        return sh_to_rgb(self.params["sh0"][:, 0]).detach().clamp(0.0, 1.0)
