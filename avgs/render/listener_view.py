"""What the listener sees: G, the scene's 3D Gaussian Splatting model, rendered from a listener pose.

A checkpoint saved with G holds all of its parameters (means, quaternions, log-scales,
opacity logits, SH of degree 3, in the normalised frame: :mod:`avgs.io.checkpoint`);
:class:`~avgs.render.renderer.SceneRenderer` keeps only G's centres and colours for drawing, so
:meth:`ListenerView.load` reads the checkpoint's ``gaussians`` again and renders them
with :func:`avgs.gaussians.rasterize.rasterize` (gsplat on CUDA, else our PyTorch
rasterizer: about 0.3 s for 50k Gaussians at 192x144 on one CPU core).

The camera stands at the listener's position, level (no pitch or roll), looking along the
listener's yaw (degrees counter-clockwise from +x), +z up: an OpenGL camera-to-world, as
the dataset's poses are.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch

from avgs.data.frame import SceneFrame

DEFAULT_FOV_Y = 60.0
"Vertical field of view of the listener's camera (degrees)."


def listener_c2w(position_normalised, yaw_degrees: float) -> torch.Tensor:
    """OpenGL camera-to-world ``[4, 4]`` float32: at ``position`` [3], facing ``yaw``, level, +z up."""
    yaw = math.radians(float(yaw_degrees))
    forward = torch.tensor([math.cos(yaw), math.sin(yaw), 0.0])
    up = torch.tensor([0.0, 0.0, 1.0])
    right = torch.linalg.cross(forward, up)  # the camera's +X
    c2w = torch.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2] = right, up, -forward  # OpenGL: the camera looks along its -Z
    c2w[:3, 3] = torch.as_tensor(np.asarray(position_normalised, dtype=np.float64).reshape(3), dtype=torch.float32)
    return c2w


class ListenerView:
    """G and the scene's frame, ready to render the view from any listener pose."""

    def __init__(self, gaussians: dict, frame: SceneFrame, device: str | torch.device = "cpu"):
        from avgs.gaussians.model import GaussianModel

        self.frame = frame
        self.device = torch.device(device)
        self.model = GaussianModel.from_dict(gaussians).to(self.device).requires_grad_(False)

    @classmethod
    def load(cls, path: str | Path, device: str | torch.device = "cpu") -> "ListenerView | None":
        """From a checkpoint file; None when it was saved without G (``--no-gaussians``)."""
        from avgs.io.checkpoint import load_checkpoint

        ckpt = load_checkpoint(path, map_location="cpu")
        if not ckpt.get("gaussians"):
            return None
        return cls(ckpt["gaussians"], SceneFrame.from_dict(ckpt["frame"]), device)

    def __len__(self) -> int:
        return len(self.model)

    def render(self, listener, yaw: float, width: int = 192, height: int = 144, fov_y: float = DEFAULT_FOV_Y,
               background=(0.0, 0.0, 0.0), stop=None) -> np.ndarray:
        """RGB ``[height, width, 3]`` uint8 of G seen from ``listener`` (world [3]) facing ``yaw`` degrees.

        ``stop``: called between chunks of tiles on the CPU; True abandons the image with
        :class:`avgs.threads.Stopped` (the explorer's inset gives way to the sound so)."""
        from avgs.gaussians.cameras import intrinsics_from_fov, viewmat_from_c2w
        from avgs.gaussians.rasterize import rasterize

        p = np.asarray(listener, dtype=np.float64).reshape(3)
        if not np.all(np.isfinite(p)) or not math.isfinite(float(yaw)):
            raise ValueError(f"listener pose must be finite, got {listener!r}, yaw {yaw!r}")
        g = self.model
        viewmat = viewmat_from_c2w(listener_c2w(self.frame.to_normalised(p), yaw)).to(self.device)
        K = intrinsics_from_fov(fov_y, width, height).to(self.device)
        bg = torch.as_tensor(background, dtype=torch.float32, device=self.device)
        with torch.inference_mode():
            rgb, _, _ = rasterize(g.means, g.quats, g.scales, g.opacities, g.sh, viewmat, K, int(width), int(height),
                                  background=bg, stop=stop)
        return (rgb.clamp(0.0, 1.0) * 255.0 + 0.5).to(torch.uint8).cpu().numpy()
