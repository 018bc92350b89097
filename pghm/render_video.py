"""Rendering avatars without a window: the library behind ``pghm render`` and the viewer's recorder.

An avatar file, a motion and a camera path become frames, drawn through the same GL path as
the viewer (``pghm.gl.SpriteRenderer`` on an EGL context, no display needed) or through the
CPU splatter (``pghm.splat.render``, the spec), and written as an MP4 (imageio-ffmpeg's
bundled ffmpeg, H.264), one PNG, or a PNG sequence in a directory.

Pieces, each usable alone (the viewer uses the first four):

* :class:`AvatarDriver`: avatar -> plain Gaussian arrays for an identity map, a pose and a
  camera centre, through :class:`~pghm.model.evaluator.CachedEvaluator` (only the branches
  whose inputs changed re-run), timing the model and skinning stages.
* :func:`orbit_camera`, :func:`frame_points`: a camera on a sphere around a target, and the
  target and distance that frame a body.
* :func:`open_sink`: MP4 / PNG / PNG-sequence writers (PNG sequence when no encoder exists).
* :class:`GLFrames`, :class:`CPUFrames`: Gaussian arrays + camera -> float RGB image.
* :func:`render_video` with a :class:`RenderJob`: the whole ``pghm render`` command.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, Protocol

import numpy as np
import torch
from torch import Tensor

from pghm.errors import DisplayError, PghmError
from pghm.splat import Camera

DEFAULT_FOV_Y = 40.0
"""Vertical field of view, degrees, of the default cameras."""
BODY_FILL = 0.85
"""The default framing makes the body's bounding box fill this fraction of the image height (or width)."""
DEFAULT_SIZE = (640, 480)
"""(W, H) of ``pghm render`` images."""
DEFAULT_FPS = 30.0
ORBIT_SECONDS = 4.0
"""An orbit without a motion lasts this long (one full turn)."""
PNG_PATTERN = "frame_{:05d}.png"
"""File names of a PNG sequence."""
POLE_TOLERANCE = 1e-6
"""|cos(pitch)| below which :func:`orbit_camera` treats the camera as straight above or below."""
MP4_QUALITY = 8
"""imageio-ffmpeg quality (0-10, 10 best): H.264 at near-visually-lossless rates."""

Backend = Literal["auto", "gl", "cpu"]
GaussianSet = Literal["dynamic", "static"]


# ----------------------------------------------------------------------------- cameras


@dataclass(frozen=True)
class Framing:
    """Where a camera looks and from how far to frame a set of points.

    Attributes:
        target: (3,) the bounding box centre, world metres.
        distance: camera distance from the target, metres.
    """

    target: tuple[float, float, float]
    distance: float


def frame_points(points: np.ndarray, fov_y_degrees: float = DEFAULT_FOV_Y, aspect: float = 1.0) -> Framing:
    """The framing of points (N, 3) seen from the front (+z), filling BODY_FILL of the image.

    The box's half-height h and half-width w must fit tan(fov_y / 2) d BODY_FILL and that
    times ``aspect`` (W / H) at distance d from the box's front face.
    """
    low, high = points.min(axis=0), points.max(axis=0)
    centre = (low + high) / 2
    half = (high - low) / 2
    tangent = math.tan(math.radians(fov_y_degrees) / 2) * BODY_FILL
    distance = max(half[1] / tangent, half[0] / (tangent * aspect)) + half[2]
    return Framing(target=tuple(float(c) for c in centre), distance=float(distance))


