"""The subject format's names, limits and shared pieces (:mod:`pghm.subject` describes the format):
the constants, the arrays of a subject, the metadata a capture states, and the value bounds
both the reader and the checker hold the arrays to."""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass

import numpy as np

from pghm.errors import listed
from pghm.motion.motion import MAX_ROTATION, MAX_TRANSLATION

SUBJECT_FORMAT = "pghm-subject"
DATASET_FORMAT = "pghm-dataset"
FORMAT_VERSION = 1

IMAGE_DIGITS = 6
CAMERA_KEYS = ("K", "world_to_camera", "height", "width")
POSE_KEYS = ("rotations", "translation", "shape", "body", "bone_names")

ZIP_TIME = (1980, 1, 1, 0, 0, 0)
"""Timestamp of every member of the .npz files we write, so equal arrays give equal bytes
(``numpy.savez`` stamps the current time)."""

ROTATION_TOLERANCE = 1e-3
"""How far R^T R of a world_to_camera may be from the identity (float32 storage)."""

FRAME_MARGIN = 0.5
"""The subject's centre may project up to this fraction of the image size outside it
(a body partly out of frame) before the checker reports it."""


def _first_line(error: BaseException) -> str:
    text = str(error).strip()
    return text.splitlines()[0] if text else type(error).__name__


def image_name(index: int) -> str:
    """File name of image ``index``: six zero-padded digits, ``000042.png``."""
    return f"{index:0{IMAGE_DIGITS}d}.png"


ALL_SPLIT = "all"
"""The name that selects every image of a subject (unless splits.json defines a split of that name):
``pghm capture --polish`` fits on all of a video's frames."""


@dataclass
class SubjectArrays:
    """Everything about a subject except its images: n images, J bones, S shape values.

    Attributes:
        K: (n, 3, 3) intrinsics, pixels.
        world_to_camera: (n, 4, 4) extrinsics, OpenCV axes.
        height: (n,) image heights H.
        width: (n,) image widths W.
        rotations: (n, J, 3) axis-angle pose of each image (as an estimator gives it).
        translation: (n, 3) root translation of each image, metres.
        shape: (S,) body shape parameters.
        body: body backend name ("anny", "smplx").
        bone_names: J bone names.
        splits: split name -> image indices.
        frame_index: (n,) time step of each image (None: image i is frame i).
        view_index: (n,) camera of each image (None: all 0).
        rotations_true: (n, J, 3) exact pose (synthetic data), or None.
        translation_true: (n, 3) exact translation, or None.
    """

    K: np.ndarray
    world_to_camera: np.ndarray
    height: np.ndarray
    width: np.ndarray
    rotations: np.ndarray
    translation: np.ndarray
    shape: np.ndarray
    body: str
    bone_names: list[str]
    splits: dict[str, list[int]]
    frame_index: np.ndarray | None = None
    view_index: np.ndarray | None = None
    rotations_true: np.ndarray | None = None
    translation_true: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.K)

    def frame_step(self) -> int:
        """The smallest difference between two of the frame numbers (1 for a whole video, N for
        ``pghm capture --every N``; 1 when the images are not frames of a video)."""
        steps = np.diff(np.unique(self.frame_index)) if self.frame_index is not None else np.ones(1)
        return int(steps.min()) if len(steps) else 1

    def poses_digest(self) -> str:
        """SHA-256 (hex) of the stored poses and their frame numbers: names the poses that
        corrections learned on them (an avatar's pose track) apply to."""
        digest = hashlib.sha256()
        frames = self.frame_index if self.frame_index is not None else np.arange(len(self.rotations))
        for array in (frames.astype(np.int64), self.rotations.astype(np.float32), self.translation.astype(np.float32)):
            digest.update(np.ascontiguousarray(array).tobytes())
        return digest.hexdigest()


POSE_NOISE_KEYS = ("rotation_std_deg", "translation_std_m")
"""The fields of meta.json's optional ``pose_noise``: the per-axis standard deviation of the stored
poses' error, joint rotations in degrees and root translation in metres."""


def stated_pose_noise(meta: dict) -> tuple[float, float] | None:
    """(rotation std in degrees, translation std in metres) a subject's meta.json states for its
    poses' error, or None when it states none; ValueError naming the problem for a malformed one."""
    stated = meta.get("pose_noise")
    if stated is None:
        return None
    values = [stated.get(key) if isinstance(stated, dict) else None for key in POSE_NOISE_KEYS]
    if not all(type(v) in (int, float) and math.isfinite(v) and v >= 0 for v in values):
        raise ValueError(f"'pose_noise' must give numbers >= 0 {' and '.join(POSE_NOISE_KEYS)}, got {stated!r:.80}")
    return float(values[0]), float(values[1])


def stated_aligned_frames(meta: dict) -> frozenset[int]:
    """Frame numbers (``frame_index``) whose stored pose a subject's meta.json says was fitted to
    the frame's own image (optional ``aligned_frames``, written by ``pghm capture --polish``): a
    fit's pose track carries no correction onto them (:meth:`pghm.io.avatar.PoseTrack.at`).
    ValueError naming the problem for a malformed one."""
    stated = meta.get("aligned_frames", [])
    if not isinstance(stated, list) or not all(type(f) is int and f >= 0 for f in stated):
        raise ValueError(f"'aligned_frames' must be a list of frame numbers >= 0, got {stated!r:.80}")
    return frozenset(stated)


