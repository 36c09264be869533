"""Pulling an audio engine's blocks the way a sound card's callback does (tests of avgs_viewer)."""

from __future__ import annotations

import numpy as np


def pull(engine, blocks: int, block: int) -> np.ndarray:
    """``blocks`` calls of ``engine.callback`` for ``block`` frames each: the output [blocks * block, 2]."""
    out = np.empty((block, 2), np.float32)
    chunks = []
    for _ in range(blocks):
        engine.callback(out, block, None, None)
        chunks.append(out.copy())
    return np.concatenate(chunks)
