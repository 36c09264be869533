"""A thread that runs only the newest request: :class:`RenderWorker`.

Requests submitted while one runs overwrite each other; when it is done only the newest
runs next. With a spare lane, :meth:`RenderWorker.expedite` starts the newest request at once on a
second thread instead of behind the one running (the explorer's release of a drag: its pose's
filter need not wait for a stale move's); a result older than one already delivered is dropped. The explorer's filter path (:mod:`avgs_viewer.worker`), its full-render path
(:mod:`avgs_viewer.refine`) each run on one. No Qt here.
"""

from __future__ import annotations

import os
import threading
from typing import Any, Callable, Generic, TypeVar

from avgs.threads import Stopped

BACKGROUND_NICE = 10
"How much lower a background thread (the listener's-view inset, the propagation map) runs than the sound."


def lower_priority(nice: int = BACKGROUND_NICE) -> bool:
    """Lower the calling thread's CPU priority by ``nice`` (Linux: a thread is a task with its own
    nice value), so that on a busy machine the scheduler runs the pose's filter, the GUI and the
    X server first; False where the system does not allow it (nothing changes then)."""
    try:
        tid = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, tid, min(19, os.getpriority(os.PRIO_PROCESS, tid) + int(nice)))
        return True
    except (AttributeError, OSError):
        return False


Request = TypeVar("Request")
"What is submitted (the filter path: a :class:`~avgs_viewer.worker.PoseRequest`)."
Result = TypeVar("Result")
"What ``render`` returns for it (the filter path: the pose's ``RenderResult``)."


class RenderWorker(Generic[Request, Result]):
    """Runs ``render(request)`` on one daemon thread, newest request wins.

    ``on_result(seq, request, result)`` / ``on_error(seq, request, exc)`` are called on the
    worker thread; ``seq`` numbers submissions from 1, and results reach ``on_result`` in that
    order (one older than a result already delivered is dropped: :attr:`superseded`).
    ``spare``: a second thread that only :meth:`expedite` uses; ``render`` must then be safe to
    run on two threads at once.
    """

    def __init__(self, render: Callable[[Request], Result], on_result: Callable[[int, Request, Result], None],
                 on_error: Callable[[int, Request, BaseException], None] | None = None, name: str = "avgs-render",
                 spare: bool = False):
        self._render = render
        self._on_result = on_result
        self._on_error = on_error
        self._cond = threading.Condition()
        self._deliver_lock = threading.Lock()  # results in submission order
        self._request: Any = None  # (seq, request: Request) of the newest not yet started, while _has_request
        self._has_request = False
        self._urgent: Any = None  # (seq, request) handed to the spare lane, until it starts
        self._running = 0  # lanes rendering now
        self._delivered = 0  # seq of the newest result delivered
        self._closed = False
        self.submitted = 0
        self.rendered = 0
        self.dropped = 0
        "Requests overwritten before they started."
        self.superseded = 0
        "Results dropped because a newer one was delivered first (a spare lane's)."
        self.stopped = 0
        "Renders that gave up (``avgs.threads.Stopped``) because a newer request came (:meth:`stale`)."
        self.expedited = 0
        "Requests the spare lane ran."
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)
        self._thread.start()
        self._spare = None
        if spare:
            self._spare = threading.Thread(target=self._spare_loop, name=f"{name}-spare", daemon=True)
            self._spare.start()

    def submit(self, request: Request) -> int:
        """Queue ``request``, replacing any not yet started; returns its sequence number."""
        with self._cond:
            if self._closed:
                raise RuntimeError("render worker is closed")
            if self._has_request:
                self.dropped += 1
            self.submitted += 1
            self._request, self._has_request = (self.submitted, request), True
            self._cond.notify_all()  # both lanes wait on it: notify() could wake only the spare, which ignores it
            return self.submitted

    def stale(self, seq: int) -> bool:
        """Whether a request newer than number ``seq`` has been submitted: a render can give up then
        by raising ``avgs.threads.Stopped`` (counted in :attr:`stopped`, not reported as an error)."""
        return self.submitted > seq

    def expedite(self) -> bool:
        """Start the request waiting behind the one running now on the spare lane (if there is one
        and it is free); True when it was handed over."""
        with self._cond:
            if self._spare is None or not self._has_request or self._running == 0 or self._urgent is not None:
                return False
            self._urgent, self._has_request, self._request = self._request, False, None
            self._cond.notify_all()
            return True

    def wait_idle(self, timeout: float = 10.0) -> bool:
        """Block until nothing is queued or running; False on timeout."""
        with self._cond:
            return self._cond.wait_for(
                lambda: not (self._has_request or self._running or self._urgent is not None), timeout)

    def close(self, timeout: float = 10.0) -> None:
        """Stop after the render in progress (queued requests are dropped)."""
        with self._cond:
            self._closed = True
            self._has_request = False
            self._cond.notify_all()
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout)

    @property
    def running(self) -> bool:
        """A request is being rendered now (on either lane)."""
        with self._cond:
            return self._running > 0

    @property
    def alive(self) -> bool:
        return self._thread.is_alive() and (self._spare is None or self._spare.is_alive())

    def _loop(self) -> None:
        while True:
            with self._cond:
                while not self._has_request and not self._closed:
                    self._cond.wait()
                if self._closed:
                    self._cond.notify_all()
                    return
                (seq, request), self._has_request = self._request, False
                self._request = None
                self._running += 1
            self._run(seq, request)

    def _spare_loop(self) -> None:
        while True:
            with self._cond:
                while self._urgent is None and not self._closed:
                    self._cond.wait()
                if self._closed:
                    self._cond.notify_all()
                    return
                (seq, request), self._urgent = self._urgent, None
                self._running += 1
                self.expedited += 1
            self._run(seq, request)

    def _run(self, seq: int, request: Request) -> None:
        try:
            result = self._render(request)
        except Stopped:
            self.stopped += 1
        except BaseException as exc:  # reported, never kills the thread
            if self._on_error is not None:
                self._on_error(seq, request, exc)
        else:
            with self._deliver_lock:
                if seq < self._delivered:
                    self.superseded += 1
                else:
                    self._delivered = seq
                    self.rendered += 1
                    self._on_result(seq, request, result)
        finally:
            with self._cond:
                self._running -= 1
                self._cond.notify_all()
