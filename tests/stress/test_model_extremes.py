"""The body model, skinning, UV maps and network at wild inputs: joint rotations up to and past
pi, identity latents scaled by 100 or zero, float32 against float64, and zero-length vectors
that must normalise to zero instead of NaN.

Independent truths: rotation vectors theta and theta - 2 pi theta/|theta| are the same rotation
(so the same posed body); the model's bounded parametrisation (scales within [min_scale,
max_scale], colours in (0, 1)) holds for any latent; float64 is the reference for float32.
"""

from __future__ import annotations

import copy
import math

import pytest
import torch
from conftest import SMALL_MODEL
from stress_kit import check

from pghm.body.pose import BodyPose
from pghm.body.skinning import safe_normalize, skin_directions
from pghm.model import subject_geometry
from pghm.uv.atlas import build_atlas
from pghm.uv.maps import vertex_normals, view_directions
from viewer.demo import development_avatar

AREA = "model and skinning"
CENTRE = torch.tensor([[0.3, 1.0, 3.0]])
"""A camera centre in front of the body."""


@pytest.fixture(scope="module")
def setup(body):
    prior = development_avatar(SMALL_MODEL, kind="prior", num_identities=2, seed=5)
    geometry = subject_geometry(body, build_atlas(body, SMALL_MODEL.uv_resolution))
    return prior.model, geometry


def outputs_finite(out) -> bool:
    sets = (out.static, out.dynamic)
    return all(
        bool(torch.isfinite(t).all()) for g in sets for t in (g.means, g.scales, g.colors, g.opacities)
    ) and bool(torch.isfinite(out.regularizer))


def rotations(body, angle: float, axis=(1.0, 1.0, 1.0)) -> torch.Tensor:
    direction = torch.tensor(axis) / torch.tensor(axis).norm()
    return (direction * angle).expand(1, body.num_bones, 3).clone()


ANGLES = (0.0, math.pi / 2, math.pi - 1e-6, math.pi, math.pi + 1e-6, 2 * math.pi, 1e4)


def test_every_joint_rotated_up_to_and_past_pi(body, setup):
    model, geometry = setup
    identity = model.decode_identity(0).detach()
    finite, largest = [], 0.0
    for angle in ANGLES:
        rotation = rotations(body, angle).requires_grad_(True)
        latent = identity.clone().requires_grad_(True)
        out = model(latent, geometry, BodyPose(rotation, torch.zeros(1, 3)), CENTRE)
        loss = sum(t.sum() for t in (out.dynamic.means, out.dynamic.scales, out.dynamic.colors)) + out.regularizer
        grads = torch.autograd.grad(loss, [rotation, latent])
        ok = outputs_finite(out) and all(bool(torch.isfinite(g).all()) for g in grads)
        finite.append(ok)
        largest = max(largest, float(out.dynamic.means.detach().abs().max()))
    check(
        AREA,
        f"every joint rotated by {', '.join(f'{a:.4g}' for a in ANGLES)} rad",
        "finite Gaussians, regulariser and gradients (rotations, latent); the body stays within metres",
        f"finite at all {len(ANGLES)} angles: {all(finite)}; largest |coordinate| {largest:.2f} m",
        all(finite) and largest < 5.0,
    )


POSE_TOLERANCE = 2e-5
"""Metres. theta and theta - 2 pi theta/|theta| differ only in float32 rounding of sin and cos at
|theta| ~ 3-6 (~5e-7 relative), compounded along ~20 bones of a kinematic chain of a 1.7 m body."""


def test_rotations_past_pi_pose_the_body_like_their_short_equivalents(body, setup):
    model, geometry = setup
    generator = torch.Generator().manual_seed(0)
    axes = torch.nn.functional.normalize(torch.randn(1, body.num_bones, 3, generator=generator), dim=-1)
    worst = 0.0
    for angle in (math.pi - 0.3, math.pi + 1e-4, math.pi + 0.3, 2 * math.pi - 0.1, 2 * math.pi + 0.2, 3.5 * math.pi):
        long = axes * angle
        short = axes * (angle - 2 * math.pi * round(angle / (2 * math.pi)))
        a = model.skin(geometry, BodyPose(long, torch.zeros(1, 3))).surface_points
        b = model.skin(geometry, BodyPose(short, torch.zeros(1, 3))).surface_points
        worst = max(worst, float((a - b).abs().max()))
    check(
        AREA,
        "rotation vectors past pi (to 3.5 pi, random axis per bone) against their equivalents in (-pi, pi]",
        f"the same posed surface (within {POSE_TOLERANCE:g} m)",
        f"max difference {worst:.1e} m",
        worst <= POSE_TOLERANCE,
    )


@pytest.mark.parametrize("scale", [100.0, 0.0], ids=["x100", "zero"])
def test_identity_latents_scaled_by_100_or_zero(body, setup, scale):
    model, geometry = setup
    config = model.config
    with torch.no_grad():
        latent = model.identity_bank[:1] * scale
        out = model(model.decode_latent(latent), geometry, BodyPose(rotations(body, 0.7), torch.zeros(1, 3)), CENTRE)
    scales = torch.cat([out.static.scales, out.dynamic.scales])
    colors = torch.cat([out.static.colors, out.dynamic.colors])
    bounded = bool(((scales >= config.min_scale) & (scales <= config.max_scale)).all()) and bool(
        ((colors >= 0) & (colors <= 1)).all()
    )
    check(
        AREA,
        f"identity latent scaled by {scale:g}",
        "finite; scales within [min_scale, max_scale], colours in [0, 1]",
        f"finite: {outputs_finite(out)}; scales [{float(scales.min()):.2g}, {float(scales.max()):.2g}] m, "
        f"colours [{float(colors.min()):.3f}, {float(colors.max()):.3f}]",
        outputs_finite(out) and bounded,
    )


