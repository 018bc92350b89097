"""Motion clips: a pose per frame, in the shared pose representation, saved as ``.npz``.

A motion file holds

    rotations    (F, J, 3) float32   axis-angle per bone, rest-aligned axes (pghm.body.pose)
    translation  (F, 3)    float32   root translation in metres
    fps          ()        float     frames per second
    body         ()        str       body backend the bones belong to ("anny", "smplx")
    bone_names   (J,)      str       the bones, to catch a clip meant for another skeleton
    source       ()        str       where it came from (a BVH path, "procedural:walk", ...)

Files are read with ``allow_pickle=False``: a motion file can never run code.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from pghm.body.pose import BodyPose
from pghm.errors import MotionFileError
from pghm.io.atomic import atomic_write_bytes
from pghm.io.read_errors import NPZ_READ_ERRORS

MOTION_KEYS = ("rotations", "translation", "fps", "body", "bone_names", "source")
MAX_FRAMES = 100_000
"""Longest clip accepted (about 55 minutes at 30 fps; 100k x 104 bones x 3 floats = 125 MB)."""
MAX_ROTATION = 1e3
"""Largest |axis-angle component| accepted, in radians (160 turns; stored clips stay within pi)."""
MAX_TRANSLATION = 1e4
"""Largest |root translation| accepted, in metres (10 km from the origin)."""
MIN_FPS = 1e-3
MAX_FPS = 1e6
"""Frame rates accepted: far beyond any capture (24 to 1000 fps) either way, but bounded, so
durations and frame counts computed from them stay finite and reasonable."""


def _first_line(error: BaseException) -> str:
    text = str(error).strip()
    return text.splitlines()[0] if text else type(error).__name__


@dataclass
class Motion:
    """A clip of F poses for one body's skeleton.

    Attributes:
        rotations: (F, J, 3) float32 axis-angle per bone.
        translation: (F, 3) float32 root translation, metres.
        fps: frames per second.
        body: backend name of the skeleton.
        bone_names: J bone names.
        source: provenance, free text.
    """

    rotations: np.ndarray
    translation: np.ndarray
    fps: float
    body: str
    bone_names: list[str]
    source: str = ""

    def __post_init__(self) -> None:
        with np.errstate(over="ignore"):  # a value beyond float32 becomes inf, refused below by name
            self.rotations = np.asarray(self.rotations, dtype=np.float32)
            self.translation = np.asarray(self.translation, dtype=np.float32)
        frames = self.rotations.shape[0] if self.rotations.ndim == 3 else -1
        if self.rotations.ndim != 3 or self.rotations.shape[1:] != (len(self.bone_names), 3):
            raise MotionFileError(
                f"motion 'rotations' has shape {self.rotations.shape}, expected (frames, {len(self.bone_names)}, 3)"
            )
        if self.translation.shape != (frames, 3):
            raise MotionFileError(f"motion 'translation' has shape {self.translation.shape}, expected ({frames}, 3)")
        if frames == 0:
            raise MotionFileError("motion has no frames")
        if frames > MAX_FRAMES:
            raise MotionFileError(f"motion has {frames} frames, more than the {MAX_FRAMES} accepted")
        if not (np.isfinite(self.fps) and MIN_FPS <= self.fps <= MAX_FPS):
            raise MotionFileError(
                f"motion 'fps' must be a positive number from {MIN_FPS:g} to {MAX_FPS:g}, got {self.fps}"
            )
        for name, limit, unit in (("rotations", MAX_ROTATION, "rad"), ("translation", MAX_TRANSLATION, "m")):
            values = getattr(self, name)
            sane = np.abs(values) <= limit  # False for NaN too
            if not sane.all():
                where = np.argwhere(~sane)[0]
                entry = f"frame {where[0]}" + (f", bone '{self.bone_names[where[1]]}'" if name == "rotations" else "")
                raise MotionFileError(
                    f"motion '{name}' at {entry} is {values[tuple(where)]:g}, "
                    f"not a finite number within +-{limit:g} {unit}"
                )

    @property
    def num_frames(self) -> int:
        return self.rotations.shape[0]

    @property
    def duration(self) -> float:
        """Seconds from the first to the last frame."""
        return (self.num_frames - 1) / self.fps

    def pose(self, frames: int | slice | np.ndarray | None = None) -> BodyPose:
        """The poses of ``frames`` (default all) as a batched :class:`BodyPose`."""
        index = slice(None) if frames is None else frames
        rot = torch.from_numpy(np.ascontiguousarray(self.rotations[index]))
        trans = torch.from_numpy(np.ascontiguousarray(self.translation[index]))
        if rot.ndim == 2:
            rot, trans = rot[None], trans[None]
        return BodyPose(rot, trans)

    def frame_at(self, seconds: float, loop: bool = True) -> int:
        """The frame shown at time ``seconds`` (nearest frame; wraps when ``loop``)."""
        frame = int(round(seconds * self.fps))
        return frame % self.num_frames if loop else min(max(frame, 0), self.num_frames - 1)

    def check_skeleton(self, body_name: str, bone_names: list[str]) -> None:
        """Raise :class:`MotionFileError` when the clip was made for another skeleton."""
        if self.body != body_name or list(self.bone_names) != list(bone_names):
            shown = repr(self.body) if len(repr(self.body)) <= 40 else repr(self.body)[:37] + "..."  # one line
            raise MotionFileError(
                f"motion is for the {shown} skeleton ({len(self.bone_names)} bones), "
                f"not '{body_name}' ({len(bone_names)} bones); re-import or re-generate it for this body"
            )

    def save(self, path: str | Path) -> None:
        """Write the clip atomically as ``.npz``."""
        buffer = io.BytesIO()
        np.savez_compressed(
            buffer,
            rotations=self.rotations,
            translation=self.translation,
            fps=np.float64(self.fps),
            body=np.str_(self.body),
            bone_names=np.array(self.bone_names, dtype=np.str_),
            source=np.str_(self.source),
        )
        atomic_write_bytes(path, buffer.getvalue())

    @staticmethod
    def load(path: str | Path) -> Motion:
        """Read a ``.npz`` motion; any problem is one :class:`MotionFileError` naming it."""
        path = Path(path)
        if not path.is_file():
            raise MotionFileError(f"{path}: motion file not found")
        try:
            with np.load(path, allow_pickle=False) as data:
                missing = [key for key in MOTION_KEYS if key not in data.files]
                if missing:
                    raise MotionFileError(f"{path}: not a pghm motion file, missing {', '.join(missing)}")
                fields = {key: data[key] for key in MOTION_KEYS}
                for key in ("body", "source"):
                    if fields[key].ndim != 0 or fields[key].dtype.kind != "U":
                        raise MotionFileError(
                            f"{path}: motion '{key}' must be one string, got {fields[key].dtype} {fields[key].shape}"
                        )
        except MotionFileError:
            raise
        except NPZ_READ_ERRORS as error:
            raise MotionFileError(f"{path}: unreadable motion file ({_first_line(error)})") from None
        try:
            return Motion(
                rotations=fields["rotations"],
                translation=fields["translation"],
                fps=float(fields["fps"]),
                body=str(fields["body"]),
                bone_names=[str(n) for n in fields["bone_names"]],
                source=str(fields["source"]),
            )
        except (TypeError, ValueError) as error:
            if isinstance(error, MotionFileError):
                raise MotionFileError(f"{path}: {error}") from None
            raise MotionFileError(f"{path}: malformed motion file ({error})") from None
