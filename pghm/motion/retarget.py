"""Retargeting BVH clips onto a body's skeleton, through the canonical joint names.

The clip's joints are named after a known rig (:data:`RIG_MAPS`, detected from the names);
each maps to a canonical joint (:data:`~pghm.body.model.CANONICAL_JOINTS`) that the body
maps to one of its bones. Writing G_k(t) for the clip joint's rest-relative world rotation
(:meth:`~pghm.motion.bvh.BvhClip.global_rotations`) and C for the rotation taking the clip's
axes to the project's (y up, facing +z, left +x; :func:`clip_facing`), the body bone of
canonical joint k gets the world rotation

    W_k(t) = C G_k(t) C^T S_k

where S_k is a fixed rest alignment: the minimal rotation taking the body's rest bone
direction u_k (from joint k to the next mapped joint down the chain, e.g. shoulder -> elbow)
onto the clip's rest bone direction v_k (in the project's axes, after C), so that in every
frame the body's bone points along the clip's:

    W_k(t) u_k = C G_k(t) C^T v_k.

Joints without such a direction (pelvis: S = I, as C already aligns the rigs' facing; head,
wrists, ankles, feet: the S of their nearest mapped ancestor, so they keep the clip's
rotation relative to their parent bone). Body bones that no clip joint drives (Anny's twist
segments and extra spine vertebrae, fingers) keep their parent's world rotation, i.e.
stay identity-local, and the local rotations of the pose representation follow along the
chain:

    R_b(t) = W_parent(b)(t)^T W_b(t).

The root trajectory is scaled by the ratio of leg lengths (hip -> knee -> ankle, body over
clip), which also converts the clip's units, rotated by C, moved so the clip starts above
the origin, and lifted so that in the first frame the lowest foot point rests on the floor
the rest body stands on.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np
import roma
import torch

from pghm.body import BodyModel
from pghm.errors import MotionFileError
from pghm.motion.bvh import BvhClip, load_bvh
from pghm.motion.motion import MAX_FRAMES, Motion
from pghm.motion.procedural import AXIS_EPS, FootContact, matrices_to_rotvecs


def _sided(common: dict[str, str], sided: dict[str, str]) -> dict[str, str]:
    """A rig map from its central joints and its left joints (the right ones mirrored)."""
    out = dict(common)
    for clip_name, canonical in sided.items():
        out[clip_name] = canonical
        out[clip_name.replace("Left", "Right", 1)] = canonical.replace("left_", "right_", 1)
    return out


RIG_MAPS: dict[str, dict[str, str]] = {
    "mixamo": _sided(
        {"Hips": "pelvis", "Spine": "spine1", "Spine1": "spine2", "Spine2": "spine3", "Neck": "neck", "Head": "head"},
        {
            "LeftShoulder": "left_collar",
            "LeftArm": "left_shoulder",
            "LeftForeArm": "left_elbow",
            "LeftHand": "left_wrist",
            "LeftUpLeg": "left_hip",
            "LeftLeg": "left_knee",
            "LeftFoot": "left_ankle",
            "LeftToeBase": "left_foot",
        },
    ),
    "mocapbank": _sided(
        {"Hips": "pelvis", "Chest": "spine1", "Chest2": "spine3", "Neck": "neck", "Head": "head"},
        {
            "LeftCollar": "left_collar",
            "LeftShoulder": "left_shoulder",
            "LeftElbow": "left_elbow",
            "LeftWrist": "left_wrist",
            "LeftHip": "left_hip",
            "LeftKnee": "left_knee",
            "LeftAnkle": "left_ankle",
        },
    ),
}
"""Clip joint name -> canonical joint, per rig. "mixamo": Adobe Mixamo's rig (also CMU's
names), with or without a ``mixamorig:``-style namespace. "mocapbank": the common
Hips/Chest/Chest2/LeftCollar/LeftShoulder/LeftElbow/LeftHip/LeftKnee/LeftAnkle rig, in
which LeftShoulder is the upper arm (in Mixamo's it is the collar bone)."""

REQUIRED_JOINTS = ("pelvis",) + tuple(
    f"{side}_{joint}" for side in ("left", "right") for joint in ("shoulder", "elbow", "hip", "knee", "ankle")
)
"""Canonical joints a clip must provide: the root, the limbs' bone directions, leg length."""

DIRECTION_TARGETS: dict[str, tuple[str, ...]] = {
    "spine1": ("spine2", "spine3", "neck"),
    "spine2": ("spine3", "neck"),
    "spine3": ("neck",),
    "neck": ("head",),
    **{
        f"{side}_{joint}": (f"{side}_{child}",)
        for side in ("left", "right")
        for joint, child in (
            ("collar", "shoulder"),
            ("shoulder", "elbow"),
            ("elbow", "wrist"),
            ("hip", "knee"),
            ("knee", "ankle"),
        )
    },
}
"""Canonical joint -> joints down its chain, in order of preference, whose direction from it
is the bone direction to align (the first one both the clip and the body provide)."""

UNIT_SCALES = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254}
"""Metres per file unit."""
TYPICAL_LEG_M = 0.85
"""Hip-to-ankle length of an adult: the clip's units are the ones that make its legs closest."""
CHUNK_FRAMES = 4096
"""Frames converted at a time: bounds the (F, J, 3, 3) float64 temporaries (~30 MB per
chunk for a 100-bone body) whatever the clip's length."""
FPS_SNAP = 1e-3
"""A frame rate within this (relative) of a whole number is that number: BVH files write
frame times such as 0.0333333."""
Units = Literal["auto", "m", "cm", "mm", "in"]


