"""Where a canonical surface point lies on the body: part, limb coordinates, head frame.

Every painter and cloth deformer in :mod:`pghm.synth` works on canonical (rest-pose)
surface points, texel centres and mesh vertices alike, described by

    part       which body part carries the point: the canonical joint (see
               :data:`pghm.body.CANONICAL_JOINTS`) that is the nearest ancestor of the
               point's most-weighted bone, mapped to a :data:`PART_NAMES` entry;
    limb_s     arc length in metres along the limb's joint chain (shoulder -> elbow ->
               wrist, hip -> knee -> ankle) of the point's projection, 0 at the top joint;
    limb_angle angle (radians) around the limb's axis, 0 towards +z (the body's front);
    u, v       surface coordinates in metres for patterns: around and along a limb, or
               around (angle x TORSO_RADIUS) and up (y) the trunk and head.

Coordinates are 3D-derived, not UV-derived, so stripes and checks run across UV seams,
and they depend only on the rest joints, so a region (a sleeve's end, a waistline) sits at
the same place on the body for every shape.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

PART_NAMES = (
    "head",
    "neck",
    "torso",
    "hips",
    "upper_arm",
    "lower_arm",
    "hand",
    "upper_leg",
    "lower_leg",
    "foot",
)
"""Body parts, indexed by the ``part`` arrays. Limb parts come in a left and a right copy,
told apart by :attr:`SurfacePoints.side`."""

PART = {name: index for index, name in enumerate(PART_NAMES)}

CANONICAL_TO_PART = {
    "pelvis": "hips",
    "spine1": "torso",
    "spine2": "torso",
    "spine3": "torso",
    "neck": "neck",
    "head": "head",
    "collar": "torso",
    "shoulder": "upper_arm",
    "elbow": "lower_arm",
    "wrist": "hand",
    "hip": "upper_leg",
    "knee": "lower_leg",
    "ankle": "foot",
    "foot": "foot",
}
"""Canonical joint (without its ``left_``/``right_`` prefix) -> body part."""

TORSO_RADIUS = 0.15
"""Metres per radian of the trunk's around-coordinate ``u`` (a typical trunk radius), so
that trunk patterns have their nominal size in metres."""

LIMB_RADIUS = 0.05
"""Metres per radian of a limb's around-coordinate ``u`` (a typical arm or leg radius)."""

HAND_LENGTH = 0.19
"""Extension of the arm chain beyond the wrist, metres, so hand points project onto it."""

FOOT_DROP = 0.08
"""Extension of the leg chain below the ankle, metres, so heel points project onto it."""


def bone_parts(bone_names: list[str], parents: list[int], joint_map: dict[str, int]) -> np.ndarray:
    """(J,) part index of every bone: the part of its nearest canonical ancestor (or itself).

    Backend-independent: it needs only the canonical joint map and the bone tree. A bone
    with no canonical ancestor (cannot happen for a tree rooted at the pelvis) gets "hips".
    """
    canonical = {bone: name.split("_", 1)[-1] for name, bone in joint_map.items()}
    parts = np.full(len(bone_names), PART["hips"], dtype=np.int64)
    for bone in range(len(bone_names)):
        ancestor = bone
        while ancestor >= 0 and ancestor not in canonical:
            ancestor = parents[ancestor]
        if ancestor >= 0:
            parts[bone] = PART[CANONICAL_TO_PART[canonical[ancestor]]]
    return parts