PRECISION = {
    1.0: {"means": ("abs", 2e-5), "scales": ("rel", 5e-6), "colors": ("abs", 5e-6)},
    100.0: {"means": ("abs", 2e-5), "scales": ("rel", 1e-4), "colors": ("abs", 5e-4)},
}
"""float32 against float64 of the same network, per latent scale. Means (metres): float32
rounding of ~1 m coordinates (6e-8) through skinning's ~20-bone chains and the bounded
offsets, whatever the latent. Scales (relative) and colours (absolute, in [0, 1]): float32's
6e-8 relative rounding over the network's ~20 layers; a latent scaled by 100 makes every
pre-activation ~100 times larger, and its absolute rounding with it. Measured errors are 5 to
10 times below these bounds."""


@pytest.mark.parametrize("scale", [1.0, 100.0], ids=["latent", "latent x100"])
def test_float32_agrees_with_float64(body, setup, scale):
    model, geometry = setup
    model64 = copy.deepcopy(model).double()
    bounds = PRECISION[scale]
    worst = {name: 0.0 for name in bounds}
    for angle in (0.3, math.pi, 4.0):
        rotation = rotations(body, angle)
        with torch.no_grad():
            single = model(
                model.decode_latent(model.identity_bank[:1] * scale),
                geometry,
                BodyPose(rotation, torch.zeros(1, 3)),
                CENTRE,
            )
            double = model64(
                model64.decode_latent(model64.identity_bank[:1] * scale),
                geometry,
                BodyPose(rotation.double(), torch.zeros(1, 3, dtype=torch.float64)),
                CENTRE.double(),
            )
        for name, (kind, _) in bounds.items():
            a, b = getattr(single.dynamic, name).double(), getattr(double.dynamic, name)
            error = (a - b).abs() / (b.abs() if kind == "rel" else 1)
            worst[name] = max(worst[name], float(error.max()))
    ok = all(worst[name] <= bound for name, (_, bound) in bounds.items())
    check(
        AREA,
        f"float32 against float64 ({'latent x100' if scale != 1 else 'latent'}, rotations 0.3, pi, 4 rad)",
        ", ".join(f"{name} {kind} <= {bound:g}" for name, (kind, bound) in bounds.items()),
        ", ".join(f"{name} {worst[name]:.1e}" for name in bounds),
        ok,
    )


def test_zero_length_vectors_normalise_to_zero_not_nan(body, setup):
    model, geometry = setup
    cases = {}
    zero = torch.zeros(4, 3, requires_grad=True)
    unit = safe_normalize(zero)
    (gradient,) = torch.autograd.grad(unit.sum(), zero)
    cases["safe_normalize of zero vectors"] = bool((unit == 0).all()) and bool((gradient == 0).all())

    vertices = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 1.0, 0.0]], requires_grad=True)
    faces = torch.tensor([[0, 1, 2], [0, 1, 3]])  # the first triangle has zero area
    normals = vertex_normals(vertices, faces)
    (gradient,) = torch.autograd.grad(normals.sum(), vertices)
    cases["vertex normals of a zero-area triangle"] = (
        bool(torch.isfinite(normals).all()) and bool(torch.isfinite(gradient).all()) and bool((normals[2] == 0).all())
    )

    points = torch.tensor([[[0.0, 1.0, 3.0], [0.0, 0.0, 0.0]]], requires_grad=True)
    camera = torch.tensor([[0.0, 1.0, 3.0]], requires_grad=True)
    directions = view_directions(points, camera)
    gradients = torch.autograd.grad(directions.sum(), [points, camera])
    cases["view direction from a point at the camera centre"] = bool((directions[0, 0] == 0).all()) and all(
        bool(torch.isfinite(g).all()) for g in gradients
    )

    # Two bones, half the weight each; bone 1 turns the normal x by pi about z to -x: the blend is 0.
    transforms = torch.eye(4).repeat(1, 2, 1, 1)
    angle = torch.tensor(math.pi, requires_grad=True)
    transforms = transforms.clone()
    transforms[0, 1, :2, :2] = torch.stack(
        [torch.stack([torch.cos(angle), -torch.sin(angle)]), torch.stack([torch.sin(angle), torch.cos(angle)])]
    )
    skinned = skin_directions(torch.tensor([[1.0, 0.0, 0.0]]), torch.tensor([[0.5, 0.5]]), transforms)
    (gradient,) = torch.autograd.grad(skinned.sum(), angle)
    cases["skinned normal blended to zero length"] = (
        bool(torch.isfinite(skinned).all()) and float(skinned.detach().norm()) < 1e-6 and bool(torch.isfinite(gradient))
    )

    texel = geometry.surface.positions[7:8].clone()
    centre = texel.clone().requires_grad_(True)
    latent = model.decode_identity(0).detach().requires_grad_(True)
    out = model(latent, geometry, BodyPose.rest(body.num_bones), centre)
    gradients = torch.autograd.grad(out.dynamic.colors.sum(), [centre, latent])
    cases["model viewed from a camera centred on a texel"] = outputs_finite(out) and all(
        bool(torch.isfinite(g).all()) for g in gradients
    )

    for name, ok in cases.items():
        check(AREA, name, "zero vector (not NaN), finite gradients", "as expected" if ok else "NaN or wrong", ok)