def strip_namespace(name: str) -> str:
    """A joint name without an exporter namespace: ``mixamorig:LeftArm`` -> ``LeftArm``."""
    return name.rsplit(":", 1)[-1]


def detect_rig(joint_names: list[str], rig: str | None = None) -> tuple[str, dict[str, int]]:
    """The rig of a clip and its canonical joints.

    Args:
        joint_names: the clip's joint names.
        rig: a key of :data:`RIG_MAPS` to use, None to pick the one matching most names
            among those providing every :data:`REQUIRED_JOINTS`.

    Returns:
        (rig name, canonical joint -> clip joint index).
    """
    if rig is not None and rig not in RIG_MAPS:
        raise MotionFileError(f"unknown rig '{rig}', expected one of {', '.join(RIG_MAPS)}")
    lookup = {strip_namespace(name).lower(): index for index, name in enumerate(joint_names)}
    candidates = RIG_MAPS if rig is None else {rig: RIG_MAPS[rig]}
    found = {}
    for name, rig_map in candidates.items():
        found[name] = {canonical: lookup[clip.lower()] for clip, canonical in rig_map.items() if clip.lower() in lookup}
    complete = {name: joints for name, joints in found.items() if all(j in joints for j in REQUIRED_JOINTS)}
    if not complete:
        shown = ", ".join(strip_namespace(n) for n in joint_names[:12]) + (", ..." if len(joint_names) > 12 else "")
        best = max(found, key=lambda name: len(found[name]))
        missing = [j for j in REQUIRED_JOINTS if j not in found[best]]
        raise MotionFileError(
            f"unrecognised skeleton (joints {shown}): closest rig '{best}' lacks "
            f"{', '.join(missing)}; known rigs: {', '.join(RIG_MAPS)}"
        )
    best = max(complete, key=lambda name: len(complete[name]))
    return best, complete[best]


def _snap_to_axis(vector: np.ndarray, allowed: np.ndarray) -> np.ndarray:
    """The signed coordinate axis, among the ``allowed`` ones (3,) bool, closest to ``vector``."""
    scores = np.where(allowed, np.abs(vector), -1.0)
    axis = int(np.argmax(scores))
    out = np.zeros(3)
    out[axis] = 1.0 if vector[axis] >= 0 else -1.0
    return out


def clip_facing(rest_positions: np.ndarray, joints: dict[str, int]) -> np.ndarray:
    """(3, 3) rotation C taking a clip's axes to the project's: its up to +y, its left to +x.

    The clip's up is the coordinate axis closest to (mean shoulder - mean hip), its left
    the remaining axis closest to (left - right) hip plus shoulder, and its forward
    left x up; rest skeletons are authored along the axes, so the snap removes the small
    asymmetries of captured skeletons. C's rows are (left, up, forward).
    """
    heads = {name: rest_positions[index] for name, index in joints.items()}
    up_raw = (heads["left_shoulder"] + heads["right_shoulder"] - heads["left_hip"] - heads["right_hip"]) / 2
    left_raw = heads["left_hip"] - heads["right_hip"] + heads["left_shoulder"] - heads["right_shoulder"]
    up = _snap_to_axis(up_raw, np.ones(3, dtype=bool))
    left = _snap_to_axis(left_raw, up == 0)
    return np.stack([left, up, np.cross(left, up)])


