"""Procedural motions, checked on the posed bodies (joints and mesh from the body model's own
forward kinematics), on Anny's A-pose and on a T-pose stick body in the SMPL layout."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pghm.body import lbs
from pghm.body.model import BodyModel, RestBody
from pghm.errors import PghmError
from pghm.motion import procedural
from pghm.motion.motion import Motion
from pghm.motion.procedural import PROCEDURAL_MOTIONS, procedural_motion

FPS = 30.0

SMPL_JOINTS = {
    # name: (parent, T-pose head in metres: y up, facing +z, left +x; roughly SMPL's template)
    "pelvis": (None, (0.0, 0.93, 0.0)),
    "left_hip": ("pelvis", (0.07, 0.84, 0.0)),
    "right_hip": ("pelvis", (-0.07, 0.84, 0.0)),
    "spine1": ("pelvis", (0.0, 1.04, -0.01)),
    "left_knee": ("left_hip", (0.1, 0.47, 0.01)),
    "right_knee": ("right_hip", (-0.1, 0.47, 0.01)),
    "spine2": ("spine1", (0.0, 1.17, 0.0)),
    "left_ankle": ("left_knee", (0.09, 0.08, -0.03)),
    "right_ankle": ("right_knee", (-0.09, 0.08, -0.03)),
    "spine3": ("spine2", (0.0, 1.23, 0.01)),
    "left_foot": ("left_ankle", (0.11, 0.02, 0.1)),
    "right_foot": ("right_ankle", (-0.11, 0.02, 0.1)),
    "neck": ("spine3", (0.0, 1.44, -0.01)),
    "left_collar": ("spine3", (0.08, 1.35, 0.0)),
    "right_collar": ("spine3", (-0.08, 1.35, 0.0)),
    "head": ("neck", (0.0, 1.52, 0.03)),
    "left_shoulder": ("left_collar", (0.18, 1.38, -0.01)),
    "right_shoulder": ("right_collar", (-0.18, 1.38, -0.01)),
    "left_elbow": ("left_shoulder", (0.44, 1.38, -0.03)),
    "right_elbow": ("right_shoulder", (-0.44, 1.38, -0.03)),
    "left_wrist": ("left_elbow", (0.7, 1.38, -0.02)),
    "right_wrist": ("right_elbow", (-0.7, 1.38, -0.02)),
}
STICK_EXTRA_POINTS = {
    # Mesh points beyond the joints: soles (heel, ball, toe tip), finger tips, head top.
    "left_ankle": [(0.09, 0.0, -0.07), (0.1, 0.0, 0.08)],
    "right_ankle": [(-0.09, 0.0, -0.07), (-0.1, 0.0, 0.08)],
    "left_foot": [(0.11, 0.0, 0.16)],
    "right_foot": [(-0.11, 0.0, 0.16)],
    "left_wrist": [(0.88, 1.38, -0.02)],
    "right_wrist": [(-0.88, 1.38, -0.02)],
    "head": [(0.0, 1.75, 0.02)],
}


class StickBody(BodyModel):
    """A T-pose skeleton in the SMPL layout, its mesh a point on every joint and limb tip,
    each skinned to one bone: independent of both real backends."""

    def __init__(self) -> None:
        super().__init__()
        self.name = "stick"
        self.bone_names = list(SMPL_JOINTS)
        self.parents = [-1 if p is None else self.bone_names.index(p) for p, _ in SMPL_JOINTS.values()]
        self.joint_map = {name: i for i, name in enumerate(self.bone_names)}
        self.shape_names = ["scale"]
        points, bones = [], []
        for bone, (name, (_, head)) in enumerate(SMPL_JOINTS.items()):
            for point in [head, *STICK_EXTRA_POINTS.get(name, [])]:
                points.append(point)
                bones.append(bone)
        self._points = torch.tensor(points)
        weights = torch.nn.functional.one_hot(torch.tensor(bones), len(self.bone_names)).float()
        faces = torch.tensor([[0, 1, 2]])
        self._register_topology(faces, faces, torch.zeros(3, 2), weights)

    def default_shape(self) -> torch.Tensor:
        return torch.ones(1)

    def rest(self, shape: torch.Tensor | None = None, dtype: torch.dtype = torch.float32) -> RestBody:
        scale = self.check_shape(shape)[0]
        joints = torch.tensor([head for _, head in SMPL_JOINTS.values()])
        return RestBody((scale * self._points).to(dtype), (scale * joints).to(dtype))


@pytest.fixture(scope="module")
def stick():
    return StickBody()


@pytest.fixture(scope="module", params=["anny", "stick"])
def any_body(request, body, stick):
    return body if request.param == "anny" else stick


def posed_joints(body: BodyModel, motion: Motion) -> np.ndarray:
    """(F, J, 3) posed joint heads: A_j applied to the rest head (float64)."""
    rest = body.rest()
    joints = rest.joints.double()
    transforms = body.bone_transforms(motion.pose().to(torch.float64), joints)
    return (transforms[..., :3, :3] @ joints[:, :, None])[..., 0].numpy() + transforms[..., :3, 3].numpy()


def posed_vertices(body: BodyModel, motion: Motion, mask: np.ndarray | None = None) -> np.ndarray:
    """(F, V', 3) posed mesh vertices (those of ``mask``, default all), skinned by the body."""
    rest = body.rest()
    keep = torch.ones(body.num_vertices, dtype=torch.bool) if mask is None else torch.from_numpy(mask)
    transforms = body.bone_transforms(motion.pose(), rest.joints)
    return lbs(rest.vertices[keep], body.skin_weights[keep], transforms).numpy()


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    cos = (a * b).sum(-1) / np.linalg.norm(a, axis=-1) / np.linalg.norm(b, axis=-1)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def limb(joints: np.ndarray, body: BodyModel, start: str, end: str) -> np.ndarray:
    return joints[:, body.joint_map[end]] - joints[:, body.joint_map[start]]


def bend_deg(joints: np.ndarray, body: BodyModel, a: str, b: str, c: str) -> np.ndarray:
    """Flexion at joint b: the angle between the a->b and b->c segments (0 = straight)."""
    return angle_deg(limb(joints, body, a, b), limb(joints, body, b, c))


def facing(joints: np.ndarray, body: BodyModel) -> np.ndarray:
    """(F, 3) horizontal forward direction from the posed hips: left x up."""
    left = limb(joints, body, "right_hip", "left_hip")
    forward = np.cross(left, [0.0, 1.0, 0.0])
    return forward / np.linalg.norm(forward, axis=-1, keepdims=True)


@pytest.fixture(scope="module")
def anny_clips(body):
    """Every registered motion on Anny, short clips (generated once for the module)."""
    return {
        name: procedural_motion(name, body, frames=48 if name != "stress" else 184, fps=FPS)
        for name in PROCEDURAL_MOTIONS
    }


def test_every_motion_is_a_valid_clip_for_the_body(body, anny_clips):
    for name, motion in anny_clips.items():
        assert motion.body == "anny" and motion.bone_names == body.bone_names
        assert motion.rotations.shape == (motion.num_frames, body.num_bones, 3) and motion.fps == FPS
        assert motion.source == f"procedural:{name}"
        assert np.isfinite(motion.rotations).all() and np.isfinite(motion.translation).all()
        # Bones outside the canonical joints (twist segments, fingers, toes) are never moved.
        moved = np.flatnonzero(np.abs(motion.rotations).max(0).max(-1) > 0)
        assert set(moved) <= set(body.joint_map.values()), name


def test_registry_defaults_and_errors(body):
    assert procedural_motion("walk", body).num_frames == procedural.DEFAULT_FRAMES
    with pytest.raises(PghmError, match="unknown procedural motion 'dance'"):
        procedural_motion("dance", body)
    with pytest.raises(PghmError, match=f"1 to {procedural.MAX_PROCEDURAL_FRAMES} frames"):
        procedural_motion("walk", body, frames=0)
    with pytest.raises(PghmError, match="fps"):
        procedural_motion("walk", body, frames=4, fps=-1.0)


FLOOR_TOL_M = 1e-3  # float32 skinning round-off is ~1e-6 m; a millimetre is invisible


def test_feet_rest_on_the_floor_in_every_frame(body, anny_clips):
    """The lowest point of the lower legs (rest height below the knees) touches the rest floor."""
    rest = body.rest()
    floor = rest.vertices[:, 1].min().item()
    lower_legs = (rest.vertices[:, 1] < rest.joints[body.joint_map["left_knee"], 1]).numpy()
    for name, motion in anny_clips.items():
        lowest = posed_vertices(body, motion, lower_legs)[..., 1].min(-1)
        np.testing.assert_allclose(lowest, floor, atol=FLOOR_TOL_M, err_msg=name)


def test_walk_goes_forward_at_walking_speed(any_body):
    motion = procedural.walk_cycle(any_body, frames=64, fps=FPS)
    joints = posed_joints(any_body, motion)
    travel = motion.translation[-1] - motion.translation[0]
    # The walker goes where it faces (the pelvis's twist averages out over whole cycles).
    assert angle_deg(travel, facing(joints, any_body).mean(0)) < 5.0
    speed = np.linalg.norm(travel) / motion.duration
    assert 0.7 < speed < 1.6  # metres per second: a normal walk, not a shuffle or a run
    knee = bend_deg(joints, any_body, "left_hip", "left_knee", "left_ankle")
    assert knee.max() > 45.0 and knee.min() < 15.0  # flexes in swing, straightens in stance


def test_walking_feet_do_not_slide(body):
    motion = procedural.walk_cycle(body, frames=64, fps=FPS)
    rest = body.rest()
    floor = rest.vertices[:, 1].min().item()
    vertices = posed_vertices(body, motion, (rest.vertices[:, 1] < floor + 0.1).numpy())
    # Points within 5 mm of the floor in two consecutive frames are in contact and must stay put.
    touching = (vertices[:-1, :, 1] < floor + 0.005) & (vertices[1:, :, 1] < floor + 0.005)
    slide = np.linalg.norm(np.diff(vertices[..., [0, 2]], axis=0), axis=-1)[touching]
    assert touching.sum() > 100
    assert np.median(slide) < 0.002 and np.percentile(slide, 90) < 0.01  # metres per frame; walking moves 0.035


def test_turning_walk_ends_facing_the_new_heading(body):
    turn = 90.0
    motion = procedural.walk_cycle(body, frames=64, fps=FPS, turn_deg=turn)
    forward = facing(posed_joints(body, motion), body)
    heading = np.degrees(np.arctan2(forward[:, 0], forward[:, 2]))
    # The pelvis twists by up to GAIT_PELVIS_TWIST_DEG either way on top of the heading.
    assert abs(heading[-1] - heading[0] - turn) < 2 * procedural.GAIT_PELVIS_TWIST_DEG + 1.0


def test_walking_arms_hang_relaxed_whatever_the_rest_pose(any_body):
    """Anny rests in an A-pose with bent elbows, the stick body in a T-pose: both walk with
    arms down and elbows slightly bent."""
    joints = posed_joints(any_body, procedural.walk_cycle(any_body, frames=40, fps=FPS))
    for side in ("left", "right"):
        upper = limb(joints, any_body, f"{side}_shoulder", f"{side}_elbow")
        assert angle_deg(upper, np.array([0.0, -1.0, 0.0])).max() < 35.0
        elbow = bend_deg(joints, any_body, f"{side}_shoulder", f"{side}_elbow", f"{side}_wrist")
        assert elbow.min() > procedural.GAIT_ELBOW_DEG - 1.0 and elbow.max() < 40.0


def test_arm_raises_go_overhead_sideways_then_forwards(any_body):
    frames = 48
    motion = procedural.arm_raises(any_body, frames=frames, fps=FPS)
    joints = posed_joints(any_body, motion)
    head = joints[:, any_body.joint_map["head"]]
    sideways, forwards = frames // 4, 3 * frames // 4
    for side, sign in (("left", 1.0), ("right", -1.0)):
        wrist = joints[:, any_body.joint_map[f"{side}_wrist"]]
        shoulder = joints[:, any_body.joint_map[f"{side}_shoulder"]]
        for frame in (sideways, forwards):
            assert wrist[frame, 1] > head[frame, 1] + 0.2  # hands well above the head
            elbow = bend_deg(joints[frame : frame + 1], any_body, f"{side}_shoulder", f"{side}_elbow", f"{side}_wrist")
            assert elbow[0] < procedural.ARM_RAISE_ELBOW_DEG + 2.0
        # Sideways: in the shoulders' plane; forwards: passing in front.
        assert abs(wrist[sideways, 2] - shoulder[sideways, 2]) < 0.1
        assert sign * (wrist[sideways, 0] - shoulder[sideways, 0]) > 0.1
        quarter = frames // 2 + frames // 8
        assert wrist[quarter, 2] - shoulder[quarter, 2] > 0.3


MIRROR_TOL_M = 0.01  # Anny's rest skeleton is symmetric to ~1 mm; posing adds lever arms


@pytest.mark.parametrize("name", ["arm_raises", "squat", "stress"])
def test_symmetric_motions_are_mirror_images(body, anny_clips, name):
    """Left and right limbs move as mirror images (swing axes mirror, twists flip sign)."""
    joints = posed_joints(body, anny_clips[name])
    limbs = ("shoulder", "elbow", "wrist", "hip", "knee", "ankle")
    if name == "stress":
        # Arms only (the legs take turns), outside the trunk's sideways bends and twists.
        slots = procedural._stress_slots()
        slot = (np.arange(len(joints)) * len(slots)) // len(joints)
        joints = joints[[slots[s][0] not in ("spine", "neck") for s in slot]]
        limbs = ("collar", "shoulder", "elbow", "wrist")
    mirror = np.array([-1.0, 1.0, 1.0])
    for joint in limbs:
        left = joints[:, body.joint_map[f"left_{joint}"]]
        right = joints[:, body.joint_map[f"right_{joint}"]]
        np.testing.assert_allclose(left, right * mirror, atol=MIRROR_TOL_M, err_msg=f"{name} {joint}")


def test_squat_goes_down_with_feet_planted(body, anny_clips):
    motion = anny_clips["squat"]
    joints = posed_joints(body, motion)
    pelvis = joints[:, body.joint_map["pelvis"]]
    assert pelvis[0, 1] - pelvis[:, 1].min() > 0.3  # a deep squat
    for side in ("left", "right"):
        ankle = joints[:, body.joint_map[f"{side}_ankle"]]
        drift = np.linalg.norm(ankle[:, [0, 2]] - ankle[:1, [0, 2]], axis=-1)
        assert drift.max() < 0.02  # metres: the feet stay where they stood


def test_turn_in_place_turns_on_the_spot(body, anny_clips):
    motion = anny_clips["turn_in_place"]
    forward = facing(posed_joints(body, motion), body)
    turned = np.degrees(np.arctan2(forward[-1, 0], forward[-1, 2]) - np.arctan2(forward[0, 0], forward[0, 2]))
    assert abs((turned % 360.0) - 180.0) < 1.0
    assert np.abs(motion.translation[:, [0, 2]]).max() < 1e-6


def test_stress_sweeps_joints_past_their_limits(body, anny_clips):
    joints = posed_joints(body, anny_clips["stress"])
    overshoot = procedural.STRESS_OVERSHOOT
    limits = {(group, move): (lo, hi) for group, move, lo, hi in procedural.STRESS_SWEEPS}
    for side in ("left", "right"):
        knee = bend_deg(joints, body, f"{side}_hip", f"{side}_knee", f"{side}_ankle")
        elbow = bend_deg(joints, body, f"{side}_shoulder", f"{side}_elbow", f"{side}_wrist")
        # Past the anatomical maximum (the sampled frames may miss the exact peak).
        assert knee.max() > limits["knee", "flexion"][1]
        assert elbow.max() > limits["elbow", "flexion"][1]
        # Sideways elevation above the horizontal, beyond vertical: the elbow rises above the shoulder.
        shoulder_to_elbow = limb(joints, body, f"{side}_shoulder", f"{side}_elbow")
        assert shoulder_to_elbow[:, 1].max() > 0.9 * np.linalg.norm(shoulder_to_elbow[0])
    # The spine bends forward well past horizontal-ish: the neck drops towards the hips' level.
    neck_height = joints[:, body.joint_map["neck"], 1] - joints[:, body.joint_map["pelvis"], 1]
    assert neck_height.min() < 0.5 * neck_height[0]
    assert overshoot > 1.0
