"""The viewer's model worker, frame cache, prefetcher, dynamic resolution and frame choice, without GL.

The worker is driven with a fake model that blocks on events (no sleeps, no timing): the
test decides when each evaluation may finish, so "the newest request wins" and "the frame
drawn is the frame the timeline names" are checked deterministically. The fake model's
Gaussians encode the request (frame, camera centre) in their values, an independent record
of what was evaluated. The pipeline's clock is passed in.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
import pytest

from pghm.errors import PghmError
from pghm.render import GaussianArrays
from pghm.render.frame_cache import FrameCache, PackedFrame, frames_ahead
from viewer.camera import OrbitView
from viewer.dynamic_resolution import SCALE_STEP, ResolutionController, ResolutionSettings
from viewer.pipeline import ORDER_REFRESH_DEGREES, ScenePipeline
from viewer.scene import Evaluated, SceneRequest
from viewer.worker import LatestRequestWorker, Superseded

WAIT = 30.0
"""Seconds a test waits for the worker thread before failing (a hang, not a timing check)."""
COUNT = 64
"""Gaussians of a fake frame."""
SETTLE = ResolutionSettings().settle_seconds
FRONT = OrbitView((0.0, 1.0, 0.0), 0.0, 0.0, 3.0, 40.0)


def arrays_of(frame: int, centre: np.ndarray, count: int = COUNT) -> GaussianArrays:
    """Gaussians whose means hold the frame number and whose colours hold the centre's x."""
    return GaussianArrays(
        means=np.full((count, 3), float(frame), np.float32),
        scales=np.full(count, 0.01, np.float32),
        colors=np.full((count, 3), 0.5 + 0.01 * float(centre[0]), np.float32),
        opacities=np.ones(count, np.float32),
        normals=np.tile(np.array([0.0, 0.0, 1.0], np.float32), (count, 1)),
    )


# ------------------------------------------------------------------------- worker


class GatedModel:
    """compute(request) records the request, signals that it started, and waits for the test's go."""

    def __init__(self) -> None:
        self.started: list[object] = []
        self.finished: list[object] = []
        self.started_event = threading.Event()
        self.go = threading.Semaphore(0)

    def __call__(self, request):
        self.started.append(request)
        self.started_event.set()
        assert self.go.acquire(timeout=WAIT), "the test never let the evaluation finish"
        self.finished.append(request)
        return f"result of {request}"


def test_newest_request_wins_and_older_waiting_ones_are_dropped():
    model = GatedModel()
    worker = LatestRequestWorker(model)
    try:
        worker.post("a")
        assert model.started_event.wait(WAIT)
        for name in ("b", "c", "d"):  # posted while "a" runs: only the newest waits
            worker.post(name)
        assert worker.pending == 2 and worker.dropped == 2
        model.go.release()  # "a" finishes
        model.go.release()  # "d" finishes
        assert worker.wait_idle(WAIT)
        assert model.started == ["a", "d"], "b and c were never evaluated"
        finished = worker.latest()
        assert finished.request == "d" and finished.result == "result of d" and finished.serial == 4
        assert worker.pending == 0
    finally:
        model.go.release()
        worker.close()


def test_a_running_evaluation_stops_at_its_next_checkpoint_when_a_newer_request_waits():
    reached = threading.Event()
    resume = threading.Event()
    computed: list[str] = []
    worker: LatestRequestWorker | None = None

    def compute(request):
        if request == "old":
            reached.set()  # the first stage is done
            assert resume.wait(WAIT)
            if worker.superseded():  # the checkpoint between two stages
                raise Superseded
        computed.append(request)
        return request

    worker = LatestRequestWorker(compute)
    try:
        worker.post("old")
        assert reached.wait(WAIT)
        worker.post("new")
        resume.set()
        assert worker.wait_idle(WAIT)
        assert computed == ["new"] and worker.latest().request == "new" and worker.dropped == 1
    finally:
        resume.set()
        worker.close()


def test_an_error_in_the_model_is_kept_and_the_worker_goes_on():
    def compute(request):
        if request == "bad":
            raise PghmError("bad request")
        return request * 2

    worker = LatestRequestWorker(compute)
    try:
        worker.post("bad")
        assert worker.wait_idle(WAIT)
        assert str(worker.latest().error) == "bad request" and worker.latest().result is None
        worker.post("ok")
        assert worker.wait_idle(WAIT)
        assert worker.latest().result == "okok" and worker.latest().error is None
    finally:
        worker.close()


