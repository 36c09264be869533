"""A thread that runs only the newest request: :class:`RenderWorker`.

Requests submitted while one runs overwrite each other; when it is done only the newest
runs next. The explorer's filter path (:mod:`avgs_viewer.worker`), its full-render path
(:mod:`avgs_viewer.refine`) and the listener's-view inset each run on one. No Qt here.
"""

from __future__ import annotations

import threading
from typing import Any, Callable, Generic, TypeVar

Request = TypeVar("Request")
"What is submitted (the filter path: a :class:`~avgs_viewer.worker.PoseRequest`)."
Result = TypeVar("Result")
"What ``render`` returns for it (the filter path: the pose's ``RenderResult``)."


class RenderWorker(Generic[Request, Result]):
    """Runs ``render(request)`` on one daemon thread, newest request wins.

    ``on_result(seq, request, result)`` / ``on_error(seq, request, exc)`` are called on the
    worker thread; ``seq`` numbers submissions from 1, so a receiver can drop stale ones.
    """

    def __init__(self, render: Callable[[Request], Result], on_result: Callable[[int, Request, Result], None],
                 on_error: Callable[[int, Request, BaseException], None] | None = None, name: str = "avgs-render"):
        self._render = render
        self._on_result = on_result
        self._on_error = on_error
        self._cond = threading.Condition()
        self._request: Any = None  # (seq, request: Request) of the newest not yet started, while _has_request
        self._has_request = False
        self._busy = False
        self._closed = False
        self.submitted = 0
        self.rendered = 0
        self.dropped = 0
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)
        self._thread.start()

    def submit(self, request: Request) -> int:
        """Queue ``request``, replacing any not yet started; returns its sequence number."""
        with self._cond:
            if self._closed:
                raise RuntimeError("render worker is closed")
            if self._has_request:
                self.dropped += 1
            self.submitted += 1
            self._request, self._has_request = (self.submitted, request), True
            self._cond.notify()
            return self.submitted

    def wait_idle(self, timeout: float = 10.0) -> bool:
        """Block until nothing is queued or running; False on timeout."""
        with self._cond:
            return self._cond.wait_for(lambda: not (self._has_request or self._busy), timeout)

    def close(self, timeout: float = 10.0) -> None:
        """Stop after the render in progress (queued requests are dropped)."""
        with self._cond:
            self._closed = True
            self._has_request = False
            self._cond.notify_all()
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout)

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    def _loop(self) -> None:
        while True:
            with self._cond:
                while not self._has_request and not self._closed:
                    self._cond.wait()
                if self._closed:
                    self._cond.notify_all()
                    return
                (seq, request), self._has_request = self._request, False
                self._request, self._busy = None, True
            try:
                result = self._render(request)
            except BaseException as exc:  # reported, never kills the thread
                if self._on_error is not None:
                    self._on_error(seq, request, exc)
            else:
                self.rendered += 1
                self._on_result(seq, request, result)
            finally:
                with self._cond:
                    self._busy = False
                    self._cond.notify_all()
