"""The configuration of ``pghm synth``: one dataclass, a few presets, JSON loading.

``pghm synth --config NAME_OR_FILE``: NAME is a preset (:data:`PRESETS`); FILE is a JSON
object of :class:`SynthConfig` fields, each optional (missing fields take the defaults
below). Everything that changes the output bytes is a field here and is recorded in
meta.json; how many processes render (``--workers``) is not, as it does not change them.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Literal, get_args

from pghm.errors import PghmError
from pghm.motion.motion import MAX_FPS, MAX_FRAMES, MIN_FPS
from pghm.synth.poses import MOTION_KINDS

Capture = Literal["multiview", "monocular"]
MAX_IDENTITIES = 10_000
"""Most subjects of one data set (the prior's bank holds one latent map per subject)."""
MAX_VIEWS = 360
"""Most cameras of a ring: one a degree."""
MAX_DISTANCE_M = 1000.0
"""Farthest camera, metres: the body is then a few pixels tall in any image synth renders."""
MAX_NOISE_DEG = 180.0
"""Largest pose noise, degrees: beyond a half turn an axis-angle component means nothing more."""
MAX_TRANSLATION_NOISE_M = 10.0
"""Largest root translation noise, metres (five body heights)."""
MAX_LAPS = 100.0
"""Most turns around the walking circle during the training frames."""
MAX_ANGLE_DEG = 360.0
"""Largest |camera pan| of the monocular clip, degrees."""
ELEVATION_LIMIT_DEG = 80.0
"""Largest |camera elevation|, degrees: the ring looks at the body, not straight down on it."""


@dataclass(frozen=True)
class SynthConfig:
    """What ``pghm synth`` generates. Defaults: the prior's training set on this CPU."""

    capture: Capture = "multiview"
    """"multiview": a ring of cameras around a subject moving in place (the prior's
    training data); "monocular": one slowly moving camera filming a subject walking in a
    circle, plus held-out novel poses and novel views (personalisation)."""

    identities: int = 16
    """Number of subjects (people) to generate."""

    views: int = 8
    """Multiview: cameras in the ring around each subject (8 to 16 in real rigs)."""

    frames: int = 30
    """Multiview: time steps per subject (test frames included). Monocular: walk frames
    used for training."""

    test_frames: int = 4
    """Multiview: the last time steps of each subject (all views) held out as novel
    poses. Monocular: held-out frames from the same camera, half continuing the walk and
    half a different motion (arm raises, squat or dance)."""

    novel_views: int = 3
    """Monocular: extra static cameras at other angles whose images are test-only."""

    novel_view_stride: int = 10
    """Monocular: the novel-view cameras render every this-many-th frame."""

    width: int = 256
    """Image width W, pixels."""

    height: int = 256
    """Image height H, pixels."""

    texture_size: int = 512
    """L: resolution of the painted UV textures (a power of two, 32 to 1024)."""

    fps: float = 30.0
    """Frames per second of the motions."""

    frame_stride: int = 3
    """Multiview: keep every this-many-th frame of the motion clip (more pose change
    between the kept frames)."""

    motions: tuple[str, ...] = MOTION_KINDS
    """Multiview: motion kinds; subject i performs motions[i mod len(motions)], so every
    kind appears once there are as many subjects."""

    camera_distance: tuple[float, float] = (2.5, 3.5)
    """Multiview: range of camera distances from the subject, metres."""

    camera_elevation_deg: tuple[float, float] = (-10.0, 35.0)
    """Multiview: range of camera heights as angles above the body's centre, degrees."""

    fill: float = 0.85
    """Multiview: fraction of the image height spanned from the soles to hands raised
    overhead (the body's height plus half a metre)."""

    mono_distance: float = 4.5
    """Monocular: camera distance from the centre of the walking circle, metres."""

    mono_elevation_deg: float = 8.0
    """Monocular: camera elevation above the body's centre, degrees."""

    mono_drift_deg: float = 15.0
    """Monocular: how far the camera pans around the scene over the clip, degrees."""

    walk_laps: float = 1.0
    """Monocular: turns around the circle during the training frames (1: every side seen once)."""

    mono_motion: str = "walk"
    """Monocular: what the training frames show: "walk" (around the circle) or another of
    :data:`~pghm.synth.poses.MOTION_KINDS` performed on the spot at the circle's centre
    (capture-bench's check that the body fit's pose prior does not hurt other motions)."""

    pose_noise_deg: float = 2.0
    """Standard deviation of the estimator noise per axis-angle component of every
    canonical joint's rotation, degrees. The images use the exact poses."""

    translation_noise_m: float = 0.01
    """Standard deviation of the estimator noise of the root translation per axis, metres."""

    msaa_samples: int = 4
    """Anti-aliasing samples per pixel (also sets the mask threshold's granularity)."""

    png_compression: int = 1
    """zlib level of the PNGs (0-9): 1 encodes ~5x faster than 6 for ~15 % larger files."""

    wrinkles: bool = True
    """Pose-dependent folds at elbows, knees, hips and shoulders."""

    cloth_geometry: bool = True
    """Cloth offsets of the mesh (loose sleeves, flares, skirts, hoods, hair volume)."""

    procedural_motions: bool = True
    """Use :mod:`pghm.motion.procedural` clips where that module offers the kind, else the
    built-in ones of :mod:`pghm.synth.poses`."""

    def validate(self) -> SynthConfig:
        """Raise :class:`PghmError` naming the first invalid field and its value; return self.

        Every number must be finite and within the range that makes physical sense (a camera
        ring of 1 to 360 views, distances up to 1 km, frame rates of motion files, ...).
        """
        for field in fields(self):
            value = getattr(self, field.name)
            numbers = value if isinstance(value, tuple) else (value,)
            if any(isinstance(v, float) and not math.isfinite(v) for v in numbers):
                raise PghmError(f"synth config: '{field.name}' must be finite, got {value}")
        for name in ("camera_distance", "camera_elevation_deg"):
            value = getattr(self, name)
            if len(value) != 2 or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
                raise PghmError(f"synth config: '{name}' must be two numbers [low, high], got {list(value)}")
        for ok, message in self._checks():
            if not ok:
                raise PghmError(f"synth config: {message}")
        return self

    def _checks(self) -> list[tuple[bool, str]]:
        """(holds, message naming the field, its range and its value) for every field with a range."""
        near, far = self.camera_distance
        low, high = self.camera_elevation_deg
        return [
            (self.capture in get_args(Capture), f"capture must be one of {', '.join(get_args(Capture))}"),
            (
                1 <= self.identities <= MAX_IDENTITIES,
                f"identities must be 1 to {MAX_IDENTITIES}, got {self.identities}",
            ),
            (1 <= self.views <= MAX_VIEWS, f"views must be 1 to {MAX_VIEWS}, got {self.views}"),
            (1 <= self.frames <= MAX_FRAMES, f"frames must be 1 to {MAX_FRAMES}, got {self.frames}"),
            (self.test_frames >= 0, f"test_frames must be >= 0, got {self.test_frames}"),
            (self.capture == "monocular" or self.test_frames < self.frames, "test_frames must be < frames"),
            (
                0 <= self.novel_views <= MAX_VIEWS and 1 <= self.novel_view_stride <= MAX_FRAMES,
                f"novel_views must be 0 to {MAX_VIEWS} and novel_view_stride 1 to {MAX_FRAMES}",
            ),
            (
                16 <= self.width <= 4096 and 16 <= self.height <= 4096,
                f"width and height must be 16 to 4096 pixels, got {self.width} x {self.height}",
            ),
            (self.texture_size in (32, 64, 128, 256, 512, 1024), "texture_size must be a power of two from 32 to 1024"),
            (MIN_FPS <= self.fps <= MAX_FPS, f"fps must be {MIN_FPS:g} to {MAX_FPS:g}, got {self.fps:g}"),
            (1 <= self.frame_stride <= MAX_FRAMES, f"frame_stride must be 1 to {MAX_FRAMES}, got {self.frame_stride}"),
            (
                len(self.motions) > 0 and all(m in MOTION_KINDS for m in self.motions),
                f"motions must be among {', '.join(MOTION_KINDS)}",
            ),
            (
                0 < near <= far <= MAX_DISTANCE_M,
                f"camera_distance must be [near, far] with 0 < near <= far <= {MAX_DISTANCE_M:g} m, "
                f"got [{near}, {far}]",
            ),
            (
                -ELEVATION_LIMIT_DEG <= low <= high <= ELEVATION_LIMIT_DEG,
                f"camera_elevation_deg must be [low, high] within -{ELEVATION_LIMIT_DEG:g}..{ELEVATION_LIMIT_DEG:g}, "
                f"got [{low}, {high}]",
            ),
            (0 < self.fill <= 1, f"fill must be in (0, 1], got {self.fill}"),
            (
                1.5 < self.mono_distance <= MAX_DISTANCE_M,
                f"mono_distance must be in (1.5, {MAX_DISTANCE_M:g}] m, got {self.mono_distance}",
            ),
            (
                abs(self.mono_elevation_deg) <= ELEVATION_LIMIT_DEG,
                f"mono_elevation_deg must be within -{ELEVATION_LIMIT_DEG:g}..{ELEVATION_LIMIT_DEG:g}, "
                f"got {self.mono_elevation_deg}",
            ),
            (
                abs(self.mono_drift_deg) <= MAX_ANGLE_DEG,
                f"mono_drift_deg must be within -{MAX_ANGLE_DEG:g}..{MAX_ANGLE_DEG:g}, got {self.mono_drift_deg}",
            ),
            (0 < self.walk_laps <= MAX_LAPS, f"walk_laps must be in (0, {MAX_LAPS:g}], got {self.walk_laps}"),
            (self.mono_motion in MOTION_KINDS, f"mono_motion must be one of {', '.join(MOTION_KINDS)}"),
            (
                0 <= self.pose_noise_deg <= MAX_NOISE_DEG,
                f"pose_noise_deg must be 0 to {MAX_NOISE_DEG:g}, got {self.pose_noise_deg}",
            ),
            (
                0 <= self.translation_noise_m <= MAX_TRANSLATION_NOISE_M,
                f"translation_noise_m must be 0 to {MAX_TRANSLATION_NOISE_M:g} m, got {self.translation_noise_m}",
            ),
            (1 <= self.msaa_samples <= 16, f"msaa_samples must be 1 to 16, got {self.msaa_samples}"),
            (0 <= self.png_compression <= 9, f"png_compression must be 0 to 9, got {self.png_compression}"),
        ]

    def to_json(self) -> dict:
        return asdict(self)


PRESETS: dict[str, SynthConfig] = {
    "tiny": SynthConfig(identities=2, views=2, frames=3, test_frames=1, width=64, height=64, texture_size=128),
    "prior": SynthConfig(),
    "mono": SynthConfig(
        capture="monocular",
        identities=1,
        frames=100,
        test_frames=30,
        novel_views=3,
        novel_view_stride=10,
        width=512,
        height=384,
        texture_size=1024,
        fps=20.0,
    ),
}
"""tiny: a smoke test (2 subjects x 2 views x 3 frames at 64 px). prior: 16 subjects x 8
views x 30 frames at 256 px (~2 minutes here). mono: one subject filmed walking, 100
training frames at 512 x 384 (landscape, as phone videos), 30 novel-pose frames, 3
novel-view cameras."""


def _coerce(name: str, value: object, default: object) -> object:
    """A JSON value as the field's type (lists become tuples); raises PghmError on a mismatch."""
    if isinstance(default, tuple):
        if not isinstance(value, list):
            raise PghmError(f"synth config: '{name}' must be a list")
        return tuple(value)
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise PghmError(f"synth config: '{name}' must be true or false")
        return value
    if isinstance(default, (int, float)) and not isinstance(default, bool):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise PghmError(f"synth config: '{name}' must be a number")
        if isinstance(default, int) and not float(value).is_integer():
            raise PghmError(f"synth config: '{name}' must be a whole number")
        return type(default)(value)
    if not isinstance(value, str):
        raise PghmError(f"synth config: '{name}' must be a string")
    return value


def load_config(name_or_path: str) -> SynthConfig:
    """A preset by name, or a JSON file of fields over the defaults; validated."""
    if name_or_path in PRESETS:
        return PRESETS[name_or_path].validate()
    path = Path(name_or_path)
    if not path.is_file():
        raise PghmError(f"synth config '{name_or_path}' is neither a preset ({', '.join(PRESETS)}) nor a JSON file")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise PghmError(f"synth config {path}: unreadable JSON ({error})") from None
    if not isinstance(data, dict):
        raise PghmError(f"synth config {path}: expected a JSON object of SynthConfig fields")
    defaults = SynthConfig()
    known = {f.name for f in fields(SynthConfig)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise PghmError(f"synth config {path}: unknown field(s) {', '.join(unknown)}")
    try:
        values = {name: _coerce(name, value, getattr(defaults, name)) for name, value in data.items()}
        return replace(defaults, **values).validate()
    except PghmError as error:
        raise PghmError(str(error).replace("synth config:", f"synth config {path}:", 1)) from None
