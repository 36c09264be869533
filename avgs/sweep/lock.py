"""One writer per run folder: the lock a run holds while it trains and scores.

A run's task takes ``OUT/<scene>/<setting>/seed<k>/sweep.lock`` (``flock``, exclusive) before
it reads where the run stands, and hands the lock's descriptor to the ``avgs train`` and
``avgs eval`` it starts. The lock is released when the last of them closes it, so a
subprocess that outlives its worker (a node lost to Ray while its machine still runs, until
the parent-death signal stops it) keeps the folder until it has stopped: the run placed
again on another node waits for it and resumes from the checkpoint it left, instead of two
trainings writing one checkpoint and one log. Two sweeps given the same ``--out`` cannot
train one run twice at once either. On Linux NFS clients ``flock`` is carried by the
server's byte-range locks, so this holds across machines sharing the output folder.
"""

from __future__ import annotations

import os
import socket
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

LOCK = "sweep.lock"
"The lock file of a run folder (its content: who holds it, for the message of a run that waits)."

WAIT_SECONDS = 60.0
"How long a run waits for its folder's lock (twice the stop time of an interrupted subprocess)."


class FolderBusy(RuntimeError):
    """The run folder stayed locked by another process for :data:`WAIT_SECONDS`."""


def holder(path: Path) -> str:
    """Who holds the lock, as its file says (``host pid N``), or ``another process``."""
    try:
        text = Path(path).read_text(encoding="utf-8").strip()
    except OSError:
        text = ""
    return text or "another process"


@contextmanager
def run_lock(folder: Path, wait: float = WAIT_SECONDS, on_wait=None) -> Iterator[int | None]:
    """Hold ``folder``'s lock for the block; yields its file descriptor (to pass to subprocesses),
    None where there is no ``flock`` (Windows: no lock).

    Polls every 0.2 s (an interrupt lands between polls); ``on_wait(holder)`` is called once
    when the lock is taken by someone else; :class:`FolderBusy` after ``wait`` seconds.
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover - Windows
        yield None
        return
    path = Path(folder) / LOCK
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        deadline = time.monotonic() + wait
        told = False
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if not told and on_wait is not None:
                    on_wait(holder(path))
                    told = True
                if time.monotonic() >= deadline:
                    raise FolderBusy(f"{folder}: in use by {holder(path)} for {wait:.0f} s "
                                     f"(another sweep with the same --out?)") from None
                time.sleep(0.2)
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{socket.gethostname()} pid {os.getpid()}\n".encode(), 0)
        yield fd
    finally:
        os.close(fd)
