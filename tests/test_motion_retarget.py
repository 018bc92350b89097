"""Retargeting the real BVH clips onto Anny and onto a T-pose body, checked against the clips'
bone directions from a forward kinematics written here, independently of pghm.motion.bvh."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import roma
import torch
from test_motion_procedural import StickBody, angle_deg, facing, posed_joints, posed_vertices

from pghm.errors import MotionFileError
from pghm.motion.bvh import load_bvh
from pghm.motion.motion import Motion
from pghm.motion.retarget import (
    RIG_MAPS,
    clip_facing,
    detect_rig,
    detect_units,
    import_bvh,
    resample,
    retarget_bvh,
)

MOTION_DIR = Path(__file__).resolve().parent.parent / "assets" / "motion"
CLIPS = ("mixamo_walk_69f.bvh", "mocapbank_455f.bvh")

# Bones compared: (name, canonical start, canonical end) and the clip joints they correspond
# to in each rig, written out here rather than taken from the retargeter's maps.
BONES = [
    (f"{side} {bone}", f"{side}_{a}", f"{side}_{b}")
    for side in ("left", "right")
    for bone, a, b in (
        ("upper arm", "shoulder", "elbow"),
        ("forearm", "elbow", "wrist"),
        ("thigh", "hip", "knee"),
        ("shin", "knee", "ankle"),
    )
] + [("spine", "pelvis", "neck")]
MIXAMO_SUFFIXES = (
    ("shoulder", "Arm"),
    ("elbow", "ForeArm"),
    ("wrist", "Hand"),
    ("hip", "UpLeg"),
    ("knee", "Leg"),
    ("ankle", "Foot"),
)
MOCAPBANK_SUFFIXES = (
    ("shoulder", "Shoulder"),
    ("elbow", "Elbow"),
    ("wrist", "Wrist"),
    ("hip", "Hip"),
    ("knee", "Knee"),
    ("ankle", "Ankle"),
)
CLIP_JOINTS = {
    "mixamo_walk_69f.bvh": {
        **{f"{s}_{j}": f"mixamorig:{S}{n}" for s, S in (("left", "Left"), ("right", "Right"))
           for j, n in MIXAMO_SUFFIXES},
        "pelvis": "mixamorig:Hips",
        "neck": "mixamorig:Neck",
    },
    "mocapbank_455f.bvh": {
        **{f"{s}_{j}": f"{S}{n}" for s, S in (("left", "Left"), ("right", "Right"))
           for j, n in MOCAPBANK_SUFFIXES},
        "pelvis": "Hips",
        "neck": "Neck",
    },
}  # fmt: skip

CLIP_RIGS = {"mixamo_walk_69f.bvh": "mixamo", "mocapbank_455f.bvh": "mocapbank"}
"""Each clip's rig, as assets/motion/SOURCE.md describes it."""
CLIP_UNIT_M = 0.01
"""Both clips are in centimetres (assets/motion/SOURCE.md)."""
TRANSLATION_TOL_M = 1e-5
"""Root translations of ~1 m are stored in float32 (~1e-7 m); the scale is float64."""

LIMB_TOL_DEG = 1e-3
"""Limb bones are aligned exactly by construction; float32 storage of the rotations costs ~1e-5 deg."""
SPINE_TOL_DEG = 15.0
"""pelvis -> neck sums several spine segments whose proportions differ between rigs (~4 deg)."""


def axis_rotations(axis: str, degrees: np.ndarray) -> np.ndarray:
    """(F, 3, 3) rotations about a coordinate axis, Rodrigues' formula per frame."""
    k = np.zeros((3, 3))
    i, j = {"X": (1, 2), "Y": (2, 0), "Z": (0, 1)}[axis]
    k[j, i], k[i, j] = 1.0, -1.0  # the cross-product matrix of the unit axis
    theta = np.radians(degrees)[:, None, None]
    return np.eye(3) + np.sin(theta) * k + (1.0 - np.cos(theta)) * (k @ k)


