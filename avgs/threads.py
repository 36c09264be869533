"""How many CPU threads torch uses in one ``avgs`` process, and how work asked for on one
thread is given up when its caller no longer wants it (:class:`Stopped`).

A render or a training step is many small operations; two threads waiting on each other
on a busy two-core machine made stage 2 about 20x slower than one thread (0.27 against 6
iterations per second, measured side by side). So unless told (``avgs --threads N``, or
``OMP_NUM_THREADS``), a process takes the cores the machine's load leaves free: the
number of cores less the 1-minute load average, at least one.
"""

from __future__ import annotations

import os
from typing import Callable


class Stopped(Exception):
    """Work abandoned because its caller's ``stop()`` returned True (a render of a pose already left:
    :meth:`avgs.render.renderer.SceneRenderer.binaural_filter`, :func:`avgs.gaussians.rasterize.rasterize`)."""


def stopped(stop: Callable[[], bool] | None, what: str) -> None:
    """Raise :class:`Stopped` (naming ``what``) when ``stop`` is given and returns True: the check
    a long piece of work makes between its stages."""
    if stop is not None and stop():
        raise Stopped(f"{what}: stopped by its caller")


def free_cores() -> int:
    """Cores not busy right now: ``cpu_count - round(1-minute load average)``, at least 1."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    try:
        load = os.getloadavg()[0]
    except (AttributeError, OSError):
        load = 0.0
    return max(1, min(cores, cores - round(load)))


def choose_threads(requested: int | None = None) -> int:
    """``requested`` if given, else ``OMP_NUM_THREADS`` if set to a positive integer, else :func:`free_cores`."""
    if requested is not None:
        if int(requested) < 1:
            raise ValueError(f"--threads must be >= 1, got {requested}")
        return int(requested)
    env = os.environ.get("OMP_NUM_THREADS", "")
    if env.isdigit() and int(env) >= 1:
        return int(env)
    return free_cores()


def set_threads(requested: int | None = None) -> int:
    """Set torch's intra-op threads to :func:`choose_threads`; returns the number."""
    import torch

    n = choose_threads(requested)
    torch.set_num_threads(n)
    return n
