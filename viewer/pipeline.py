"""Which Gaussians the viewer draws this frame, without ever waiting for the model (no GL here).

Each frame the UI states what it wants: a scene state (:class:`~viewer.scene.SceneSnapshot`),
the frame the timeline names, the orbit view. :meth:`ScenePipeline.update` decides

* whether the view is *moving*: playing, or the view or the state changed less than
  ``settle_seconds`` ago (then the frame may be approximate: reduced resolution, frames
  whose view-dependent colour was made for the last still view);
* what to ask the model worker (:class:`~viewer.worker.LatestRequestWorker`): when still,
  the exact evaluation of (state, frame, camera centre); while a slider or the timeline is
  dragged, the newest (state, frame), unless the frame cache has it; while playing, nothing
  (the prefetcher fills the clip ahead of the playhead, for the *colour view*); for a
  camera that only moves, nothing until it has turned COLOUR_REFRESH_DEGREES from the
  colour view (the view the view-dependent colour was last made for), then one request
  and that view becomes the colour view;
* in which depth order to composite: while the camera moves, the order of the *order view*,
  kept until the view has turned ORDER_REFRESH_DEGREES from it (isotropic sprites: a
  slightly stale order only swaps overlapping ones); once the view is still, the view's own
  order (the exact image);
* what to draw, best first: the exact evaluation; the cached frame of (state, frame); a
  finished evaluation of (state, frame) for another view; else the Gaussians drawn last
  (the HUD then shows the update as pending).

Time is passed in (``now``, seconds), so tests drive the clock.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from pghm.model.evaluator import Interrupted
from pghm.render import GaussianArrays
from pghm.render.frame_cache import FrameCache
from viewer.camera import OrbitView
from viewer.dynamic_resolution import ResolutionSettings
from viewer.prefetch import ClipPlan, ClipPrefetcher
from viewer.scene import Evaluated, SceneRequest, SceneSnapshot, evaluate_request
from viewer.worker import LatestRequestWorker, Superseded

COLOUR_REFRESH_DEGREES = 20.0
"""While the view moves, view-dependent colour is re-evaluated (in the worker) each time the view
has turned this far from the view it was last made for; otherwise once the view is still. Each
refresh runs the network on both cores while llvmpipe rasterises the moving frames, yet with the
moving frames culled and each orbit starting at the moving scale (docs/viewer.md) the quiet orbit
p95 was 14.0 / 14.0 ms at 20 degrees, 13.5 / 14.3 at 30 and 14.3 / 13.2 / 12.9 at 45: no reason to
show the colour of a view further behind (45 degrees behind: 7.0e-3 mean RGB off and a back
washed out with front-view colour; 20: 2.9e-3). The settled frame is exact whatever the angle."""
ORDER_REFRESH_DEGREES = 10.0
"""While the view moves, the sprites keep the depth order of a view until the view has turned this
far from it (benchmarks/bench_viewer.py measures the error: 10 degrees behind, mean 4e-4 RGB on the
synthetic avatar at 1280 x 720, an eighth of the reduced resolution's); once still, the exact order."""
WORKER_THREADS = 2
"""torch threads (process-wide, the UI thread runs almost no torch) while the worker evaluates."""


@dataclass(frozen=True)
class Shown:
    """The Gaussians chosen for a frame.

    Attributes:
        source: identifies the arrays (equal sources: equal arrays, no new upload).
        arrays: the Gaussians, or None before the first evaluation finished.
        state: (scene state key, frame) the arrays belong to.
        exact: the arrays are the full-precision evaluation for the wanted camera centre.
        model_ms, skinning_ms: what evaluating them cost (0 for a cached frame).
    """

    source: tuple
    arrays: GaussianArrays | None
    state: tuple | None
    exact: bool
    model_ms: float = 0.0
    skinning_ms: float = 0.0


NOTHING = Shown(("nothing",), None, None, False)


@dataclass(frozen=True)
class FrameStatus:
    """The pipeline's answer for one frame."""

    shown: Shown
    moving: bool
    """Draw approximately (reduced resolution) now."""
    pending: bool
    """What is drawn is not yet what the state names (or not exact while still)."""
    order_view: OrbitView
    """The view whose depth order composites the sprites: the drawn view unless moving."""


class ScenePipeline:
    """The model worker, the frame cache and its prefetcher, and the choice of what to draw.

    Args:
        cache: the frame cache (its budget is the memory setting).
        settings: the settle delay (``settle_seconds``).
        evaluate: the model call, :func:`~viewer.scene.evaluate_request` (tests pass a fake);
            it gets the request and an ``interrupt()`` to call between stages.
        threads: torch threads while evaluating.
    """

    def __init__(
        self,
        cache: FrameCache,
        settings: ResolutionSettings | None = None,
        evaluate: Callable[[SceneRequest, Callable[[], bool]], Evaluated] = evaluate_request,
        threads: int | None = WORKER_THREADS,
    ) -> None:
        self.cache = cache
        self.settings = settings or ResolutionSettings()
        self._evaluate = evaluate
        # The worker is made after its background job: the interrupt looks it up when called.
        self.prefetcher = ClipPrefetcher(cache, evaluate, lambda: self.worker.superseded())
        start = (lambda: torch.set_num_threads(threads)) if threads else None
        self.worker: LatestRequestWorker[SceneRequest, Evaluated] = LatestRequestWorker(
            self._compute, self.prefetcher, on_start=start
        )
        self.shown = NOTHING
        self.error: str | None = None
        """The newest evaluation's error (one line), shown by the UI; None once one succeeds."""
        self._view: OrbitView | None = None
        self._state: tuple | None = None
        self._view_at = self._state_at = -math.inf
        self._colour_view: OrbitView | None = None
        self._order_view: OrbitView | None = None
        self._posted: tuple | None = None

    def close(self) -> None:
        self.worker.close()

    # ------------------------------------------------------------------ per frame

    def update(
        self,
        snapshot: SceneSnapshot,
        frame: int,
        view: OrbitView,
        offset: np.ndarray,
        now: float,
        playing: bool = False,
        loop: bool = True,
        settled: bool = False,
        block: bool = False,
    ) -> FrameStatus:
        """What to draw for (``snapshot``, ``frame``, ``view``) at time ``now``.

        Args:
            offset: (3,) the camera target's shift at ``frame`` (following the body).
            playing: the clip plays (frames come from the prefetched cache).
            settled: treat the view as still now (tests, scripts, screenshots).
            block: wait for the exact evaluation, no prefetching (fixed-rate recording of a
                motion; the synchronous viewer).
        """
        state = (snapshot.key, frame)
        if view != self._view:
            self._view, self._view_at = view, now
        if state != self._state:
            self._state, self._state_at = state, now
        if settled or block:
            self._view_at = self._state_at = -math.inf
        settle = self.settings.settle_seconds
        view_still = now - self._view_at >= settle
        turned = self._colour_view is None or view.degrees_to(self._colour_view) > COLOUR_REFRESH_DEGREES
        if view_still or turned:
            self._colour_view = view
        if view_still or self._order_view is None or view.degrees_to(self._order_view) > ORDER_REFRESH_DEGREES:
            self._order_view = view
        moving = not block and (playing or not view_still or now - self._state_at < settle)

        request = snapshot.request(frame, view, offset)
        cached = self.cache.get(state)
        if not moving:
            self._post(request)
        elif not playing and ((state != self.shown.state and cached is None) or turned):
            self._post(request)  # a drag: the newest (state, frame) wins
        if block:
            self.worker.wait_idle()
        self._plan(snapshot, frame, playing, loop, wanted=not block and (playing or not moving))

        self.shown = self._choose(request, state, cached)
        pending = self.worker.pending > 0 or self.shown.state != state or (not moving and not self.shown.exact)
        return FrameStatus(self.shown, moving, pending, self._order_view)

    def _post(self, request: SceneRequest) -> None:
        if request.key != self._posted and self.shown.source != ("exact", request.key):
            self.worker.post(request)
            self._posted = request.key

    def _plan(self, snapshot: SceneSnapshot, frame: int, playing: bool, loop: bool, wanted: bool) -> None:
        """Prefetch the clip when ``wanted``: while it plays or while everything is still, not during a drag."""
        plan = None
        if snapshot.motion.num_frames > 1 and wanted:
            playhead = (frame + 1) % snapshot.motion.num_frames if playing else frame
            plan = ClipPlan(snapshot, self._colour_view, playhead, loop)
        if self.prefetcher.set_plan(plan):
            self.worker.wake()

    def _choose(self, request: SceneRequest, state: tuple, cached) -> Shown:
        finished = self.worker.latest()
        if finished is not None:  # the newest evaluation's error stays shown until one succeeds
            self.error = str(finished.error).splitlines()[0] if finished.error is not None else None
        if finished is not None and finished.result is not None and finished.request.key == request.key:
            result = finished.result
            return Shown(("exact", request.key), result.arrays, state, True, result.model_ms, result.skinning_ms)
        if cached is not None:
            source = ("cache", state, cached.view)
            if self.shown.source == source:
                return self.shown
            return Shown(source, cached.unpack(), state, False)
        if finished is not None and finished.result is not None and finished.request.key[:2] == state:
            result = finished.result
            return Shown(("result", finished.serial), result.arrays, state, False, result.model_ms, result.skinning_ms)
        return self.shown

    # ------------------------------------------------------------ worker thread

    def _compute(self, request: SceneRequest) -> Evaluated:
        """The worker's job: evaluate, and keep a clip's frame in the cache for scrubbing back.

        Stops between the model's stages when a newer request waits.
        """
        try:
            evaluated = self._evaluate(request, self.worker.superseded)
        except Interrupted:
            raise Superseded from None
        if request.snapshot.motion.num_frames > 1:
            self.prefetcher.store(request.snapshot.key, request.frame, request.view, evaluated)
        return evaluated
