"""The configuration of ``pghm capture``: one dataclass, every option of the command.

The body fit's own settings (:class:`BodyFitConfig`) nest inside as ``body``; ``None``
takes its defaults. The body fit (:mod:`pghm.capture.bodyfit`) is imported only when the
pipeline reaches it, so that reading the video and finding the person (and every bad-input error
they raise) do not wait for torch and the body model to load.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from pghm.errors import PghmError
from pghm.io.avatar import recorded_path
from pghm.subject.format import FOV_RANGE_DEG, focal_range

MIN_FRAMES = 8
"""Fewest frames with the person found that make a subject: with the default
``test_every`` of 8, seven training frames and one test frame."""

MIN_SIZE = 16
"""Smallest --size (pixels): below it MediaPipe finds no body."""
MAX_FOCAL_PX = 1e6
"""Largest --focal, pixels (a 1,000 mm lens on a 1 um-pixel sensor)."""
DEFAULT_SIZE = 512
"""Longest side of the subject images, pixels (what ``pghm fit`` trains at on 2 cores)."""

DEFAULT_TEST_EVERY = 8
"""Every this-many-th kept frame goes to the test split."""

DEFAULT_TARGET_FRAMES = 100
"""Frames a longer video is thinned to when ``--every`` is not given: one frame in floor(F / 100)
is read, keeping 100 to 199. ``pghm fit`` takes a fixed number of steps, so more frames add time,
not detail (docs/lab/defaults.md, "Capture: frames kept from a long video")."""

HEIGHT_RANGE_M = (1.12, 2.13)
"""Heights (metres) Anny's average body reaches with its height phenotype in [0, 1]: the range of
``--height`` (a test checks them against the body model)."""

DEFAULT_CROP_MARGIN = 0.1
"""Margin added on each side of the region the person occupies, as a fraction of that
region's longest side (room for a hand the segmentation clipped)."""


@dataclass(frozen=True)
class BodyFitConfig:
    """Options of the body fit (:func:`pghm.capture.bodyfit.fit_body`)."""

    body: str = "anny"
    """Body model backend (only Anny's landmark correspondence is measured)."""

    default_fov_deg: float = 60.0
    """Field of view over the image's longer side assumed when the intrinsics are unknown
    (a phone's main camera is 60-70 degrees); the fit refines it."""

    fit_focal: bool = True
    """Refine the focal length when the intrinsics are unknown."""

    steps: tuple[int, int, int] = (60, 200, 300)
    """Adam steps of the three stages (camera/root, pose, shape + silhouette). The silhouette
    stage sees ``silhouette_frames`` frames a step, so each frame of a 100-frame video is
    aligned to its mask about 100 times."""

    learning_rate: float = 0.03
    """Adam step for rotations (radians) and the shape logits; translation uses a tenth."""

    min_confidence: float = 0.3
    """Landmarks below this confidence are ignored."""

    robust_sigma: float = 0.06
    """Geman-McClure scale of the 2D terms, as a fraction of the person's height."""

    weight_2d: float = 1.0
    weight_3d: float = 0.5
    huber_3d_m: float = 0.05
    weight_outside: float = 30.0
    weight_coverage: float = 10.0
    weight_smooth: float = 50.0
    weight_pose: float = 0.002
    weight_motion_prior: float = 0.2
    motion_prior_scale: float = 20.0
    """The pose prior learned from motion capture (:mod:`pghm.capture.pose_prior`): its weight, and
    the squared Mahalanobis distance c at which its robust penalty saturates (0 weight: off). The
    saturation keeps motions the clips never show (arm raises) from being pulled to a walk."""
    weight_limits: float = 1.0
    weight_focal: float = 0.1
    weight_shape: float = 1.0
    """Weights of the objective's terms (module docstring of :mod:`pghm.capture.bodyfit`):
    weight_focal pulls log f to the default, weight_shape the phenotypes to Anny's average (the
    landmarks over clothes hardly tell the shape). weight_3d is low because MediaPipe's world
    landmarks are far less accurate than its 2D ones; the mask terms are strong so that the
    body's outline, not the landmarks' bias, places it; weight_smooth leaves the gait's fast leg
    swings alone (docs/lab/defaults.md, "Body fit: the objective's weights")."""

    silhouette_vertices: int = 1000
    """Mesh vertices (an even subsample) tested against the mask."""

    coverage_samples: int = 128
    """Mask pixels per frame that the body should cover."""

    silhouette_frames: int = 32
    """Frames (drawn at random each step) on which the mask terms are evaluated: the shape
    they mostly inform is shared, and their cost stays independent of the video's length."""

    mask_size: int = 128
    """Longest side (pixels) at which the masks are compared."""

    repair_swaps: bool = True
    """Undo MediaPipe's left/right label swaps (the whole body mirrored, legs or arms traded)
    found over time (:mod:`pghm.capture.swaps`) before fitting."""

    seed: int = 0
    """Random subsampling of vertices and mask pixels."""

    height_m: float | None = None
    """The person's height in metres when known (``pghm capture --height``): the shape starts, and
    the shape prior pulls, at Anny's average body with its height phenotype set to it
    (:func:`pghm.capture.bodyfit.shape_of_height`), and the shape stage holds the rest body's
    height to it (the term ``weight_height ((h(s) - height_m) / HEIGHT_SCALE_M)^2``, h the
    crown-to-sole extent). One uncalibrated video does not tell a person's size."""
    weight_height: float = 1.0
    """Weight of the height term (untuned: at 1 the fitted height is the given one)."""

    def validate(self) -> BodyFitConfig:
        if self.body != "anny":
            raise PghmError(f"body fit: only the anny body has a measured landmark correspondence, got {self.body!r}")
        if not 10.0 <= self.default_fov_deg <= 150.0:
            raise PghmError(f"body fit: default_fov_deg must be 10 to 150 degrees, got {self.default_fov_deg}")
        if len(self.steps) != 3 or min(self.steps) < 0:
            raise PghmError(f"body fit: steps must be three non-negative counts, got {self.steps}")
        return self


