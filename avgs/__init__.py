"""AV-GS: novel-view acoustic synthesis with audio-visual Gaussian splatting.

``import avgs`` stays light: :class:`avgs.SceneRenderer` (from :mod:`avgs.render.renderer`)
is imported on first use.
"""

from __future__ import annotations

__all__ = ["SceneRenderer"]


def __getattr__(name: str):
    if name == "SceneRenderer":
        from avgs.render.renderer import SceneRenderer

        return SceneRenderer
    raise AttributeError(f"module 'avgs' has no attribute {name!r}")
