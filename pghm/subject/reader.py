"""Reading subjects and datasets: :class:`Subject` keeps the small arrays in memory and reads an
image only when its :class:`Frame` is requested; every defect is a DatasetError naming the file."""

from __future__ import annotations

import json
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image

from pghm.errors import DatasetError
from pghm.io.read_errors import IMAGE_READ_ERRORS, NPZ_READ_ERRORS
from pghm.subject.checker import check_subject
from pghm.subject.format import (
    ALL_SPLIT,
    CAMERA_KEYS,
    DATASET_FORMAT,
    POSE_KEYS,
    SubjectArrays,
    _first_line,
    image_name,
    stated_aligned_frames,
)


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


def _read_arrays(directory: Path) -> SubjectArrays:
    """The arrays of a subject that :func:`~pghm.subject.checker.check_subject` found valid (read, not
    checked again)."""
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
        :func:`~pghm.subject.checker.check_subject` finds (the checks of ``pghm data check`` but
        the images' pixels)."""
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