def test_background_steps_run_only_when_no_request_waits():
    order: list[str] = []
    steps_left = threading.Semaphore(0)
    done = threading.Event()

    class Job:
        remaining = 3

        def step(self) -> bool:
            assert steps_left.acquire(timeout=WAIT)
            order.append("step")
            self.remaining -= 1
            if self.remaining == 0:
                done.set()
            return self.remaining > 0

    worker = LatestRequestWorker(lambda r: order.append(r), background=Job())
    try:
        steps_left.release()  # one background step
        worker.post("request")  # waits until that step ends, then runs before the next step
        steps_left.release()
        steps_left.release()
        assert done.wait(WAIT) and worker.wait_idle(WAIT)
        assert order.count("step") == 3 and "request" in order
        assert order.index("request") <= 1, "a waiting request goes before further background steps"
    finally:
        worker.close()


# -------------------------------------------------------------------------- cache


def packed(frame: int, count: int = COUNT) -> PackedFrame:
    return PackedFrame.pack(arrays_of(frame, np.zeros(3), count))


def test_a_packed_frame_has_the_documented_size_and_precision():
    rng = np.random.default_rng(0)
    count = 1000
    arrays = GaussianArrays(
        means=rng.uniform(-1, 1, (count, 3)).astype(np.float32),
        scales=rng.uniform(1e-3, 3e-2, count).astype(np.float32),
        colors=rng.uniform(0, 1, (count, 3)).astype(np.float32),
        opacities=rng.uniform(0.01, 1, count).astype(np.float32),
        normals=rng.normal(size=(count, 3)).astype(np.float32),
    )
    frame = PackedFrame.pack(arrays)
    assert frame.nbytes == 32 * count, "5 float32 footprint values + 6 float16 shading values"
    back = frame.unpack()
    for name in ("means", "scales", "opacities"):
        assert np.array_equal(getattr(back, name), getattr(arrays, name)), f"{name} stay float32"
    # float16 keeps 11 significant bits: relative rounding <= 2^-11
    for name in ("colors", "normals"):
        original, restored = getattr(arrays, name), getattr(back, name)
        assert np.all(np.abs(restored - original) <= 2.0**-11 * np.abs(original) + 1e-7), name


def test_the_cache_stays_within_its_budget_and_evicts_the_least_recently_used():
    size = packed(0).nbytes
    cache = FrameCache(budget_bytes=3 * size)
    for frame in range(3):
        cache.put(("clip", frame), packed(frame))
    assert len(cache) == 3 and cache.nbytes == 3 * size
    assert cache.get(("clip", 0)) is not None  # frame 0 becomes the most recently used
    cache.put(("clip", 3), packed(3))  # over budget: the least recently used (frame 1) goes
    assert cache.peek(("clip", 1)) is None
    assert [key[1] for key in cache.keys()] == [2, 0, 3]
    assert cache.nbytes == 3 * size <= cache.budget_bytes and cache.evictions == 1
    cache.put(("clip", 4), packed(4))
    assert [key[1] for key in cache.keys()] == [0, 3, 4], "peek did not refresh frame 2"
    cache.put(("big", 0), packed(0, count=4 * COUNT))  # larger than the whole budget: not kept
    assert cache.peek(("big", 0)) is None and cache.nbytes <= cache.budget_bytes
    cache.put(("clip", 4), packed(4))  # replacing a key does not count it twice
    assert cache.nbytes == 3 * size


def test_a_negative_budget_is_refused():
    with pytest.raises(PghmError, match="budget"):
        FrameCache(budget_bytes=-1)


def test_frames_ahead_of_the_playhead():
    assert frames_ahead(3, 6, loop=True) == [3, 4, 5, 0, 1, 2]
    assert frames_ahead(3, 6, loop=False) == [3, 4, 5, 2, 1, 0]
    assert frames_ahead(0, 1, loop=True) == [0]


# --------------------------------------------------------------- dynamic resolution


@pytest.mark.parametrize("full_ms", [5.0, 40.0, 160.0, 1000.0])
def test_the_resolution_controller_settles_where_the_draw_holds_the_budget(full_ms):
    """A fragment-bound draw takes full_ms s^2; the scale converges to sqrt(budget / full_ms) (clamped)."""
    settings = ResolutionSettings(draw_budget_ms=10.0, min_scale=0.25)
    controller = ResolutionController(settings)
    scale = controller.scale
    for _ in range(40):
        scale = controller.update(scale, full_ms * scale**2)
    ideal = min(1.0, max(settings.min_scale, np.sqrt(settings.draw_budget_ms / full_ms)))
    assert abs(scale - ideal) <= SCALE_STEP / 2 + 1e-9
    assert settings.min_scale <= scale <= 1.0
    assert abs(scale / SCALE_STEP - round(scale / SCALE_STEP)) < 1e-9


