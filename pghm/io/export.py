"""Export an avatar's posed Gaussians as a standard 3DGS .ply or a .spz (the layouts are in
:mod:`pghm.io.ply` and :mod:`pghm.io.spz`; the file's suffix chooses)."""

from __future__ import annotations

import math

import torch

from pghm.errors import PghmError
from pghm.motion.motion import MAX_TRANSLATION

POSED_FORMATS = (".ply", ".spz")
"""The suffixes of the posed-frame files :func:`export_posed` writes."""
FRONT_DISTANCE = 3.0
"""Default baking view: this many metres in front of the posed root (+z, the body's front)."""


def parse_vector(text: str) -> torch.Tensor:
    """(3,) a point "X,Y,Z" in metres, each coordinate within the scene's +-MAX_TRANSLATION."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 3 or not all(math.isfinite(v) and abs(v) <= MAX_TRANSLATION for v in values):
        raise PghmError(
            f"expected three comma-separated numbers of metres within +-{MAX_TRANSLATION:g}, like 0,1,3, got {text!r}"
        )
    return torch.tensor(values)


def export_posed(
    avatar_path: str,
    pose_source: str,
    frame: int,
    out: str,
    view: str | None = None,
    identity: int = 0,
    body_model_path: str | None = None,
    device: torch.device | str = "cpu",
) -> int:
    """Write the dynamic Gaussians of ``avatar_path`` in frame ``frame`` of ``pose_source`` to
    ``out``, a .ply or a .spz by its suffix (:data:`POSED_FORMATS`).

    The view-dependent colour is baked for a camera centred at ``view`` ("X,Y,Z"; default
    FRONT_DISTANCE in front of the posed root). The network runs on ``device``. Returns the
    number of Gaussians written.
    """
    from pghm.body import load_body
    from pghm.device import move
    from pghm.io.avatar import avatar_geometry, load_avatar
    from pghm.io.ply import write_ply
    from pghm.io.spz import write_spz
    from pghm.model.evaluator import CachedEvaluator
    from pghm.motion.open_motion import open_motion

    avatar = load_avatar(avatar_path).to(device)
    avatar.check_identity(identity)
    body = load_body(avatar.body_name, body_model_path)
    motion = open_motion(pose_source, body, avatar.shape_of(identity), avatar.pose_track)
    if not 0 <= frame < motion.num_frames:
        raise PghmError(f"--frame {frame} is outside the motion's {motion.num_frames} frames")
    pose = move(motion.pose(frame), avatar.device)
    geometry = avatar_geometry(avatar, identity, body_model_path)
    evaluator = CachedEvaluator(avatar.model, geometry)
    if view is None:
        root = evaluator.model.skin(geometry, pose).root[0]
        centre = root + torch.tensor([0.0, 0.0, FRONT_DISTANCE], device=root.device)
    else:
        centre = move(parse_vector(view), avatar.device)
    gaussians = move(evaluator.evaluate(avatar.identity_map(identity), pose, centre).dynamic, torch.device("cpu"))
    write = write_spz if out.lower().endswith(".spz") else write_ply
    write(out, gaussians.means[0], gaussians.scales[0], gaussians.colors[0], gaussians.opacities[0])
    return gaussians.num_gaussians
