"""The whole ``pghm render`` command: a :class:`RenderJob` -> frames -> a file.

:func:`plan_frames` turns the job and its motion into one :class:`FrameSpec` per output
frame; :func:`render_video` drives the avatar (:mod:`pghm.render.driver`), places the
camera (:mod:`pghm.render.framing`), draws (:mod:`pghm.render.frames`) and writes
(:mod:`pghm.render.sinks`), and returns a :class:`RenderSummary`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pghm._fault_injection import interrupt_point
from pghm.errors import PghmError
from pghm.io.outputs import check_output
from pghm.render.driver import AvatarDriver, GaussianSet
from pghm.render.frame_cache import FrameCache, PackedFrame
from pghm.render.frames import Backend, CPUFrames, frame_renderer
from pghm.render.framing import DEFAULT_FOV_Y, floor_shift, frame_points, orbit_camera
from pghm.render.sinks import check_frame_size, open_sink, output_kind, to_uint8

DEFAULT_SIZE = (640, 480)
"""(W, H) of ``pghm render`` images."""
DEFAULT_FPS = 30.0
ORBIT_SECONDS = 4.0
"""An orbit without a motion lasts this long (one full turn)."""
MAX_RENDER_PIXELS = 2**26
"""Largest image (W x H) one render makes, 8192 x 8192: its float buffers alone take 0.8 GB, the
splatter's per-pixel state several times that; larger asks are refused before any allocation."""
MAX_RENDER_FRAMES = 1_000_000
"""Most frames one ``pghm render`` writes (9 hours at 30 fps): a motion with an absurd
duration, or an absurd --frames, is refused before a frame list is built."""


@dataclass(frozen=True)
class RenderJob:
    """Everything ``pghm render`` does, one field per option."""

    avatar: Path
    """The avatar or prior file."""
    out: Path
    """``.mp4``, ``.png`` (one frame) or a directory (PNG sequence)."""
    motion: str | None = None
    """A motion file (.npz, .bvh) or a procedural name (walk, squat, ...); None: rest pose."""
    orbit: bool = False
    """Turn the camera once around the body over the video."""
    size: tuple[int, int] = DEFAULT_SIZE
    """(W, H) in pixels."""
    fps: float = DEFAULT_FPS
    """Frames per second of the output (the motion is sampled at this rate)."""
    frames: int | None = None
    """How many frames; None: the motion once, one orbit of ORBIT_SECONDS, or 1 still."""
    start: float = 0.0
    """Seconds into the motion of the first frame."""
    backend: Backend = "auto"
    """"gl": the viewer's GL path on a headless EGL context; "cpu": the CPU splatter; "auto":
    GL when EGL works, else CPU."""
    identity: int = 0
    """Which identity of a prior's bank (ignored for an avatar)."""
    gaussians: GaussianSet = "dynamic"
    """The dynamic set (I_d, with pose- and view-dependent terms) or the static one (I_s)."""
    view_dependent: bool = True
    """Whether the dynamic set's colour includes the view-dependent term."""
    background: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """RGB in [0, 1] behind the avatar."""
    pitch: float = 0.0
    """Camera elevation, degrees."""
    yaw: float = 0.0
    """Camera azimuth of the first frame, degrees (0: the body's front)."""
    follow: bool = True
    """Keep the camera aimed at the moving root (horizontal translation only)."""
    body_model_path: str | None = None
    """The model file of bodies that are not embedded (SMPL-X)."""
    device: str = "cpu"
    """Where the network runs, and the splatter when ``backend`` is "cpu" (on CUDA: gsplat)."""


@dataclass(frozen=True)
class FrameSpec:
    """One output frame: the motion frame shown and the camera's yaw."""

    motion_frame: int
    yaw: float


@dataclass
class RenderSummary:
    """What :func:`render_video` wrote."""

    path: Path
    frames: int
    size: tuple[int, int]
    fps: float
    backend: str
    driver: str
    seconds: float
    timings: dict[str, float] = field(default_factory=dict)
    evaluated: int = 0
    """Frames the model evaluated; the others repeated an evaluated (motion frame, camera centre)."""


