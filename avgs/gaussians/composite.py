"""Front-to-back alpha compositing of projected Gaussians, in tiles (the torch back end's
second half).

As gsplat does it: each Gaussian is listed in every ``tile_size`` x ``tile_size`` tile its
``3 sigma`` box touches, each tile's list is sorted by depth, and each pixel (centre at
``(j + 0.5, i + 0.5)``) blends its tile's list front to back with
``alpha = min(0.999, o exp(-sigma))``, skipping ``alpha < 1/255`` and stopping before the
transmittance would fall to ``1e-4``.

Tiles are processed in chunks of similar list length, padded to the chunk's longest list
and capped at ``chunk_elements`` (tiles x list x pixels), so memory stays bounded for any
scene. The per-chunk blend is a custom autograd function whose backward recomputes the
alphas and applies the closed-form gradient of the blend (as gsplat's CUDA backward does),
so nothing of size tiles x list x pixels is kept between forward and backward.
"""

from __future__ import annotations

import math

import torch
from torch.autograd.function import once_differentiable

ALPHA_MIN = 1.0 / 255.0
"Smallest alpha a Gaussian contributes with (gsplat, 3D-GS)."
T_MIN = 1e-4
"A pixel stops blending before its transmittance falls to this (gsplat, 3D-GS)."
ALPHA_MAX = 0.999
"Largest alpha of one Gaussian at one pixel (keeps 1 - alpha > 0)."


def _blend(sigma, op):
    """Forward quantities per (tile, Gaussian, pixel) ``[Tc, K, P]`` from ``sigma`` and opacities ``[Tc, K]``.

    Returns ``e = exp(-sigma)``, ``a_raw = o e``, ``alpha`` (clamped, small ones zeroed),
    ``one_minus = 1 - alpha``, transmittance after each Gaussian ``t_after``, ``keep``
    (blended before the early stop) and the blend weights ``w = alpha T_before``.
    ``sigma`` is overwritten.
    """
    e = sigma.neg_().exp_()
    a_raw = e * op[..., None]
    alpha = a_raw.clamp_max(ALPHA_MAX).mul_(a_raw >= ALPHA_MIN)
    one_minus = 1.0 - alpha
    t_after = torch.cumprod(one_minus, dim=1)
    keep = t_after > T_MIN
    w = (t_after / one_minus).mul_(alpha).mul_(keep)
    return e, a_raw, alpha, one_minus, t_after, keep, w


class _BlendTiles(torch.autograd.Function):
    """``(rgb [Tc, P, C], acc [Tc, P])`` from per-tile depth-sorted lists of ``K`` Gaussians.

    ``coef [Tc, K, 6]`` holds each Gaussian's ``sigma`` as a quadratic in the tile's pixel
    coordinates, ``basis [6, P]`` those monomials (so ``sigma = coef @ basis``, one matrix
    product); ``op [Tc, K]`` opacities, ``col [Tc, K, C]`` colours.
    """

    @staticmethod
    def forward(ctx, coef, basis, op, col):
        _, _, _, _, _, _, w = _blend(coef @ basis, op)
        rgb = torch.bmm(w.transpose(1, 2), col)  # [Tc, P, C]
        acc = w.sum(1)  # [Tc, P]
        ctx.save_for_backward(coef, basis, op, col)
        return rgb, acc

    @staticmethod
    @once_differentiable
    def backward(ctx, g_rgb, g_acc):
        coef, basis, op, col = ctx.saved_tensors
        e, a_raw, alpha, one_minus, t_after, keep, w = _blend(coef @ basis, op)
        g_col = torch.bmm(w, g_rgb)  # [Tc, K, C]
        v = torch.bmm(col, g_rgb.transpose(1, 2)).add_(g_acc[:, None, :])  # dL/dw [Tc, K, P]
        vw = v * w
        suffix = vw.sum(1, keepdim=True) - torch.cumsum(vw, dim=1)  # over the Gaussians behind
        # dL/dalpha_i = T_i v_i - (sum_{k > i} w_k v_k) / (1 - alpha_i), for blended i
        g = v.mul_(t_after).sub_(suffix).div_(one_minus).mul_(keep)
        g.mul_((alpha > 0) & (a_raw < ALPHA_MAX))  # dL/da_raw
        g_op = (g * e).sum(-1)  # [Tc, K]
        g_sigma = g.mul_(a_raw).neg_()  # [Tc, K, P]
        g_coef = g_sigma @ basis.T  # [Tc, K, 6]
        return g_coef, None, g_op, g_col