# -------------------------------------------------------------------- the pipeline


@dataclass(frozen=True)
class FakeMotion:
    num_frames: int


class FakeSnapshot:
    """What the pipeline reads of a :class:`~viewer.scene.SceneSnapshot`: key, motion, request()."""

    def __init__(self, name: str, frames: int) -> None:
        self.key = (name,)
        self.motion = FakeMotion(frames)

    def request(self, frame: int, view: OrbitView, offset: np.ndarray | None = None) -> SceneRequest:
        return SceneRequest(self, frame, view, view.centre(np.zeros(3)))


class FakeModel:
    """Evaluations gated by the test (one ``allow`` per evaluation), recorded by frame."""

    def __init__(self) -> None:
        self.frames: list[int] = []
        self.gate = threading.Semaphore(0)
        self.ungated = threading.Event()

    def __call__(self, request: SceneRequest, interrupt) -> Evaluated:
        if not self.ungated.is_set():
            assert self.gate.acquire(timeout=WAIT), "the test never let the evaluation run"
        self.frames.append(request.frame)
        return Evaluated(arrays_of(request.frame, request.centre), 1.0, 1.0)


@pytest.fixture
def model_pipeline():
    model = FakeModel()
    pipeline = ScenePipeline(FrameCache(), evaluate=model, threads=None)
    yield model, pipeline
    model.ungated.set()
    for _ in range(100):
        model.gate.release()
    pipeline.close()


def drawn_frame(status) -> int:
    return int(status.shown.arrays.means[0, 0])


def test_after_a_seek_settles_the_drawn_frame_is_the_frame_the_timeline_names(model_pipeline):
    model, pipeline = model_pipeline
    clip = FakeSnapshot("clip", frames=1)  # one frame per "clip": no prefetching in this test
    now = 0.0
    status = pipeline.update(clip, 0, FRONT, np.zeros(3), now)
    model.gate.release()
    assert pipeline.worker.wait_idle(WAIT)
    # A scrub: the timeline names 5, 6, ..., 12 on consecutive frames while the model is slow.
    for frame in range(5, 13):
        now += 0.01
        status = pipeline.update(FakeSnapshot("clip", 1), frame, FRONT, np.zeros(3), now)
        assert status.moving and status.pending
    model.gate.release()  # the first scrub request finishes; the newer ones replaced each other
    model.gate.release()
    assert pipeline.worker.wait_idle(WAIT)
    now += 0.01
    status = pipeline.update(FakeSnapshot("clip", 1), 12, FRONT, np.zeros(3), now)
    assert drawn_frame(status) == 12 and status.shown.state[1] == 12
    now += 2 * SETTLE  # still for the settle delay: the exact evaluation is asked
    status = pipeline.update(FakeSnapshot("clip", 1), 12, FRONT, np.zeros(3), now)
    assert not status.moving
    model.gate.release()
    assert pipeline.worker.wait_idle(WAIT)
    status = pipeline.update(FakeSnapshot("clip", 1), 12, FRONT, np.zeros(3), now + 0.01)
    assert status.shown.exact and not status.pending and drawn_frame(status) == 12
    # The worker took one scrub frame before the newest replaced the rest: which one depends on
    # when its thread ran (5 when at once, a later one on a loaded machine), not on the pipeline.
    between = set(model.frames) - {0, 12}
    assert len(between) <= 1 and between <= set(range(5, 12)) and len(model.frames) <= 4, "the scrub queued frames"


def test_a_moving_camera_asks_nothing_until_it_turns_far_and_the_still_view_is_exact(model_pipeline):
    model, pipeline = model_pipeline
    model.ungated.set()
    still = FakeSnapshot("pose", frames=1)
    pipeline.update(still, 0, FRONT, np.zeros(3), 0.0)
    assert pipeline.worker.wait_idle(WAIT)
    pipeline.update(still, 0, FRONT, np.zeros(3), 1.0)
    evaluated = len(model.frames)
    now = 1.0
    for step in range(1, 5):  # 4 x 4 degrees: under the refresh angle, no model work
        now += 0.01
        status = pipeline.update(still, 0, OrbitView(FRONT.target, 4.0 * step, 0.0, 3.0, 40.0), np.zeros(3), now)
        assert status.moving
    assert pipeline.worker.wait_idle(WAIT) and len(model.frames) == evaluated
    turned = OrbitView(FRONT.target, 90.0, 0.0, 3.0, 40.0)
    status = pipeline.update(still, 0, turned, np.zeros(3), now + 0.01)
    assert pipeline.worker.wait_idle(WAIT) and len(model.frames) == evaluated + 1, "a far turn refreshes the colour"
    status = pipeline.update(still, 0, turned, np.zeros(3), now + 2 * SETTLE)
    assert status.shown.exact and not status.moving
    expected = arrays_of(0, turned.centre(np.zeros(3)))
    assert np.array_equal(status.shown.arrays.colors, expected.colors), "the colour is the turned view's"


