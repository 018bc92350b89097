"""The on-disk subject format: writer, lazy reader and checker (see docs/data.md).

A subject is one folder:

    images/NNNNNN.png   RGB, white background, image i named with six digits
    masks/NNNNNN.png    8-bit grey alpha matte: 255 on the person, 0 off it, on the outline
                        the covered fraction (a binary 0/255 mask is a valid matte); the
                        person is the pixels >= 128
    cameras.npz         K (n, 3, 3), world_to_camera (n, 4, 4) (OpenCV axes: x right,
                        y down, z forward), height (n,), width (n,); optional
                        frame_index (n,), view_index (n,) (multi-view captures)
    poses.npz           rotations (n, J, 3) axis-angle per bone in rest-aligned axes,
                        translation (n, 3) root translation in metres (pghm.body.pose),
                        shape (S,), body (backend name), bone_names (J,); optional
                        rotations_true, translation_true (exact poses, synthetic data)
    splits.json         {"train": [image indices], "test": [...], ...}
    meta.json           {"format": "pghm-subject", "format_version": 1, ...}

A dataset (the prior's training set) is a folder of subject folders with a meta.json
{"format": "pghm-dataset", "format_version": 1, "subjects": [folder names], ...}.

:class:`Subject` keeps the small arrays in memory and reads an image only when its
:class:`Frame` is requested. :func:`check` streams through a subject or dataset, decoding
one image or mask at a time.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import zipfile
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image

from pghm.body.model import shape_problem
from pghm.data.motion import MAX_ROTATION, MAX_TRANSLATION
from pghm.errors import DatasetError, listed
from pghm.io.atomic import atomic_write_bytes
from pghm.io.read_errors import IMAGE_READ_ERRORS, NPZ_READ_ERRORS

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


def npz_bytes(arrays: dict[str, np.ndarray]) -> bytes:
    """An ``.npz`` archive of ``arrays`` with fixed timestamps (reproducible bytes).

    Readable with ``numpy.load(..., allow_pickle=False)``: strings are stored as fixed-width
    unicode arrays, never as objects.
    """
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for name, array in arrays.items():
            info = zipfile.ZipInfo(f"{name}.npy", date_time=ZIP_TIME)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            member = io.BytesIO()
            np.lib.format.write_array(member, np.asanyarray(array), allow_pickle=False)
            archive.writestr(info, member.getvalue())
    return buffer.getvalue()


def json_bytes(value: object) -> bytes:
    """Stable JSON: sorted keys, two-space indent, trailing newline."""
    return (json.dumps(value, indent=2, sort_keys=True) + "\n").encode("utf-8")


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


def write_subject(directory: str | Path, arrays: SubjectArrays, meta: dict) -> None:
    """Write a subject's cameras.npz, poses.npz, splits.json and meta.json (atomically).

    Images are written separately with :func:`write_image`. ``meta`` gets the format
    name and version added; write it last, when every image is on disk.
    """
    directory = Path(directory)
    n = len(arrays)
    cameras = {
        "K": np.asarray(arrays.K, dtype=np.float32),
        "world_to_camera": np.asarray(arrays.world_to_camera, dtype=np.float32),
        "height": np.asarray(arrays.height, dtype=np.int32),
        "width": np.asarray(arrays.width, dtype=np.int32),
    }
    if arrays.frame_index is not None:
        cameras["frame_index"] = np.asarray(arrays.frame_index, dtype=np.int32)
    if arrays.view_index is not None:
        cameras["view_index"] = np.asarray(arrays.view_index, dtype=np.int32)
    poses = {
        "rotations": np.asarray(arrays.rotations, dtype=np.float32),
        "translation": np.asarray(arrays.translation, dtype=np.float32),
        "shape": np.asarray(arrays.shape, dtype=np.float32),
        "body": np.str_(arrays.body),
        "bone_names": np.array(arrays.bone_names, dtype=np.str_),
    }
    if arrays.rotations_true is not None:
        poses["rotations_true"] = np.asarray(arrays.rotations_true, dtype=np.float32)
        poses["translation_true"] = np.asarray(arrays.translation_true, dtype=np.float32)
    for name, indices in arrays.splits.items():
        if any(not 0 <= int(i) < n for i in indices):
            raise DatasetError(f"split '{name}' lists an image index outside 0..{n - 1}")
    atomic_write_bytes(directory / "cameras.npz", npz_bytes(cameras))
    atomic_write_bytes(directory / "poses.npz", npz_bytes(poses))
    splits = {name: [int(i) for i in indices] for name, indices in arrays.splits.items()}
    atomic_write_bytes(directory / "splits.json", json_bytes(splits))
    atomic_write_bytes(
        directory / "meta.json", json_bytes({**meta, "format": SUBJECT_FORMAT, "format_version": FORMAT_VERSION})
    )


def png_bytes(pixels: np.ndarray, compress_level: int) -> bytes:
    """PNG encoding of a uint8 (H, W, 3) RGB or (H, W) grey image (no timestamp chunks)."""
    buffer = io.BytesIO()
    Image.fromarray(pixels).save(buffer, format="PNG", compress_level=compress_level)
    return buffer.getvalue()


def write_image(directory: str | Path, index: int, rgb: np.ndarray, mask: np.ndarray, compress_level: int = 1) -> None:
    """Write image ``index`` and its mask into a subject folder.

    Args:
        directory: the subject folder (``images/`` and ``masks/`` are created).
        index: image index.
        rgb: (H, W, 3) uint8, composited on white.
        mask: (H, W) uint8 alpha matte, 255 x the covered fraction (0 or 255 for a binary mask).
        compress_level: zlib level 0-9; 1 is ~5x faster than the default 6 for ~15 % more bytes.
    """
    directory = Path(directory)
    for folder, pixels in (("images", rgb), ("masks", mask)):
        atomic_write_bytes(directory / folder / image_name(index), png_bytes(pixels, compress_level))


def write_dataset_meta(directory: str | Path, subjects: list[str], meta: dict) -> None:
    """Write a dataset's top-level meta.json listing its subject folders."""
    body = {**meta, "format": DATASET_FORMAT, "format_version": FORMAT_VERSION, "subjects": list(subjects)}
    atomic_write_bytes(Path(directory) / "meta.json", json_bytes(body))


