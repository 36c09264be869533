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
so nothing of size tiles x list x pixels is kept between forward and backward; lists are
walked in short segments so that tiles whose pixels have all saturated stop early.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from torch.autograd.function import once_differentiable

from avgs.threads import stopped

ALPHA_MIN = 1.0 / 255.0
"Smallest alpha a Gaussian contributes with (gsplat, 3D-GS)."
T_MIN = 1e-4
"A pixel stops blending before its transmittance falls to this (gsplat, 3D-GS)."
ALPHA_MAX = 0.999
"Largest alpha of one Gaussian at one pixel (keeps 1 - alpha > 0)."


SEGMENT = 32
"Fewest Gaussians per tile list blended at a time; tiles whose pixels all saturated stop early."
SEGMENT_ELEMENTS = 1 << 18
"Segments grow to about this many (tile, Gaussian, pixel) elements, so few tiles with long lists take few steps."


def _blend(sigma, op, t0):
    """Forward quantities per (tile, Gaussian, pixel) ``[A, S, P]`` for one segment of the
    lists, from ``sigma``, opacities ``op [A, S]`` and the transmittance ``t0 [A, P]`` before it.

    Returns ``e = exp(-sigma)``, ``a_raw = o e``, ``alpha`` (clamped, small ones zeroed),
    ``one_minus = 1 - alpha``, transmittance after each Gaussian ``t_after``, ``keep``
    (blended before the early stop) and the blend weights ``w = alpha T_before``.
    ``sigma`` is overwritten.
    """
    e = sigma.neg_().exp_()
    a_raw = e * op[..., None]
    alpha = a_raw.clamp_max(ALPHA_MAX).mul_(a_raw >= ALPHA_MIN)
    one_minus = 1.0 - alpha
    t_after = torch.cumprod(one_minus, dim=1).mul_(t0[:, None, :])
    keep = t_after > T_MIN
    w = (t_after / one_minus).mul_(alpha).mul_(keep)
    return e, a_raw, alpha, one_minus, t_after, keep, w


def _rows(t: torch.Tensor, alive: torch.Tensor | None, s: int, e: int) -> torch.Tensor:
    """``t[alive, s:e]`` (all rows when ``alive`` is None)."""
    return t[:, s:e] if alive is None else t[alive, s:e]


class _BlendTiles(torch.autograd.Function):
    """``(rgb [Tc, P, C], acc [Tc, P])`` from per-tile depth-sorted lists of ``K`` Gaussians.

    ``coef [Tc, K, 6]`` holds each Gaussian's ``sigma`` as a quadratic in the tile's pixel
    coordinates, ``basis [6, P]`` those monomials (so ``sigma = coef @ basis``, one matrix
    product); ``op [Tc, K]`` opacities, ``col [Tc, K, C]`` colours.

    The lists are walked in segments of :data:`SEGMENT`, front to back; a tile leaves once
    every pixel of it has stopped (transmittance <= ``T_MIN``), so opaque surfaces cost
    only the Gaussians in front of them. Backward walks the same segments back to front,
    carrying the sum over the Gaussians behind.
    """

    @staticmethod
    def forward(ctx, coef, basis, op, col):
        Tc, K = op.shape
        T = torch.ones(Tc, basis.shape[1], dtype=op.dtype, device=op.device)  # [Tc, P]
        rgb = torch.zeros(Tc, basis.shape[1], col.shape[-1], dtype=col.dtype, device=col.device)
        acc = torch.zeros_like(T)
        segments = []
        alive = None  # None: every tile of the chunk
        step = max(SEGMENT, SEGMENT_ELEMENTS // (Tc * basis.shape[1]))
        for s in range(0, K, step):
            e = min(K, s + step)
            t0 = T if alive is None else T[alive]
            _, _, _, _, t_after, _, w = _blend(_rows(coef, alive, s, e) @ basis, _rows(op, alive, s, e), t0)
            seg_rgb = torch.bmm(w.transpose(1, 2), _rows(col, alive, s, e))  # [A, P, C]
            if alive is None:
                rgb += seg_rgb
                acc += w.sum(1)
                T = t_after[:, -1].clone()
            else:
                rgb.index_add_(0, alive, seg_rgb)
                acc.index_add_(0, alive, w.sum(1))
                T[alive] = t_after[:, -1]
            segments.append((s, e, alive, t0))
            still = (t_after[:, -1] > T_MIN).any(-1)  # [A]
            if not bool(still.all()):
                idx = torch.nonzero(still).squeeze(-1)
                alive = idx if alive is None else alive[idx]
                if len(alive) == 0:
                    break
        ctx.segments = segments
        ctx.save_for_backward(coef, basis, op, col)
        return rgb, acc

    @staticmethod
    @once_differentiable
    def backward(ctx, g_rgb, g_acc):
        coef, basis, op, col = ctx.saved_tensors
        g_coef, g_op, g_col = torch.zeros_like(coef), torch.zeros_like(op), torch.zeros_like(col)
        behind = torch.zeros_like(g_acc)  # [Tc, P] sum of w v over later segments
        for s, e, alive, t0 in reversed(ctx.segments):
            c = _rows(col, alive, s, e)
            ex, a_raw, alpha, one_minus, t_after, keep, w = _blend(_rows(coef, alive, s, e) @ basis, _rows(op, alive, s, e), t0)
            G = g_rgb if alive is None else g_rgb[alive]  # [A, P, C]
            ga = g_acc if alive is None else g_acc[alive]
            v = torch.bmm(c, G.transpose(1, 2)).add_(ga[:, None, :])  # dL/dw [A, S, P]
            vw = v * w
            seg_total = vw.sum(1)  # [A, P]
            later = behind if alive is None else behind[alive]
            suffix = (seg_total + later)[:, None, :] - torch.cumsum(vw, dim=1)  # over the Gaussians behind
            # dL/dalpha_i = T_i v_i - (sum_{k > i} w_k v_k) / (1 - alpha_i), for blended i
            g = v.mul_(t_after).sub_(suffix).div_(one_minus).mul_(keep)
            g.mul_((alpha > 0) & (a_raw < ALPHA_MAX))  # dL/da_raw
            g_o = (g * ex).sum(-1)  # [A, S]
            g_c = g.mul_(a_raw).neg_() @ basis.T  # dL/dsigma [A, S, P] -> [A, S, 6]
            g_w = torch.bmm(w, G)  # [A, S, C]
            if alive is None:
                g_op[:, s:e], g_coef[:, s:e], g_col[:, s:e] = g_o, g_c, g_w
                behind += seg_total
            else:
                g_op[alive, s:e], g_coef[alive, s:e], g_col[alive, s:e] = g_o, g_c, g_w
                behind.index_add_(0, alive, seg_total)
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
    stop: Callable[[], bool] | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Blend projected Gaussians into an image.

    Args: ``means2d [N, 2]``, ``conics [N, 3]``, ``opacities [N]`` in [0, 1],
    ``colors [N, C]``, ``depths [N]``, ``radii [N]`` (0 = culled), ``background [C]`` or None (zeros).
    ``stop``: called before each chunk of tiles; when it returns True the image is abandoned
    (:class:`avgs.threads.Stopped` is raised). It may also block, to pause the work.
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
            stopped(stop, "composite")
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