def naive_bvh_joint_positions(path: Path) -> tuple[list[str], np.ndarray]:
    """Joint names and (F, J, 3) world joint positions, by the textbook reading of BVH.

    Line by line: a joint's head is its parent's head plus the parent's world rotation
    applied to its OFFSET; its world rotation is the parent's times the product, in channel
    order, of one axis rotation per rotation channel; the root's head is its position
    channels. Float64, all frames at once.
    """
    lines = path.read_text().splitlines()
    names, parents, offsets, channels, stack = [], [], [], [], []
    motion = lines.index("MOTION")
    for line in lines[:motion]:
        words = line.split()
        if words and words[0] in ("ROOT", "JOINT"):
            parents.append(stack[-1] if stack else -1)
            names.append(words[1])
            stack.append(len(names) - 1)
            channels.append([])
        elif words and words[0] == "End":
            stack.append(None)
        elif words and words[0] == "OFFSET" and stack[-1] is not None:
            offsets.append(np.array([float(w) for w in words[1:4]]))
        elif words and words[0] == "CHANNELS":
            channels[-1] = words[2:]
        elif words and words[0] == "}":
            stack.pop()
    data = np.loadtxt(lines[motion + 3 :], ndmin=2)
    frames = len(data)
    positions = np.zeros((frames, len(names), 3))
    world: list[np.ndarray] = []
    column = 0
    for j, parent in enumerate(parents):
        rotation, translation = np.broadcast_to(np.eye(3), (frames, 3, 3)), np.tile(offsets[j], (frames, 1))
        for channel in channels[j]:
            if channel.endswith("rotation"):
                rotation = rotation @ axis_rotations(channel[0], data[:, column])
            else:
                translation[:, "XYZ".index(channel[0])] = data[:, column]
            column += 1
        if parent < 0:
            positions[:, j] = translation
            world.append(rotation)
        else:
            positions[:, j] = positions[:, parent] + world[parent] @ offsets[j]
            world.append(world[parent] @ rotation)
    return names, positions


@pytest.fixture(scope="module")
def clip_positions():
    return {name: naive_bvh_joint_positions(MOTION_DIR / name) for name in CLIPS}


@pytest.fixture(scope="module")
def stick():
    return StickBody()


@pytest.fixture(scope="module")
def anny_motions(body):
    return {name: import_bvh(MOTION_DIR / name, body) for name in CLIPS}


def bone_errors(body, motion: Motion, clip_name: str, clip_positions) -> dict[str, float]:
    """Max over frames of the angle between each body bone and the clip's, in degrees."""
    names, positions = clip_positions[clip_name]
    joints = posed_joints(body, motion)
    table = CLIP_JOINTS[clip_name]
    errors = {}
    for label, start, end in BONES:
        clip_bone = positions[:, names.index(table[end])] - positions[:, names.index(table[start])]
        body_bone = joints[:, body.joint_map[end]] - joints[:, body.joint_map[start]]
        errors[label] = float(angle_deg(clip_bone, body_bone).max())
    return errors


@pytest.mark.parametrize("clip_name", CLIPS)
@pytest.mark.parametrize("target", ["anny", "stick"])
def test_retargeted_bones_follow_the_clip(body, stick, anny_motions, clip_positions, clip_name, target):
    """Both clips face +z with their left at +x (left hips at +x, toes at +z in the files), the
    project's frame, so the clip's and the body's bone directions compare directly."""
    clip = load_bvh(MOTION_DIR / clip_name)
    np.testing.assert_array_equal(clip_facing(clip.rest_positions(), detect_rig(clip.names)[1]), np.eye(3))
    target_body = body if target == "anny" else stick
    motion = anny_motions[clip_name] if target == "anny" else retarget_bvh(clip, stick)
    assert motion.num_frames == clip.num_frames and motion.fps == 30.0
    errors = bone_errors(target_body, motion, clip_name, clip_positions)
    for label, error in errors.items():
        assert error < (SPINE_TOL_DEG if label == "spine" else LIMB_TOL_DEG), (label, error)