NUMERIC_KEYS = {
    "cameras.npz": (*CAMERA_KEYS, "frame_index", "view_index"),
    "poses.npz": ("rotations", "translation", "shape", "rotations_true", "translation_true"),
}
"""Arrays that must hold numbers (all but ``shape`` at least one-dimensional)."""


def _non_numeric(arrays: dict[str, np.ndarray], keys: tuple[str, ...]) -> list[tuple[str, str]]:
    """(key, problem) for each of ``keys`` present that is not a numeric array of the right rank."""
    found = []
    for key in keys:
        if key not in arrays:
            continue
        array = arrays[key]
        if array.dtype.kind not in "fiu":
            found.append((key, f"must hold numbers, not {array.dtype}"))
        elif array.ndim == 0 and key != "shape":
            found.append((key, "must be an array, not a single number"))
    return found


MAX_FRAME_INDEX = 10**6
"""Largest frame_index accepted: one pose-correction slot is allocated per frame up to it."""
INDEX_KEYS = ("frame_index", "view_index")
"""Optional per-image integers of cameras.npz: the frame of the video and the camera of the ring."""
FOV_RANGE_DEG = (1.0, 179.0)
"""A camera's field of view along its image's longest side, degrees: what lenses give (a pinhole's
lies strictly between 0 and 180; a focal length outside it is a unit mistake or corrupt data)."""


def focal_range(longest_side: float) -> tuple[float, float]:
    """(shortest, longest) focal length in pixels whose field of view across ``longest_side`` pixels
    lies in :data:`FOV_RANGE_DEG`: f = (L / 2) / tan(fov / 2)."""
    low, high = (0.5 * longest_side / math.tan(math.radians(fov) / 2) for fov in reversed(FOV_RANGE_DEG))
    return low, high


MAX_INTRINSIC = 1e7
"""Largest |entry| of K, in pixels (a focal length of 1e7 px is a 0.006 degree field of view)."""
VALUE_BOUNDS = {
    ("cameras.npz", "K"): (MAX_INTRINSIC, "px"),
    ("cameras.npz", "world_to_camera"): (MAX_TRANSLATION, "m"),
    ("poses.npz", "rotations"): (MAX_ROTATION, "rad"),
    ("poses.npz", "translation"): (MAX_TRANSLATION, "m"),
    ("poses.npz", "rotations_true"): (MAX_ROTATION, "rad"),
    ("poses.npz", "translation_true"): (MAX_TRANSLATION, "m"),
}
"""Largest |value| of each array (the bounds of motion files, pghm.motion.motion): a pose of 1e20
rad or a camera 1e40 m away is corrupt data, refused at the loader rather than met as a NaN."""


def size_problem(width: np.ndarray, height: np.ndarray) -> str | None:
    """Why a subject's image sizes (n,) cannot be trained on, or None: a training step renders a
    subject's images as one batch, so they must share one size. Shared by ``pghm data check`` and
    the loader that ``fit``, ``eval`` and ``train-prior`` read through."""
    sizes = sorted({(int(w), int(h)) for w, h in zip(width, height)})
    if len(sizes) <= 1:
        return None
    listed = ", ".join(f"{w}x{h}" for w, h in sizes[:4]) + (", ..." if len(sizes) > 4 else "")
    return f"the images have {len(sizes)} sizes ({listed}); a subject's images must all have one size"


def value_problems(
    cameras: dict[str, np.ndarray], poses: dict[str, np.ndarray] | None
) -> list[tuple[str, str, np.ndarray]]:
    """(file, problem, per-image mask) for values out of bounds (NaN included) and camera rotations
    that are not rotations; the arrays' shapes must already be right. Shared by the loader (which
    raises the first) and ``pghm data check`` (which lists them all)."""
    found = []
    for (file, key), (limit, unit) in VALUE_BOUNDS.items():
        arrays = cameras if file == "cameras.npz" else poses
        if arrays is None or key not in arrays:
            continue
        values = arrays[key].astype(np.float64).reshape(len(arrays[key]), -1)
        finite = np.isfinite(values).all(1)
        if not finite.all():
            found.append((file, f"'{key}' is not finite", ~finite))
            continue
        huge = (np.abs(values) > limit).any(1)
        if huge.any():
            found.append((file, f"'{key}' is beyond +-{limit:g} {unit} ({values[huge][0].max():g})", huge))
    E = cameras["world_to_camera"].astype(np.float64)
    finite = np.isfinite(E).reshape(len(E), -1).all(1)
    with np.errstate(all="ignore"):
        rotation = E[:, :3, :3]
        gram = np.einsum("nji,njk->nik", rotation, rotation) - np.eye(3)
        not_rigid = finite & (
            (np.abs(gram).reshape(len(E), -1).max(1) > ROTATION_TOLERANCE)
            | (np.abs(np.linalg.det(rotation) - 1.0) > ROTATION_TOLERANCE)
            | (np.abs(E[:, 3] - np.array([0.0, 0.0, 0.0, 1.0])).max(1) > ROTATION_TOLERANCE)
        )
    if not_rigid.any():
        message = "world_to_camera is not a rigid transform (its rotation is not a rotation)"
        found.append(("cameras.npz", message, not_rigid))
    return found


SHOWN_INDICES = 8
"""Image indices a problem line names before "and N more"."""


def indices_text(mask: np.ndarray) -> str:
    """Compact list of the True positions of a (n,) bool array, for messages."""
    return listed(np.flatnonzero(mask).tolist(), SHOWN_INDICES)