@dataclass(frozen=True)
class Frame:
    """One image of a subject with everything needed to render it.

    Attributes:
        index: image index in the subject.
        image: (H, W, 3) float32 RGB in [0, 1], white background.
        mask: (H, W) float32 alpha matte in [0, 1]: 1 on the subject, 0 elsewhere, the covered
            fraction on its outline (>= 0.5 is the subject).
        K: (3, 3) float32 intrinsics.
        world_to_camera: (4, 4) float32 extrinsics, OpenCV axes.
        rotations: (J, 3) float32 axis-angle pose.
        translation: (3,) float32 root translation.
        frame_index: time step.
        view_index: camera.
        rotations_true: (J, 3) exact pose, or None for real captures.
        translation_true: (3,) exact translation, or None.
    """

    index: int
    image: np.ndarray
    mask: np.ndarray
    K: np.ndarray
    world_to_camera: np.ndarray
    rotations: np.ndarray
    translation: np.ndarray
    frame_index: int
    view_index: int
    rotations_true: np.ndarray | None = None
    translation_true: np.ndarray | None = None

    @property
    def height(self) -> int:
        return self.image.shape[0]

    @property
    def width(self) -> int:
        return self.image.shape[1]


def _read_json(path: Path) -> object:
    if not path.is_file():
        raise DatasetError(f"{path}: missing")
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as error:
        raise DatasetError(f"{path}: unreadable JSON ({error})") from None


def _read_npz(path: Path, required: tuple[str, ...]) -> dict[str, np.ndarray]:
    if not path.is_file():
        raise DatasetError(f"{path}: missing")
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {key: data[key] for key in data.files}
    except NPZ_READ_ERRORS as error:
        raise DatasetError(f"{path}: unreadable ({_first_line(error)})") from None
    missing = [key for key in required if key not in arrays]
    if missing:
        raise DatasetError(f"{path}: missing {', '.join(missing)}")
    return arrays


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
"""Largest |value| of each array (the bounds of motion files, pghm.data.motion): a pose of 1e20
rad or a camera 1e40 m away is corrupt data, refused at the loader rather than met as a NaN."""


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