def orbit_camera(
    target: tuple[float, float, float] | np.ndarray,
    yaw_degrees: float,
    pitch_degrees: float,
    distance: float,
    fov_y_degrees: float,
    width: int,
    height: int,
) -> Camera:
    """A camera ``distance`` from ``target`` looking at it, world y up on screen.

    Yaw 0 puts the camera on the +z side (the body's front, pghm.body.pose), yaw 90 on +x
    (the body's left); pitch > 0 lifts it above the target. At |pitch| = 90 the up vector
    turns to -z / +z so that the view stays defined (top and bottom views).
    """
    yaw, pitch = math.radians(yaw_degrees), math.radians(pitch_degrees)
    direction = np.array([math.cos(pitch) * math.sin(yaw), math.sin(pitch), math.cos(pitch) * math.cos(yaw)])
    eye = np.asarray(target, dtype=np.float64) + distance * direction
    up = (0.0, 1.0, 0.0)
    if abs(math.cos(pitch)) < POLE_TOLERANCE:
        # Straight above (below) the target world y is the view axis; the limit of its
        # projection as the pitch approaches the pole is away from (towards) where the
        # camera came from horizontally.
        sign = math.copysign(1.0, pitch)
        up = (-sign * math.sin(yaw), 0.0, -sign * math.cos(yaw))
    return Camera.look_at(eye, target, up=up, fov_y_degrees=fov_y_degrees, width=width, height=height)


# ---------------------------------------------------------------------- avatar -> arrays


@dataclass(frozen=True)
class GaussianArrays:
    """One frame's Gaussians as plain float32 numpy arrays (what the renderers consume).

    Attributes:
        means: (N, 3) world positions.
        scales: (N,) isotropic standard deviations, metres.
        colors: (N, 3) RGB in [0, 1].
        opacities: (N,) in (0, 1].
        normals: (N, 3) posed unit surface normals at the Gaussians' texels.
    """

    means: np.ndarray
    scales: np.ndarray
    colors: np.ndarray
    opacities: np.ndarray
    normals: np.ndarray

    @property
    def count(self) -> int:
        return self.means.shape[0]


@dataclass
class StageTimes:
    """Milliseconds of the last :meth:`AvatarDriver.evaluate`.

    Attributes:
        model_ms: the network branches that re-ran and assembling the Gaussians (skinning excluded).
        skinning_ms: forward kinematics and LBS of the texel surface (0 when the pose was unchanged).
    """

    model_ms: float = 0.0
    skinning_ms: float = 0.0


class _TimedModel:
    """The model as :class:`CachedEvaluator` sees it, timing ``skin`` and keeping its output.

    Every other attribute is the wrapped :class:`~pghm.model.pghm.PGHM`'s. The evaluator
    calls ``skin`` exactly when the pose changed, so ``skinned`` is the current pose's.
    """

    def __init__(self, model) -> None:
        self._model = model
        self.skinning_ms = 0.0
        self.skinned = None

    def skin(self, geometry, pose):
        start = time.perf_counter()
        self.skinned = self._model.skin(geometry, pose)
        self.skinning_ms += (time.perf_counter() - start) * 1e3
        return self.skinned

    def __getattr__(self, name: str):
        return getattr(self._model, name)