def driven_bones(target_body, clip_name: str) -> set[int]:
    """Body bones some joint of the clip maps to: the clip's joint names (namespace and case
    aside) looked up in its rig's name map, then the canonical names in the body's map."""
    rig_map = {name.lower(): canonical for name, canonical in RIG_MAPS[CLIP_RIGS[clip_name]].items()}
    names = [name.rsplit(":", 1)[-1].lower() for name in load_bvh(MOTION_DIR / clip_name).names]
    canonical = {rig_map[name] for name in names if name in rig_map}
    return {target_body.joint_map[name] for name in canonical if name in target_body.joint_map}


@pytest.mark.parametrize("clip_name", CLIPS)
@pytest.mark.parametrize("target", ["anny", "stick"])
def test_bones_no_clip_joint_drives_stay_exactly_at_rest(body, stick, anny_motions, clip_name, target):
    """Twist segments, extra vertebrae, fingers and toes that no clip joint maps to keep a zero
    rotation in every frame (exactly, not up to round-off), and every bone a clip joint maps
    to moves: so the set of moving bones is exactly the driven set. (On the 22-bone stick
    body the Mixamo rig drives every bone; the MocapBank rig leaves spine2 and the feet.)"""
    target_body = body if target == "anny" else stick
    motion = anny_motions[clip_name] if target == "anny" else import_bvh(MOTION_DIR / clip_name, stick)
    driven = driven_bones(target_body, clip_name)
    undriven = sorted(set(range(target_body.num_bones)) - driven)
    np.testing.assert_array_equal(motion.rotations[:, undriven], 0.0)
    moving = set(np.flatnonzero(np.abs(motion.rotations).max((0, 2)) > 0))
    assert moving == driven


def leg_length_of(at) -> float:
    """Mean over both sides of |knee - hip| + |ankle - knee|, ``at`` giving a canonical joint's
    position: the length the retargeter fits strides to (docs/motion.md, Root)."""
    return float(
        np.mean(
            [
                np.linalg.norm(at(f"{s}_knee") - at(f"{s}_hip")) + np.linalg.norm(at(f"{s}_ankle") - at(f"{s}_knee"))
                for s in ("left", "right")
            ]
        )
    )


@pytest.mark.parametrize("clip_name", CLIPS)
def test_root_trajectory_is_scaled_to_the_body(body, anny_motions, clip_positions, clip_name):
    """docs/motion.md, Root: the clip's root path in metres times s = body leg / clip leg
    (in metres), so strides fit the body's legs. Both clips already face +z with y up, so no
    axis change; frame 0 is moved above the origin and lifted by a constant, which the
    differences to frame 0 remove."""
    names, positions = clip_positions[clip_name]
    table = CLIP_JOINTS[clip_name]
    rest_joints = body.rest().joints.double().numpy()
    body_leg_m = leg_length_of(lambda joint: rest_joints[body.joint_map[joint]])
    # Rotations keep bone lengths, so the first frame's joints give the clip's rest lengths.
    clip_leg_m = leg_length_of(lambda joint: positions[0, names.index(table[joint])]) * CLIP_UNIT_M
    root_m = positions[:, 0] * CLIP_UNIT_M
    scale = body_leg_m / clip_leg_m
    motion = anny_motions[clip_name]
    expected = scale * (root_m - root_m[0])
    assert np.abs(expected).max() > 0.1, "the root travels, so a wrong scale shows"
    np.testing.assert_allclose(motion.translation - motion.translation[0], expected, atol=TRANSLATION_TOL_M, rtol=0)


def first_frame(motion: Motion) -> Motion:
    return replace(motion, rotations=motion.rotations[:1], translation=motion.translation[:1])


