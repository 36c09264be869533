"""A stream that processes its input near unit peak, as a one-shot render does.

:meth:`SceneRenderer.render <avgs.render.renderer.SceneRenderer.render>` divides the whole input by
its peak before anything else (:func:`avgs.render.tasks.unit_input`): the syntheses square STFT
magnitudes in float32, which overflow for inputs peaking above ~1e17 and underflow for denormal
ones. A stream cannot know the whole input's peak, so :class:`UnitScaleStream` fixes a power of two
at the first block that is not silent and divides every block by it (multiplying the output back):
the division is exact in floating point, so the output is the inner stream's to float rounding
wherever that one does not overflow or underflow. The scale is at least 2^-40: samples far below
it (denormal float32) may still come out silent, as they do in a one-shot render of a louder input.
"""

from __future__ import annotations

import math

import numpy as np

from .tasks import BlockStream, peak

LEAST_SCALE_EXP = -40
"The scale is at least 2^-40 (-240 dB re 1): a stream that starts below it still takes louder blocks later."
RANGE_EXP = 40
"A block may peak at most 2^40 (240 dB) above the scale; the syntheses' float32 powers overflow about 2^57 above it."


class UnitScaleStream:
    """``inner`` (a :class:`~avgs.render.tasks.BlockStream`) fed each block over a scale ``2^k``
    (``k`` from the first block with a sample other than zero: its peak rounded up to a power of two,
    at least ``2^LEAST_SCALE_EXP``), its output times the same scale. A block louder than
    ``2^RANGE_EXP`` times the scale raises ValueError naming both before it is taken (the stream goes
    on as if it had not come); an output beyond float32's range raises ValueError too."""

    def __init__(self, inner: BlockStream):
        self.inner = inner
        self.scale: float | None = None
        "The power of two every block is divided by (None until a block that is not silent)."

    @property
    def latency(self) -> int:
        return self.inner.latency

    def set_pose(self, masks, impulse) -> None:
        self.inner.set_pose(masks, impulse)

    def _scaled(self, block) -> np.ndarray:
        x = np.asarray(block)
        if x.dtype not in (np.float32, np.float64):  # ints, float16 (whose range the division could leave), lists
            x = x.astype(np.float64)
        top = peak(x)  # NaN for NaN or Inf samples
        if not math.isfinite(top):
            return x  # the inner stream says what is wrong with it (NaN or Inf)
        if self.scale is None:
            if top == 0.0:
                return x
            self.scale = 2.0 ** max(math.frexp(top)[1], LEAST_SCALE_EXP)
        elif top > self.scale * 2.0 ** RANGE_EXP:
            raise ValueError(
                f"mono block peaks at {top:.3g}, more than 2^{RANGE_EXP} times the stream's scale {self.scale:.3g} "
                f"(set by its first block that was not silent): beyond float32's range; start a new stream, "
                f"or scale the input"
            )
        return x / self.scale

    def _out(self, y: np.ndarray) -> np.ndarray:
        if self.scale is None or y.size == 0:
            return y
        out = y * np.float32(self.scale)
        if not np.all(np.isfinite(out)):
            raise ValueError(f"the output peaks beyond float32's range (input scale {self.scale:.3g}); scale the input")
        return out

    def process(self, block) -> np.ndarray:
        """Output ``[2, m]`` for the next mono samples ``block [n]`` (the inner stream's, scaled back)."""
        return self._out(self.inner.process(self._scaled(block)))

    def flush(self) -> np.ndarray:
        """The rest of the output ``[2, m]``; the stream takes no more input."""
        return self._out(self.inner.flush())