class AvatarDriver:
    """An avatar or prior driven frame by frame: identity map, pose, camera -> :class:`GaussianArrays`.

    Set-up builds the body, the subject geometry of identity ``index`` (its body shape) and a
    :class:`~pghm.model.evaluator.CachedEvaluator`; :meth:`evaluate` re-runs only what
    changed and returns the same :class:`GaussianArrays` object when nothing did.

    Args:
        avatar: a loaded :class:`~pghm.io.avatar.Avatar`.
        index: identity of a prior whose body shape to use (ignored for an avatar).
        body_model_path: the model file of bodies that are not embedded (SMPL-X).
    """

    def __init__(self, avatar, index: int = 0, body_model_path: str | None = None) -> None:
        from pghm.body import load_body
        from pghm.io.avatar import avatar_geometry
        from pghm.model.evaluator import CachedEvaluator

        self.avatar = avatar
        self.index = index
        self.body = load_body(avatar.body_name, body_model_path)
        self.geometry = avatar_geometry(avatar, index, body_model_path)
        self.rest = self.body.rest(self.geometry.shape)
        self._timed = _TimedModel(avatar.model)
        self.evaluator = CachedEvaluator(self._timed, self.geometry)
        self.times = StageTimes()
        self._key: tuple | None = None  # (evaluator output, which set) the arrays were made from
        self._arrays: GaussianArrays | None = None

    @property
    def model(self):
        """The avatar's network (:class:`~pghm.model.pghm.PGHM`), e.g. for ``run_counts``."""
        return self.avatar.model

    def rest_pose(self):
        """The canonical rest pose (1, J, 3), (1, 3) of the body."""
        from pghm.body import BodyPose

        return BodyPose.rest(self.body.num_bones)

    @torch.no_grad()
    def evaluate(
        self,
        identity_map: Tensor,
        pose,
        camera_centre: Tensor | np.ndarray,
        gaussians: GaussianSet = "dynamic",
        view_dependent: bool = True,
    ) -> GaussianArrays:
        """The Gaussians of ``identity_map`` (1, C, L, L) in ``pose`` (1 pose) seen from ``camera_centre`` (3,).

        ``gaussians`` picks the paper's static set V_sta (image I_s) or dynamic set V_dyn
        (I_d); ``view_dependent=False`` drops the view-dependent colour V_c^o (D_view is
        then not run).
        """
        if gaussians not in ("dynamic", "static"):
            raise PghmError(f"gaussians must be 'dynamic' or 'static', got {gaussians!r}")
        start = time.perf_counter()
        self._timed.skinning_ms = 0.0
        centre = torch.as_tensor(np.asarray(camera_centre, dtype=np.float32))
        dynamic = gaussians == "dynamic"
        output = self.evaluator.evaluate(
            identity_map, pose, centre, dynamic=dynamic, view_dependent=dynamic and view_dependent
        )
        # The same output object means nothing re-ran; the single-head model returns it for
        # either set, so the set is part of the key.
        if self._key is None or self._key[0] is not output or self._key[1] != dynamic:
            chosen = output.dynamic if dynamic else output.static
            self._arrays = GaussianArrays(
                means=chosen.means[0].numpy().astype(np.float32),
                scales=chosen.scales[0].numpy().astype(np.float32),
                colors=chosen.colors[0].numpy().astype(np.float32),
                opacities=chosen.opacities[0].numpy().astype(np.float32),
                normals=self._timed.skinned.normals[0].numpy().astype(np.float32),
            )
            self._key = (output, dynamic)
        total = (time.perf_counter() - start) * 1e3
        self.times = StageTimes(model_ms=total - self._timed.skinning_ms, skinning_ms=self._timed.skinning_ms)
        return self._arrays

    def root_position(self, pose) -> np.ndarray:
        """(3,) the posed root joint of a 1-pose BodyPose (for cameras that follow the body)."""
        transforms = self.geometry.transforms(pose)[0, 0]
        return (transforms[:3, :3] @ self.geometry.joints[0] + transforms[:3, 3]).numpy().astype(np.float64)


# ------------------------------------------------------------------------- frame sinks


class FrameSink(Protocol):
    """Where rendered frames go: ``write`` (H, W, 3) uint8 images, then ``close``."""

    path: Path
    frames: int

    def write(self, image: np.ndarray) -> None: ...

    def close(self) -> None: ...


def to_uint8(rgb: np.ndarray) -> np.ndarray:
    """(H, W, 3) float in [0, 1] -> uint8, rounded to nearest."""
    return np.clip(rgb * 255.0 + 0.5, 0, 255).astype(np.uint8)


def encoder_available() -> bool:
    """Whether imageio-ffmpeg and its ffmpeg binary are present (MP4 output)."""
    try:
        import imageio_ffmpeg

        return Path(imageio_ffmpeg.get_ffmpeg_exe()).exists()
    except (ImportError, RuntimeError):
        return False


class Mp4Sink:
    """H.264 MP4 through imageio-ffmpeg; the size is fixed by the first frame (even W and H)."""

    def __init__(self, path: Path, fps: float) -> None:
        self.path, self.fps, self.frames = path, fps, 0
        self._writer = None

    def write(self, image: np.ndarray) -> None:
        import imageio_ffmpeg

        height, width = image.shape[:2]
        if self._writer is None:
            if width % 2 or height % 2:
                raise PghmError(f"an MP4 (H.264, yuv420p) needs an even width and height, got {width} x {height}")
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._size = (width, height)
            self._writer = imageio_ffmpeg.write_frames(
                str(self.path), self._size, fps=self.fps, codec="libx264", quality=MP4_QUALITY,
                macro_block_size=1, pix_fmt_out="yuv420p", ffmpeg_log_level="error",
            )
            self._writer.send(None)  # start the generator
        if (width, height) != self._size:
            raise PghmError(f"frame size changed from {self._size} to {(width, height)} while recording")
        self._writer.send(np.ascontiguousarray(image, dtype=np.uint8))
        self.frames += 1

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None


