"""Filling the frame cache ahead of the playhead, in the model worker's idle time.

The UI hands the prefetcher a :class:`ClipPlan` (the scene state, the settled view, the
playhead) whenever the clip plays or the view settles; each :meth:`ClipPrefetcher.step`
evaluates one frame: the first frame in playing order from the playhead
(:func:`~pghm.render.frame_cache.frames_ahead`) that is missing from the cache or whose
view-dependent colour was made for another view. Only as many frames as the budget holds
are visited, so a clip longer than the cache does not evict the frames about to play.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass

from pghm.model.evaluator import Interrupted
from pghm.render.frame_cache import FrameCache, PackedFrame, frames_ahead
from viewer.camera import OrbitView
from viewer.scene import Evaluated, SceneRequest, SceneSnapshot
from viewer.worker import Superseded


@dataclass(frozen=True, eq=False)
class ClipPlan:
    """What to prefetch: a clip's frames in ``snapshot``'s state seen from ``view``, from ``playhead``."""

    snapshot: SceneSnapshot
    view: OrbitView
    playhead: int
    loop: bool

    @property
    def key(self) -> tuple:
        return self.snapshot.key, self.view, self.playhead, self.loop


class ClipPrefetcher:
    """A :class:`~viewer.worker.BackgroundJob` evaluating a plan's frames into ``cache``.

    A frame is stored under ``(snapshot.key, frame)``; its packed view records ``view``.

    Args:
        cache: where frames go.
        evaluate: the model call (:func:`viewer.scene.evaluate_request`), on the worker thread.
        interrupt: passed to ``evaluate``; stops a step when a request waits.
    """

    def __init__(
        self,
        cache: FrameCache,
        evaluate: Callable[[SceneRequest, Callable[[], bool]], Evaluated],
        interrupt: Callable[[], bool],
    ) -> None:
        self.cache = cache
        self._evaluate = evaluate
        self._interrupt = interrupt
        self._frame_bytes = 0  # of the last frame stored: how many frames the budget holds
        self._plan: ClipPlan | None = None
        self._lock = threading.Lock()
        self.evaluated = 0
        """Frames evaluated so far."""

    def set_plan(self, plan: ClipPlan | None) -> bool:
        """Prefetch for ``plan`` from now on (None: nothing); True if the plan changed."""
        with self._lock:
            changed = (plan is None) != (self._plan is None) or (plan is not None and plan.key != self._plan.key)
            self._plan = plan
            return changed

    def next_frame(self, plan: ClipPlan) -> int | None:
        """The first frame of ``plan`` the cache lacks or holds for another view (None: all done)."""
        motion = plan.snapshot.motion
        if motion.num_frames <= 1:
            return None
        order = frames_ahead(plan.playhead, motion.num_frames, plan.loop)
        fits = self.cache.budget_bytes // self._frame_bytes if self._frame_bytes else len(order)
        for frame in order[:fits]:
            stored = self.cache.peek((plan.snapshot.key, frame))
            if stored is None or stored.view != plan.view:
                return frame
        return None

    def step(self) -> bool:
        with self._lock:
            plan = self._plan
        if plan is None:
            return False
        frame = self.next_frame(plan)
        if frame is None:
            return False
        try:
            evaluated = self._evaluate(plan.snapshot.request(frame, plan.view), self._interrupt)
        except Interrupted:
            raise Superseded from None  # a request waits; this frame comes again in a later step
        self.store(plan.snapshot.key, frame, plan.view, evaluated)
        self.evaluated += 1
        return True

    def store(self, state: tuple, frame: int, view: OrbitView, evaluated: Evaluated) -> None:
        """Keep ``evaluated`` as frame ``frame`` of scene state ``state`` (also the UI's requests)."""
        packed = PackedFrame.pack(evaluated.arrays, view)
        self._frame_bytes = packed.nbytes
        self.cache.put((state, frame), packed)
