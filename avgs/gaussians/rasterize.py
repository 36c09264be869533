"""``rasterize``: render 3D Gaussians from one pinhole camera, with a choice of back end.

- ``"torch"``: our differentiable pure-PyTorch rasterizer (:mod:`.projection` +
  :mod:`.composite`); runs on any device, a laptop CPU included.
- ``"gsplat"``: ``gsplat.rasterization`` (CUDA only; ``pip install avgs[cuda]``). Imported
  on first use, so importing avgs never needs CUDA or gsplat.
- ``"auto"``: gsplat when the tensors live on a CUDA device and gsplat imports, else torch.

Both follow gsplat's conventions (``viewmat`` world-to-camera in OpenCV's camera frame,
pixel centres at ``+0.5``, SH colours ``max(sh + 0.5, 0)``) and agree to float precision
up to gsplat's tile culling of far tails (see ``tests/test_gaussians.py``, marked cuda).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Literal

import torch

from avgs.gaussians.cameras import camera_center
from avgs.gaussians.composite import composite
from avgs.gaussians.projection import project_gaussians
from avgs.gaussians.sh import MAX_DEGREE, sh_colors

Backend = Literal["auto", "torch", "gsplat"]
TORCH_TILE = 8
"Default tile edge of the torch back end (pixels)."
GSPLAT_TILE = 16
"Default tile edge of gsplat (pixels)."


@functools.lru_cache(maxsize=1)
def gsplat_available() -> bool:
    """True when CUDA is present and ``gsplat`` imports."""
    if not torch.cuda.is_available():
        return False
    try:
        import gsplat  # noqa: F401
    except Exception:  # ImportError, or a broken CUDA build
        return False
    return True


def resolve_backend(backend: str, device: torch.device | str) -> str:
    """The back end ``"auto"`` stands for on ``device`` (``"torch"`` or ``"gsplat"``)."""
    if backend not in ("auto", "torch", "gsplat"):
        raise ValueError(f"rasterizer backend must be 'auto', 'torch' or 'gsplat', got {backend!r}")
    if backend == "auto":
        return "gsplat" if torch.device(device).type == "cuda" and gsplat_available() else "torch"
    return backend


def _check(name: str, t: torch.Tensor, shape: tuple) -> None:
    ok = t.dim() == len(shape) and all(s is None or s == d for s, d in zip(shape, t.shape))
    if not ok:
        want = "[" + ", ".join("*" if s is None else str(s) for s in shape) + "]"
        raise ValueError(f"rasterize: {name} must be {want}, got {list(t.shape)}")


def rasterize(
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    opacities: torch.Tensor,
    colors: torch.Tensor,
    viewmat: torch.Tensor,
    K: torch.Tensor,
    width: int,
    height: int,
    sh_degree: int | None = None,
    backend: Backend = "auto",
    *,
    background: torch.Tensor | None = None,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    eps2d: float = 0.3,
    tile_size: int | None = None,
    stop: Callable[[], bool] | None = None,
) -> tuple[torch.Tensor, torch.Tensor, dict]:
    """Render ``N`` Gaussians into an ``height x width`` RGB image, differentiably.

    Args:
        means: ``[N, 3]`` centres (world).
        quats: ``[N, 4]`` rotations (w, x, y, z); need not be unit length (zero -> identity).
        scales: ``[N, 3]`` standard deviations along the rotated axes (exp of log-scales; >= 0).
        opacities: ``[N]`` in [0, 1] (sigmoid of the logits).
        colors: ``[N, 3]`` RGB, or SH coefficients ``[N, K, 3]`` with ``K >= (sh_degree + 1)^2``.
        viewmat: ``[4, 4]`` world-to-camera, OpenCV camera frame (x right, y down, z forward);
            from our OpenGL camera-to-world use :func:`avgs.gaussians.cameras.viewmat_from_c2w`.
        K: ``[3, 3]`` pinhole intrinsics in pixels (pixel ``(j, i)`` is centred at ``(j+0.5, i+0.5)``).
        width, height: image size in pixels.
        sh_degree: SH degree to evaluate (0..3) when ``colors`` holds SH coefficients;
            None with ``[N, K, 3]`` uses all K; must be None for ``[N, 3]`` colours.
        backend: ``"auto"``, ``"torch"`` or ``"gsplat"``.
        background: ``[3]`` colour behind the Gaussians (default black).
        near_plane, far_plane: camera depth range outside which Gaussians are culled.
        eps2d: low-pass dilation added to the projected covariance (pixels^2; 3D-GS: 0.3).
        tile_size: tile edge in pixels; None: 16 for gsplat (its default), 8 for torch (about
            1.4x faster on a CPU than 16: a tighter cover of each Gaussian's box).
        stop: torch back end only: called between chunks of tiles; when it returns True the
            render is abandoned with :class:`avgs.threads.Stopped` (a viewer's
            background render gives way to a newer pose this way). gsplat renders in one call.

    Returns:
        ``rgb [H, W, 3]``, ``alpha [H, W]`` (accumulated opacity), and ``aux``: ``means2d``
        (the projected centres as a tensor in the graph: ``[N, 2]`` for torch, ``[1, N, 2]``
        for gsplat; call ``retain_grad()`` before backward for densification), ``radii [N]``
        (pixels, 0 = culled), ``depths [N]``, ``width``, ``height``, ``n_cameras`` (1), ``backend``.
    """
    N = means.shape[0] if means.dim() == 2 else -1
    _check("means", means, (None, 3))
    _check("quats", quats, (N, 4))
    _check("scales", scales, (N, 3))
    _check("opacities", opacities, (N,))
    _check("viewmat", viewmat, (4, 4))
    _check("K", K, (3, 3))
    if colors.dim() == 2:
        _check("colors", colors, (N, 3))
        if sh_degree is not None:
            raise ValueError("rasterize: sh_degree given but colors is [N, 3] (plain RGB); pass SH as [N, K, 3]")
    else:
        _check("colors (SH)", colors, (N, None, 3))
        k = colors.shape[1]
        if sh_degree is None:
            sh_degree = int(round(k**0.5)) - 1
        if not 0 <= sh_degree <= MAX_DEGREE or (sh_degree + 1) ** 2 > k:
            raise ValueError(f"rasterize: sh_degree {sh_degree} needs 0..{MAX_DEGREE} and (degree + 1)^2 <= K = {k}")
    if int(width) < 1 or int(height) < 1:
        raise ValueError(f"rasterize: image size must be positive, got {width}x{height}")
    if background is not None:
        background = torch.as_tensor(background, dtype=means.dtype, device=means.device).reshape(3)
    which = resolve_backend(backend, means.device)
    if tile_size is None:
        tile_size = TORCH_TILE if which == "torch" else GSPLAT_TILE
    args = (means, quats, scales, opacities, colors, viewmat, K, int(width), int(height), sh_degree, background)
    kw = dict(near_plane=near_plane, far_plane=far_plane, eps2d=eps2d, tile_size=tile_size)
    if which == "gsplat":
        return _rasterize_gsplat(*args, **kw)
    return _rasterize_torch(*args, **kw, stop=stop)


def _rasterize_torch(
    means, quats, scales, opacities, colors, viewmat, K, width, height, sh_degree, background,
    *, near_plane, far_plane, eps2d, tile_size, stop=None,
):  # fmt: skip
    proj = project_gaussians(means, quats, scales, viewmat, K, width, height, near_plane, far_plane, eps2d)
    radii = proj["radii"]
    if colors.dim() == 3:  # SH: evaluate for the visible Gaussians only
        vis = radii > 0
        rgb = colors.new_zeros(len(means), 3)
        if bool(vis.any()):
            rgb = rgb.index_put((vis,), sh_colors(sh_degree, colors[vis], means[vis], camera_center(viewmat)))
        colors = rgb
    image, alpha = composite(
        proj["means2d"], proj["conics"], opacities, colors, proj["depths"], radii, width, height, background, tile_size,
        stop=stop,
    )
    aux = {
        "means2d": proj["means2d"],
        "radii": radii,
        "depths": proj["depths"],
        "width": width,
        "height": height,
        "n_cameras": 1,
        "backend": "torch",
    }
    return image, alpha, aux


def _rasterize_gsplat(
    means, quats, scales, opacities, colors, viewmat, K, width, height, sh_degree, background,
    *, near_plane, far_plane, eps2d, tile_size,
):  # fmt: skip
    if means.device.type != "cuda":
        raise ValueError(f"rasterize: backend 'gsplat' needs CUDA tensors, got device {means.device}")
    try:
        from gsplat import rasterization
    except ImportError as exc:
        raise ImportError(f"rasterize: backend 'gsplat' needs the gsplat package (pip install 'avgs[cuda]'): {exc}") from None
    renders, alphas, meta = rasterization(
        means,
        quats,
        scales,
        opacities,
        colors,
        viewmats=viewmat[None],
        Ks=K[None],
        width=width,
        height=height,
        near_plane=near_plane,
        far_plane=far_plane,
        eps2d=eps2d,
        sh_degree=sh_degree,
        backgrounds=None if background is None else background[None],
        tile_size=tile_size,
        packed=False,
        rasterize_mode="classic",
        render_mode="RGB",
    )
    radii = meta["radii"][0]
    if radii.dim() == 2:  # gsplat >= 1.5 keeps per-axis radii
        radii = radii.max(-1).values
    aux = {
        "means2d": meta["means2d"],
        "radii": radii.to(torch.int32),
        "depths": meta["depths"][0],
        "width": width,
        "height": height,
        "n_cameras": 1,
        "backend": "gsplat",
    }
    return renders[0], alphas[0, ..., 0], aux