def test_retargeted_clips_start_on_the_floor_above_the_origin(body, anny_motions):
    floor = body.rest().vertices[:, 1].min().item()
    for name, motion in anny_motions.items():
        lowest = posed_vertices(body, first_frame(motion))[..., 1].min()
        assert abs(lowest - floor) < 1e-3, name  # metres; float32 skinning is good to ~1e-6
        np.testing.assert_array_equal(motion.translation[0, [0, 2]], 0.0)


def test_the_walker_faces_where_it_walks(body, anny_motions):
    """The Mixamo clip walks ~0.9 m along +z, turns around and walks back: the body's hips
    face its direction of travel at both ends (facing and trajectory go through the same C)."""
    motion = anny_motions["mixamo_walk_69f.bvh"]
    forward = facing(posed_joints(body, motion), body)
    velocity = np.gradient(motion.translation, axis=0) * np.array([1.0, 0.0, 1.0])
    for ends in (slice(0, 10), slice(-10, None)):
        assert angle_deg(forward[ends].mean(0), velocity[ends].mean(0)) < 20.0  # hips sway ~10 deg in a stride


def test_motion_file_round_trip(tmp_path, anny_motions):
    motion = anny_motions["mocapbank_455f.bvh"]
    motion.save(tmp_path / "clip.npz")
    loaded = Motion.load(tmp_path / "clip.npz")
    np.testing.assert_array_equal(loaded.rotations, motion.rotations)
    np.testing.assert_array_equal(loaded.translation, motion.translation)
    assert (loaded.fps, loaded.body, loaded.bone_names, loaded.source) == (
        motion.fps,
        motion.body,
        motion.bone_names,
        motion.source,
    )
    assert loaded.source == "bvh:mocapbank_455f.bvh (rig mocapbank, cm)"


def turned_clip(clip, turn: np.ndarray):
    """The same recording with the whole scene turned by ``turn`` (3, 3): offsets and root
    positions rotated, every joint rotation conjugated (Q' = T Q T^T), rewritten as Euler
    angles in each joint's own channel order."""
    values = clip.values.copy()
    local = clip.local_rotations()
    for joint, channels in enumerate(clip.channels):
        columns = list(clip.channel_columns(joint))
        rotation = [(col, ch[0]) for col, ch in zip(columns, channels) if ch.endswith("rotation")]
        order = "".join(axis for _, axis in rotation)
        turned = torch.from_numpy(turn @ local[:, joint] @ turn.T)
        values[:, [col for col, _ in rotation]] = roma.rotmat_to_euler(order, turned, degrees=True).numpy()
        position = [(col, "XYZ".index(ch[0])) for col, ch in zip(columns, channels) if ch.endswith("position")]
        if position:
            values[:, [col for col, _ in position]] = (clip.root_positions() @ turn.T)[
                :, [axis for _, axis in position]
            ]
    return replace(clip, offsets=clip.offsets @ turn.T, values=values)


@pytest.mark.parametrize("clip_name", CLIPS)
def test_rigs_facing_another_axis_give_the_same_motion(stick, clip_name):
    """A recording whose rig faces +x (turned 90 deg about y) retargets to the same motion:
    the facing is detected from the rest skeleton, and rotations and root move together."""
    clip = load_bvh(MOTION_DIR / clip_name)
    turn = roma.rotvec_to_rotmat(torch.tensor([0.0, np.pi / 2, 0.0], dtype=torch.float64)).numpy()
    turned = turned_clip(clip, turn)
    np.testing.assert_allclose(clip_facing(turned.rest_positions(), detect_rig(turned.names)[1]), turn.T, atol=1e-12)
    original, moved = retarget_bvh(clip, stick), retarget_bvh(turned, stick)
    rotation = lambda m: roma.rotvec_to_rotmat(torch.from_numpy(m.rotations).double()).numpy()  # noqa: E731
    np.testing.assert_allclose(rotation(moved), rotation(original), atol=1e-5)  # float32 storage
    np.testing.assert_allclose(moved.translation, original.translation, atol=1e-5)