def _read_arrays(directory: Path) -> SubjectArrays:
    """The arrays of a subject that :func:`check_subject` found valid (read, not checked again)."""
    cameras = _read_npz(directory / "cameras.npz", CAMERA_KEYS)
    poses = _read_npz(directory / "poses.npz", POSE_KEYS)
    bones = [str(name) for name in np.atleast_1d(poses["bone_names"])]
    splits = _read_json(directory / "splits.json")
    return SubjectArrays(
        K=cameras["K"].astype(np.float32),
        world_to_camera=cameras["world_to_camera"].astype(np.float32),
        height=cameras["height"].astype(np.int64),
        width=cameras["width"].astype(np.int64),
        rotations=poses["rotations"].astype(np.float32),
        translation=poses["translation"].astype(np.float32),
        shape=np.atleast_1d(poses["shape"]).astype(np.float32),
        body=str(poses["body"]),
        bone_names=bones,
        splits={str(name): list(indices) for name, indices in splits.items()},
        frame_index=cameras["frame_index"].astype(np.int64) if "frame_index" in cameras else None,
        view_index=cameras["view_index"].astype(np.int64) if "view_index" in cameras else None,
        rotations_true=poses["rotations_true"].astype(np.float32) if "rotations_true" in poses else None,
        translation_true=poses["translation_true"].astype(np.float32) if "translation_true" in poses else None,
    )


def read_rgb(path: Path) -> np.ndarray:
    """(H, W, 3) float32 in [0, 1] from a PNG (grey or RGBA files are converted to RGB)."""
    try:
        with Image.open(path) as image:
            pixels = np.asarray(image.convert("RGB"))
    except IMAGE_READ_ERRORS as error:
        raise DatasetError(f"{path}: unreadable image ({_first_line(error)})") from None
    return pixels.astype(np.float32) / 255.0


def read_mask(path: Path) -> np.ndarray:
    """(H, W) float32 alpha matte in [0, 1] from a mask PNG (pixel / 255; >= 128 is the subject)."""
    try:
        with Image.open(path) as image:
            pixels = np.asarray(image.convert("L"))
    except IMAGE_READ_ERRORS as error:
        raise DatasetError(f"{path}: unreadable mask ({_first_line(error)})") from None
    return pixels.astype(np.float32) / 255.0


class SubjectSplit(Sequence[Frame]):
    """The frames of one split, in the order splits.json lists them; loaded on access."""

    def __init__(self, subject: Subject, name: str, indices: list[int]) -> None:
        self.subject = subject
        self.name = name
        self.indices = list(indices)

    def __len__(self) -> int:
        return len(self.indices)

    def __getitem__(self, position: int) -> Frame:  # type: ignore[override]
        return self.subject[self.indices[position]]

    def __iter__(self) -> Iterator[Frame]:
        for index in self.indices:
            yield self.subject[index]


