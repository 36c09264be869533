"""The room's floor plan and the one clamp of positions, from the library
(:mod:`avgs.data.floor_plan`, which ``avgs render`` uses too). No Qt, no VTK."""

from __future__ import annotations

from avgs.data.floor_plan import Footprint, keep_inside, outer_rings

__all__ = ["Footprint", "keep_inside", "outer_rings"]