class PngSequenceSink:
    """frame_00000.png, frame_00001.png, ... in a directory."""

    def __init__(self, directory: Path) -> None:
        self.path, self.frames = directory, 0
        directory.mkdir(parents=True, exist_ok=True)

    def write(self, image: np.ndarray) -> None:
        from PIL import Image

        Image.fromarray(image).save(self.path / PNG_PATTERN.format(self.frames))
        self.frames += 1

    def close(self) -> None:
        """Nothing buffered: each frame is a file."""


class PngFileSink:
    """One PNG file: exactly one frame."""

    def __init__(self, path: Path) -> None:
        self.path, self.frames = path, 0

    def write(self, image: np.ndarray) -> None:
        from PIL import Image

        if self.frames:
            raise PghmError(f"{self.path}: a .png holds one frame; give a directory for a sequence")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        Image.fromarray(image).save(self.path)
        self.frames = 1

    def close(self) -> None:
        """Nothing buffered."""


def output_kind(path: str | Path) -> Literal["mp4", "png", "dir"]:
    """What ``path`` asks for: ``.mp4``, ``.png``, or a directory (anything else)."""
    suffix = Path(path).suffix.lower()
    if str(path).endswith(("/", "\\")) or Path(path).is_dir() or not suffix:
        return "dir"
    if suffix in (".mp4", ".png"):
        return suffix[1:]
    raise PghmError(f"{path}: output must be a .mp4, a .png or a directory, not {suffix}")


def open_sink(path: str | Path, fps: float, on_fallback: Callable[[str], None] | None = None) -> FrameSink:
    """The writer for ``path`` (see :func:`output_kind`).

    An ``.mp4`` without an encoder becomes a PNG sequence in ``<stem>_frames/`` beside it;
    ``on_fallback`` is told so in one line.
    """
    path = Path(path)
    kind = output_kind(path)
    if kind == "png":
        return PngFileSink(path)
    if kind == "dir":
        return PngSequenceSink(path)
    if encoder_available():
        return Mp4Sink(path, fps)
    directory = path.with_name(f"{path.stem}_frames")
    if on_fallback is not None:
        on_fallback(f"no MP4 encoder (imageio-ffmpeg) found: writing a PNG sequence to {directory}/ instead")
    return PngSequenceSink(directory)


# ------------------------------------------------------------------------ frame renderers


class GLFrames:
    """Gaussian arrays -> float RGB through the GL sprite renderer on a headless EGL context.

    Set-up creates the context and renderer; :meth:`release` frees both.
    """

    def __init__(self) -> None:
        from pghm.gl import SpriteRenderer, driver_info, headless_context

        self.ctx = headless_context()
        self.renderer = SpriteRenderer(self.ctx)
        self.driver = str(driver_info(self.ctx))
        self._arrays: GaussianArrays | None = None

    def render(self, arrays: GaussianArrays, camera: Camera, background: tuple[float, float, float]) -> np.ndarray:
        """(H, W, 3) float32 image, row 0 at the top."""
        if arrays is not self._arrays:
            self.renderer.set_gaussians(arrays.means, arrays.scales, arrays.colors, arrays.opacities)
            self._arrays = arrays
        return self.renderer.render(camera, background).rgb

    def release(self) -> None:
        self.renderer.release()
        self.ctx.release()


