"""Export an avatar's posed Gaussians as a standard 3DGS .ply (the layout is in :mod:`pghm.io.ply`)."""

from __future__ import annotations

import torch

from pghm.errors import PghmError

FRONT_DISTANCE = 3.0
"""Default baking view: this many metres in front of the posed root (+z, the body's front)."""


def parse_vector(text: str) -> torch.Tensor:
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 3 or not all(torch.isfinite(torch.tensor(values))):
        raise PghmError(f"expected three comma-separated numbers like 0,1,3, got {text!r}")
    return torch.tensor(values)


def export_posed_ply(
    avatar_path: str,
    pose_source: str,
    frame: int,
    out: str,
    view: str | None = None,
    identity: int = 0,
    body_model_path: str | None = None,
) -> int:
    """Write the dynamic Gaussians of ``avatar_path`` in frame ``frame`` of ``pose_source``.

    The view-dependent colour is baked for a camera centred at ``view`` ("X,Y,Z"; default
    FRONT_DISTANCE in front of the posed root). Returns the number of Gaussians written.
    """
    from pghm.body import load_body
    from pghm.io.avatar import avatar_geometry, load_avatar
    from pghm.io.ply import write_ply
    from pghm.model.evaluator import CachedEvaluator
    from pghm.motion.open_motion import open_motion

    avatar = load_avatar(avatar_path)
    avatar.check_identity(identity)
    body = load_body(avatar.body_name, body_model_path)
    motion = open_motion(pose_source, body, avatar.shape_of(identity), avatar.pose_track)
    if not 0 <= frame < motion.num_frames:
        raise PghmError(f"--frame {frame} is outside the motion's {motion.num_frames} frames")
    pose = motion.pose(frame)
    geometry = avatar_geometry(avatar, identity, body_model_path)
    evaluator = CachedEvaluator(avatar.model, geometry)
    if view is None:
        root = evaluator.model.skin(geometry, pose).root[0]
        centre = root + torch.tensor([0.0, 0.0, FRONT_DISTANCE])
    else:
        centre = parse_vector(view)
    gaussians = evaluator.evaluate(avatar.identity_map(identity), pose, centre).dynamic
    write_ply(out, gaussians.means[0], gaussians.scales[0], gaussians.colors[0], gaussians.opacities[0])
    return gaussians.num_gaussians
