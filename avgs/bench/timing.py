"""Small, honest timing helpers: wall-clock samples, medians and 95th percentiles.

Our machines are shared and noisy, so every figure is a median over repeats, and
comparisons are always measured side by side in one run.
"""

from __future__ import annotations

import statistics
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np


@dataclass(frozen=True)
class Timing:
    """Seconds per call over ``n`` repeats."""

    samples: tuple[float, ...]

    @property
    def n(self) -> int:
        return len(self.samples)

    @property
    def median(self) -> float:
        return statistics.median(self.samples)

    @property
    def p95(self) -> float:
        return float(np.percentile(np.asarray(self.samples), 95))

    @property
    def median_ms(self) -> float:
        return 1e3 * self.median

    @property
    def p95_ms(self) -> float:
        return 1e3 * self.p95

    def to_dict(self) -> dict:
        return {"n": self.n, "median_ms": self.median_ms, "p95_ms": self.p95_ms}


def time_calls(fn: Callable[[], object], repeats: int = 20, warmup: int = 2, sync: Callable[[], None] | None = None) -> Timing:
    """Call ``fn`` ``warmup`` times untimed, then ``repeats`` times timed (``sync`` after each, e.g. CUDA)."""
    for _ in range(warmup):
        fn()
        if sync:
            sync()
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        if sync:
            sync()
        samples.append(time.perf_counter() - t0)
    return Timing(tuple(samples))


def time_interleaved(fns: dict[str, Callable[[int], object]], repeats: int = 20, block: int = 4,
                     sync: Callable[[], None] | None = None) -> dict[str, Timing]:
    """Each of ``fns`` timed ``repeats`` times, taking turns in blocks: every round, each function
    runs one untimed call (its caches warm again after the others') and then ``block`` timed
    ones. A shared machine's load moves on the scale of seconds, so it falls on all of them
    alike and their ratios hold, while each timed call runs as it would repeated alone.
    ``fns[name](i)`` is called with the call's index i (the untimed one repeats its block's
    first; every function gets the same i's in the same order: give them the same inputs)."""
    samples: dict[str, list[float]] = {name: [] for name in fns}
    rounds = -(-repeats // block)
    for r in range(rounds):
        for name, fn in fns.items():
            fn(r * block)  # untimed: warms what the other functions' calls evicted
            if sync:
                sync()
            for j in range(block):
                t0 = time.perf_counter()
                fn(r * block + j)
                if sync:
                    sync()
                samples[name].append(time.perf_counter() - t0)
    return {name: Timing(tuple(v[:repeats])) for name, v in samples.items()}


class Stopwatch:
    """Accumulates named sections: ``with sw("vicinity"): ...``; ``sw.timings()`` per name."""

    def __init__(self) -> None:
        self._samples: dict[str, list[float]] = {}
        self._name: str | None = None
        self._t0 = 0.0

    def __call__(self, name: str) -> "Stopwatch":
        self._name = name
        return self

    def __enter__(self) -> "Stopwatch":
        self._t0 = time.perf_counter()
        return self

    def __exit__(self, *exc) -> None:
        assert self._name is not None
        self._samples.setdefault(self._name, []).append(time.perf_counter() - self._t0)
        self._name = None

    def timings(self) -> dict[str, Timing]:
        return {k: Timing(tuple(v)) for k, v in self._samples.items()}