class CPUFrames:
    """Gaussian arrays -> float RGB through the CPU splatter ``pghm.splat.render`` (the spec)."""

    driver = "CPU splatter (pghm.splat)"

    def render(self, arrays: GaussianArrays, camera: Camera, background: tuple[float, float, float]) -> np.ndarray:
        """(H, W, 3) float32 image, row 0 at the top."""
        from pghm.splat import render

        out = render(
            torch.from_numpy(arrays.means),
            torch.from_numpy(arrays.scales),
            torch.from_numpy(arrays.colors),
            torch.from_numpy(arrays.opacities),
            camera,
            background=background,
        )
        return out.rgb.numpy()

    def release(self) -> None:
        """Nothing to free."""


@contextmanager
def frame_renderer(backend: Backend, log: Callable[[str], None] | None = None) -> Iterator[GLFrames | CPUFrames]:
    """A :class:`GLFrames` or :class:`CPUFrames`, released on exit.

    "auto" is GL when a headless EGL context can be made, else the CPU splatter (``log``
    is told why in one line): same image either way, up to the 2e-3 GL/CPU tolerance.
    """
    if backend not in ("auto", "gl", "cpu"):
        raise PghmError(f"backend must be 'auto', 'gl' or 'cpu', got {backend!r}")
    if backend == "auto":
        try:
            frames = GLFrames()
        except DisplayError as error:
            if log is not None:
                log(f"no headless OpenGL ({str(error).splitlines()[0]}); rendering with the CPU splatter")
            frames = CPUFrames()
    else:
        frames = GLFrames() if backend == "gl" else CPUFrames()
    try:
        yield frames
    finally:
        frames.release()


# ------------------------------------------------------------------------------ the job


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


def plan_frames(job: RenderJob, motion) -> list[FrameSpec]:
    """The frames of ``job`` for ``motion`` (None: rest pose).

    Frame k shows time start + k / fps of the motion (looping) and the camera at
    yaw + 360 k / frames when orbiting.
    """
    if job.fps <= 0 or not math.isfinite(job.fps):
        raise PghmError(f"--fps must be positive, got {job.fps}")
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
    from pghm.data.open_motion import open_motion
    from pghm.io.avatar import load_avatar

    width, height = job.size
    if width < 1 or height < 1:
        raise PghmError(f"--size must be positive, got {width}x{height}")
    output_kind(job.out)  # reject a bad output name before the slow work
    avatar = load_avatar(job.avatar)
    if avatar.kind == "prior" and not 0 <= job.identity < avatar.model.num_identities:
        raise PghmError(f"--identity must be in [0, {avatar.model.num_identities}), got {job.identity}")
    driver = AvatarDriver(avatar, job.identity, job.body_model_path)
    motion = open_motion(job.motion, driver.body, driver.geometry.shape) if job.motion else None
    specs = plan_frames(job, motion)
    identity_map = avatar.identity_map(job.identity)
    rest_points = driver.geometry.surface.positions.numpy()
    framing = frame_points(rest_points, DEFAULT_FOV_Y, width / height)
    rest_root = driver.root_position(driver.rest_pose())

    started = time.perf_counter()
    totals = {"model_ms": 0.0, "skinning_ms": 0.0, "render_ms": 0.0, "write_ms": 0.0}
    sink = open_sink(job.out, job.fps, on_fallback=log)
    try:
        with frame_renderer(job.backend, log) as renderer:
            for spec in specs:
                pose = motion.pose(spec.motion_frame) if motion is not None else driver.rest_pose()
                target = np.asarray(framing.target, dtype=np.float64)
                if job.follow:
                    shift = driver.root_position(pose) - rest_root
                    target = target + np.array([shift[0], 0.0, shift[2]])
                camera = orbit_camera(target, spec.yaw, job.pitch, framing.distance, DEFAULT_FOV_Y, width, height)
                arrays = driver.evaluate(identity_map, pose, camera.centre, job.gaussians, job.view_dependent)
                totals["model_ms"] += driver.times.model_ms
                totals["skinning_ms"] += driver.times.skinning_ms
                start = time.perf_counter()
                rgb = renderer.render(arrays, camera, job.background)
                totals["render_ms"] += (time.perf_counter() - start) * 1e3
                start = time.perf_counter()
                sink.write(to_uint8(rgb))
                totals["write_ms"] += (time.perf_counter() - start) * 1e3
            driver_name = renderer.driver
    finally:
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
    )