@dataclass
class CaptureConfig:
    """What ``pghm capture`` does with a video. Defaults: a phone video, camera unknown."""

    every: int | None = None
    """Keep every this-many-th frame of the video (source frame numbers 0, N, 2N, ...); None: the
    stride :meth:`stride` chooses (1, or about ``target_frames`` frames of a longer video)."""

    max_frames: int | None = None
    """Stop after this many kept frames (None: the whole video)."""

    target_frames: int = DEFAULT_TARGET_FRAMES
    """See :data:`DEFAULT_TARGET_FRAMES`; 0: every frame of any video when ``every`` is None."""

    size: int = DEFAULT_SIZE
    """Longest side of the subject images after the crop, pixels. Frames are never
    enlarged: a crop smaller than this keeps its own size."""

    fov_deg: float | None = None
    """Field of view along the video frame's longest side, degrees, when known (phones'
    main cameras: about 65-70). None with ``focal_px`` None: the body fit estimates the
    focal length (falling back to its named default field of view if it cannot)."""

    focal_px: float | None = None
    """Focal length in pixels of the video's frames at their full resolution (upright),
    when known; exclusive with ``fov_deg``."""

    test_every: int = DEFAULT_TEST_EVERY
    """Every this-many-th kept frame (the 8th, 16th, ... with 8) is in the test split."""

    crop_margin: float = DEFAULT_CROP_MARGIN
    """See :data:`DEFAULT_CROP_MARGIN`."""

    min_frames: int = MIN_FRAMES
    """See :data:`MIN_FRAMES`."""

    mirror_pass: bool = True
    """Also run the landmark model on each frame mirrored left-right and fuse its landmarks,
    mirrored back, with the original's (flip test-time augmentation,
    :func:`pghm.capture.frontend.fuse_mirrored`; pass 2 only, one more MediaPipe call a frame)."""

    pose_prior: bool = True
    """Hold the body fit's poses to how people move, with the pose prior learned from motion
    capture (:mod:`pghm.capture.pose_prior`; its weight is ``body.weight_motion_prior``). Off, the
    fit keeps only its per-joint L2 prior and joint limits: for motions far from the clips it
    was learned from (walking, sitting), such as dancing."""

    height_m: float | None = None
    """The person's height in metres, when known (:attr:`BodyFitConfig.height_m`); None: the body
    fit's average adult (one uncalibrated video does not tell a person's size)."""

    polish: str | None = None
    """A prior file (``pghm train-prior``'s, e.g. assets/prior.pt): after the body fit, align the
    held-out (test) frames' poses to their images through an avatar personalised from it on all
    frames (:mod:`pghm.capture.polish`; about 7 minutes per 100 frames on 2 cores). None: off."""

    progress: bool = True
    """A tqdm bar per stage on stderr."""

    body: BodyFitConfig | None = None
    """The body fit's settings (None: its defaults)."""

    def validate(self) -> CaptureConfig:
        """Raise :class:`PghmError` naming the first option out of range; return self."""
        if self.every is not None and self.every < 1:
            raise PghmError(f"--every must be >= 1, got {self.every}")
        if self.target_frames < 0:
            raise PghmError(f"--target-frames must be >= 0, got {self.target_frames}")
        if self.max_frames is not None and self.max_frames < 1:
            raise PghmError(f"--max-frames must be >= 1, got {self.max_frames}")
        if self.size < MIN_SIZE:
            raise PghmError(f"--size must be >= {MIN_SIZE} pixels, got {self.size}")
        if self.fov_deg is not None and self.focal_px is not None:
            raise PghmError("give --fov or --focal, not both")
        if self.fov_deg is not None and not FOV_RANGE_DEG[0] <= self.fov_deg <= FOV_RANGE_DEG[1]:
            raise PghmError(f"--fov must be in {FOV_RANGE_DEG[0]:g}..{FOV_RANGE_DEG[1]:g} degrees, got {self.fov_deg}")
        if self.focal_px is not None and not (math.isfinite(self.focal_px) and 0 < self.focal_px <= MAX_FOCAL_PX):
            raise PghmError(f"--focal must be a number of pixels in (0, {MAX_FOCAL_PX:g}], got {self.focal_px}")
        if self.test_every < 2:
            raise PghmError(f"--test-every must be >= 2 (1 would leave no training frame), got {self.test_every}")
        if not 0.0 <= self.crop_margin <= 1.0:
            raise PghmError(f"crop_margin must be in [0, 1], got {self.crop_margin}")
        if self.min_frames < 2:
            raise PghmError(f"min_frames must be >= 2, got {self.min_frames}")
        if self.height_m is not None and not HEIGHT_RANGE_M[0] <= self.height_m <= HEIGHT_RANGE_M[1]:
            low, high = HEIGHT_RANGE_M
            raise PghmError(f"--height must be {low:g} to {high:g} m (the body model's range), got {self.height_m}")
        if self.polish is not None and not Path(self.polish).is_file():
            raise PghmError(f"--polish {self.polish}: no such prior file")
        return self

    def stride(self, frame_count: int | None) -> int:
        """The stride frames are read at, for a video of about ``frame_count`` frames (None: unknown).

        ``every`` when given; else floor(F / ``target_frames``), which keeps ``target_frames`` to
        twice that, spread evenly over the video; 1 when ``max_frames`` already bounds the frames
        read, when ``target_frames`` is 0, or when the length is unknown.
        """
        if self.every is not None:
            return self.every
        if self.max_frames is not None or not self.target_frames or not frame_count:
            return 1
        return max(1, frame_count // self.target_frames)

    def check_camera(self, width: int, height: int) -> None:
        """Raise :class:`PghmError` when ``focal_px`` gives W x H frames a field of view outside
        :data:`FOV_RANGE_DEG` (fov = 2 atan((L / 2) / f), L = max(W, H)): no lens has it, and the
        body fit would meet it as a zero or infinite focal length. Asked as soon as the size is known."""
        if self.focal_px is None:
            return
        longest = max(width, height)
        low, high = focal_range(longest)
        if not low <= self.focal_px <= high:
            fov = math.degrees(2 * math.atan(0.5 * longest / self.focal_px))
            raise PghmError(
                f"--focal {self.focal_px:g}: a field of view of {fov:.4g} degrees on these {width}x{height} frames; "
                f"a lens's {FOV_RANGE_DEG[0]:g} to {FOV_RANGE_DEG[1]:g} degrees are {low:.4g} to {high:.4g} pixels"
            )

    def check_crop_camera(self, region_width: int, region_height: int, width: int, height: int) -> None:
        """Raise :class:`PghmError` when the lens ``fov_deg`` or ``focal_px`` states for W x H frames
        would give the person's crop (region_width x region_height of them) a field of view below
        :data:`FOV_RANGE_DEG`'s, which the subject's checker refuses: a crop narrows the lens's view
        by the share of the frame it keeps, tan(fov' / 2) = tan(fov / 2) crop / frame (longest sides).
        Asked once the crop is known, before any image is written."""
        K = self.source_intrinsics(width, height)
        if K is None:
            return
        region_long = max(region_width, region_height)
        longest_focal = focal_range(region_long)[1]
        if K[0, 0] <= longest_focal:
            return
        crop_fov = math.degrees(2 * math.atan(0.5 * region_long / K[0, 0]))
        crop = f"the person's crop ({region_width}x{region_height} of the {width}x{height} frames)"
        if self.focal_px is not None:
            raise PghmError(
                f"--focal {self.focal_px:g}: {crop} would see {crop_fov:.3g} degrees, below the "
                f"{FOV_RANGE_DEG[0]:g} a camera may have; a focal length of at most {longest_focal:.4g} pixels fits"
            )
        least = math.degrees(2 * math.atan(0.5 * max(width, height) / longest_focal))
        raise PghmError(
            f"--fov {self.fov_deg:g}: {crop} would see {crop_fov:.3g} degrees, below the "
            f"{FOV_RANGE_DEG[0]:g} a camera may have; give --fov {math.ceil(least * 100) / 100:g} or more"
        )

    def source_intrinsics(self, width: int, height: int) -> np.ndarray | None:
        """(3, 3) K in pixels of the full upright video frame (W x H), or None when unknown.

        fx = fy = ``focal_px``, or (L / 2) / tan(fov / 2) with L = max(W, H); the principal
        point at the frame centre (W / 2, H / 2), pixel centres at half-integers.
        """
        if self.focal_px is not None:
            focal = self.focal_px
        elif self.fov_deg is not None:
            focal = 0.5 * max(width, height) / math.tan(math.radians(self.fov_deg) / 2)
        else:
            return None
        return np.array([[focal, 0.0, width / 2], [0.0, focal, height / 2], [0.0, 0.0, 1.0]])

    def to_json(self) -> dict:
        """The options, for meta.json (the body fit's settings as it gives them, or null)."""
        values = {key: value for key, value in asdict(self).items() if key not in ("body", "progress")}
        values["body"] = asdict(self.body) if self.body is not None else None
        values["polish"] = recorded_path(self.polish) if self.polish is not None else None
        return values