def test_units_are_detected_and_cancel_out(stick):
    clip = load_bvh(MOTION_DIR / "mocapbank_455f.bvh")
    metres = replace(clip, offsets=clip.offsets / 100, values=clip.values.copy())
    metres.values[:, :3] /= 100  # the root's position channels
    assert detect_units(85.0) == "cm" and detect_units(0.8) == "m" and detect_units(900.0) == "mm"
    in_cm, in_m = retarget_bvh(clip, stick), retarget_bvh(metres, stick)
    np.testing.assert_allclose(in_m.rotations, in_cm.rotations, atol=1e-6)
    np.testing.assert_allclose(in_m.translation, in_cm.translation, atol=1e-6)
    assert in_m.source.endswith("m)") and in_cm.source.endswith("cm)")
    # Without fitting to the body, the root moves exactly as recorded, in metres.
    raw = retarget_bvh(clip, stick, scale_to_body=False)
    root = clip.root_positions()
    np.testing.assert_allclose(np.diff(raw.translation, axis=0), np.diff(root, axis=0) / 100, atol=1e-5)


def test_rig_detection():
    mixamo = ["Hips", "Spine", "Neck", "Head"] + [
        f"{s}{j}" for s in ("Left", "Right") for j in ("Arm", "ForeArm", "Hand", "UpLeg", "Leg", "Foot")
    ]
    assert detect_rig(mixamo)[0] == "mixamo"
    assert detect_rig([f"mixamorig1:{n}" for n in mixamo])[0] == "mixamo"
    name, joints = detect_rig(load_bvh(MOTION_DIR / "mocapbank_455f.bvh").names)
    assert name == "mocapbank" and joints["left_shoulder"] == 4 and "spine2" not in joints
    with pytest.raises(MotionFileError, match="unrecognised skeleton .* lacks"):
        detect_rig(["root", "pelvis", "thigh_l", "calf_l"])
    with pytest.raises(MotionFileError, match="unknown rig 'cmu'"):
        detect_rig(mixamo, rig="cmu")


def test_resampling_keeps_duration_and_interpolates_on_the_sphere(anny_motions):
    motion = anny_motions["mixamo_walk_69f.bvh"]
    half = resample(motion, 15.0)
    assert half.num_frames == 35 and half.duration == pytest.approx(motion.duration)
    rotation = lambda r: roma.rotvec_to_rotmat(torch.from_numpy(r).double())  # noqa: E731
    # Every other frame of 30 fps is a frame at 15 fps.
    torch.testing.assert_close(rotation(half.rotations), rotation(motion.rotations[::2]), atol=1e-5, rtol=0)
    double = resample(motion, 60.0)
    assert double.num_frames == 137
    # A new frame lies halfway (geodesically) between its neighbours: equal angles to both.
    mid, before, after = (rotation(double.rotations[1]), rotation(motion.rotations[0]), rotation(motion.rotations[1]))
    to_before = roma.rotmat_geodesic_distance(mid, before)
    to_after = roma.rotmat_geodesic_distance(mid, after)
    torch.testing.assert_close(to_before, to_after, atol=1e-5, rtol=0)
    np.testing.assert_allclose(double.translation[1], motion.translation[:2].mean(0), atol=1e-6)


def test_long_clips_are_converted_in_chunks_with_the_same_result(stick, monkeypatch):
    from pghm.motion import retarget

    clip = load_bvh(MOTION_DIR / "mocapbank_455f.bvh")
    whole = retarget_bvh(clip, stick)
    resampled = resample(whole, 24.0)
    monkeypatch.setattr(retarget, "CHUNK_FRAMES", 100)
    np.testing.assert_array_equal(retarget_bvh(clip, stick).rotations, whole.rotations)
    np.testing.assert_array_equal(resample(whole, 24.0).rotations, resampled.rotations)