@dataclass
class Subject:
    """A subject folder opened for reading; images are read only when a frame is requested.

    Attributes:
        directory: the folder.
        arrays: cameras, poses, shape and splits (small, in memory).
        meta: the parsed meta.json.
    """

    directory: Path
    arrays: SubjectArrays
    meta: dict = field(default_factory=dict)

    @classmethod
    def open(cls, directory: str | Path) -> Subject:
        """Open a subject folder; raises :class:`DatasetError` naming the first problem
        :func:`check_subject` finds (the checks of ``pghm data check`` but the images' pixels)."""
        directory = Path(directory)
        if not directory.is_dir():
            raise DatasetError(f"{directory}: not a folder")
        problems = check_subject(directory, images=False)
        if problems:
            more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
            first = problems[0]
            raise DatasetError(f"{directory / first.path}: {first.message}{more}; run pghm data check {directory}")
        return cls(directory, _read_arrays(directory), _read_json(directory / "meta.json"))

    def __len__(self) -> int:
        return len(self.arrays)

    def aligned_frames(self) -> frozenset[int]:
        """Frame numbers whose stored pose was fitted to the frame's own image (:func:`stated_aligned_frames`)."""
        try:
            return stated_aligned_frames(self.meta)
        except ValueError as error:
            raise DatasetError(f"{self.directory / 'meta.json'}: {error}") from None

    @property
    def split_names(self) -> list[str]:
        return list(self.arrays.splits)

    def split(self, name: str) -> SubjectSplit:
        """The frames of split ``name`` ("train", "test", ...); :data:`ALL_SPLIT`: every image."""
        if name == ALL_SPLIT and name not in self.arrays.splits:
            return SubjectSplit(self, name, list(range(len(self))))
        if name not in self.arrays.splits:
            raise DatasetError(f"{self.directory}: no split '{name}' (has {', '.join(self.arrays.splits) or 'none'})")
        return SubjectSplit(self, name, self.arrays.splits[name])

    def image_path(self, index: int) -> Path:
        return self.directory / "images" / image_name(index)

    def mask_path(self, index: int) -> Path:
        return self.directory / "masks" / image_name(index)

    def __getitem__(self, index: int) -> Frame:
        if not 0 <= index < len(self):
            raise IndexError(f"image {index} out of range 0..{len(self) - 1}")
        a = self.arrays
        return Frame(
            index=index,
            image=read_rgb(self.image_path(index)),
            mask=read_mask(self.mask_path(index)),
            K=a.K[index],
            world_to_camera=a.world_to_camera[index],
            rotations=a.rotations[index],
            translation=a.translation[index],
            frame_index=int(a.frame_index[index]) if a.frame_index is not None else index,
            view_index=int(a.view_index[index]) if a.view_index is not None else 0,
            rotations_true=a.rotations_true[index] if a.rotations_true is not None else None,
            translation_true=a.translation_true[index] if a.translation_true is not None else None,
        )

    def __iter__(self) -> Iterator[Frame]:
        for index in range(len(self)):
            yield self[index]


class Dataset(Sequence[Subject]):
    """A folder of subjects (the prior's training data); subjects are opened on access."""

    def __init__(self, directory: str | Path) -> None:
        self.directory = Path(directory)
        meta = _read_json(self.directory / "meta.json")
        if not isinstance(meta, dict) or meta.get("format") != DATASET_FORMAT:
            raise DatasetError(f"{self.directory / 'meta.json'}: not a {DATASET_FORMAT}")
        subjects = meta.get("subjects")
        if not isinstance(subjects, list) or not all(isinstance(s, str) for s in subjects):
            raise DatasetError(f"{self.directory / 'meta.json'}: 'subjects' must list the subject folders")
        self.meta = meta
        self.names: list[str] = subjects

    @classmethod
    def open(cls, directory: str | Path) -> Dataset:
        return cls(directory)

    def __len__(self) -> int:
        return len(self.names)

    def __getitem__(self, index: int) -> Subject:  # type: ignore[override]
        return Subject.open(self.directory / self.names[index])


def is_dataset(path: str | Path) -> bool:
    """Whether ``path`` holds a data set, by its meta.json's format (a subject otherwise: its own
    checks then name what is missing, cameras.npz rather than the data set's meta.json)."""
    try:
        meta = json.loads((Path(path) / "meta.json").read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError):
        return False
    return isinstance(meta, dict) and meta.get("format") == DATASET_FORMAT


def open_subjects(path: str | Path) -> list[Subject]:
    """The subjects of a data set folder, or the one subject of a subject folder."""
    return list(Dataset.open(path)) if is_dataset(path) else [Subject.open(path)]


# ---------------------------------------------------------------------------- checker


@dataclass(frozen=True)
class Problem:
    """One defect of a subject folder: the file it is in and what is wrong."""

    path: str
    message: str

    def __str__(self) -> str:
        return f"{self.path}: {self.message}"


