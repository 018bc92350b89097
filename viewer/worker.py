"""The model off the UI thread: one worker thread, the newest request wins, idle time fills a cache.

The UI posts a request whenever what it wants to show changes (a pose slider, an identity
edit, a timeline move, the settled view) and keeps drawing the last finished result. A
request posted while another waits replaces it (the older one is dropped, never queued),
and the one running stops at its next checkpoint (:class:`Superseded`, raised by the model
between its stages), so the newest value waits at most one stage. When no request
waits, the worker runs background steps (:class:`BackgroundJob`, e.g. evaluating motion
frames ahead of the playhead into :class:`pghm.render.frame_cache.FrameCache`), one short step at
a time so that a new request waits at most one step.

A thread, not a process: torch releases the GIL inside its kernels, the model's weights and
the body are shared without copying, and the results (a few numpy arrays of 11k rows) need
no pickling. docs/viewer.md has the UI frame times measured with the worker busy.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, Protocol, TypeVar

Request = TypeVar("Request")
Result = TypeVar("Result")


class Superseded(Exception):
    """``compute`` (or a background step) raises it to stop early once
    :meth:`LatestRequestWorker.superseded` is True: the work is dropped like a request replaced
    while waiting, and the newer one starts."""


class BackgroundJob(Protocol):
    """Work the worker does when no request waits."""

    def step(self) -> bool:
        """Do one short unit of work; False when there is nothing left to do."""


@dataclass(frozen=True)
class Finished(Generic[Request, Result]):
    """A computed request: ``serial`` counts the requests posted, so a newer one has a larger serial."""

    serial: int
    request: Request
    result: Result | None
    error: Exception | None = None


class LatestRequestWorker(Generic[Request, Result]):
    """Runs ``compute(request)`` on a worker thread for the newest posted request.

    Args:
        compute: the model call; runs only on the worker thread. An exception it raises is
            kept in the :class:`Finished` result (the UI shows it), the thread goes on.
        background: work for idle time, or None.
        on_start: called once on the worker thread before anything else (e.g. torch threads).
    """

    def __init__(
        self,
        compute: Callable[[Request], Result],
        background: BackgroundJob | None = None,
        on_start: Callable[[], None] | None = None,
    ) -> None:
        self._compute = compute
        self._background = background
        self._on_start = on_start
        self._lock = threading.Condition()
        self._waiting: tuple[int, Request] | None = None
        self._running: int | None = None  # serial being computed
        self._finished: Finished[Request, Result] | None = None
        self._serial = 0
        self._background_idle = background is None
        self._stop = False
        self.dropped = 0
        """Requests replaced by a newer one before they started."""
        self.background_error: Exception | None = None
        """The last exception of a background step."""
        self._thread = threading.Thread(target=self._loop, name="pghm-model-worker", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ UI side

    def post(self, request: Request) -> int:
        """Ask for ``request``; a request still waiting is dropped. Returns its serial."""
        with self._lock:
            self._serial += 1
            if self._waiting is not None:
                self.dropped += 1
            self._waiting = (self._serial, request)
            self._lock.notify_all()
            return self._serial

    def wake(self) -> None:
        """Tell the worker that background work may exist again (e.g. a new clip or playhead)."""
        with self._lock:
            self._background_idle = self._background is None
            self._lock.notify_all()

    def latest(self) -> Finished[Request, Result] | None:
        """The newest finished request (None before the first)."""
        with self._lock:
            return self._finished

    def superseded(self) -> bool:
        """Whether a request waits (for ``compute`` and background steps to stop early; any thread)."""
        return self._waiting is not None

    @property
    def pending(self) -> int:
        """Requests posted and not finished: waiting or running (0, 1 or 2)."""
        with self._lock:
            return (self._waiting is not None) + (self._running is not None)

    @property
    def background_busy(self) -> bool:
        """Whether background steps remain (until a step reports nothing left)."""
        with self._lock:
            return not self._background_idle

    def wait_idle(self, timeout: float | None = None) -> bool:
        """Block until no request waits or runs (background work aside); False on timeout."""
        with self._lock:
            return self._lock.wait_for(lambda: self._waiting is None and self._running is None, timeout)

    def wait_background_idle(self, timeout: float | None = None) -> bool:
        """Block until no request is left and the background job reported nothing left; False on timeout."""
        with self._lock:
            return self._lock.wait_for(
                lambda: self._waiting is None and self._running is None and self._background_idle, timeout
            )

    def close(self) -> None:
        """Stop the thread after the step it is in."""
        with self._lock:
            self._stop = True
            self._lock.notify_all()
        self._thread.join()

    # -------------------------------------------------------------- worker side

    def _loop(self) -> None:
        if self._on_start is not None:
            self._on_start()
        while True:
            with self._lock:
                self._lock.wait_for(lambda: self._stop or self._waiting is not None or not self._background_idle)
                if self._stop:
                    return
                job, self._waiting = self._waiting, None
                if job is not None:
                    self._running = job[0]
            if job is None:
                try:
                    more = self._background.step()
                except Superseded:
                    more = True
                except Exception as error:  # kept for the UI; background work stops until woken
                    self.background_error, more = error, False
                with self._lock:
                    if not more:
                        self._background_idle = True
                        self._lock.notify_all()
                continue
            serial, request = job
            try:
                finished = Finished(serial, request, self._compute(request))
            except Superseded:
                finished = None
            except Exception as error:  # shown by the UI; the worker must outlive a bad request
                finished = Finished(serial, request, None, error)
            with self._lock:
                if finished is None:
                    self.dropped += 1
                else:
                    self._finished = finished
                self._running = None
                self._lock.notify_all()
