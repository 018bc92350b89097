"""Procedural motions for any body, built from canonical joint names and the rest skeleton.

Every clip is a :class:`~pghm.motion.motion.Motion` in the shared pose representation
(:mod:`pghm.body.pose`): per-bone axis-angle rotations in *rest-aligned* axes. A local
rotation R_j acts on the rest pose's world vectors before the parent's rotation does
(W_j = W_parent(j) R_j), so every rotation axis here is a direction of the rest pose,
computed from the rest skeleton rather than hard-coded:

    swing axis of a bone with rest direction d towards a direction t:   a = (d x t) / |d x t|

(rotating d about a by a positive angle moves it towards t): shoulder abduction swings the
upper arm towards up, the elbow's hinge is perpendicular to the upper arm and the front.
Movements in the sagittal plane (hip, knee and ankle flexion, forward arm swings) turn
about the body's lateral axis (right hip -> left hip at rest), signed the same way, so a
splayed limb keeps its sideways lean and hip, knee and ankle turns that sum to zero leave
the foot as it was. Arm elevations are anatomical angles (from the arm
hanging straight down) converted with the body's own rest elevation, so the same clip looks
the same on Anny's A-pose and SMPL-X's T-pose. Left and right limbs are mirror images:
swing axes mirror by construction (cross products of mirrored vectors), twists about a
bone's own axis flip sign with the side.

The root is placed afterwards from the posed feet (:class:`FootContact`): every frame is
lifted so that the lowest foot point rests on the ground the rest body stands on, and in
clips that plant their feet the root moves so that the supporting foot does not slide;
walking speed and the bob of the hips follow from the legs.

World frame (the project's): y up, the body facing +z, its left towards +x.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import roma
import torch

from pghm.body import BodyModel, BodyPose, RestBody, lbs
from pghm.errors import PghmError
from pghm.motion.motion import MAX_FRAMES, Motion

UP = np.array([0.0, 1.0, 0.0])
FORWARD = np.array([0.0, 0.0, 1.0])
LEFT = np.array([1.0, 0.0, 0.0])
SIDES = (("left", 1.0), ("right", -1.0))
"""Canonical side prefix and its sign: +1 for the body's left (+x), -1 for its right."""

DEFAULT_FPS = 30.0
DEFAULT_FRAMES = 120
AXIS_EPS = 1e-6
"""Below this |d x t| a bone is parallel to the swing target and another axis is used."""

FOOT_WEIGHT = 0.5
"""A vertex belongs to a foot when at least this much of its skinning weight lies on the
ankle bone and its descendants."""
CONTACT_SOFTNESS = 0.01
"""Metres: foot points within a few of these of the foot's lowest point share the ground
contact (a soft argmin, so the contact glides from heel to toe without jumps)."""
SUPPORT_SOFTNESS = 0.003
"""Metres: a foot this much higher than the other carries 1/e of its share of the weight;
small, as a swinging foot passes only a centimetre or two above the floor."""

REQUIRED_JOINTS = tuple(
    f"{side}_{joint}" for side, _ in SIDES for joint in ("shoulder", "elbow", "wrist", "hip", "knee", "ankle")
) + ("pelvis",)
SPINE_JOINTS = ("spine1", "spine2", "spine3")
NECK_JOINTS = ("neck", "head")

ARM_HANG_DEG = 12.0
"""Elevation of relaxed arms (degrees from hanging straight down): clear of the thighs."""
ARM_OVERHEAD_DEG = 165.0
"""Elevation of raised arms, short of vertical as people hold them."""
ARM_RAISE_ELBOW_DEG = 5.0
"""Elbow flexion of arms held out (raised, reaching forward): nearly straight."""