def rotation_between(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(3, 3) minimal rotation taking the direction ``source`` onto ``target``.

    About a = s x t by the angle between them: R = I + K + K^2 / (1 + s.t) with K the
    cross-product matrix of a (s, t unit); for opposite directions, a half turn about an
    axis perpendicular to s.
    """
    s = source / np.linalg.norm(source)
    t = target / np.linalg.norm(target)
    cos = float(s @ t)
    if cos < -1.0 + AXIS_EPS:
        perpendicular = np.cross(s, np.eye(3)[np.argmin(np.abs(s))])
        perpendicular /= np.linalg.norm(perpendicular)
        return 2.0 * np.outer(perpendicular, perpendicular) - np.eye(3)
    x, y, z = np.cross(s, t)
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + k + k @ k / (1.0 + cos)


def detect_units(length: float) -> str:
    """The metric unit (m, cm, mm) in which a leg ``length`` is closest to an adult's."""
    metric = ("m", "cm", "mm")
    return min(metric, key=lambda unit: abs(np.log(length * UNIT_SCALES[unit] / TYPICAL_LEG_M)))


def leg_length(positions: np.ndarray, joints: dict[str, int]) -> float:
    """Mean over both sides of |knee - hip| + |ankle - knee|."""
    lengths = [
        np.linalg.norm(positions[joints[f"{side}_knee"]] - positions[joints[f"{side}_hip"]])
        + np.linalg.norm(positions[joints[f"{side}_ankle"]] - positions[joints[f"{side}_knee"]])
        for side in ("left", "right")
    ]
    return float(np.mean(lengths))


def _snap_fps(fps: float) -> float:
    return float(round(fps)) if abs(fps - round(fps)) < FPS_SNAP * fps else fps


def _rest_alignments(
    body: BodyModel, body_joints: np.ndarray, clip_rest: np.ndarray, provided: dict[str, int], facing: np.ndarray
) -> dict[str, np.ndarray]:
    """S_k for every provided canonical joint k (see the module docstring)."""
    canonical_of_bone = {body.joint_map[name]: name for name in provided}
    alignment: dict[str, np.ndarray] = {}
    for bone in sorted(canonical_of_bone):
        name = canonical_of_bone[bone]
        target = next((t for t in DIRECTION_TARGETS.get(name, ()) if t in provided), None)
        if target is not None:
            u = body_joints[body.joint_map[target]] - body_joints[bone]
            v = facing @ (clip_rest[provided[target]] - clip_rest[provided[name]])
            if np.linalg.norm(u) > AXIS_EPS and np.linalg.norm(v) > AXIS_EPS:
                alignment[name] = rotation_between(u, v)
                continue
        ancestor = body.parents[bone]
        while ancestor >= 0 and ancestor not in canonical_of_bone:
            ancestor = body.parents[ancestor]
        alignment[name] = alignment[canonical_of_bone[ancestor]] if ancestor >= 0 else np.eye(3)
    return alignment


def _local_rotations(
    body: BodyModel,
    clip: BvhClip,
    provided: dict[str, int],
    alignment: dict[str, np.ndarray],
    facing: np.ndarray,
    frames: slice,
) -> np.ndarray:
    """(F', J, 3) the body's axis-angle pose rotations for the clip's ``frames``.

    W_k = C G_k C^T S_k for driven bones, W_b = W_parent(b) for the others, and
    R_b = W_parent(b)^T W_b.
    """
    global_clip = facing @ clip.global_rotations(frames) @ facing.T  # (F', Jc, 3, 3)
    driven = {body.joint_map[name]: name for name in provided}
    world = np.empty((len(global_clip), body.num_bones, 3, 3))
    local = np.empty_like(world)
    for bone, parent in enumerate(body.parents):
        parent_world = world[:, parent] if parent >= 0 else np.eye(3)
        if bone in driven:
            name = driven[bone]
            world[:, bone] = global_clip[:, provided[name]] @ alignment[name]
            local[:, bone] = np.swapaxes(parent_world, -1, -2) @ world[:, bone]
        else:
            world[:, bone] = parent_world
            local[:, bone] = np.eye(3)  # exactly: undriven bones must not drift by round-off
    return matrices_to_rotvecs(local)


def retarget_bvh(
    clip: BvhClip,
    body: BodyModel,
    *,
    shape: torch.Tensor | None = None,
    rig: str | None = None,
    units: Units = "auto",
    scale_to_body: bool = True,
    fps: float | None = None,
) -> Motion:
    """Retarget a parsed BVH clip onto ``body`` (method in the module docstring).

    Args:
        clip: the parsed file.
        body: the target body model.
        shape: the body's shape parameters (None: its default shape); sets leg length and floor.
        rig: a key of :data:`RIG_MAPS`, None to detect it from the joint names.
        units: the clip's length unit, "auto" to detect it from its leg length; used for
            the root trajectory when ``scale_to_body`` is False.
        scale_to_body: scale the root trajectory by the ratio of leg lengths (else only
            convert units), so that strides fit the body's legs.
        fps: resample to this frame rate (None keeps the clip's).

    Returns:
        the clip as a :class:`Motion` for ``body``.
    """
    try:
        rig_name, clip_joints = detect_rig(clip.names, rig)
    except MotionFileError as error:
        raise MotionFileError(f"{clip.source}: {error}") from None
    provided = {name: index for name, index in clip_joints.items() if name in body.joint_map}
    missing = [name for name in REQUIRED_JOINTS if name not in body.joint_map]
    if missing:
        raise MotionFileError(f"the {body.name} body does not map {', '.join(missing)}, which retargeting needs")
    if units not in ("auto", *UNIT_SCALES):
        raise MotionFileError(f"unknown unit '{units}', expected auto or one of {', '.join(UNIT_SCALES)}")
    clip_rest = clip.rest_positions()
    clip_leg = leg_length(clip_rest, clip_joints)
    if not clip_leg > AXIS_EPS:
        raise MotionFileError(f"{clip.source}: the skeleton's legs have zero length (hip, knee and ankle coincide)")
    rest = body.rest(shape)
    body_joints = rest.joints.detach().double().numpy()
    facing = clip_facing(clip_rest, clip_joints)

    alignment = _rest_alignments(body, body_joints, clip_rest, provided, facing)
    rotations = np.concatenate(
        [
            _local_rotations(body, clip, provided, alignment, facing, slice(start, start + CHUNK_FRAMES))
            for start in range(0, clip.num_frames, CHUNK_FRAMES)
        ]
    )

    unit = detect_units(clip_leg) if units == "auto" else units
    scale = leg_length(body_joints, body.joint_map) / clip_leg if scale_to_body else UNIT_SCALES[unit]
    root = clip.root_positions()
    translation = scale * (root - root[:1]) @ facing.T
    # Start above the origin, feet on the floor: lift frame 0's lowest foot point to it.
    translation[:, 1] += FootContact(body, rest).lift(rotations[:1], translation[:1])[0]

    motion = Motion(
        rotations,
        translation,
        _snap_fps(clip.fps),
        body.name,
        list(body.bone_names),
        f"bvh:{Path(clip.source).name} (rig {rig_name}, {unit})",
    )
    return motion if fps is None else resample(motion, fps)


def resample(motion: Motion, fps: float) -> Motion:
    """The clip at another frame rate, spanning the same duration.

    Frame i of the result shows time t = i / fps; with x = t * motion.fps, i0 = floor(x)
    and w = x - i0, each local rotation follows the geodesic
    R = R_i0 exp(w log(R_i0^T R_i0+1)) and the translation the straight line between them.
    """
    if not (np.isfinite(fps) and fps > 0):
        raise MotionFileError(f"fps must be a positive number, got {fps}")
    count = int(np.floor(motion.duration * fps + AXIS_EPS)) + 1
    if count > MAX_FRAMES:
        raise MotionFileError(f"resampling to {fps} fps gives {count} frames, more than the {MAX_FRAMES} accepted")
    position = np.arange(count) / fps * motion.fps
    first = np.minimum(np.floor(position).astype(int), motion.num_frames - 1)
    second = np.minimum(first + 1, motion.num_frames - 1)
    weight = (position - first)[:, None]
    rotvecs = torch.from_numpy(motion.rotations.astype(np.float64))
    rotations = np.empty((count, *motion.rotations.shape[1:]))
    for chunk in range(0, count, CHUNK_FRAMES):
        part = slice(chunk, chunk + CHUNK_FRAMES)
        start, end = roma.rotvec_to_rotmat(rotvecs[first[part]]), roma.rotvec_to_rotmat(rotvecs[second[part]])
        relative = roma.rotmat_to_rotvec(start.transpose(-1, -2) @ end)
        step = roma.rotvec_to_rotmat(relative * torch.from_numpy(weight[part])[..., None])
        rotations[part] = roma.rotmat_to_rotvec(start @ step).numpy()
    translation = (1.0 - weight) * motion.translation[first] + weight * motion.translation[second]
    return Motion(rotations, translation, fps, motion.body, list(motion.bone_names), motion.source)


def import_bvh(path: str | Path, body: BodyModel, **options: object) -> Motion:
    """Read a ``.bvh`` file and retarget it onto ``body`` (options of :func:`retarget_bvh`)."""
    return retarget_bvh(load_bvh(path), body, **options)
