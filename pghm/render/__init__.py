"""Rendering avatars without a window: the library behind ``pghm render`` and the viewer's recorder.

An avatar file, a motion and a camera path become frames, drawn through the same GL path as
the viewer (``pghm.gl.SpriteRenderer`` on an EGL context, no display needed) or through the
CPU splatter (``pghm.splat.render``, the spec), and written as an MP4 (imageio-ffmpeg's
bundled ffmpeg, H.264), one PNG, or a PNG sequence in a directory.

One module per piece, each usable alone (the viewer uses the first three):

* :mod:`pghm.render.driver`: :class:`AvatarDriver`, avatar -> plain Gaussian arrays
  (:class:`GaussianArrays`) for an identity map, a pose and a camera centre, through
  :class:`~pghm.model.evaluator.CachedEvaluator` (only the branches whose inputs changed
  re-run), timing the model and skinning stages.
* :mod:`pghm.render.framing`: :func:`orbit_camera`, :func:`frame_points`: a camera on a
  sphere around a target, and the target and distance that frame a body.
* :mod:`pghm.render.sinks`: :func:`open_sink`, MP4 / PNG / PNG-sequence writers (PNG
  sequence when no encoder exists).
* :mod:`pghm.render.frames`: :class:`GLFrames`, :class:`CPUFrames`: Gaussian arrays +
  camera -> float RGB image; :func:`frame_renderer` picks one for a backend.
* :mod:`pghm.render.frame_cache`: :class:`FrameCache`, evaluated frames (:class:`PackedFrame`)
  kept under a byte budget, least recently used evicted; ``pghm render`` evaluates a repeated
  (motion frame, camera centre) once, the viewer keeps a clip's frames for playback.
* :mod:`pghm.render.job`: :func:`render_video` with a :class:`RenderJob`: the whole
  ``pghm render`` command.

Dependencies run one way: ``job`` uses the other five, ``frames`` and ``frame_cache`` use
``driver``'s :class:`GaussianArrays`, and ``driver``, ``framing`` and ``sinks`` use none of
the others.
The names below are re-exported here; patch a name in the module that looks it up (e.g.
``pghm.render.frames.GLFrames`` for :func:`frame_renderer`).
"""

from pghm.render.driver import AvatarDriver, GaussianArrays, GaussianSet, StageTimes
from pghm.render.frame_cache import FrameCache, PackedFrame
from pghm.render.frames import Backend, CPUFrames, GLFrames, frame_renderer
from pghm.render.framing import BODY_FILL, DEFAULT_FOV_Y, POLE_TOLERANCE, Framing, frame_points, orbit_camera
from pghm.render.job import (
    DEFAULT_FPS,
    DEFAULT_SIZE,
    MAX_RENDER_FRAMES,
    ORBIT_SECONDS,
    FrameSpec,
    RenderJob,
    RenderSummary,
    plan_frames,
    render_video,
)
from pghm.render.sinks import (
    MP4_QUALITY,
    PNG_PATTERN,
    FrameSink,
    Mp4Sink,
    PngFileSink,
    PngSequenceSink,
    encoder_available,
    open_sink,
    output_kind,
    to_uint8,
)

__all__ = [
    "BODY_FILL",
    "DEFAULT_FOV_Y",
    "DEFAULT_FPS",
    "DEFAULT_SIZE",
    "MAX_RENDER_FRAMES",
    "MP4_QUALITY",
    "ORBIT_SECONDS",
    "PNG_PATTERN",
    "POLE_TOLERANCE",
    "AvatarDriver",
    "Backend",
    "CPUFrames",
    "FrameCache",
    "FrameSink",
    "FrameSpec",
    "Framing",
    "GLFrames",
    "GaussianArrays",
    "GaussianSet",
    "Mp4Sink",
    "PngFileSink",
    "PackedFrame",
    "PngSequenceSink",
    "RenderJob",
    "RenderSummary",
    "StageTimes",
    "encoder_available",
    "frame_points",
    "frame_renderer",
    "open_sink",
    "orbit_camera",
    "output_kind",
    "plan_frames",
    "render_video",
    "to_uint8",
]