def plan_frames(job: RenderJob, motion) -> list[FrameSpec]:
    """The frames of ``job`` for ``motion`` (None: rest pose).

    Frame k shows time start + k / fps of the motion (looping) and the camera at
    yaw + 360 k / frames when orbiting.
    """
    if job.fps <= 0 or not math.isfinite(job.fps):
        raise PghmError(f"--fps must be positive, got {job.fps}")
    for name in ("start", "pitch", "yaw"):
        if not math.isfinite(getattr(job, name)):
            raise PghmError(f"--{name} must be a finite number, got {getattr(job, name)}")
    if job.frames is not None and job.frames < 1:
        raise PghmError(f"--frames must be at least 1, got {job.frames}")
    single = output_kind(job.out) == "png"
    if job.frames is not None:
        count = job.frames
    elif single:
        count = 1
    elif motion is not None and motion.num_frames > 1:
        count = max(1, int(math.floor((motion.duration - job.start) * job.fps + 1e-9)) + 1)
    elif job.orbit:
        count = int(round(ORBIT_SECONDS * job.fps))
    else:
        count = 1
    if single and count != 1:
        raise PghmError(f"{job.out}: a .png holds one frame, but {count} were asked; give a directory or an .mp4")
    if count > MAX_RENDER_FRAMES:
        raise PghmError(f"{count} frames asked, more than the {MAX_RENDER_FRAMES} one render writes; pass --frames")
    specs = []
    for k in range(count):
        frame = motion.frame_at(job.start + k / job.fps, loop=True) if motion is not None else 0
        yaw = job.yaw + (360.0 * k / count if job.orbit else 0.0)
        specs.append(FrameSpec(frame, yaw))
    return specs


def render_video(job: RenderJob, log: Callable[[str], None] = print) -> RenderSummary:
    """Render ``job`` and write its output; returns what was written.

    Raises :class:`~pghm.errors.PghmError` (one line) for a bad avatar or motion file, a
    missing EGL (use ``backend="cpu"``) or bad options.
    """
    from pghm.io.avatar import load_avatar
    from pghm.motion.open_motion import open_motion

    width, height = job.size
    if width < 1 or height < 1 or width * height > MAX_RENDER_PIXELS:
        raise PghmError(
            f"--size {width}x{height}: each side must be positive and the image at most {MAX_RENDER_PIXELS:,} pixels"
        )
    folder = output_kind(job.out) == "dir"  # a bad output name is refused before the slow work
    check_output(job.out, inputs=[job.avatar, job.motion, job.body_model_path], folder=folder)
    check_frame_size(job.out, width, height)
    avatar = load_avatar(job.avatar).to(job.device)
    avatar.check_identity(job.identity)
    driver = AvatarDriver(avatar, job.identity, job.body_model_path)
    shape = driver.geometry.shape.cpu()
    motion = open_motion(job.motion, driver.body, shape, avatar.pose_track) if job.motion else None
    specs = plan_frames(job, motion)
    identity_map = avatar.identity_map(job.identity)
    rest_points = driver.geometry.surface.positions.cpu().numpy()
    framing = frame_points(rest_points, DEFAULT_FOV_Y, width / height)
    rest_root = driver.root_position(driver.rest_pose())

    started = time.perf_counter()
    totals = {"model_ms": 0.0, "skinning_ms": 0.0, "render_ms": 0.0, "write_ms": 0.0}
    # Frames repeat when the motion loops or the output rate exceeds the motion's: each
    # (motion frame, camera centre) is evaluated once. Full precision: the files are exact.
    frames = FrameCache()
    view_dependent = job.gaussians == "dynamic" and job.view_dependent
    reused = 0
    sink = open_sink(job.out, job.fps, on_fallback=log)
    try:
        with frame_renderer(job.backend, log, avatar.device) as renderer:
            renderer.check_size(width, height)
            for spec in specs:
                pose = motion.pose(spec.motion_frame) if motion is not None else driver.rest_pose()
                target = np.asarray(framing.target, dtype=np.float64)
                if job.follow:
                    target = target + floor_shift(driver.root_position(pose), rest_root)
                camera = orbit_camera(target, spec.yaw, job.pitch, framing.distance, DEFAULT_FOV_Y, width, height)
                # The view-dependent colour is the only term that depends on the camera.
                key = (spec.motion_frame, camera.centre.numpy().tobytes() if view_dependent else None)
                stored = frames.get(key)
                if stored is None:
                    arrays = driver.evaluate(identity_map, pose, camera.centre, job.gaussians, job.view_dependent)
                    frames.put(key, PackedFrame.pack(arrays, exact=True))
                    totals["model_ms"] += driver.times.model_ms
                    totals["skinning_ms"] += driver.times.skinning_ms
                else:
                    arrays = stored.unpack()
                    reused += 1
                start = time.perf_counter()
                rgb = renderer.render(arrays, camera, job.background)
                totals["render_ms"] += (time.perf_counter() - start) * 1e3
                start = time.perf_counter()
                sink.write(to_uint8(rgb))
                interrupt_point("render-frame")
                totals["write_ms"] += (time.perf_counter() - start) * 1e3
            driver_name = renderer.driver
    except BaseException:
        sink.abort()
        raise
    sink.close()
    return RenderSummary(
        path=sink.path,
        frames=sink.frames,
        size=(width, height),
        fps=job.fps,
        backend="cpu" if isinstance(renderer, CPUFrames) else "gl",
        driver=driver_name,
        seconds=time.perf_counter() - started,
        timings={name: value / max(len(specs), 1) for name, value in totals.items()},
        evaluated=len(specs) - reused,
    )