@dataclass(frozen=True)
class Landmarks:
    """Rest-pose reference points of one shaped body (metres, world frame).

    Attributes:
        arm_chains: (2, 4, 3) left/right shoulder, elbow, wrist, hand tip.
        leg_chains: (2, 4, 3) left/right hip, knee, ankle, heel.
        pelvis: (3,) root joint.
        spine: (3, 3) the spine1..spine3 joints, bottom up.
        neck: (3,) neck joint.
        head: (3,) head joint (bottom of the skull).
        head_top: height of the top of the head.
        feet: height of the soles.
        eye_height: height of the eyes.
        face_front: z of the front of the face.
        eye_offset: half the distance between the eyes (x).
    """

    arm_chains: np.ndarray
    leg_chains: np.ndarray
    pelvis: np.ndarray
    spine: np.ndarray
    neck: np.ndarray
    head: np.ndarray
    head_top: float
    feet: float
    eye_height: float
    face_front: float
    eye_offset: float

    @property
    def height(self) -> float:
        return self.head_top - self.feet

    @property
    def centre_height(self) -> float:
        """Height halfway between soles and crown: where cameras aim."""
        return 0.5 * (self.head_top + self.feet)


EYE_BELOW_CROWN = 0.115
"""Crown-to-eye distance of an adult head, metres (anthropometric average, ~ half the
head height), used to place the eyes on backends without eye bones."""

EYE_OFFSET_DEFAULT = 0.031
"""Half the adult interpupillary distance (~62 mm), metres."""


def landmarks(
    vertices: np.ndarray,
    joints: np.ndarray,
    vertex_parts: np.ndarray,
    joint_map: dict[str, int],
    bone_names: list[str],
) -> Landmarks:
    """Reference points of a shaped rest body.

    Args:
        vertices: (V, 3) rest vertices.
        joints: (J, 3) rest joints.
        vertex_parts: (V,) part index of every vertex.
        joint_map: canonical joint name -> bone index.
        bone_names: J bone names (eye bones, when the backend has them, place the eyes).
    """

    def joint(name: str) -> np.ndarray:
        return joints[joint_map[name]].astype(np.float64)

    def chain(side: str, names: tuple[str, str, str], extension: float) -> np.ndarray:
        a, b, c = (joint(f"{side}_{name}") for name in names)
        direction = (c - b) / max(np.linalg.norm(c - b), 1e-9)
        return np.stack([a, b, c, c + extension * direction])

    arms = np.stack([chain(side, ("shoulder", "elbow", "wrist"), HAND_LENGTH) for side in ("left", "right")])
    legs = np.stack([chain(side, ("hip", "knee", "ankle"), FOOT_DROP) for side in ("left", "right")])
    head_points = vertices[vertex_parts == PART["head"]]
    head_top = float(head_points[:, 1].max())
    eyes = [bone_names.index(name) for name in ("eye.L", "eye.R") if name in bone_names]
    if len(eyes) == 2:
        eye_height = float(joints[eyes, 1].mean())
        eye_offset = float(abs(joints[eyes[0], 0] - joints[eyes[1], 0]) / 2)
    else:
        eye_height = head_top - EYE_BELOW_CROWN
        eye_offset = EYE_OFFSET_DEFAULT
    near_eyes = head_points[np.abs(head_points[:, 1] - eye_height) < 0.03]
    return Landmarks(
        arm_chains=arms,
        leg_chains=legs,
        pelvis=joint("pelvis"),
        spine=np.stack([joint(name) for name in ("spine1", "spine2", "spine3")]),
        neck=joint("neck"),
        head=joint("head"),
        head_top=head_top,
        feet=float(vertices[:, 1].min()),
        eye_height=eye_height,
        face_front=float(near_eyes[:, 2].max()) if len(near_eyes) else float(head_points[:, 2].max()),
        eye_offset=eye_offset,
    )


@dataclass(frozen=True)
class SurfacePoints:
    """Canonical surface points with their body coordinates (module docstring).

    Attributes:
        position: (N, 3) rest positions.
        normal: (N, 3) rest unit normals.
        part: (N,) part index into :data:`PART_NAMES`.
        side: (N,) +1 for the body's left (x > 0), -1 for its right.
        limb_s: (N,) arc length along the limb chain, metres (0 off the limbs).
        limb_angle: (N,) angle around the limb axis, radians (0 off the limbs).
        u: (N,) around-coordinate, metres.
        v: (N,) along-coordinate, metres.
    """

    position: np.ndarray
    normal: np.ndarray
    part: np.ndarray
    side: np.ndarray
    limb_s: np.ndarray
    limb_angle: np.ndarray
    u: np.ndarray
    v: np.ndarray

    def is_part(self, *names: str) -> np.ndarray:
        """(N,) bool, True where the point's part is one of ``names``."""
        return np.isin(self.part, [PART[name] for name in names])


