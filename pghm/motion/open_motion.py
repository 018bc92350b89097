"""Resolve what a user names as a motion: a procedural clip, ``rest``, a ``.npz``, a ``.bvh``, or a
subject folder (its video's poses, such as a capture's: the avatar replays the video's motion).

The CLIs (``--pose``, ``--motion``) and the viewer's "open motion" all accept the same
forms, so one function turns each into a :class:`~pghm.motion.motion.Motion` for a body.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from torch import Tensor

from pghm.body.model import BodyModel
from pghm.errors import MotionFileError
from pghm.io.avatar import MAX_BRACKET_STEPS
from pghm.motion.motion import Motion
from pghm.motion.procedural import PROCEDURAL_MOTIONS, procedural_motion
from pghm.motion.retarget import import_bvh

if TYPE_CHECKING:
    from pghm.io.avatar import PoseTrack

REST = "rest"
REST_FPS = 30.0
SUBJECT_FPS = 30.0
"""Frame rate of a subject's consecutive frame numbers when its meta.json does not state the video's
(``fps``, which ``pghm capture`` records): a phone video's usual rate."""


def motion_names() -> list[str]:
    """The names accepted besides file paths."""
    return [REST, *PROCEDURAL_MOTIONS]


def open_motion(
    source: str | Path, body: BodyModel, shape: Tensor | None = None, track: PoseTrack | None = None
) -> Motion:
    """The motion ``source`` names, for ``body`` (of ``shape``, which places the feet).

    Args:
        source: "rest", a procedural name (walk, squat, ...), a ``.npz`` motion file, a
            ``.bvh`` file (retargeted on the fly), or a subject folder (:func:`subject_motion`).
        track: the avatar's pose track, applied to a subject folder it was learned on.
    """
    name = str(source)
    if name == REST:
        return Motion(
            np.zeros((1, body.num_bones, 3)), np.zeros((1, 3)), REST_FPS, body.name, list(body.bone_names), REST
        )
    if name in PROCEDURAL_MOTIONS:
        return procedural_motion(name, body, shape=shape)
    path = Path(name)
    if path.is_dir():
        motion = subject_motion(path, track)
        motion.check_skeleton(body.name, body.bone_names)
        return motion
    if path.suffix.lower() == ".bvh":
        return import_bvh(path, body, shape=shape)
    if path.suffix.lower() == ".npz" or path.exists():
        motion = Motion.load(path)
        motion.check_skeleton(body.name, body.bone_names)
        return motion
    raise MotionFileError(f"{name}: not a motion file (.npz, .bvh) nor one of {', '.join(motion_names())}")


def subject_motion(directory: str | Path, track: PoseTrack | None = None) -> Motion:
    """A subject folder's stored poses as a motion: one pose per frame number (its first image's,
    the views of an instant sharing it), in time order, at the video's frame rate (meta.json's
    ``fps``, else :data:`SUBJECT_FPS`) over the frame step (``pghm capture --every``).

    With ``track``, the pose track of an avatar fitted on this subject, every frame takes the
    corrections the fit learned for it (:meth:`PoseTrack.at`: a trained frame its own, a held-out
    one the fit aligned to its image its own too, another its neighbours' interpolated unless the
    capture aligned it to its image): the avatar replays its video with the poses it was fitted
    with. A track learned on other poses (its digest differs) is ignored.
    """
    from pghm.subject import Subject

    subject = Subject.open(directory)
    arrays = subject.arrays
    stated = subject.meta.get("fps")
    fps = float(stated) if isinstance(stated, int | float) and not isinstance(stated, bool) else SUBJECT_FPS
    numbers = arrays.frame_index if arrays.frame_index is not None else np.arange(len(arrays))
    frames, first = np.unique(numbers, return_index=True)
    step = arrays.frame_step()
    rotations, translation = arrays.rotations[first].copy(), arrays.translation[first].copy()
    if track is not None and track.poses == arrays.poses_digest():
        aligned = subject.aligned_frames()
        delta_rotations, delta_translation, _, _ = track.at(frames, MAX_BRACKET_STEPS * step, aligned)
        rotations[:, track.bones.numpy()] += delta_rotations.numpy()
        translation += delta_translation.numpy()
    return Motion(
        rotations,
        translation,
        fps / step,
        arrays.body,
        list(arrays.bone_names),
        source=f"subject {Path(directory).name}",
    )
