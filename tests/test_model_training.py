"""The model learns: one identity fitted to a handful of rendered views ."""

from __future__ import annotations

import torch
from conftest import SMALL_MODEL as SMALL

from pghm.body import BodyPose
from pghm.model import PGHM, subject_geometry
from pghm.splat import Camera, render
from pghm.train.losses import objective
from pghm.uv.atlas import build_atlas

SIZE = 48


def target_views(geometry, pose, cameras):
    """Ground truth: the body surface painted with a striped pattern, drawn by the splatter."""
    points = geometry.surface.positions
    colors = torch.stack(
        [
            0.5 + 0.5 * torch.sin(points[:, 1] * 40.0),
            0.5 + 0.5 * torch.cos(points[:, 0] * 30.0),
            (points[:, 2] > 0).float() * 0.8 + 0.1,
        ],
        -1,
    )
    from pghm.uv.maps import posed_points

    posed = posed_points(geometry.surface, geometry.transforms(pose))[0]
    scales = geometry.texel_length * 0.6
    return [render(posed, scales, colors, torch.ones(len(posed)), cam).rgb.permute(2, 0, 1) for cam in cameras]


def test_loss_halves_within_a_few_dozen_steps(body):
    torch.manual_seed(0)
    geometry = subject_geometry(body, build_atlas(body, SMALL.uv_resolution))
    pose = BodyPose(torch.zeros(1, body.num_bones, 3), torch.zeros(1, 3))
    cameras = [
        Camera.look_at(
            eye=(3.0 * torch.sin(torch.tensor(a)).item(), 0.0, 3.0 * torch.cos(torch.tensor(a)).item()),
            target=(0.0, 0.0, 0.0),
            fov_y_degrees=40.0,
            width=SIZE,
            height=SIZE,
        )
        for a in (0.0, 2.1, 4.2)
    ]
    targets = torch.stack(target_views(geometry, pose, cameras))
    model = PGHM(SMALL, num_identities=1)
    network = [p for name, p in model.named_parameters() if name != "identity_bank"]
    optimizer = torch.optim.Adam([{"params": network, "lr": 3e-3}, {"params": [model.identity_bank], "lr": 5e-2}])
    centres = torch.stack([c.centre.float() for c in cameras])
    losses = []
    for _ in range(30):
        out = model(
            model.decode_identity(0),
            geometry,
            BodyPose(pose.rotations.expand(3, -1, -1), pose.translation.expand(3, -1)),
            centres,
        )
        renders = {
            name: torch.stack(
                [
                    render(g.means[b], g.scales[b], g.colors[b], g.opacities[b], cam).rgb.permute(2, 0, 1)
                    for b, cam in enumerate(cameras)
                ]
            )
            for name, g in (("static", out.static), ("dynamic", out.dynamic))
        }
        loss, _ = objective(renders["static"], renders["dynamic"], targets, out.regularizer)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    assert losses[-1] <= 0.5 * losses[0], losses[::5]
