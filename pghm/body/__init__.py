"""Parametric body models behind one interface: Anny (default, embedded) and SMPL-X (optional)."""

from __future__ import annotations

from functools import lru_cache
from typing import Literal

from pghm.body.model import CANONICAL_JOINTS, BodyModel, RestBody
from pghm.body.pose import BodyPose, PoseError
from pghm.body.skinning import forward_kinematics, lbs, safe_normalize, skin_directions
from pghm.errors import PghmError

BodyName = Literal["anny", "smplx"]
BODY_NAMES: tuple[str, ...] = ("anny", "smplx")


@lru_cache(maxsize=4)
def load_body(name: str = "anny", model_path: str | None = None) -> BodyModel:
    """The body model ``name``, built once per process.

    Args:
        name: "anny" (default, needs no file) or "smplx" (needs ``model_path``).
        model_path: the user's SMPL-X model file.
    """
    if name == "anny":
        from pghm.body.anny_backend import AnnyBody

        return AnnyBody()
    if name == "smplx":
        if model_path is None:
            raise PghmError("the SMPL-X body needs --body-model-path pointing to your SMPLX_*.npz")
        from pghm.body.smplx_backend import SMPLXBody

        return SMPLXBody(model_path)
    shown = repr(name) if len(repr(name)) <= 40 else repr(name)[:37] + "..."  # a name from a file: one line
    raise PghmError(f"unknown body model {shown}, expected one of {', '.join(BODY_NAMES)}")


__all__ = [
    "BODY_NAMES",
    "CANONICAL_JOINTS",
    "BodyModel",
    "BodyPose",
    "PoseError",
    "RestBody",
    "forward_kinematics",
    "lbs",
    "load_body",
    "safe_normalize",
    "skin_directions",
]