def _load_npz_for_check(path: Path, required: tuple[str, ...], problems: list[Problem]) -> dict | None:
    """The archive's arrays, or None after recording why it cannot be used."""
    if not path.is_file():
        problems.append(Problem(path.name, "missing"))
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {key: data[key] for key in data.files}
    except NPZ_READ_ERRORS as error:
        problems.append(Problem(path.name, f"unreadable .npz archive ({_first_line(error)})"))
        return None
    missing = [key for key in required if key not in arrays]
    if missing:
        problems.append(Problem(path.name, f"missing {', '.join(missing)}"))
        return None
    wrong = _non_numeric(arrays, NUMERIC_KEYS.get(path.name, ()))
    for key, problem in wrong:
        problems.append(Problem(path.name, f"'{key}' {problem}"))
    return None if wrong else arrays


SHOWN_INDICES = 8
"""Image indices a problem line names before "and N more"."""


def _indices(mask: np.ndarray) -> str:
    """Compact list of the True positions of a (n,) bool array, for messages."""
    return listed(np.flatnonzero(mask).tolist(), SHOWN_INDICES)


def _check_cameras(cameras: dict, poses: dict | None, problems: list[Problem]) -> None:
    K = cameras["K"].astype(np.float64)
    E = cameras["world_to_camera"].astype(np.float64)
    finite = np.isfinite(K).reshape(len(K), -1).all(1) & np.isfinite(E).reshape(len(E), -1).all(1)
    longest = np.maximum(cameras["width"], cameras["height"]).astype(np.float64).clip(min=1.0)
    shortest_focal, longest_focal = focal_range(1.0)
    focal = np.stack([K[:, 0, 0], K[:, 1, 1]], axis=1) / longest[:, None]
    bad_focal = finite & ~((focal >= shortest_focal) & (focal <= longest_focal)).all(1)
    if bad_focal.any():
        low, high = FOV_RANGE_DEG
        message = f"K's focal length is outside a field of view of {low:g} to {high:g} degrees for image(s)"
        problems.append(Problem("cameras.npz", f"{message} {_indices(bad_focal)}"))
    rotation = E[:, :3, :3]
    not_rigid = np.zeros(len(E), bool)
    for _, message, bad in value_problems(cameras, None):
        if message.startswith("world_to_camera is not a rigid"):
            not_rigid |= bad
    if poses is None or poses["translation"].shape != (len(E), 3):
        return
    # The subject's centre (its root translation) must lie in front of each camera and
    # project near the image.
    centre = poses["translation"].astype(np.float64)
    ok = finite & ~not_rigid & np.isfinite(centre).all(1)
    cam = np.einsum("nij,nj->ni", rotation, centre) + E[:, :3, 3]
    behind = ok & (cam[:, 2] <= 0)
    for i in np.flatnonzero(behind):
        problems.append(
            Problem(
                "cameras.npz",
                f"camera of image {i} looks away from the subject (subject centre at depth {cam[i, 2]:.2f} m)",
            )
        )
    front = ok & ~behind
    z = np.where(front, cam[:, 2], 1.0)
    u = K[:, 0, 0] * cam[:, 0] / z + K[:, 0, 2]
    v = K[:, 1, 1] * cam[:, 1] / z + K[:, 1, 2]
    width, height = cameras["width"].astype(np.float64), cameras["height"].astype(np.float64)
    outside = front & (
        (u < -FRAME_MARGIN * width)
        | (u > (1 + FRAME_MARGIN) * width)
        | (v < -FRAME_MARGIN * height)
        | (v > (1 + FRAME_MARGIN) * height)
    )
    for i in np.flatnonzero(outside):
        problems.append(
            Problem("cameras.npz", f"subject centre projects far outside image {i} (at u={u[i]:.0f}, v={v[i]:.0f})")
        )


INDEX_KEYS = ("frame_index", "view_index")
"""Optional per-image integers of cameras.npz: the frame of the video and the camera of the ring."""


def _check_indices(cameras: dict, problems: list[Problem]) -> None:
    """frame_index and view_index in 0..MAX_FRAME_INDEX - 1 (one pose slot is allocated per frame)."""
    for key in INDEX_KEYS:
        if key in cameras:
            bad = ~((cameras[key] >= 0) & (cameras[key] < MAX_FRAME_INDEX))
            if bad.any():
                message = f"'{key}' must be in 0..{MAX_FRAME_INDEX - 1} for image(s) {_indices(bad)}"
                problems.append(Problem("cameras.npz", message))


