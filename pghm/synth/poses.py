"""Pose sequences for the synthetic subjects, and the estimator noise added to them.

:func:`synth_motion` makes a clip of a named kind for any body whose canonical joints
(:data:`pghm.body.CANONICAL_JOINTS`) are mapped, from a few sinusoidal joint-angle
trajectories (a walk cycle, arm raises, squats, a turn on the spot, a random dance for
pose diversity). Rotation axes come from the rest skeleton, so "bend the elbow" bends it
forward whatever the rest pose (A-pose for Anny, T-pose for SMPL-X). Every clip keeps the
lower ankle on the rest ankle's height (ground contact). :func:`motion_clip` prefers the
project's procedural generator (:mod:`pghm.motion.procedural`, with planted feet) for the
kinds it offers; the source of every clip is recorded in meta.json.

Axes (world, y up, facing +z, left = +x): for a limb pointing along d, the rotation
theta (d x z) / |d x z| swings it forwards by theta (Rodrigues: R d = d cos theta +
z sin theta for d perpendicular to z).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import roma
import torch

from pghm.body import BodyModel, BodyPose

MOTION_KINDS = ("walk", "arm_raises", "squat", "turn", "dance")
"""Clips :func:`synth_motion` can make."""

WALK_SPEED = 1.1
"""Metres per second along the path."""

STRIDE_LENGTH = 1.3
"""Metres per gait cycle (two steps)."""

SEGMENT_CHILD = {
    "left_shoulder": "left_elbow",
    "right_shoulder": "right_elbow",
    "left_elbow": "left_wrist",
    "right_elbow": "right_wrist",
    "left_hip": "left_knee",
    "right_hip": "right_knee",
    "left_knee": "left_ankle",
    "right_knee": "right_ankle",
}
"""Joint -> the joint at the end of the segment it moves (the segment that swings)."""

ARM_HANG = np.radians(10.0)
"""Angle from vertical at which lowered arms hang, clear of the hips."""


@dataclass(frozen=True)
class _Skeleton:
    """Joint indices and rest directions of one body.

    Attributes:
        bones: canonical joint name -> bone index.
        segments: joint -> (3,) rest unit direction of the segment it moves.
        arm_down: per side, radians about z that lower the rest arm to hang at ARM_HANG
            (about 0.55 for Anny's A-pose, about 1.4 for a T-pose).
        ankle_height: rest height of the ankles.
    """

    bones: dict[str, int]
    segments: dict[str, np.ndarray]
    arm_down: dict[str, float]
    ankle_height: float


def _skeleton(body: BodyModel, joints: np.ndarray) -> _Skeleton:
    bones = body.joint_map
    segments = {}
    for joint, child in SEGMENT_CHILD.items():
        direction = joints[bones[child]] - joints[bones[joint]]
        segments[joint] = direction / np.linalg.norm(direction)
    arm_down = {}
    for side, sign in (("left", 1.0), ("right", -1.0)):
        d = segments[f"{side}_shoulder"]
        abduction = np.arctan2(abs(d[0]), -d[1])  # 0: hanging down, pi/2: T-pose
        arm_down[side] = -sign * (abduction - ARM_HANG)
    return _Skeleton(bones, segments, arm_down, float(joints[bones["left_ankle"], 1]))


def _z(angle: np.ndarray) -> np.ndarray:
    return np.stack([np.zeros_like(angle), np.zeros_like(angle), angle], axis=-1)


def _x(angle: np.ndarray) -> np.ndarray:
    return np.stack([angle, np.zeros_like(angle), np.zeros_like(angle)], axis=-1)


def _y(angle: np.ndarray) -> np.ndarray:
    return np.stack([np.zeros_like(angle), angle, np.zeros_like(angle)], axis=-1)


class _Pose:
    """Accumulates axis-angle rotations for F frames, composing several per joint."""

    def __init__(self, skeleton: _Skeleton, frames: int, num_bones: int) -> None:
        self.skeleton = skeleton
        self.rotations = torch.zeros(frames, num_bones, 3, dtype=torch.float64)

    def rotate(self, joint: str, rotvec: np.ndarray) -> None:
        """Apply ``rotvec`` (F, 3) after the joint's current rotation (both in rest axes)."""
        bone = self.skeleton.bones[joint]
        self.rotations[:, bone] = roma.rotvec_composition([torch.from_numpy(rotvec), self.rotations[:, bone]])

    def forward_axis(self, joint: str) -> np.ndarray:
        """(F, 3) axis d x z / |d x z| that swings the joint's segment, now along d, forwards."""
        current = roma.rotvec_to_rotmat(self.rotations[:, self.skeleton.bones[joint]]).numpy()
        direction = current @ self.skeleton.segments[joint]
        axis = np.cross(direction, np.array([0.0, 0.0, 1.0]))
        norm = np.linalg.norm(axis, axis=-1, keepdims=True)
        # A segment pointing straight forwards has no forward swing; use the x axis.
        return np.where(norm > 1e-6, axis / np.maximum(norm, 1e-12), np.array([-1.0, 0.0, 0.0]))

    def swing(self, joint: str, angle: np.ndarray, axis_of: str | None = None) -> None:
        """Swing the joint's segment forwards by ``angle`` (F,) radians.

        ``axis_of`` borrows another joint's forward axis (the ankle uses the knee's, as
        the foot itself points forwards).
        """
        axis = self.forward_axis(axis_of or joint)
        self.rotate(joint, np.asarray(angle)[:, None] * axis)

    def arms_down(self, extra: np.ndarray | float = 0.0) -> None:
        """Lower the arms to hang by the sides, then raise them sideways by ``extra``."""
        frames = self.rotations.shape[0]
        for side in ("left", "right"):
            sign = 1.0 if side == "left" else -1.0
            angle = np.full(frames, self.skeleton.arm_down[side]) + sign * np.asarray(extra)
            self.rotate(f"{side}_shoulder", _z(angle))


def _walk(p: _Pose, t: np.ndarray, rng: np.random.Generator) -> None:
    phase = 2 * np.pi * WALK_SPEED * t / STRIDE_LENGTH + rng.uniform(0, 2 * np.pi)
    p.arms_down()
    for side, offset in (("left", 0.0), ("right", np.pi)):
        s = np.sin(phase + offset)
        p.swing(f"{side}_hip", 0.45 * s)
        # The knee bends most in swing (hip moving forwards) and a little at heel strike.
        swing_phase = np.maximum(0.0, np.sin(phase + offset + np.pi / 2))
        knee = -(0.12 + 0.9 * swing_phase**2)
        p.swing(f"{side}_knee", knee)
        p.swing(f"{side}_ankle", -0.6 * (0.45 * s + knee), axis_of=f"{side}_knee")
        p.swing(f"{side}_shoulder", -0.35 * s)
        p.swing(f"{side}_elbow", 0.25 + 0.2 * np.maximum(0.0, -s))
    p.rotate("spine2", _y(0.08 * np.sin(phase)))
    p.rotate("pelvis", _y(-0.06 * np.sin(phase)))


def _arm_raises(p: _Pose, t: np.ndarray, rng: np.random.Generator) -> None:
    period = rng.uniform(2.0, 3.0)
    lift = 0.5 - 0.5 * np.cos(2 * np.pi * t / period)
    p.arms_down(extra=2.3 * lift)
    for side, delay in (("left", 0.0), ("right", 0.4)):
        bend = 0.5 - 0.5 * np.cos(2 * np.pi * (t / period + delay))
        p.swing(f"{side}_elbow", 1.9 * bend)
        p.swing(f"{side}_shoulder", 0.5 * np.sin(2 * np.pi * t / period + delay))
    p.rotate("head", _x(-0.2 * lift))


def _squat(p: _Pose, t: np.ndarray, rng: np.random.Generator) -> None:
    period = rng.uniform(2.0, 3.2)
    depth = 0.5 - 0.5 * np.cos(2 * np.pi * t / period)
    p.arms_down()
    for side in ("left", "right"):
        p.swing(f"{side}_hip", 1.5 * depth)
        p.swing(f"{side}_knee", -2.0 * depth)
        # The foot's pitch is the sum of the three swings: keep it flat on the ground.
        p.swing(f"{side}_ankle", 0.5 * depth, axis_of=f"{side}_knee")
        p.swing(f"{side}_shoulder", 1.3 * depth)
        p.swing(f"{side}_elbow", 0.6 * depth)
    p.rotate("spine2", _x(0.35 * depth))


def _turn(p: _Pose, t: np.ndarray, rng: np.random.Generator) -> None:
    duration = max(float(t[-1]), 1e-6)
    p.rotate("pelvis", _y(2 * np.pi * t / duration * rng.choice([-1.0, 1.0])))
    step = np.sin(2 * np.pi * t * 1.6)
    p.arms_down(extra=0.15)
    for side, sign in (("left", 1.0), ("right", -1.0)):
        p.swing(f"{side}_hip", 0.3 * np.maximum(0.0, sign * step))
        p.swing(f"{side}_knee", -0.6 * np.maximum(0.0, sign * step))
        p.swing(f"{side}_elbow", 0.4 + 0.3 * np.sin(2 * np.pi * t * 0.5 + sign))
    p.rotate("head", _y(0.3 * np.sin(2 * np.pi * t * 0.4)))


DANCE_RANGES = {
    "left_shoulder": 1.2,
    "right_shoulder": 1.2,
    "left_elbow": 1.1,
    "right_elbow": 1.1,
    "left_hip": 0.7,
    "right_hip": 0.7,
    "left_knee": 0.8,
    "right_knee": 0.8,
}
"""Half-ranges (radians) of the dance's forward swings; each is offset so that it bends
the natural way (elbows and knees never hyper-extend)."""


def _dance(p: _Pose, t: np.ndarray, rng: np.random.Generator) -> None:
    def wave(scale: float) -> np.ndarray:
        total = np.zeros_like(t)
        for _ in range(2):
            total += np.sin(2 * np.pi * rng.uniform(0.2, 0.9) * t + rng.uniform(0, 2 * np.pi))
        return scale * total / 2

    p.arms_down(extra=1.0 + wave(1.0))
    for joint, scale in DANCE_RANGES.items():
        value = wave(scale)
        if joint.endswith("elbow"):
            value = np.abs(value) + 0.1
        elif joint.endswith("knee"):
            value = -np.abs(value)
        p.swing(joint, value)
    p.rotate("spine2", np.stack([wave(0.25), wave(0.35), wave(0.15)], axis=-1))
    p.rotate("head", np.stack([wave(0.3), wave(0.5), wave(0.1)], axis=-1))
    p.rotate("pelvis", _y(wave(1.5)))


_KINDS: dict[str, Callable[[_Pose, np.ndarray, np.random.Generator], None]] = {
    "walk": _walk,
    "arm_raises": _arm_raises,
    "squat": _squat,
    "turn": _turn,
    "dance": _dance,
}


def ground_translation(
    body: BodyModel, joints: torch.Tensor, rotations: torch.Tensor, ankle_height: float
) -> np.ndarray:
    """(F,) root height that puts the lower ankle of each pose at ``ankle_height``."""
    pose = BodyPose(rotations, torch.zeros(rotations.shape[0], 3, dtype=rotations.dtype))
    transforms = body.bone_transforms(pose, joints.to(rotations.dtype))
    ankles = [body.joint_map["left_ankle"], body.joint_map["right_ankle"]]
    heads = joints.to(rotations.dtype)[ankles]  # (2, 3)
    posed = (transforms[:, ankles, :3, :3] @ heads[None, :, :, None])[..., 0] + transforms[:, ankles, :3, 3]
    return (ankle_height - posed[..., 1].min(dim=1).values).numpy()


def synth_motion(
    kind: str,
    body: BodyModel,
    joints: torch.Tensor,
    frames: int,
    fps: float,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """A clip of ``kind`` in place (no heading or path; see :func:`place_on_path`).

    Args:
        kind: one of :data:`MOTION_KINDS`.
        body: the body model.
        joints: (J, 3) rest joints of the shaped body.
        frames: F.
        fps: frames per second.
        rng: random phases and periods.

    Returns:
        rotations: (F, J, 3) float64 axis-angle.
        translation: (F, 3) float64, only the height set (ground contact).
    """
    skeleton = _skeleton(body, joints.double().numpy())
    pose = _Pose(skeleton, frames, body.num_bones)
    _KINDS[kind](pose, np.arange(frames) / fps, rng)
    translation = np.zeros((frames, 3))
    translation[:, 1] = ground_translation(body, joints.double(), pose.rotations, skeleton.ankle_height)
    return pose.rotations.numpy(), translation


def place_on_path(
    rotations: np.ndarray, translation: np.ndarray, heading: np.ndarray, position: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Turn each frame to ``heading`` (F,) radians about y and move it to ``position`` (F, 3).

    The root rotation becomes R_y(heading) R_root; the root translation becomes the
    path position plus the clip's own (ground-contact) height.
    """
    root = torch.from_numpy(rotations[:, 0])
    turned = roma.rotvec_composition([torch.from_numpy(_y(heading)), root]).numpy()
    rotations = rotations.copy()
    rotations[:, 0] = turned
    return rotations, translation + position


PROCEDURAL_NAMES = {"walk": "walk", "arm_raises": "arm_raises", "squat": "squat", "turn": "turn_in_place"}
"""Our motion kinds -> :mod:`pghm.motion.procedural` names; "dance" has no counterpart there."""

MAX_START_OFFSET_S = 2.0
"""Procedural clips are deterministic; each subject starts at a random time up to this
many seconds into its clip, so subjects doing the same motion are not in lockstep."""


def motion_clip(
    kind: str,
    body: BodyModel,
    shape: torch.Tensor,
    joints: torch.Tensor,
    frames: int,
    fps: float,
    rng: np.random.Generator,
    use_procedural: bool,
    turn_deg: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, str]:
    """A clip from :mod:`pghm.motion.procedural` when asked for and offered, else :func:`synth_motion`.

    Args:
        kind: one of :data:`MOTION_KINDS`.
        body: the body model.
        shape: (S,) the subject's shape (procedural clips put its feet on the ground).
        joints: (J, 3) its rest joints.
        frames: F.
        fps: frames per second.
        rng: random start offset (procedural) or phases (built-in).
        use_procedural: try :mod:`pghm.motion.procedural` first.
        turn_deg: procedural walks only: total heading change over the clip (a walk on a
            circle); the root then travels along the curved path.

    Returns:
        rotations: (F, J, 3) float64; translation: (F, 3) float64 (procedural clips move
        the root with the planted feet; built-in clips only set its height); the source,
        ``"procedural:<name>"`` or ``"synth:<kind>"``.
    """
    name = PROCEDURAL_NAMES.get(kind)
    procedural = None
    if use_procedural and name is not None:
        try:
            procedural = importlib.import_module("pghm.motion.procedural")
        except ImportError:
            procedural = None
    if procedural is not None:
        offset = int(rng.integers(0, int(MAX_START_OFFSET_S * fps) + 1))
        options: dict[str, object] = {"shape": shape}
        if kind == "walk":
            options["turn_deg"] = turn_deg * (frames + offset) / frames
        elif kind == "turn":
            options["turn_deg"] = float(rng.choice([-1.0, 1.0]) * rng.uniform(90.0, 360.0))
        motion = procedural.procedural_motion(name, body, frames=frames + offset, fps=fps, **options)
        rotations = np.asarray(motion.rotations[offset:], dtype=np.float64)
        translation = np.asarray(motion.translation[offset:], dtype=np.float64)
        return rotations, translation, f"procedural:{name}"
    rotations, translation = synth_motion(kind, body, joints, frames, fps, rng)
    return rotations, translation, f"synth:{kind}"


def add_pose_noise(
    rotations: np.ndarray,
    translation: np.ndarray,
    bones: list[int],
    rotation_std: float,
    translation_std: float,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """What a pose estimator would report: the true pose with random errors.

    Each listed bone's rotation is composed with a random rotation whose axis-angle vector
    has i.i.d. N(0, rotation_std^2) components (radians), R' = exp([eps]) R; the root
    translation gets i.i.d. N(0, translation_std^2) per axis (metres).

    Args:
        rotations: (F, J, 3) true axis-angle.
        translation: (F, 3) true root translation.
        bones: the bones that receive noise (the estimator's joints).
        rotation_std: radians.
        translation_std: metres.
        rng: the noise source.
    """
    noisy = rotations.copy()
    eps = rng.normal(0.0, rotation_std, (rotations.shape[0], len(bones), 3))
    noisy[:, bones] = roma.rotvec_composition([torch.from_numpy(eps), torch.from_numpy(rotations[:, bones])]).numpy()
    return noisy, translation + rng.normal(0.0, translation_std, translation.shape)
