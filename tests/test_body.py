"""The body model interface, forward kinematics and skinning against independent truths."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from geometry import rodrigues

from pghm.body import BodyPose, PoseError, lbs
from pghm.body.anny_backend import ANNY_TO_WORLD
from pghm.body.model import CANONICAL_JOINTS


def naive_transforms(rotvecs: np.ndarray, joints: np.ndarray, parents: list[int], translation: np.ndarray):
    """Skinning transforms by recursion over explicit 4x4 matrices (float64, one bone at a time)."""
    num = len(parents)
    world = [None] * num
    for j in range(num):
        local = np.eye(4)
        local[:3, :3] = rodrigues(rotvecs[j])
        local[:3, 3] = joints[j] - (joints[parents[j]] if parents[j] >= 0 else -translation)
        world[j] = local if parents[j] < 0 else world[parents[j]] @ local
    out = np.stack(world)
    unjoint = np.tile(np.eye(4), (num, 1, 1))
    unjoint[:, :3, 3] = -joints
    return out @ unjoint


def random_pose(body, seed: int, scale: float = 0.5, dtype=torch.float64) -> BodyPose:
    gen = torch.Generator().manual_seed(seed)
    rot = torch.randn(1, body.num_bones, 3, generator=gen, dtype=dtype) * scale
    trans = torch.randn(1, 3, generator=gen, dtype=dtype)
    return BodyPose(rot, trans)


def test_anny_topology(body, rest):
    assert body.num_vertices == 13718 and body.faces.shape == (27420, 3)
    assert body.uv_faces.shape == body.faces.shape
    assert body.num_bones == 104 and len(body.parents) == 104 and body.parents[0] == -1
    assert rest.vertices.shape == (13718, 3) and rest.joints.shape == (104, 3)
    torch.testing.assert_close(body.skin_weights.sum(-1), torch.ones(body.num_vertices))
    assert set(body.joint_map) <= set(CANONICAL_JOINTS)


def test_anny_frame_is_y_up_facing_z(body, rest):
    joints = {name: rest.joints[index] for name, index in body.joint_map.items()}
    height = rest.vertices[:, 1].max() - rest.vertices[:, 1].min()
    assert 1.4 < height < 2.0  # an adult, in metres
    assert joints["head"][1] > joints["pelvis"][1] > joints["left_knee"][1] > joints["left_ankle"][1]
    assert joints["left_shoulder"][0] > 0 > joints["right_shoulder"][0]  # left is +x
    nose_tip_z = rest.vertices[rest.vertices[:, 1] > joints["head"][1], 2].max()
    assert nose_tip_z > joints["head"][2]  # the face looks along +z


def test_forward_kinematics_matches_recursive_reference(body, rest):
    pose = random_pose(body, seed=1)
    joints = rest.joints.double()
    got = body.bone_transforms(pose, joints)[0].numpy()
    want = naive_transforms(pose.rotations[0].numpy(), joints.numpy(), body.parents, pose.translation[0].numpy())
    np.testing.assert_allclose(got, want, atol=1e-12)


def test_skinning_matches_anny(body):
    """Our FK + LBS, fed to Anny's own skinning through its 'world' parameterisation."""
    anny_model = body._anny
    rest64 = body.rest(dtype=torch.float64)
    pose = random_pose(body, seed=2)
    transforms = body.bone_transforms(pose, rest64.joints)
    to_anny = torch.eye(4, dtype=torch.float64)
    to_anny[:3, :3] = ANNY_TO_WORLD.double().T
    rest_bone_poses = anny_model()["rest_bone_poses"]
    posed_bone_poses = to_anny @ transforms @ to_anny.T @ rest_bone_poses
    theirs = anny_model(pose_parameters=posed_bone_poses, pose_parameterization="world")["vertices"]
    ours = body.posed_vertices(pose, rest64)
    # Anny's stored weights sum to one only to float32 precision; we renormalise them.
    torch.testing.assert_close(ours, theirs @ to_anny[:3, :3], atol=1e-6, rtol=0)


def test_rest_pose_is_identity(body, rest):
    transforms = body.bone_transforms(body.rest_pose(), rest.joints)
    posed = lbs(rest.vertices, body.skin_weights, transforms)[0]
    assert torch.equal(posed, rest.vertices)  # bit-exact, by construction (see pghm.body.skinning)


