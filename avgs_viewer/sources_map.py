"""The propagation map of several sources: the level (and ILD) of the sum of their powers.

A source's map (:mod:`avgs.render.propagation_map`) holds per cell the level
``L = 10 log10(mean over ears and bins of P)`` and ``ILD = 10 log10(sum P_left / sum P_right)``,
so each ear's share of the power is ``m r / (1 + r)`` and ``m / (1 + r)`` (``m = 10^(L/10)``,
``r = 10^(ILD/10)``). Sources play at once and are uncorrelated: their powers add, each times
its gain squared; the sum's level and ILD come from the summed ear powers.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np


def ear_powers(level: np.ndarray, ild: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(left, right) [ny, nx] shares of the mean power of a map's ``level`` and ``ild`` (dB)."""
    m = 10.0 ** (np.asarray(level, np.float64) / 10.0)
    r = 10.0 ** (np.asarray(ild, np.float64) / 10.0)
    return m * r / (1.0 + r), m / (1.0 + r)


def sum_maps(maps: list, gains: list[float]):
    """One map (a :class:`~avgs.render.propagation_map.PropagationMap` like the first) of the sources'
    summed powers, each map's times its gain squared; NaN where any map is not computed."""
    if not maps or len(maps) != len(gains):
        raise ValueError(f"sum_maps needs one gain per map, got {len(maps)} maps and {len(gains)} gains")
    left = np.zeros(maps[0].level.shape)
    right = np.zeros(maps[0].level.shape)
    for pmap, gain in zip(maps, gains):
        lp, rp = ear_powers(pmap.level, pmap.ild)
        left += float(gain) ** 2 * lp
        right += float(gain) ** 2 * rp
    with np.errstate(divide="ignore", invalid="ignore"):
        level = 10.0 * np.log10(left + right)
        ild = 10.0 * np.log10(left / right)
    return replace(maps[0], level=level.astype(maps[0].level.dtype), ild=ild.astype(maps[0].ild.dtype),
                   done=min(m.done for m in maps))
