"""Contact sheets: a front and a back view of every subject of a dataset, plus a strip of
a monocular sequence, to eyeball a generated (or converted) dataset at a glance."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import roma
import torch
from PIL import Image

from pghm.io.atomic import atomic_write_bytes
from pghm.subject import Subject, open_subjects

GAP = 4
"""Pixels of white between subjects and between the grid and the strip."""

STRIP_BAND = (235, 235, 235)
"""Background of the monocular strip, to set it apart from the grid."""


def front_and_back(subject: Subject) -> tuple[int, int]:
    """Image indices of the first time step seen most from the front and most from behind.

    The body faces R_root (0, 0, 1); an image's frontality is the cosine between that and
    the direction from the subject (its root translation) to the camera centre.
    """
    a = subject.arrays
    frames = a.frame_index if a.frame_index is not None else np.arange(len(a))
    candidates = np.flatnonzero(frames == frames.min())
    rotations = a.rotations_true if a.rotations_true is not None else a.rotations
    translation = a.translation_true if a.translation_true is not None else a.translation
    root = roma.rotvec_to_rotmat(torch.from_numpy(rotations[candidates, 0].astype(np.float64))).numpy()
    facing = root[:, :, 2]
    E = a.world_to_camera[candidates].astype(np.float64)
    centres = -np.einsum("nji,nj->ni", E[:, :3, :3], E[:, :3, 3])
    towards = centres - translation[candidates]
    towards /= np.linalg.norm(towards, axis=1, keepdims=True)
    score = (facing * towards).sum(1)
    return int(candidates[score.argmax()]), int(candidates[score.argmin()])


def _tile(subject: Subject, index: int, size: int) -> np.ndarray:
    with Image.open(subject.image_path(index)) as image:
        return np.asarray(image.convert("RGB").resize((size, size), Image.Resampling.LANCZOS))


def contact_sheet(
    dataset_dir: str | Path,
    out: str | Path,
    tile: int = 256,
    pairs_per_row: int = 4,
    mono_dir: str | Path | None = None,
    strip_frames: int = 8,
) -> np.ndarray:
    """Write a PNG sheet of every subject's front and back view, plus an optional mono strip.

    Args:
        dataset_dir: a dataset folder (or a single subject folder).
        out: the PNG to write.
        tile: size of each square tile, pixels.
        pairs_per_row: subjects per row of the grid.
        mono_dir: a monocular subject (or a dataset whose first subject is one) whose
            training frames, evenly spaced, form a strip under the grid.
        strip_frames: frames in the strip.

    Returns:
        (H, W, 3) uint8, the sheet.
    """
    subjects = open_subjects(dataset_dir)
    pairs = []
    for subject in subjects:
        front, back = front_and_back(subject)
        pairs.append(np.concatenate([_tile(subject, front, tile), _tile(subject, back, tile)], axis=1))
    pair_width = 2 * tile
    columns = min(pairs_per_row, len(pairs))
    rows = -(-len(pairs) // columns)
    width = columns * pair_width + (columns - 1) * GAP
    sheet = np.full((rows * tile + (rows - 1) * GAP, width, 3), 255, dtype=np.uint8)
    for k, pair in enumerate(pairs):
        r, c = divmod(k, columns)
        y, x = r * (tile + GAP), c * (pair_width + GAP)
        sheet[y : y + tile, x : x + pair_width] = pair
    if mono_dir is not None:
        strip = _strip(open_subjects(mono_dir)[0], strip_frames, width)
        sheet = np.concatenate([sheet, np.full((GAP, width, 3), 255, np.uint8), strip])
    buffer = _png(sheet)
    atomic_write_bytes(out, buffer)
    return sheet


def _strip(subject: Subject, count: int, width: int) -> np.ndarray:
    """``count`` evenly spaced training images side by side, scaled to ``width``."""
    train = subject.arrays.splits.get("train") or list(range(len(subject)))
    picks = [train[int(round(k))] for k in np.linspace(0, len(train) - 1, count)]
    size = (width - (count - 1) * GAP) // count
    strip = np.full((size, width, 3), STRIP_BAND, dtype=np.uint8)
    for k, index in enumerate(picks):
        x = k * (size + GAP)
        strip[:, x : x + size] = _tile(subject, index, size)
    return strip


def _png(pixels: np.ndarray) -> bytes:
    import io

    buffer = io.BytesIO()
    Image.fromarray(pixels).save(buffer, format="PNG", optimize=True)
    return buffer.getvalue()