def chain_coordinates(points: np.ndarray, chain: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Arc length and angle of points around a joint chain (polyline).

    Each point is projected onto the nearest of the chain's segments a_k -> b_k:

        lambda = clamp(<p - a, b - a> / |b - a|^2, 0, 1),  s = S_k + lambda |b - a|

    with S_k the chain length before segment k, and its angle around that segment is
    atan2(<r, e2>, <r, e1>) for the radial part r of p - a, e1 the +z axis made
    perpendicular to the segment and e2 = axis x e1.

    Args:
        points: (N, 3).
        chain: (K, 3) joint positions along the chain.

    Returns:
        s: (N,) arc length, metres.
        angle: (N,) radians in (-pi, pi].
    """
    starts, ends = chain[:-1], chain[1:]
    lengths = np.linalg.norm(ends - starts, axis=1)
    offsets = np.concatenate([[0.0], np.cumsum(lengths)[:-1]])
    axes = (ends - starts) / lengths[:, None]
    rel = points[:, None, :] - starts[None]  # (N, K, 3)
    lam = np.clip((rel * axes[None]).sum(-1) / lengths[None], 0.0, 1.0)
    closest = starts[None] + lam[..., None] * (ends - starts)[None]
    nearest = np.linalg.norm(points[:, None, :] - closest, axis=-1).argmin(1)
    rows = np.arange(len(points))
    s = offsets[nearest] + lam[rows, nearest] * lengths[nearest]
    axis = axes[nearest]
    front = np.array([0.0, 0.0, 1.0])
    e1 = front - (axis @ front)[:, None] * axis
    e1 /= np.maximum(np.linalg.norm(e1, axis=1, keepdims=True), 1e-9)
    e2 = np.cross(axis, e1)
    radial = rel[rows, nearest]
    return s, np.arctan2((radial * e2).sum(1), (radial * e1).sum(1))


def describe_points(
    position: np.ndarray, normal: np.ndarray, part_weights: np.ndarray, marks: Landmarks
) -> SurfacePoints:
    """Body coordinates of canonical points.

    Args:
        position: (N, 3) rest positions.
        normal: (N, 3) rest unit normals.
        part_weights: (N, P) skinning weight summed per part (P = len(PART_NAMES)).
        marks: landmarks of the same shaped body.
    """
    part = part_weights.argmax(1)
    side = np.where(position[:, 0] >= 0.0, 1, -1)
    limb_s = np.zeros(len(position))
    limb_angle = np.zeros(len(position))
    u = np.arctan2(position[:, 0], position[:, 2] - marks.spine[1, 2]) * TORSO_RADIUS
    v = position[:, 1].astype(np.float64).copy()
    limbs = (
        (("upper_arm", "lower_arm", "hand"), marks.arm_chains),
        (("upper_leg", "lower_leg", "foot"), marks.leg_chains),
    )
    for parts, chains in limbs:
        for side_index, sign in enumerate((1, -1)):
            rows = np.isin(part, [PART[p] for p in parts]) & (side == sign)
            if rows.any():
                s, angle = chain_coordinates(position[rows].astype(np.float64), chains[side_index])
                limb_s[rows], limb_angle[rows] = s, angle
                u[rows], v[rows] = angle * LIMB_RADIUS, -s
    return SurfacePoints(
        position=position.astype(np.float64),
        normal=normal.astype(np.float64),
        part=part,
        side=side,
        limb_s=limb_s,
        limb_angle=limb_angle,
        u=u,
        v=v,
    )


def chain_lengths(chain: np.ndarray) -> np.ndarray:
    """(K-1,) cumulative arc length at each joint after the first of a (K, 3) chain."""
    return np.cumsum(np.linalg.norm(np.diff(chain, axis=0), axis=1))