def test_rotating_a_bone_moves_only_its_subtree(body, rest):
    elbow = body.joint_map["left_elbow"]
    rotations = torch.zeros(1, body.num_bones, 3)
    rotations[0, elbow] = torch.tensor([0.0, 0.0, 1.2])
    pose = BodyPose(rotations, torch.zeros(1, 3))
    posed = body.posed_vertices(pose, rest)[0]
    subtree = {elbow}
    for bone, parent in enumerate(body.parents):
        if parent in subtree:
            subtree.add(bone)
    outside = body.skin_weights[:, sorted(subtree)].sum(-1) == 0
    inside = body.skin_weights[:, sorted(subtree)].sum(-1) > 0.999
    assert (posed[outside] - rest.vertices[outside]).abs().max() < 1e-6
    # Points fully on the forearm keep their distance to the elbow joint (a rigid rotation).
    centre = rest.joints[elbow]
    before = (rest.vertices[inside] - centre).norm(dim=-1)
    after = (posed[inside] - centre).norm(dim=-1)
    assert (before - after).abs().max() < 1e-5
    assert (posed[inside] - rest.vertices[inside]).norm(dim=-1).max() > 0.05


def test_translation_moves_everything(body, rest):
    shift = torch.tensor([[0.3, -0.2, 1.5]])
    pose = BodyPose(torch.zeros(1, body.num_bones, 3), shift)
    posed = body.posed_vertices(pose, rest)[0]
    torch.testing.assert_close(posed, rest.vertices + shift, atol=1e-6, rtol=0)


def test_batched_poses_equal_one_at_a_time(body, rest):
    rot = torch.randn(3, body.num_bones, 3) * 0.3
    trans = torch.randn(3, 3)
    batched = body.posed_vertices(BodyPose(rot, trans), rest)
    for b in range(3):
        single = body.posed_vertices(BodyPose(rot[b : b + 1], trans[b : b + 1]), rest)
        torch.testing.assert_close(batched[b : b + 1], single, atol=1e-6, rtol=0)


def test_shape_changes_the_body(body):
    tall = body.rest(torch.tensor([0.5, 0.5, 0.5, 0.5, 1.0, 0.5]))
    short = body.rest(torch.tensor([0.5, 0.5, 0.5, 0.5, 0.0, 0.5]))
    height = lambda r: r.vertices[:, 1].max() - r.vertices[:, 1].min()  # noqa: E731
    assert height(tall) > height(short) + 0.1


@pytest.mark.parametrize(
    "rotations, translation, field",
    [
        (np.zeros((103, 3)), None, "rotations"),
        (np.zeros((104, 4)), None, "rotations"),
        (np.zeros((2, 104, 3)), np.zeros((3, 3)), "translation"),
        (np.full((104, 3), np.nan), None, "rotations"),
        (np.zeros((104, 3)), [0.0, np.inf, 0.0], "translation"),
        ([["a"] * 3] * 104, None, "rotations"),
    ],
)
def test_bad_poses_name_the_field(body, rotations, translation, field):
    with pytest.raises(PoseError, match=f"'{field}'"):
        body.pose_from_arrays(rotations, translation)
    assert issubclass(PoseError, ValueError)


def test_good_pose_arrays_are_batched(body):
    pose = body.pose_from_arrays(np.zeros((104, 3)), [0.0, 1.0, 0.0])
    assert pose.rotations.shape == (1, 104, 3) and pose.translation.shape == (1, 3)


def test_bad_shape_is_rejected(body):
    with pytest.raises(PoseError, match="body shape"):
        body.rest(torch.zeros(5))


def test_lbs_of_a_batch_is_each_pose_blended_point_by_point():
    """A batch of poses through the one wide product against sum_j w_j A_j [x; 1], point by point."""
    gen = torch.Generator().manual_seed(7)
    batch, bones, points = 3, 5, 11
    transforms = torch.eye(4, dtype=torch.float64).repeat(batch, bones, 1, 1)
    transforms[..., :3, :] += 0.3 * torch.randn(batch, bones, 3, 4, generator=gen, dtype=torch.float64)
    weights = torch.rand(points, bones, generator=gen, dtype=torch.float64)
    weights /= weights.sum(-1, keepdim=True)
    x = torch.randn(points, 3, generator=gen, dtype=torch.float64)
    expected = torch.zeros(batch, points, 3, dtype=torch.float64)
    for b in range(batch):
        for n in range(points):
            blended = sum(weights[n, j] * transforms[b, j] for j in range(bones))
            expected[b, n] = (blended @ torch.cat([x[n], torch.ones(1, dtype=torch.float64)]))[:3]
    torch.testing.assert_close(lbs(x, weights, transforms), expected, atol=1e-12, rtol=0)
