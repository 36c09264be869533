"""EWA projection of 3D Gaussians to the image plane (the torch back end's first half).

Follows gsplat 1.4's ``fully_fused_projection`` (perspective camera) so the two back ends
agree: ``Sigma = R S S^T R^T``, ``Sigma' = J W Sigma W^T J^T + eps2d I`` (the 0.3 px^2 low-pass
dilation of 3D-GS), the Jacobian's ``x/z, y/z`` clamped to 1.3x the field of view, a
radius of ``ceil(3 sqrt(lambda_max))`` pixels, and Gaussians culled (radius 0) when their
centre is nearer than ``near`` or farther than ``far``, or their box misses the image.

Every intermediate is kept finite for any input: zero scales give ``Sigma' = eps2d I``,
an all-zero quaternion gives the identity rotation, and culled Gaussians are projected
with a dummy depth so that no 0/0 reaches the gradients.
"""

from __future__ import annotations


import torch


def quat_to_rotmat(quats: torch.Tensor) -> torch.Tensor:
    """Quaternions ``[N, 4]`` (w, x, y, z; any length) -> rotation matrices ``[N, 3, 3]``.

    Normalised with a guarded norm; the zero quaternion maps to the identity.
    """
    q = quats / torch.sqrt((quats * quats).sum(-1, keepdim=True).clamp_min(1e-24))  # [N, 4]
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    ).reshape(*quats.shape[:-1], 3, 3)


def covariance_3d(quats: torch.Tensor, scales: torch.Tensor) -> torch.Tensor:
    """``Sigma = R S S^T R^T`` ``[N, 3, 3]`` from quaternions ``[N, 4]`` and scales ``[N, 3]``."""
    M = quat_to_rotmat(quats) * scales[..., None, :]  # [N, 3, 3] = R S
    return M @ M.transpose(-1, -2)


def project_gaussians(
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    viewmat: torch.Tensor,
    K: torch.Tensor,
    width: int,
    height: int,
    near: float = 0.01,
    far: float = 1e10,
    eps2d: float = 0.3,
) -> dict[str, torch.Tensor]:
    """Project ``N`` Gaussians through one pinhole camera.

    Args: ``means [N, 3]``, ``quats [N, 4]``, ``scales [N, 3]`` (world frame, scales
    already exponentiated), ``viewmat [4, 4]`` world-to-camera (OpenCV), ``K [3, 3]``.

    Returns ``means2d [N, 2]`` (pixels), ``conics [N, 3]`` (upper triangle a, b, c of
    ``inverse(Sigma')``), ``depths [N]`` (camera z), ``radii [N]`` int32 (0 = culled).
    """
    R, t = viewmat[:3, :3], viewmat[:3, 3]
    mean_c = means @ R.T + t  # [N, 3] camera frame
    x, y, z = mean_c.unbind(-1)
    with torch.no_grad():
        in_range = (z > near) & (z < far)  # [N]
    z_safe = torch.where(in_range, z, torch.ones_like(z))  # [N] no division by ~0 anywhere
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    rz = 1.0 / z_safe
    tan_fovx, tan_fovy = 0.5 * width / fx, 0.5 * height / fy
    tx = z_safe * torch.minimum((width - cx) / fx + 0.3 * tan_fovx, torch.maximum(-(cx / fx + 0.3 * tan_fovx), x * rz))
    ty = z_safe * torch.minimum((height - cy) / fy + 0.3 * tan_fovy, torch.maximum(-(cy / fy + 0.3 * tan_fovy), y * rz))
    zero = torch.zeros_like(rz)
    J = torch.stack([fx * rz, zero, -fx * tx * rz * rz, zero, fy * rz, -fy * ty * rz * rz], -1).reshape(-1, 2, 3)
    JW = J @ R  # [N, 2, 3]
    cov2d = JW @ covariance_3d(quats, scales) @ JW.transpose(-1, -2)  # [N, 2, 2]
    a = cov2d[:, 0, 0] + eps2d
    b = cov2d[:, 0, 1]
    c = cov2d[:, 1, 1] + eps2d
    det = a * c - b * b  # [N] >= eps2d^2 > 0 for eps2d > 0
    det_safe = torch.where(det > 0, det, torch.ones_like(det))
    conics = torch.stack([c / det_safe, -b / det_safe, a / det_safe], -1)  # [N, 3]
    means2d = torch.stack([fx * x * rz + cx, fy * y * rz + cy], -1)  # [N, 2]
    with torch.no_grad():
        half = 0.5 * (a + c)
        lam = half + torch.sqrt(torch.clamp_min(half * half - det, 0.01))
        radius = torch.ceil(3.0 * torch.sqrt(lam))  # [N]
        mx, my = means2d.unbind(-1)
        on_image = (mx + radius > 0) & (mx - radius < width) & (my + radius > 0) & (my - radius < height)
        ok = in_range & (det > 0) & on_image & torch.isfinite(radius)
        radii = torch.where(ok, radius, torch.zeros_like(radius)).to(torch.int32)
    return {"means2d": means2d, "conics": conics, "depths": z, "radii": radii}