def _quadratic(m2d, con, x0, y0):
    """``sigma`` of each Gaussian as coefficients ``[..., 6]`` of (x^2, xy, y^2, x, y, 1) in tile
    coordinates (pixel minus the tile's corner ``x0, y0``).

    ``sigma = a/2 dx^2 + b dx dy + c/2 dy^2`` with ``(a, b, c)`` the conic. Local
    coordinates keep every term within about 1e3 of the result for Gaussians whose box
    touches the tile, so float32 loses nothing that matters.
    """
    mx, my = m2d[..., 0] - x0, m2d[..., 1] - y0
    a, b, c = con.unbind(-1)
    return torch.stack(
        [0.5 * a, b, 0.5 * c, -(a * mx + b * my), -(b * mx + c * my), 0.5 * a * mx * mx + b * mx * my + 0.5 * c * my * my],
        -1,
    )


def tile_lists(means2d, radii, depths, width: int, height: int, tile_size: int):
    """Depth-sorted (tile, Gaussian) pairs.

    Args: ``means2d [M, 2]``, ``radii [M]`` (> 0), ``depths [M]`` of the visible Gaussians.
    Returns ``gauss [E]`` (Gaussian of each pair, sorted by tile then depth),
    ``starts [n_tiles]``, ``counts [n_tiles]`` (each tile's slice of ``gauss``).
    """
    tw, th = math.ceil(width / tile_size), math.ceil(height / tile_size)
    n_tiles = tw * th
    dev = means2d.device
    m = means2d.detach()
    r = radii.to(m.dtype)
    x0 = torch.floor((m[:, 0] - r) / tile_size).clamp(0, tw).long()
    x1 = torch.ceil((m[:, 0] + r) / tile_size).clamp(0, tw).long()
    y0 = torch.floor((m[:, 1] - r) / tile_size).clamp(0, th).long()
    y1 = torch.ceil((m[:, 1] + r) / tile_size).clamp(0, th).long()
    span_x = x1 - x0
    n_per = span_x * (y1 - y0)  # [M]
    total = int(n_per.sum())
    if total == 0:
        empty = torch.zeros(0, dtype=torch.long, device=dev)
        return empty, torch.zeros(n_tiles, dtype=torch.long, device=dev), torch.zeros(n_tiles, dtype=torch.long, device=dev)
    M = len(m)
    gauss = torch.repeat_interleave(torch.arange(M, device=dev), n_per)  # [E]
    local = torch.arange(total, device=dev) - torch.repeat_interleave(torch.cumsum(n_per, 0) - n_per, n_per)
    w = span_x[gauss]
    tile = (y0[gauss] + local // w) * tw + (x0[gauss] + local % w)  # [E]
    rank = torch.empty(M, dtype=torch.long, device=dev)
    rank[torch.sort(depths.detach(), stable=True).indices] = torch.arange(M, device=dev)
    order = torch.sort(tile * M + rank[gauss], stable=True).indices
    gauss, tile = gauss[order], tile[order]
    counts = torch.bincount(tile, minlength=n_tiles)
    starts = torch.cumsum(counts, 0) - counts
    return gauss, starts, counts


def _chunks(counts: torch.Tensor, pixels: int, budget: int) -> list[tuple[torch.Tensor, int]]:
    """Non-empty tiles grouped as ``(tile ids, longest list)``, longest lists first, each
    group's ``tiles x longest x pixels`` at most ``budget`` (a single tile may exceed it)."""
    order = torch.sort(counts, descending=True, stable=True).indices
    sorted_counts = counts[order].tolist()
    out, i, n = [], 0, len(sorted_counts)
    while i < n and sorted_counts[i] > 0:
        k = sorted_counts[i]
        take = max(1, budget // (k * pixels))
        j = i
        while j < min(n, i + take) and sorted_counts[j] > 0:
            j += 1
        out.append((order[i:j], k))
        i = j
    return out


def composite(
    means2d: torch.Tensor,
    conics: torch.Tensor,
    opacities: torch.Tensor,
    colors: torch.Tensor,
    depths: torch.Tensor,
    radii: torch.Tensor,
    width: int,
    height: int,
    background: torch.Tensor | None = None,
    tile_size: int = 16,
    chunk_elements: int = 1 << 22,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Blend projected Gaussians into an image.

    Args: ``means2d [N, 2]``, ``conics [N, 3]``, ``opacities [N]`` in [0, 1],
    ``colors [N, C]``, ``depths [N]``, ``radii [N]`` (0 = culled), ``background [C]`` or None (zeros).
    Returns ``image [H, W, C]`` and ``alpha [H, W]`` (1 - final transmittance).
    """
    dev, dtype, C = colors.device, colors.dtype, colors.shape[-1]
    tw, th = math.ceil(width / tile_size), math.ceil(height / tile_size)
    P = tile_size * tile_size
    vis = torch.nonzero(radii > 0).squeeze(-1)  # [M]
    img = torch.zeros(tw * th, P, C, dtype=dtype, device=dev)  # [tiles, P, C]
    acc = torch.zeros(tw * th, P, dtype=dtype, device=dev)
    if len(vis) > 0:
        gauss, starts, counts = tile_lists(means2d[vis], radii[vis], depths[vis], width, height, tile_size)
        # the visible Gaussians' tables, plus a transparent dummy at index M for padding
        m2d, con, opa, col = (torch.cat([t[vis], t.new_zeros((1, *t.shape[1:]))]) for t in (means2d, conics, opacities, colors))
        dummy = len(vis)
        j = torch.arange(tile_size, device=dev, dtype=dtype) + 0.5
        x, y = j.repeat(tile_size), j.repeat_interleave(tile_size)  # [P] within a tile, row-major
        basis = torch.stack([x * x, x * y, y * y, x, y, torch.ones_like(x)])  # [6, P]
        ids_all, rgb_all, acc_all = [], [], []
        for tiles, k in _chunks(counts, P, chunk_elements):
            slot = torch.arange(k, device=dev)
            pos = starts[tiles, None] + slot  # [Tc, K]
            valid = slot < counts[tiles, None]
            idx = torch.where(valid, gauss[pos.clamp_max(len(gauss) - 1)], torch.full_like(pos, dummy))
            x0 = (tiles % tw).to(dtype)[:, None] * tile_size  # [Tc, 1]
            y0 = (tiles // tw).to(dtype)[:, None] * tile_size
            coef = _quadratic(m2d[idx], con[idx], x0, y0)  # [Tc, K, 6]
            rgb, a = _BlendTiles.apply(coef, basis, opa[idx], col[idx])
            ids_all.append(tiles)
            rgb_all.append(rgb)
            acc_all.append(a)
        if ids_all:
            ids = torch.cat(ids_all)
            img = img.index_copy(0, ids, torch.cat(rgb_all))
            acc = acc.index_copy(0, ids, torch.cat(acc_all))
    if background is not None:
        img = img + (1.0 - acc)[..., None] * background.to(dtype)
    img = img.reshape(th, tw, tile_size, tile_size, C).permute(0, 2, 1, 3, 4).reshape(th * tile_size, tw * tile_size, C)
    acc = acc.reshape(th, tw, tile_size, tile_size).permute(0, 2, 1, 3).reshape(th * tile_size, tw * tile_size)
    return img[:height, :width], acc[:height, :width]
