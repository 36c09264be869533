"""G: the 3D Gaussian Splatting scene of stage 1.

- :mod:`.model`: :class:`GaussianModel` (means, quats, log-scales, opacity logits, SH degree 3)
- :mod:`.rasterize`: :func:`rasterize` with ``backend="auto" | "torch" | "gsplat"``
  (:mod:`.projection` and :mod:`.composite` are the pure-PyTorch back end)
- :mod:`.ssim`, :mod:`.densify` (clone / split / prune strategy), :mod:`.trainer` (stage 1)

Importing this package needs neither CUDA nor gsplat.
"""

from avgs.gaussians.model import GaussianModel
from avgs.gaussians.rasterize import rasterize

__all__ = ["GaussianModel", "rasterize"]