def _check_png(path: Path, label: str, mode: str, size: tuple[int, int], problems: list[Problem]) -> None:
    """Size and mode of one PNG, and its pixels decoded (a truncated file fails there, not in
    training)."""
    if not path.is_file():
        problems.append(Problem(label, "missing"))
        return
    try:
        with Image.open(path) as image:
            if image.format != "PNG":
                problems.append(Problem(label, f"not a PNG ({image.format})"))
                return
            if image.size != size:
                problems.append(
                    Problem(label, f"size {image.size[0]}x{image.size[1]}, cameras.npz says {size[0]}x{size[1]}")
                )
            if image.mode != mode:
                problems.append(Problem(label, f"mode {image.mode}, expected {mode}"))
            image.load()
    except IMAGE_READ_ERRORS as error:
        problems.append(Problem(label, f"unreadable PNG ({_first_line(error)})"))


def check_subject(directory: str | Path, images: bool = True) -> list[Problem]:
    """Every problem found in a subject folder (empty when it is valid): the one validator of the
    format, run by ``pghm data check`` and by :meth:`Subject.open` (every command that reads a subject).

    Reads the small files whole, then (with ``images``) streams through the images and masks,
    decoding each (one at a time) so a truncated PNG is found here. Without ``images`` the
    readers meet a damaged image when they load it (training skips it with a warning).
    """
    directory = Path(directory)
    problems: list[Problem] = []
    meta_path = directory / "meta.json"
    if not meta_path.is_file():
        problems.append(Problem("meta.json", "missing"))
    else:
        try:
            meta = json.loads(meta_path.read_text(encoding="utf-8"))
            if not isinstance(meta, dict) or meta.get("format") != SUBJECT_FORMAT:
                problems.append(Problem("meta.json", f'"format" must be "{SUBJECT_FORMAT}"'))
            else:
                stated_pose_noise(meta)
                stated_aligned_frames(meta)
        except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as error:
            problems.append(Problem("meta.json", f"unreadable JSON ({error})"))
        except ValueError as error:
            problems.append(Problem("meta.json", str(error)))
    cameras = _load_npz_for_check(directory / "cameras.npz", CAMERA_KEYS, problems)
    poses = _load_npz_for_check(directory / "poses.npz", POSE_KEYS, problems)
    if cameras is None:
        return problems
    n = len(cameras["K"])
    if n == 0:
        problems.append(Problem("cameras.npz", "describes no images"))
        return problems
    shapes_ok = True
    camera_shapes = {"K": (n, 3, 3), "world_to_camera": (n, 4, 4), "height": (n,), "width": (n,)}
    camera_shapes.update({key: (n,) for key in INDEX_KEYS if key in cameras})
    for key, shape in camera_shapes.items():
        if cameras[key].shape != shape:
            problems.append(Problem("cameras.npz", f"'{key}' has shape {cameras[key].shape}, expected {shape}"))
            shapes_ok = False
    if poses is not None:
        bones = np.atleast_1d(poses["bone_names"]).shape[0]
        expected = {"rotations": (n, bones, 3), "translation": (n, 3)}
        for key in ("rotations_true", "translation_true"):
            if key in poses:
                expected[key] = expected[key.replace("_true", "")]
        for key, shape in expected.items():
            if poses[key].shape != shape:
                problems.append(Problem("poses.npz", f"'{key}' has shape {poses[key].shape}, expected {shape}"))
                continue
        bad_shape = shape_problem(str(poses["body"]), np.asarray(poses["shape"], dtype=np.float64))
        if bad_shape is not None:
            problems.append(Problem("poses.npz", f"'shape' {bad_shape}"))
        if poses["translation"].shape != (n, 3):
            poses = None
    if shapes_ok:
        pose_values = poses if poses is not None and all(p.path != "poses.npz" for p in problems) else None
        for file, message, bad in value_problems(cameras, pose_values):
            problems.append(Problem(file, f"{message} for image(s) {_indices(bad)}"))
        _check_cameras(cameras, poses, problems)
        _check_indices(cameras, problems)

    splits_path = directory / "splits.json"
    try:
        splits = json.loads(splits_path.read_text(encoding="utf-8"))
        if not isinstance(splits, dict) or "train" not in splits:
            problems.append(Problem("splits.json", 'expected {"train": [indices], "test": [indices], ...}'))
        else:
            for name, indices in splits.items():
                if not isinstance(indices, list) or not all(type(i) is int and 0 <= i < n for i in indices):
                    problems.append(Problem("splits.json", f"split {name!r} must list image indices in 0..{n - 1}"))
            if splits["train"] == []:
                problems.append(Problem("splits.json", "split 'train' is empty: a subject needs images to train on"))
            if isinstance(splits.get("test"), list) and isinstance(splits["train"], list):
                shared = {i for i in splits["train"] if type(i) is int} & {i for i in splits["test"] if type(i) is int}
                if shared:
                    problems.append(Problem("splits.json", f"{len(shared)} image(s) are in both train and test"))
    except FileNotFoundError:
        problems.append(Problem("splits.json", "missing"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as error:
        problems.append(Problem("splits.json", f"unreadable JSON ({error})"))

    if not shapes_ok:
        return problems
    sizes = np.stack([cameras["width"], cameras["height"]], axis=1).astype(np.float64)
    bad_size = ~((sizes >= 1) & (sizes <= 2**31 - 1)).all(1)
    if bad_size.any():
        problems.append(Problem("cameras.npz", f"height and width must be positive for image(s) {_indices(bad_size)}"))
        return problems
    if not images:
        return problems
    for folder in ("images", "masks"):
        if not (directory / folder).is_dir():
            problems.append(Problem(folder, "missing folder"))
            continue
        expected_names = {image_name(i) for i in range(n)}
        stray = sorted(p.name for p in (directory / folder).glob("*.png") if p.name not in expected_names)
        for name in stray:
            problems.append(Problem(f"{folder}/{name}", f"not one of the {n} images cameras.npz describes"))
        mode = "RGB" if folder == "images" else "L"
        for i in range(n):
            size = (int(cameras["width"][i]), int(cameras["height"][i]))
            name = image_name(i)
            _check_png(directory / folder / name, f"{folder}/{name}", mode, size, problems)
    return problems


def check(path: str | Path) -> list[Problem]:
    """Problems of a subject folder or of every subject of a dataset folder.

    Paths in the problems are relative to ``path`` (prefixed with the subject folder for
    datasets).
    """
    path = Path(path)
    if not path.is_dir():
        return [Problem(str(path), "not a folder")]
    meta_path = path / "meta.json"
    meta = None
    if meta_path.is_file():
        try:
            meta = json.loads(meta_path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as error:
            return [Problem("meta.json", f"unreadable JSON ({error})")]
    if isinstance(meta, dict) and meta.get("format") == DATASET_FORMAT:
        subjects = meta.get("subjects")
        if not isinstance(subjects, list) or not all(isinstance(s, str) for s in subjects):
            return [Problem("meta.json", "'subjects' must list the subject folders")]
        problems = []
        for name in subjects:
            if not (path / name).is_dir():
                problems.append(Problem(name, "subject folder missing"))
                continue
            problems += [Problem(f"{name}/{p.path}", p.message) for p in check_subject(path / name)]
        return problems
    if meta is None and not (path / "cameras.npz").is_file():
        return [
            Problem(
                str(path), "neither a subject (cameras.npz, poses.npz, ...) nor a dataset (meta.json listing subjects)"
            )
        ]
    return check_subject(path)


def count_images(path: str | Path) -> tuple[int, int]:
    """(subjects, images) in a valid subject or dataset folder."""
    path = Path(path)
    meta = json.loads((path / "meta.json").read_text(encoding="utf-8"))
    folders = [path / name for name in meta["subjects"]] if meta.get("format") == DATASET_FORMAT else [path]
    total = 0
    for folder in folders:
        with np.load(folder / "cameras.npz", allow_pickle=False) as data:
            total += len(data["K"])
    return len(folders), total
