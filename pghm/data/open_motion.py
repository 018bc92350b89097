"""Resolve what a user names as a motion: a procedural clip, ``rest``, a ``.npz`` or a ``.bvh``.

The CLIs (``--pose``, ``--motion``) and the viewer's "open motion" all accept the same
forms, so one function turns each into a :class:`~pghm.data.motion.Motion` for a body.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from torch import Tensor

from pghm.body.model import BodyModel
from pghm.data.motion import Motion
from pghm.data.procedural import PROCEDURAL_MOTIONS, procedural_motion
from pghm.data.retarget import import_bvh
from pghm.errors import MotionFileError

REST = "rest"
REST_FPS = 30.0


def motion_names() -> list[str]:
    """The names accepted besides file paths."""
    return [REST, *PROCEDURAL_MOTIONS]


def open_motion(source: str | Path, body: BodyModel, shape: Tensor | None = None) -> Motion:
    """The motion ``source`` names, for ``body`` (of ``shape``, which places the feet).

    Args:
        source: "rest", a procedural name (walk, squat, ...), a ``.npz`` motion file, or a
            ``.bvh`` file (retargeted on the fly).
    """
    name = str(source)
    if name == REST:
        return Motion(
            np.zeros((1, body.num_bones, 3)), np.zeros((1, 3)), REST_FPS, body.name, list(body.bone_names), REST
        )
    if name in PROCEDURAL_MOTIONS:
        return procedural_motion(name, body, shape=shape)
    path = Path(name)
    if path.suffix.lower() == ".bvh":
        return import_bvh(path, body, shape=shape)
    if path.suffix.lower() == ".npz" or path.exists():
        motion = Motion.load(path)
        motion.check_skeleton(body.name, body.bone_names)
        return motion
    raise MotionFileError(f"{name}: not a motion file (.npz, .bvh) nor one of {', '.join(motion_names())}")
