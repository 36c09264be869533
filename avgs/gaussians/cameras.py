"""Camera conventions shared by the rasterizer back ends.

Our poses are OpenGL / nerfstudio camera-to-world matrices (the camera looks along its
-Z, +Y up, +X right), as RWAVS stores them. The rasterizer takes gsplat's convention: a
world-to-camera ``viewmat`` in OpenCV's camera frame (looks along +Z, +Y down, +X right)
and pinhole intrinsics ``K`` in pixels, where pixel ``(j, i)`` has its centre at
``(j + 0.5, i + 0.5)``.
"""

from __future__ import annotations

import math

import torch

_GL_TO_CV = (1.0, -1.0, -1.0)
"Flip of the camera's Y and Z axes between OpenGL and OpenCV camera frames."


def viewmat_from_c2w(c2w: torch.Tensor) -> torch.Tensor:
    """OpenGL camera-to-world ``[..., 4, 4]`` -> OpenCV world-to-camera ``[..., 4, 4]``.

    Inverted in closed form (rotation transpose), so a rigid pose stays exactly rigid.
    """
    c2w = torch.as_tensor(c2w)
    if c2w.shape[-2:] != (4, 4):
        raise ValueError(f"camera-to-world must be [..., 4, 4], got {tuple(c2w.shape)}")
    flip = torch.tensor(_GL_TO_CV, dtype=c2w.dtype, device=c2w.device)
    R = c2w[..., :3, :3] * flip  # [..., 3, 3] OpenCV camera axes as columns
    t = c2w[..., :3, 3:]  # [..., 3, 1] camera centre
    Rt = R.transpose(-1, -2)
    out = torch.zeros_like(c2w)
    out[..., :3, :3] = Rt
    out[..., :3, 3:] = -Rt @ t
    out[..., 3, 3] = 1.0
    return out


def camera_center(viewmat: torch.Tensor) -> torch.Tensor:
    """World position ``[..., 3]`` of the camera of a world-to-camera ``[..., 4, 4]``."""
    R = viewmat[..., :3, :3]
    t = viewmat[..., :3, 3:]
    return (-R.transpose(-1, -2) @ t)[..., 0]


def intrinsics(fx: float, fy: float, cx: float, cy: float, dtype=torch.float32) -> torch.Tensor:
    """Pinhole matrix ``[3, 3]`` in pixels."""
    return torch.tensor([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=dtype)


def intrinsics_from_fov(fov_y_deg: float, width: int, height: int, dtype=torch.float32) -> torch.Tensor:
    """``K [3, 3]`` for a vertical field of view (degrees), square pixels, centred principal point."""
    fy = 0.5 * height / math.tan(math.radians(fov_y_deg) / 2)
    return intrinsics(fy, fy, width / 2, height / 2, dtype)
