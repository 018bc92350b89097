"""UV maps: texel skinning, U_theta, the view-direction map, normals."""

from __future__ import annotations

import pytest
import torch

from pghm.body import BodyPose
from pghm.uv.maps import (
    gather_from_map,
    posed_points,
    scatter_to_map,
    texel_surface,
    uv_position_map,
    vertex_normals,
    view_direction_map,
    view_directions,
)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_skinned_texels_equal_blend_of_skinned_vertices(body, atlas128, seed):
    gen = torch.Generator().manual_seed(seed)
    rest = body.rest(dtype=torch.float64)
    pose = BodyPose(
        torch.randn(2, body.num_bones, 3, generator=gen, dtype=torch.float64) * 0.6,
        torch.randn(2, 3, generator=gen, dtype=torch.float64),
    )
    transforms = body.bone_transforms(pose, rest.joints)
    texels = posed_points(texel_surface(body, atlas128, rest), transforms)
    vertices = body.posed_vertices(pose, rest)  # (B, V, 3)
    corners = vertices[:, body.faces[atlas128.face]]  # (B, N, 3, 3)
    blended = (corners * atlas128.barycentric.double()[None, :, :, None]).sum(2)
    assert (texels - blended).abs().max() < 1e-10  # float64: the same sum in another order
    # The same in float32, the precision the model runs at.
    rest32 = body.rest()
    texels32 = posed_points(texel_surface(body, atlas128, rest32), transforms.float())
    assert (texels32.double() - blended).abs().max() < 1e-5


def test_rest_pose_returns_canonical_points_exactly(body, atlas128, rest):
    surface = texel_surface(body, atlas128, rest)
    transforms = body.bone_transforms(body.rest_pose(), rest.joints)
    assert torch.equal(posed_points(surface, transforms)[0], surface.positions)


def test_position_map_layout(body, atlas128, rest):
    surface = texel_surface(body, atlas128, rest)
    pose = BodyPose(torch.randn(1, body.num_bones, 3) * 0.3, torch.zeros(1, 3))
    transforms = body.bone_transforms(pose, rest.joints)
    maps = uv_position_map(surface, atlas128, transforms)
    assert maps.shape == (1, 3, 128, 128)
    assert (maps[0].abs().sum(0)[~atlas128.mask] == 0).all()
    row, col = atlas128.texel_rc[17]
    torch.testing.assert_close(maps[0, :, row, col], posed_points(surface, transforms)[0, 17])
    torch.testing.assert_close(gather_from_map(maps, atlas128), posed_points(surface, transforms))


def test_scatter_gather_round_trip(atlas128):
    values = torch.randn(2, atlas128.num_texels, 5)
    assert torch.equal(gather_from_map(scatter_to_map(values, atlas128), atlas128), values)


def test_view_directions_point_at_the_camera(body, atlas128, rest):
    surface = texel_surface(body, atlas128, rest)
    transforms = body.bone_transforms(body.rest_pose(), rest.joints)
    camera = torch.tensor([[0.0, 0.2, 3.0]])
    directions, normals = view_direction_map(surface, atlas128, transforms, camera)
    dirs = gather_from_map(directions, atlas128)[0]
    torch.testing.assert_close(dirs.norm(dim=-1), torch.ones(len(dirs)))
    expected = camera - surface.positions
    torch.testing.assert_close(dirs, expected / expected.norm(dim=-1, keepdim=True))
    posed_normals = gather_from_map(normals, atlas128)[0]
    torch.testing.assert_close(posed_normals, surface.normals, atol=1e-6, rtol=0)
    # Seen from the front, the front of the torso faces the camera.
    chest = rest.joints[body.joint_map["spine3"]]
    front = ((surface.positions - chest).abs() < torch.tensor([0.15, 0.1, 1.0])).all(-1)
    front &= surface.positions[:, 2] > chest[2] + 0.08  # the front of the ribcage
    assert ((dirs[front] * posed_normals[front]).sum(-1) > 0).float().mean() > 0.97


def test_zero_length_vectors_do_not_become_nan():
    points = torch.zeros(1, 4, 3, requires_grad=True)
    directions = view_directions(points, torch.zeros(1, 3))
    assert torch.equal(directions, torch.zeros(1, 4, 3))
    directions.sum().backward()
    assert torch.isfinite(points.grad).all()
    degenerate = torch.zeros(3, 3)  # one triangle collapsed to a point
    normals = vertex_normals(degenerate, torch.tensor([[0, 1, 2]]))
    assert torch.equal(normals, torch.zeros(3, 3))


def test_canonical_normals_point_outwards(body, atlas128, rest):
    surface = texel_surface(body, atlas128, rest)
    torch.testing.assert_close(surface.normals.norm(dim=-1), torch.ones(atlas128.num_texels))
    # On the chest, normals point away from the body's vertical axis.
    chest_height = rest.joints[body.joint_map["spine3"], 1]
    torso = ((surface.positions[:, 1] - chest_height).abs() < 0.1) & (surface.positions[:, 0].abs() < 0.12)
    radial = (surface.positions[torso] - rest.joints[body.joint_map["spine3"]]) * torch.tensor([1.0, 0.0, 1.0])
    assert ((radial * surface.normals[torso]).sum(-1) > 0).float().mean() > 0.95
    weights_sum = surface.weights.sum(-1)
    torch.testing.assert_close(weights_sum, torch.ones_like(weights_sum))


def test_offsets_are_rotated_with_the_surface(body, atlas128):
    """An offset turns with the bone that carries its texel, and keeps its length."""
    rest = body.rest(dtype=torch.float64)
    surface = texel_surface(body, atlas128, rest)
    elbow = body.joint_map["left_elbow"]
    rotations = torch.zeros(1, body.num_bones, 3, dtype=torch.float64)
    rotations[0, elbow] = torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64)
    transforms = body.bone_transforms(BodyPose(rotations, torch.zeros(1, 3, dtype=torch.float64)), rest.joints)
    offsets = surface.normals * 0.02
    moved = (posed_points(surface, transforms, offsets) - posed_points(surface, transforms))[0]
    subtree = {elbow}
    for bone, parent in enumerate(body.parents):
        if parent in subtree:
            subtree.add(bone)
    in_subtree = surface.weights[:, sorted(subtree)].sum(-1)
    forearm, elsewhere = in_subtree > 1 - 1e-9, in_subtree < 1e-9
    assert forearm.sum() > 100 and elsewhere.sum() > 100
    rotation = transforms[0, elbow, :3, :3]
    torch.testing.assert_close(moved[forearm], offsets[forearm] @ rotation.T)
    torch.testing.assert_close(moved[elsewhere], offsets[elsewhere])
