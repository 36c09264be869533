"""A render of any length with working memory bounded by a block: the pose's block stream
(:meth:`SceneRenderer.stream <avgs.render.renderer.SceneRenderer.stream>`) over the input, written
to the output file as it comes, equal to :meth:`SceneRenderer.render` of the whole clip to float
rounding (the streams' own equality: tests/test_stability.py, tests/test_chunked_render.py).

:func:`render_blocks` yields the output ``[2, n]`` block by block, scaled as ``render`` scales
its result: the input at unit peak, the headroom limit (``limit`` / the output's peak, when
the caller knows it) and the input's peak back. :func:`render_to_file` writes those blocks to
an audio file atomically: a first pass writes them and measures the output's peak; only when
the headroom or the format's full scale (every format but WAV's float) needs the output
scaled down is the clip rendered again, scaled (the render is deterministic). Memory: the input
array (4 bytes a sample, as :func:`avgs.io.audio_input.read_mono` gives it) and one block.
A synthesis that does not stream (phase iterations from the source's or the filter's phase,
a conv head) is rendered whole by ``render``.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from avgs.render.tasks import HEADROOM_DB, HeadroomLimited, peak, unit_input

BLOCK = 1 << 16
"Input samples fed to the stream at a time (3 s at 22050 Hz)."
FLOAT_SUBTYPES = ("FLOAT", "DOUBLE")
"Subtypes that hold samples beyond full scale (nothing else is scaled down to fit)."


def render_blocks(renderer, listener, yaw: float, mono, source=None, gain: float = 1.0,
                  block: int = BLOCK) -> Iterator[np.ndarray]:
    """The render of ``mono`` at this pose as blocks ``[2, n]`` float32 (their concatenation is
    ``renderer.render(listener, yaw, mono, source).binaural * gain`` to float rounding, without
    ``render``'s headroom limit: the caller applies it through ``gain``)."""
    x, scale = unit_input(mono)
    try:
        stream = renderer.stream(listener, yaw, source)
    except ValueError:  # a synthesis that needs the whole signal (or a pose render refuses as well)
        y = renderer.render(listener, yaw, x, source=source).binaural  # [2, T]
        for i in range(0, y.shape[1], block):
            yield y[:, i : i + block] * np.float32(gain)
        return
    factor = np.float32(gain * scale)
    inv = np.float32(scale)
    with torch.inference_mode():
        for i in range(0, x.size, block):
            y = stream.process(x[i : i + block] / inv)  # [2, n], at unit input peak
            if y.shape[1]:
                yield y * factor
        yield stream.flush() * factor


def render_to_file(renderer, path, listener, yaw: float, mono, source=None, format: str = "WAV",
                   subtype: str = "FLOAT", block: int = BLOCK):
    """Render ``mono`` at this pose into the audio file ``path`` (soundfile's ``format`` and
    ``subtype``, written atomically, see :mod:`avgs.io.atomic`) in blocks; returns the pose's
    :class:`~avgs.render.renderer.RenderResult` (``binaural`` None: the render is in the file)
    and the number of samples. The output is that of ``render``: limited to the headroom
    (:class:`HeadroomLimited` warned), and scaled down to full scale for a format of fixed
    point or lossy samples (a warning says by how much)."""
    import soundfile as sf

    from avgs.io.atomic import guarded_open, atomic_path

    x, scale = unit_input(mono)
    if source is not None and not renderer.source_aware:
        renderer.warn_one_source(source)
    pose = renderer.masks(listener, yaw, source)  # the pose's result (theta, positions, gains)
    limit = 10.0 ** (HEADROOM_DB / 20.0)

    def write(tmp: Path, gain: float) -> tuple[float, int]:
        top, n = 0.0, 0
        with guarded_open(tmp) as out, sf.SoundFile(out, "w", int(renderer.sample_rate), 2, subtype=subtype, format=format) as f:
            for y in render_blocks(renderer, listener, yaw, x, source, gain, block):
                top = max(top, peak(y))
                n += y.shape[1]
                f.write(np.ascontiguousarray(y.T))
                out.check()
        return top, n

    with atomic_path(path) as tmp:
        top, n = write(tmp, 1.0)  # the output at the input's level: its peak
        if not math.isfinite(top):
            raise ValueError(f"{renderer.path or 'this checkpoint'}: the render at listener {listener!r} is not finite")
        gain = 1.0
        if top > limit * scale:  # render()'s headroom, relative to the input's peak
            warnings.warn(f"the render peaks {20 * math.log10(top / scale):.1f} dB over the input; limited to the "
                          f"{HEADROOM_DB:g} dB headroom", HeadroomLimited, stacklevel=2)
            gain = limit * scale / top
        if subtype not in FLOAT_SUBTYPES and top * gain > 1.0:
            warnings.warn(f"{path}: the render peaks at {20 * np.log10(top * gain):+.1f} dBFS; scaled down by that much to "
                          f"fit {subtype} (write a .wav to keep the level)", stacklevel=2)
            gain /= top * gain
        if gain != 1.0:
            write(tmp, gain)
    return replace(pose, binaural=None), n