def axis_angle_matrices(axis: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Rotations by ``angles`` (F,) radians about the unit ``axis`` (3,): (F, 3, 3) float64.

    Rodrigues: R = I + sin(a) K + (1 - cos(a)) K^2 with K the cross-product matrix of the axis.
    """
    angles = np.asarray(angles, dtype=np.float64)
    x, y, z = np.asarray(axis, dtype=np.float64)
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    sin, cos = np.sin(angles)[:, None, None], np.cos(angles)[:, None, None]
    return np.eye(3) + sin * k + (1.0 - cos) * (k @ k)


def matrices_to_rotvecs(matrices: np.ndarray) -> np.ndarray:
    """Axis-angle vectors (..., 3) of rotation matrices (..., 3, 3), float64."""
    return roma.rotmat_to_rotvec(torch.from_numpy(np.array(matrices, dtype=np.float64))).numpy()


def swing_axis(direction: np.ndarray, toward: np.ndarray) -> np.ndarray:
    """Unit axis a = d x t about which ``direction`` d turns towards ``toward`` t.

    When d is parallel to t (a degenerate rest skeleton), d is crossed with the world axis
    least aligned with it instead, so the result is always a unit vector perpendicular to d.
    """
    axis = np.cross(direction, toward)
    norm = np.linalg.norm(axis)
    if norm < AXIS_EPS:
        fallback = np.eye(3)[np.argmin(np.abs(direction))]
        axis = np.cross(direction, fallback)
        norm = np.linalg.norm(axis)
    return axis / norm


def _unit(vector: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(vector)
    return vector / norm if norm > AXIS_EPS else UP.copy()


def _descendants(parents: list[int], bone: int) -> list[int]:
    """``bone`` and every bone below it (parents precede children)."""
    inside = {bone}
    for child, parent in enumerate(parents):
        if parent in inside:
            inside.add(child)
    return sorted(inside)


class FootContact:
    """Where the feet of a posed body touch the ground.

    Each foot is the set of rest vertices skinned mostly (>= :data:`FOOT_WEIGHT`) to its
    ankle bone and the bones below it; a body whose mesh has no such vertices falls back to
    those bones' heads. ``ground`` is the height of the lowest foot point at rest, the floor
    the rest body stands on.
    """

    def __init__(self, body: BodyModel, rest: RestBody) -> None:
        self.body = body
        self.rest = rest
        self.points: list[torch.Tensor] = []  # per foot (N, 3) rest positions
        self.weights: list[torch.Tensor] = []  # per foot (N, J) skinning weights
        for side, _ in SIDES:
            bones = _descendants(body.parents, body.joint_map[f"{side}_ankle"])
            on_foot = body.skin_weights[:, bones].sum(-1) >= FOOT_WEIGHT
            if on_foot.any():
                self.points.append(rest.vertices[on_foot].double())
                self.weights.append(body.skin_weights[on_foot].double())
            else:
                self.points.append(rest.joints[bones].double())
                self.weights.append(torch.eye(body.num_bones, dtype=torch.float64)[bones])
        self.ground = float(min(points[:, 1].min() for points in self.points))

    def posed(self, rotations: np.ndarray, translation: np.ndarray) -> list[np.ndarray]:
        """Posed foot points, one (F, N, 3) array per foot (left, right)."""
        pose = BodyPose(torch.from_numpy(rotations).double(), torch.from_numpy(translation).double())
        transforms = self.body.bone_transforms(pose, self.rest.joints.double())
        return [lbs(p, w, transforms).numpy() for p, w in zip(self.points, self.weights, strict=True)]

    def lift(self, rotations: np.ndarray, translation: np.ndarray) -> np.ndarray:
        """(F,) vertical shift putting each frame's lowest foot point on ``ground``."""
        lowest = np.min([feet[..., 1].min(-1) for feet in self.posed(rotations, translation)], axis=0)
        return self.ground - lowest

    def planted_translation(self, rotations: np.ndarray, support: np.ndarray | None = None) -> np.ndarray:
        """(F, 3) root translation that keeps the supporting foot still and on the ground.

        With the root at the origin, foot s has points x_p(t) and lowest height y_s(t). The
        points touching the ground get weights w_p(t) = exp(-(y_p - y_s) / CONTACT_SOFTNESS)
        (normalised per foot), the feet support in proportion to ``support`` (2, F) when given,
        else to v_s(t) = softmin_s(y_s(t) / SUPPORT_SOFTNESS), and the root cancels the motion of
        the touching points in the floor plane (material points: a foot rolling from heel to
        toe does not slide):

            T_xz(t) = T_xz(t-1) - sum_s v_s(t) sum_p w_p(t) (x_p(t) - x_p(t-1))_xz
            T_y(t)  = ground - min_s y_s(t)
        """
        frames = rotations.shape[0]
        feet = self.posed(rotations, np.zeros((frames, 3)))
        lowest = np.stack([foot[..., 1].min(-1) for foot in feet])  # (2, F)
        slide = []
        for foot, low in zip(feet, lowest, strict=True):
            weight = np.exp(-(foot[1:, :, 1] - low[1:, None]) / CONTACT_SOFTNESS)
            weight /= weight.sum(1, keepdims=True)
            slide.append((weight[..., None] * np.diff(foot, axis=0)).sum(1))
        if support is None:
            support = np.exp(-(lowest - lowest.min(0)) / SUPPORT_SOFTNESS)
        share = support[:, 1:] / np.maximum(support[:, 1:].sum(0), AXIS_EPS)
        step = (share[..., None] * np.stack(slide)).sum(0)  # (F - 1, 3)
        translation = np.zeros((frames, 3))
        translation[1:, [0, 2]] = -np.cumsum(step[:, [0, 2]], axis=0)
        translation[:, 1] = self.ground - lowest.min(0)
        return translation


class _Skeleton:
    """Rest-pose anatomy of a body: joint positions and the axes its limbs move about."""

    def __init__(self, body: BodyModel, rest: RestBody) -> None:
        missing = [name for name in REQUIRED_JOINTS if name not in body.joint_map]
        if missing:
            raise PghmError(
                f"the {body.name} body does not map the joints {', '.join(missing)} that procedural motions move"
            )
        self.body = body
        self.joints = rest.joints.detach().double().numpy()
        self.spine = [name for name in SPINE_JOINTS if name in body.joint_map]
        self.neck = [name for name in NECK_JOINTS if name in body.joint_map]

    def head(self, name: str) -> np.ndarray:
        return self.joints[self.body.joint_map[name]]

    @property
    def lateral(self) -> np.ndarray:
        """The body's left-right axis at rest: from the right hip to the left hip."""
        return _unit(self.head("left_hip") - self.head("right_hip"))

    def sagittal_axis(self, direction: np.ndarray, toward: np.ndarray) -> np.ndarray:
        """The lateral axis, signed so that turning about it moves ``direction`` towards ``toward``.

        Flexion and extension of the legs, and the arms' forward swings, turn about this one
        axis: unlike :func:`swing_axis` it keeps a splayed limb's sideways lean (knees do
        not fold inwards in a squat, raised arms stay apart), and successive hip, knee and
        ankle turns about it cancel exactly, so a foot kept level stays level.
        """
        lateral = self.lateral
        return lateral if np.cross(direction, toward) @ lateral >= 0.0 else -lateral

    def direction(self, start: str, end: str) -> np.ndarray:
        """Unit rest direction from joint ``start`` to joint ``end``."""
        return _unit(self.head(end) - self.head(start))

    def arm_elevation(self, side: str) -> float:
        """Rest angle (radians) between the upper arm and straight down: ~0.7 A-pose, ~1.6 T-pose."""
        upper = self.direction(f"{side}_shoulder", f"{side}_elbow")
        return float(np.arccos(np.clip(-upper[1], -1.0, 1.0)))

    def elbow_flexion(self, side: str) -> float:
        """Rest flexion of the elbow (radians) about :meth:`elbow_axis`: ~0.7 for Anny, 0 for a T-pose."""
        upper = self.direction(f"{side}_shoulder", f"{side}_elbow")
        fore = self.direction(f"{side}_elbow", f"{side}_wrist")
        return float(np.arctan2(np.cross(upper, fore) @ self.elbow_axis(side), upper @ fore))

    def elbow_axis(self, side: str) -> np.ndarray:
        """Hinge of the elbow: flexion swings the forearm forward, perpendicular to the upper arm."""
        return swing_axis(self.direction(f"{side}_shoulder", f"{side}_elbow"), FORWARD)

    def wrist_axes(self, side: str) -> tuple[np.ndarray, np.ndarray]:
        """(flexion, deviation) axes of the wrist, perpendicular to the rest hand direction.

        The hand points from the wrist to the mean of its child bones' heads (the knuckles);
        flexion turns about the elbow hinge made perpendicular to the hand, deviation about
        the remaining axis.
        """
        wrist = self.body.joint_map[f"{side}_wrist"]
        children = [j for j, p in enumerate(self.body.parents) if p == wrist]
        hand = self.direction(f"{side}_elbow", f"{side}_wrist")
        if children:
            hand = _unit(self.joints[children].mean(0) - self.joints[wrist])
        hinge = self.elbow_axis(side)
        flexion = _unit(hinge - hand * (hinge @ hand))
        return flexion, np.cross(hand, flexion)


class _PoseBuilder:
    """Local rotations (F, 3, 3) per canonical joint, composed one elementary turn at a time."""

    def __init__(self, skeleton: _Skeleton, rest: RestBody, frames: int) -> None:
        self.skeleton = skeleton
        self.rest = rest
        self.frames = frames
        self.local: dict[str, np.ndarray] = {}

    def turn(self, joint: str, axis: np.ndarray, angles: np.ndarray | float) -> None:
        """Follow the joint's current local rotation by a turn of ``angles`` (radians) about ``axis``.

        R_j <- Rot(axis, angle) R_j: the axis is a rest-pose direction, as the convention wants.
        """
        if joint not in self.skeleton.body.joint_map:
            return
        angles = np.broadcast_to(np.asarray(angles, dtype=np.float64), (self.frames,))
        current = self.local.get(joint, np.broadcast_to(np.eye(3), (self.frames, 3, 3)))
        self.local[joint] = axis_angle_matrices(axis, angles) @ current

    def spread(self, joints: list[str], axis: np.ndarray, angles: np.ndarray | float) -> None:
        """Share a bend equally between a chain of joints (the spine, the neck)."""
        for joint in joints:
            self.turn(joint, axis, np.asarray(angles) / len(joints))

    def relax_arms(self, amount: np.ndarray | float = 1.0) -> dict[str, np.ndarray]:
        """Lower (or raise) the rest arms towards :data:`ARM_HANG_DEG` by ``amount`` in [0, 1].

        Returns each side's upper-arm direction once fully relaxed, the direction later
        swings are computed from.
        """
        hanging = {}
        for side, _ in SIDES:
            upper = self.skeleton.direction(f"{side}_shoulder", f"{side}_elbow")
            delta = np.radians(ARM_HANG_DEG) - self.skeleton.arm_elevation(side)
            axis = swing_axis(upper, UP)
            self.turn(f"{side}_shoulder", axis, delta * np.asarray(amount))
            hanging[side] = axis_angle_matrices(axis, np.array([delta]))[0] @ upper
        return hanging

    def motion(
        self,
        root: np.ndarray | None,
        lock_feet: bool,
        fps: float,
        source: str,
        support: np.ndarray | None = None,
    ) -> Motion:
        """Assemble the clip: (F, J, 3) rotations, the root placed by :class:`FootContact`.

        Args:
            root: (F, 3, 3) extra root rotation (turning), applied after the pelvis's own.
            lock_feet: move the root so the supporting foot stays planted (walking);
                otherwise the root only moves vertically.
            support: (2, F) share of the weight on the left and right foot when known
                (see :meth:`FootContact.planted_translation`).
        """
        body = self.skeleton.body
        local = dict(self.local)
        if root is not None:
            local["pelvis"] = root @ local.get("pelvis", np.eye(3))
        rotations = np.zeros((self.frames, body.num_bones, 3))
        for joint, matrices in local.items():
            rotations[:, body.joint_map[joint]] = matrices_to_rotvecs(np.broadcast_to(matrices, (self.frames, 3, 3)))
        contact = FootContact(body, self.rest)
        if lock_feet:
            translation = contact.planted_translation(rotations, support)
        else:
            translation = np.zeros((self.frames, 3))
            translation[:, 1] = contact.lift(rotations, translation)
        return Motion(rotations, translation, fps, body.name, list(body.bone_names), source)


def _setup(body: BodyModel, frames: int, fps: float, shape: torch.Tensor | None) -> tuple[_PoseBuilder, np.ndarray]:
    """Validate the common arguments; the builder and the (F,) frame times in seconds."""
    if not (isinstance(frames, int | np.integer) and 1 <= frames <= MAX_FRAMES):
        raise PghmError(f"a motion has 1 to {MAX_FRAMES} frames, got frames={frames!r}")
    if not (np.isfinite(fps) and fps > 0):
        raise PghmError(f"fps must be a positive number, got {fps!r}")
    rest = body.rest(shape)
    return _PoseBuilder(_Skeleton(body, rest), rest, int(frames)), np.arange(frames) / fps


def _pulse(cycle: np.ndarray, centre: float, width: float) -> np.ndarray:
    """A periodic Gaussian pulse over the cycle fraction: exp(-d^2 / 2 width^2), d the
    wrapped distance of ``cycle`` from ``centre`` (both in cycles, period 1)."""
    distance = (cycle - centre + 0.5) % 1.0 - 0.5
    return np.exp(-0.5 * (distance / width) ** 2)


def _smoothstep(x: np.ndarray, start: float, end: float) -> np.ndarray:
    """0 before ``start``, 1 after ``end``, the cubic 3u^2 - 2u^3 in between."""
    u = np.clip((x - start) / (end - start), 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def _up_and_down(u: np.ndarray) -> np.ndarray:
    """Smooth 0 -> 1 -> 0 over u in [0, 1] (zero velocity at both ends and at the top)."""
    return 0.5 - 0.5 * np.cos(2.0 * np.pi * np.clip(u, 0.0, 1.0))


# A gait cycle of one leg, as a fraction c in [0, 1) of the cycle from its heel strike:
# stance until toe-off at GAIT_STANCE, swing after. Angles in degrees, roughly the averages
# of clinical gait analysis: the hip swings between extension and flexion (linearly in
# stance, so the walking speed is steady), the knee flexes ~55 deg in swing, the ankle
# keeps the foot flat in mid-stance and pushes off; the arms swing against the legs, the
# pelvis and thorax twist a few degrees against each other.
GAIT_STANCE = 0.6
GAIT_HIP_MEAN_DEG = 0.0
GAIT_HIP_SWING_DEG = 21.0
GAIT_KNEE_STANCE_DEG = 5.0
GAIT_KNEE_SWING = (55.0, 0.73, 0.09)
"""(peak degrees, centre, width in cycles) of the knee's flexion in swing."""
GAIT_FOOT_FLAT = (0.0, 0.08, 0.38, 0.52)
"""Cycle fractions where the stance foot goes flat (ramping in from heel strike) and lifts
its heel again (ramping out): in between the ankle keeps the sole level, ankle = knee - hip."""
GAIT_ANKLE_PULSES = ((-15.0, 0.6, 0.05), (6.0, 0.82, 0.1))
"""Ankle outside the flat-foot window (degrees, positive lifting the toes): push-off,
toes cleared in swing."""
GAIT_HANDOVER = 0.05
"""Fraction of the cycle after a heel strike over which the weight passes to the landing
foot (the trailing foot stays down a little longer, but it is already pushing off)."""
GAIT_ELBOW_DEG = 18.0
GAIT_PELVIS_TWIST_DEG = 4.0
GAIT_THORAX_TWIST_DEG = 6.0
GAIT_PERIOD_S = 1.05
"""Seconds per gait cycle (two steps): ~115 steps a minute."""


def _gait_hip(cycle: np.ndarray) -> np.ndarray:
    """Hip flexion in [-1, 1] units of the swing: 1 -> -1 linearly over stance, back with a
    cosine ease over swing (the foot lands and leaves with little speed)."""
    stance = 1.0 - 2.0 * cycle / GAIT_STANCE
    swing = -np.cos(np.pi * (cycle - GAIT_STANCE) / (1.0 - GAIT_STANCE))
    return np.where(cycle < GAIT_STANCE, stance, swing)


def walk_cycle(
    body: BodyModel,
    frames: int = DEFAULT_FRAMES,
    fps: float = DEFAULT_FPS,
    *,
    period: float = GAIT_PERIOD_S,
    arm_swing_deg: float = 20.0,
    turn_deg: float = 0.0,
    shape: torch.Tensor | None = None,
) -> Motion:
    """A walk: legs in gait, arms swinging against them, the thorax counter-rotating.

    Each leg runs the cycle c = t / period (+ 1/2 for the right leg) from heel strike:
    hip = mean + swing * h(c) with h of :func:`_gait_hip`, the knee flexing in swing
    (:data:`GAIT_KNEE_SWING`), the ankle keeping the sole level (ankle = knee - hip) in the
    flat-foot window :data:`GAIT_FOOT_FLAT` and following :data:`GAIT_ANKLE_PULSES`
    outside it. Each arm swings with the opposite leg,
    -arm_swing * cos(2 pi c). The root advances by keeping the supporting foot planted
    (:meth:`FootContact.planted_translation`), so speed and stride follow from the legs.
    ``turn_deg`` turns the walker steadily by that much over the clip.

    Args:
        body: any body mapping the canonical limb joints.
        frames: F, number of frames.
        fps: frames per second.
        period: seconds per gait cycle.
        arm_swing_deg: amplitude of the arm swing about the shoulder.
        turn_deg: total change of heading (positive turns left, about +y).
        shape: the body's shape parameters (None: its default shape).
    """
    builder, time = _setup(body, frames, fps, shape)
    skeleton = builder.skeleton
    hanging = builder.relax_arms()
    support = []
    for (side, _), offset in zip(SIDES, (0.0, 0.5), strict=True):
        cycle = (time / period + offset) % 1.0
        thigh = skeleton.direction(f"{side}_hip", f"{side}_knee")
        shin = skeleton.direction(f"{side}_knee", f"{side}_ankle")
        hip = GAIT_HIP_MEAN_DEG + GAIT_HIP_SWING_DEG * _gait_hip(cycle)
        knee = GAIT_KNEE_STANCE_DEG + GAIT_KNEE_SWING[0] * _pulse(cycle, *GAIT_KNEE_SWING[1:])
        flat = _smoothstep(cycle, *GAIT_FOOT_FLAT[:2]) * (1.0 - _smoothstep(cycle, *GAIT_FOOT_FLAT[2:]))
        ankle = flat * (knee - hip) + (1.0 - flat) * sum(peak * _pulse(cycle, c, w) for peak, c, w in GAIT_ANKLE_PULSES)
        # The foot bears weight from its heel strike to the other foot's, handing over linearly.
        support.append(np.clip(np.minimum(cycle, 0.5 + GAIT_HANDOVER - cycle) / GAIT_HANDOVER, 0.0, 1.0))
        builder.turn(f"{side}_hip", skeleton.sagittal_axis(thigh, FORWARD), np.radians(hip))
        builder.turn(f"{side}_knee", skeleton.sagittal_axis(shin, -FORWARD), np.radians(knee))
        builder.turn(f"{side}_ankle", skeleton.sagittal_axis(FORWARD, UP), np.radians(ankle))
        # The arm is back when its own leg lands in front (c = 0), forward when the leg is behind.
        arm = -arm_swing_deg * np.cos(2.0 * np.pi * cycle)
        builder.turn(f"{side}_shoulder", skeleton.sagittal_axis(hanging[side], FORWARD), np.radians(arm))
        elbow = np.radians(GAIT_ELBOW_DEG + 0.5 * np.maximum(arm, 0.0)) - skeleton.elbow_flexion(side)
        builder.turn(f"{side}_elbow", skeleton.elbow_axis(side), elbow)
    # The pelvis brings the landing leg's side ahead (about -y for the left), the thorax the other way.
    twist = np.cos(2.0 * np.pi * time / period)
    builder.turn("pelvis", UP, -np.radians(GAIT_PELVIS_TWIST_DEG) * twist)
    builder.spread(skeleton.spine, UP, np.radians(GAIT_PELVIS_TWIST_DEG + GAIT_THORAX_TWIST_DEG) * twist)
    heading = np.radians(turn_deg) * time / max(time[-1], 1.0 / fps)
    root = axis_angle_matrices(UP, heading)
    return builder.motion(root, lock_feet=True, fps=fps, source="procedural:walk", support=np.stack(support))


def arm_raises(
    body: BodyModel, frames: int = DEFAULT_FRAMES, fps: float = DEFAULT_FPS, *, shape: torch.Tensor | None = None
) -> Motion:
    """Both arms raised sideways to overhead and back, then forwards to overhead and back.

    First half: abduction from the rest elevation e_rest to :data:`ARM_OVERHEAD_DEG` about
    the swing axis (upper arm x up). Second half: the arms are brought to hanging and then
    flexed about (hanging arm x forward), both scaled by the same smooth 0 -> 1 -> 0 profile.
    The elbows straighten (to :data:`ARM_RAISE_ELBOW_DEG`) as the arms rise.
    """
    builder, _ = _setup(body, frames, fps, shape)
    skeleton = builder.skeleton
    u = (np.arange(frames) + 0.5) / frames
    first, second = _up_and_down(2.0 * u) * (u < 0.5), _up_and_down(2.0 * u - 1.0) * (u >= 0.5)
    hanging = builder.relax_arms(second)
    for side, _ in SIDES:
        upper = skeleton.direction(f"{side}_shoulder", f"{side}_elbow")
        lift = np.radians(ARM_OVERHEAD_DEG) - skeleton.arm_elevation(side)
        builder.turn(f"{side}_shoulder", swing_axis(upper, UP), lift * first)
        builder.turn(
            f"{side}_shoulder",
            skeleton.sagittal_axis(hanging[side], FORWARD),
            np.radians(ARM_OVERHEAD_DEG - ARM_HANG_DEG) * second,
        )
        straighten = np.radians(ARM_RAISE_ELBOW_DEG) - skeleton.elbow_flexion(side)
        builder.turn(f"{side}_elbow", skeleton.elbow_axis(side), straighten * (first + second))
    return builder.motion(None, lock_feet=False, fps=fps, source="procedural:arm_raises")


SQUAT_HIP_DEG = 95.0
SQUAT_KNEE_DEG = 130.0
SQUAT_TRUNK_DEG = 25.0
SQUAT_ARMS_DEG = 80.0
"""Hips flexed to just past horizontal thighs, knees to 130 deg; the ankles dorsiflex by
knee - hip so the feet stay flat, the trunk leans and the arms reach forward to balance."""


def squat(
    body: BodyModel,
    frames: int = DEFAULT_FRAMES,
    fps: float = DEFAULT_FPS,
    *,
    repetitions: int = 1,
    depth: float = 1.0,
    shape: torch.Tensor | None = None,
) -> Motion:
    """Down into a squat and back up, ``repetitions`` times; ``depth`` scales all angles.

    Feet stay flat: about the lateral axis the foot's world rotation is
    -hip + knee - ankle = 0. The root moves (back and down) so that the feet stay planted.
    """
    builder, _ = _setup(body, frames, fps, shape)
    skeleton = builder.skeleton
    amount = depth * _up_and_down((np.arange(frames) * repetitions / max(frames - 1, 1)) % 1.0)
    hanging = builder.relax_arms(amount)
    for side, _ in SIDES:
        thigh = skeleton.direction(f"{side}_hip", f"{side}_knee")
        shin = skeleton.direction(f"{side}_knee", f"{side}_ankle")
        builder.turn(f"{side}_hip", skeleton.sagittal_axis(thigh, FORWARD), np.radians(SQUAT_HIP_DEG) * amount)
        builder.turn(f"{side}_knee", skeleton.sagittal_axis(shin, -FORWARD), np.radians(SQUAT_KNEE_DEG) * amount)
        builder.turn(
            f"{side}_ankle", skeleton.sagittal_axis(FORWARD, UP), np.radians(SQUAT_KNEE_DEG - SQUAT_HIP_DEG) * amount
        )
        builder.turn(
            f"{side}_shoulder", skeleton.sagittal_axis(hanging[side], FORWARD), np.radians(SQUAT_ARMS_DEG) * amount
        )
        straighten = np.radians(ARM_RAISE_ELBOW_DEG) - skeleton.elbow_flexion(side)
        builder.turn(f"{side}_elbow", skeleton.elbow_axis(side), straighten * amount)
    builder.spread(skeleton.spine, swing_axis(UP, FORWARD), np.radians(SQUAT_TRUNK_DEG) * amount)
    return builder.motion(None, lock_feet=True, fps=fps, source="procedural:squat")


TURN_STEP_HIP_DEG = 20.0
TURN_STEP_KNEE_DEG = 40.0
TURN_STEPS_PER_S = 2.0


def turn_in_place(
    body: BodyModel,
    frames: int = DEFAULT_FRAMES,
    fps: float = DEFAULT_FPS,
    *,
    turn_deg: float = 180.0,
    shape: torch.Tensor | None = None,
) -> Motion:
    """Turn on the spot by ``turn_deg`` (positive: to the left), stepping while turning.

    The heading eases in and out (smoothstep); the feet lift alternately, two steps a
    second, only while the body turns. The root stays above the same point of the floor.
    """
    builder, time = _setup(body, frames, fps, shape)
    skeleton = builder.skeleton
    u = np.arange(frames) / max(frames - 1, 1)
    heading = np.radians(turn_deg) * (3.0 * u**2 - 2.0 * u**3)
    turning = np.sin(np.pi * u)  # steps fade in and out with the turn
    builder.relax_arms()
    for (side, _), offset in zip(SIDES, (0.0, np.pi), strict=True):
        lift = turning * np.maximum(0.0, np.sin(np.pi * TURN_STEPS_PER_S * time + offset)) ** 2
        thigh = skeleton.direction(f"{side}_hip", f"{side}_knee")
        shin = skeleton.direction(f"{side}_knee", f"{side}_ankle")
        builder.turn(f"{side}_hip", skeleton.sagittal_axis(thigh, FORWARD), np.radians(TURN_STEP_HIP_DEG) * lift)
        builder.turn(f"{side}_knee", skeleton.sagittal_axis(shin, -FORWARD), np.radians(TURN_STEP_KNEE_DEG) * lift)
        elbow = np.radians(GAIT_ELBOW_DEG) - skeleton.elbow_flexion(side)
        builder.turn(f"{side}_elbow", skeleton.elbow_axis(side), elbow)
    root = axis_angle_matrices(UP, heading)
    return builder.motion(root, lock_feet=False, fps=fps, source="procedural:turn_in_place")


STRESS_OVERSHOOT = 1.15
"""Sweeps go this far beyond the anatomical limits, to exercise implausible poses too."""

STRESS_SWEEPS: tuple[tuple[str, str, float, float], ...] = (
    # (joint group, movement, lower limit deg, upper limit deg): roughly the normal ranges
    # of motion of clinical goniometry tables, signs as in _stress_axis and stress().
    ("spine", "flexion", -30.0, 90.0),
    ("spine", "lateral", -40.0, 40.0),
    ("spine", "twist", -45.0, 45.0),
    ("neck", "flexion", -60.0, 70.0),
    ("neck", "lateral", -45.0, 45.0),
    ("neck", "twist", -80.0, 80.0),
    ("shoulder", "abduction", 0.0, 180.0),
    ("shoulder", "flexion", -60.0, 180.0),
    ("shoulder", "twist", -90.0, 90.0),
    ("elbow", "flexion", -10.0, 150.0),
    ("elbow", "twist", -80.0, 80.0),
    ("wrist", "flexion", -70.0, 80.0),
    ("wrist", "deviation", -30.0, 20.0),
    ("hip", "flexion", -30.0, 120.0),
    ("hip", "abduction", -30.0, 45.0),
    ("hip", "twist", -45.0, 45.0),
    ("knee", "flexion", -10.0, 150.0),
    ("ankle", "flexion", -50.0, 20.0),
)
"""Shoulder abduction and elbow flexion are anatomical angles (from the hanging, straight
arm; converted with the body's rest angles); all other angles are from the rest pose."""


def _stress_axis(
    skeleton: _Skeleton, group: str, movement: str, side: str, sign: float
) -> tuple[str, np.ndarray, float]:
    """The joint, rest-pose axis and reference angle (radians) of one limb movement.

    The reference is the rest pose's own angle for the movement: the rest elevation for
    shoulder abduction, the rest flexion for the elbow (anatomical angles from the hanging,
    straight arm), zero (angles from the rest pose) for the others.
    """
    joint = f"{side}_{group}"
    if group == "shoulder":
        upper = skeleton.direction(f"{side}_shoulder", f"{side}_elbow")
        if movement == "abduction":
            return joint, swing_axis(upper, UP), skeleton.arm_elevation(side)
        if movement == "flexion":
            return joint, skeleton.sagittal_axis(-UP, FORWARD), 0.0
        return joint, sign * upper, 0.0
    if group == "elbow":
        if movement == "flexion":
            return joint, skeleton.elbow_axis(side), skeleton.elbow_flexion(side)
        return joint, sign * skeleton.direction(f"{side}_elbow", f"{side}_wrist"), 0.0
    if group == "wrist":
        flexion, deviation = skeleton.wrist_axes(side)
        return (joint, flexion, 0.0) if movement == "flexion" else (joint, sign * deviation, 0.0)
    if group == "hip":
        thigh = skeleton.direction(f"{side}_hip", f"{side}_knee")
        axes = {"flexion": skeleton.sagittal_axis(thigh, FORWARD), "abduction": swing_axis(thigh, sign * LEFT)}
        return joint, axes.get(movement, sign * thigh), 0.0
    if group == "knee":
        return joint, skeleton.sagittal_axis(skeleton.direction(f"{side}_knee", f"{side}_ankle"), -FORWARD), 0.0
    return joint, skeleton.sagittal_axis(FORWARD, UP), 0.0  # ankle: positive lifts the toes


def _stress_slots() -> list[tuple[str, str, float, float, tuple[tuple[str, float], ...]]]:
    """The sweeps in clip order with the sides each moves: arms together, legs one at a time
    (both thighs flexed at once would leave no foot to stand on)."""
    slots = []
    for group, movement, lower, upper in STRESS_SWEEPS:
        if group in ("hip", "knee", "ankle"):
            slots += [(group, movement, lower, upper, (side,)) for side in SIDES]
        else:
            slots.append((group, movement, lower, upper, SIDES))
    return slots


def stress(
    body: BodyModel,
    frames: int = 360,
    fps: float = DEFAULT_FPS,
    *,
    overshoot: float = STRESS_OVERSHOOT,
    shape: torch.Tensor | None = None,
) -> Motion:
    """Each major joint swept to its limits and ``overshoot`` beyond, one after another.

    The clip is split evenly into the sweeps of :func:`_stress_slots`; within its slot
    (u in [0, 1)) a movement turns by

        angle(u) = w (k upper - ref)   where w = sin(2 pi u) >= 0,
                   w (ref - k lower)   elsewhere,

    k the overshoot and ref the reference of :func:`_stress_axis`: from rest to the upper
    limit, back through rest to the lower limit, back to rest. The arms move together,
    mirrored, the legs one after the other; spine and neck bends are shared between their
    joints. The feet are put on the ground, the root does not travel.
    """
    builder, _ = _setup(body, frames, fps, shape)
    skeleton = builder.skeleton
    slots = _stress_slots()
    position = np.arange(frames) / frames * len(slots)
    slot, wave = np.floor(position).astype(int), np.sin(2.0 * np.pi * (position % 1.0))
    central = {"spine": skeleton.spine, "neck": skeleton.neck}
    central_axes = {"flexion": swing_axis(UP, FORWARD), "lateral": swing_axis(UP, LEFT), "twist": UP}
    for index, (group, movement, lower, upper, sides) in enumerate(slots):
        active_wave = np.where(slot == index, wave, 0.0)
        upper_rad, lower_rad = np.radians(overshoot * upper), np.radians(overshoot * lower)
        if group in central:
            angle = active_wave * np.where(active_wave >= 0.0, upper_rad, -lower_rad)
            builder.spread(central[group], central_axes[movement], angle)
            continue
        for side, sign in sides:
            joint, axis, ref = _stress_axis(skeleton, group, movement, side, sign)
            angle = active_wave * np.where(active_wave >= 0.0, upper_rad - ref, ref - lower_rad)
            builder.turn(joint, axis, angle)
    return builder.motion(None, lock_feet=False, fps=fps, source="procedural:stress")


PROCEDURAL_MOTIONS: dict[str, Callable[..., Motion]] = {
    "walk": walk_cycle,
    "arm_raises": arm_raises,
    "squat": squat,
    "turn_in_place": turn_in_place,
    "stress": stress,
}
"""Name -> generator; every generator takes (body, frames, fps, *, options...)."""


MAX_PROCEDURAL_FRAMES = 10_000
"""Most frames one procedural clip is made with (5.5 minutes at 30 fps): generating costs ~0.2 MB
per frame (10,000 frames: 2.5 GB, 20 s here; 100,000 were killed for want of memory)."""


def procedural_motion(
    name: str, body: BodyModel, frames: int | None = None, fps: float = DEFAULT_FPS, **options: object
) -> Motion:
    """The procedural motion ``name`` for ``body`` (``frames`` None: the generator's default)."""
    if name not in PROCEDURAL_MOTIONS:
        raise PghmError(f"unknown procedural motion '{name}', expected one of {', '.join(PROCEDURAL_MOTIONS)}")
    generator = PROCEDURAL_MOTIONS[name]
    if frames is not None and not 1 <= frames <= MAX_PROCEDURAL_FRAMES:
        raise PghmError(f"a procedural motion has 1 to {MAX_PROCEDURAL_FRAMES} frames, {frames} were asked")
    if frames is None:
        return generator(body, fps=fps, **options)
    return generator(body, frames, fps, **options)