def test_a_moving_camera_keeps_a_recent_depth_order_and_the_still_view_sorts_exactly(model_pipeline):
    """While moving, the order view lags the drawn view by at most ORDER_REFRESH_DEGREES and is
    then replaced by the newest view (not an older one); once still, it is the drawn view."""
    model, pipeline = model_pipeline
    model.ungated.set()
    still = FakeSnapshot("pose", frames=1)
    status = pipeline.update(still, 0, FRONT, np.zeros(3), 0.0)
    assert status.order_view == FRONT
    step = 3.0  # degrees of yaw per frame
    views = [OrbitView(FRONT.target, step * k, 0.0, 3.0, 40.0) for k in range(1, 16)]
    now, stale, refreshed = 1.0, 0, []
    for view in views:
        now += 0.01
        status = pipeline.update(still, 0, view, np.zeros(3), now)
        assert status.moving
        assert status.order_view in (FRONT, *views[: views.index(view) + 1]), "an order of a view that was drawn"
        assert view.degrees_to(status.order_view) <= ORDER_REFRESH_DEGREES + 1e-9
        stale += status.order_view != view
        if status.order_view == view:
            refreshed.append(view)
    assert stale > len(views) / 2, "most moving frames keep the last order"
    assert refreshed, "a turn past the refresh angle takes the newest view's order"
    assert all(b.degrees_to(a) > ORDER_REFRESH_DEGREES for a, b in zip([FRONT, *refreshed], refreshed))
    status = pipeline.update(still, 0, views[-1], np.zeros(3), now + 0.01)
    assert status.moving and status.order_view != views[-1], "a view that just stopped is still moving"
    status = pipeline.update(still, 0, views[-1], np.zeros(3), now + 2 * SETTLE)
    assert not status.moving and status.order_view == views[-1], "the still view composites in its own order"


def test_playing_a_clip_after_one_pass_draws_cached_frames_only(model_pipeline):
    model, pipeline = model_pipeline
    model.ungated.set()
    frames = 12
    clip = FakeSnapshot("walk", frames=frames)
    pipeline.update(clip, 0, FRONT, np.zeros(3), 0.0)
    pipeline.update(clip, 0, FRONT, np.zeros(3), 1.0)  # still: exact frame 0, prefetch the rest
    assert pipeline.worker.wait_idle(WAIT)
    assert pipeline.worker.wait_background_idle(WAIT)
    assert sorted(set(model.frames)) == list(range(frames))
    assert len(pipeline.cache) == frames
    evaluated = len(model.frames)
    now = 2.0
    for k in range(2 * frames):  # play two loops
        now += 1 / 30
        frame = k % frames
        status = pipeline.update(clip, frame, FRONT, np.zeros(3), now, playing=True)
        assert drawn_frame(status) == frame and status.shown.state == (clip.key, frame)
        assert status.moving
    assert len(model.frames) == evaluated, "no model work while playing a cached clip"


def test_still_frames_only_lower_the_resolution_controller_scale():
    """A still frame's estimate (full scale, over budget) caps the moving scale but never raises it."""
    settings = ResolutionSettings(draw_budget_ms=5.0, min_scale=0.25)
    controller = ResolutionController(settings)
    assert controller.update(1.0, 80.0, moving=False) == pytest.approx(0.25)  # sqrt(5 / 80): the cap
    controller = ResolutionController(settings)
    first = controller.update(1.0, 20.0, moving=False)
    assert first == pytest.approx(0.5)  # sqrt(5 / 20), no smoothing towards the initial 1.0
    for _ in range(10):  # moving frames with a fixed cost: at the least scale still over budget
        scale = controller.update(controller.scale, 20.0)
    assert scale == pytest.approx(0.25)
    assert controller.update(1.0, 20.0, moving=False) == pytest.approx(0.25)  # the still frame does not raise it
    assert controller.update(0.25, 1.0) > 0.25  # a fast moving frame does
