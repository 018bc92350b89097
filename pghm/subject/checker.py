"""Checking subjects and datasets (``pghm data check``): every defect found, as a list of
:class:`Problem`, streaming through the images one at a time."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from pghm.body.model import shape_problem
from pghm.io.read_errors import IMAGE_READ_ERRORS, NPZ_READ_ERRORS
from pghm.subject.format import (
    CAMERA_KEYS,
    DATASET_FORMAT,
    FOV_RANGE_DEG,
    FRAME_MARGIN,
    INDEX_KEYS,
    MAX_FRAME_INDEX,
    NUMERIC_KEYS,
    POSE_KEYS,
    SUBJECT_FORMAT,
    _first_line,
    _non_numeric,
    focal_range,
    image_name,
    indices_text,
    size_problem,
    stated_aligned_frames,
    stated_pose_noise,
    value_problems,
)


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
        problems.append(Problem("cameras.npz", f"{message} {indices_text(bad_focal)}"))
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


def _check_indices(cameras: dict, problems: list[Problem]) -> None:
    """frame_index and view_index in 0..MAX_FRAME_INDEX - 1 (one pose slot is allocated per frame)."""
    for key in INDEX_KEYS:
        if key in cameras:
            bad = ~((cameras[key] >= 0) & (cameras[key] < MAX_FRAME_INDEX))
            if bad.any():
                message = f"'{key}' must be in 0..{MAX_FRAME_INDEX - 1} for image(s) {indices_text(bad)}"
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
    format, run by ``pghm data check`` and by :meth:`~pghm.subject.reader.Subject.open` (every command
    that reads a subject).

    Reads the small files whole, then (with ``images``) streams through the images and masks,
    decoding each (one at a time) so a truncated PNG is found here. Without ``images`` the
    readers meet a damaged image when they load it.
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
            problems.append(Problem(file, f"{message} for image(s) {indices_text(bad)}"))
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
        problems.append(
            Problem("cameras.npz", f"height and width must be positive for image(s) {indices_text(bad_size)}")
        )
        return problems
    if (problem := size_problem(cameras["width"], cameras["height"])) is not None:
        problems.append(Problem("cameras.npz", problem))
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
