"""What covers each surface point, how far cloth stands off the body, and pose-dependent folds.

Three functions of canonical points (:class:`~.regions.SurfacePoints`), used for texels
(colour) and mesh vertices (geometry) alike:

* :func:`material_labels`: skin, hair, top, bottom (trousers, shorts, skirt) or shoes;
* :func:`cloth_displacements`: mostly along the rest normal (fabric thickness, hair
  volume, loose sleeves, flared trousers, a hood); a skirt wraps hips and thighs in a
  flared elliptic cone;
* :func:`fold_patterns`: the static fold pattern G_k of each of the
  :data:`WRINKLE_JOINTS`, a ring of ripples across the limb around the joint,

      G_k(p) = f(d) c(phi) w(p) sign(r) |r|^FOLD_SHARPNESS,
      r = sin(2 pi d / lambda + 1.4 sin(2 phi + psi_k) + psi'_k)

  with d = s - s_k the arc length from the joint along the limb, phi the angle around it,
  f(d) = exp(-(d / sigma_k)^2) the fall-off, c(phi) = c_0 + (1 - c_0) (1 + cos(phi -
  phi_k)) / 2 (c_0 = CREASE_FLOOR) emphasising the crease side phi_k of the bend, and
  w(p) 1 on fabric, SKIN_FOLDS on skin.

Per frame the folds are scaled by :func:`wrinkle_amplitudes`, a_k = clip(theta_k /
theta_full_k, 0, 1) with theta_k the joint's rotation angle, so a straight joint has none:

    height h(p) = sum_k a_k G_k(p)  in [-1, 1],

applied as geometry (``h`` x :data:`FOLD_GEOMETRY_DEPTH` along the normal), as shading
(bump mapping and darkening, :mod:`.render`).
"""

from __future__ import annotations

import numpy as np

from pghm.synth.identity import Identity
from pghm.synth.regions import Landmarks, SurfacePoints, chain_coordinates, chain_lengths

SKIN, HAIR, TOP, BOTTOM, SHOES = range(5)
"""The materials :func:`material_labels` assigns."""

FABRIC_THICKNESS = {TOP: 0.006, BOTTOM: 0.007, SHOES: 0.009}
"""Metres the fabric stands off the skin, per material."""

WAIST_ABOVE_PELVIS = 0.45
"""Waistband height between the pelvis joint (0) and spine2 (1)."""

UNTUCKED_DROP = 0.09
"""Metres an untucked top's hem hangs below the waistband."""

NECKLINE_DEPTH = {"crew": 0.025, "round": 0.06, "v": 0.12}
NECKLINE_HALF_WIDTH = {"crew": 0.06, "round": 0.075, "v": 0.07}

HAIR_FRONT_ABOVE_EYES = 0.055
HAIR_SIDE_ABOVE_EYES = 0.025
HAIR_BACK_BELOW_EYES = 0.04
HAIR_LENGTH_SCALE = 0.13
"""Metres the back hairline drops from a cropped cut (hair_length 0) to shoulder length (1)."""

HEAD_DEPTH = 0.095
"""Metres from the front of the face back to the head's vertical axis."""

SHOE_BELOW_ANKLE = 0.05
"""Metres below the ankle joint (along the leg chain) where a low shoe begins."""

HOOD_SIZE = 0.045
"""Peak outward offset of a hood lying on the upper back, metres."""

SKIRT_MIN_RADIUS = 0.05
"""Floor on a point's elliptic radius in :func:`_skirt_shift`, so points on the skirt's
axis (the crotch) move a bounded amount instead of to infinity."""

SKIRT_PELVIS_BLEND = 0.6
"""Share of a skirt hem's skinning weight moved from the legs to the pelvis."""

WRINKLE_JOINTS = (
    "left_elbow",
    "right_elbow",
    "left_knee",
    "right_knee",
    "left_hip",
    "right_hip",
    "left_shoulder",
    "right_shoulder",
)
"""The joints whose bending makes folds, in the order of the 8 fold channels."""

WRINKLE_FALLOFF = {"elbow": 0.06, "knee": 0.075, "hip": 0.07, "shoulder": 0.06}
"""sigma_k: metres along the limb over which a joint's folds fade."""

FULL_BEND = {"elbow": 1.9, "knee": 1.9, "hip": 1.4, "shoulder": 1.6}
"""theta_full_k: radians of joint rotation at which the folds reach full amplitude."""

CREASE_FLOOR = 0.5
"""c(phi) on the outside of a bend, relative to 1 in its crease."""

FOLD_SHARPNESS = 0.6
"""Exponent < 1 on the ripple: ridges become narrower and steeper, like cloth folds."""

SKIN_FOLDS = 0.3
"""Fold weight on bare skin relative to fabric."""

FOLD_GEOMETRY_DEPTH = 0.005
"""Metres of outward geometry displacement at h = 1."""


def _smoothstep(edge0: float | np.ndarray, edge1: float | np.ndarray, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - edge0) / (edge1 - edge0), 0.0, 1.0)
    return t * t * (3 - 2 * t)


def waist_height(marks: Landmarks) -> float:
    return float(marks.pelvis[1] + WAIST_ABOVE_PELVIS * (marks.spine[1, 1] - marks.pelvis[1]))


def hem_height(marks: Landmarks, identity: Identity) -> float:
    """Height where the top ends and the bottom begins."""
    return waist_height(marks) - (UNTUCKED_DROP if identity.untucked else 0.0)


def hairline_height(points: SurfacePoints, marks: Landmarks, identity: Identity) -> np.ndarray:
    """(N,) height of the hairline above each point's direction around the head.

    A smooth curve through the front (phi = 0), side (pi/2) and back (pi) heights,
    y(phi) = a + b cos phi + c cos 2 phi, plus a small wave so it looks cut, not drawn.
    """
    if identity.hair_length < 0:
        return np.full(len(points.part), np.inf)
    q = points.position - np.array([0.0, marks.eye_height, marks.face_front - HEAD_DEPTH])
    phi = np.arctan2(q[:, 0], q[:, 2])
    front = marks.eye_height + HAIR_FRONT_ABOVE_EYES - 0.03 * identity.fringe
    side = marks.eye_height + HAIR_SIDE_ABOVE_EYES
    back = marks.eye_height - HAIR_BACK_BELOW_EYES - HAIR_LENGTH_SCALE * identity.hair_length
    b = (front - back) / 2
    a = ((front + back) / 2 + side) / 2
    c = ((front + back) / 2 - side) / 2
    return a + b * np.cos(phi) + c * np.cos(2 * phi) + 0.004 * np.sin(9 * phi)


def _hood_weight(points: SurfacePoints, marks: Landmarks) -> np.ndarray:
    """(N,) 0..1 bell over the upper back and back of the neck where a hood lies."""
    p = points.position
    shoulder_y = float(marks.arm_chains[:, 0, 1].mean())
    centre = np.array([0.0, shoulder_y + 0.02, marks.spine[2, 2] - 0.08])
    rel = (p - centre) / np.array([0.13, 0.09, 0.2])
    behind = _smoothstep(0.0, 0.04, marks.neck[2] - p[:, 2])
    trunk = points.is_part("torso", "neck", "upper_arm")
    return np.exp(-(rel**2).sum(1)) * behind * trunk


def material_labels(points: SurfacePoints, marks: Landmarks, identity: Identity) -> np.ndarray:
    """(N,) material of every point: SKIN, HAIR, TOP, BOTTOM or SHOES."""
    p = points.position
    labels = np.full(len(p), SKIN, dtype=np.int64)
    arm_length = chain_lengths(marks.arm_chains[0])[1]
    ankle_s = chain_lengths(marks.leg_chains[0])[1]
    trunk = points.is_part("torso", "hips")
    arms = points.is_part("upper_arm", "lower_arm")
    legs = points.is_part("upper_leg", "lower_leg")
    hem = hem_height(marks, identity)

    # The top: the trunk above the hem, minus the neckline; sleeves down the arms.
    depth = NECKLINE_DEPTH[identity.neckline]
    half_width = NECKLINE_HALF_WIDTH[identity.neckline]
    across = np.clip(np.abs(p[:, 0]) / half_width, 0.0, 1.0)
    dip = depth * (1 - across if identity.neckline == "v" else np.sqrt(1 - across**2))
    collar = marks.neck[1] - 0.035
    front = p[:, 2] > marks.spine[2, 2]
    neck_open = np.where(front, p[:, 1] > collar - dip, p[:, 1] > collar + 0.005)
    top = (trunk | points.is_part("upper_leg")) & (p[:, 1] > hem) & ~neck_open
    top |= arms & (points.limb_s < identity.sleeve * arm_length)
    if identity.hood:
        top |= _hood_weight(points, marks) > 0.25
    labels[top] = TOP

    # The bottom: trunk and legs below the hem, down the legs to its length.
    bottom = (trunk | legs) & (p[:, 1] <= hem) & ~top
    bottom &= ~legs | (points.limb_s < identity.lower_length)
    labels[bottom] = BOTTOM

    # Shoes: the feet, and the leg from a little below the ankle (higher for boots).
    shoe_start = ankle_s - SHOE_BELOW_ANKLE - identity.shoe_height
    shoes = points.is_part("foot") | (points.is_part("lower_leg") & (points.limb_s > shoe_start))
    labels[shoes] = SHOES

    head = points.is_part("head", "neck")
    labels[head & (p[:, 1] > hairline_height(points, marks, identity))] = HAIR
    return labels


def _skirt_region(points: SurfacePoints, labels: np.ndarray, marks: Landmarks) -> np.ndarray:
    """(N,) bool: fabric below the waist, which the skirt (with an untucked top over it) wraps."""
    fabric = np.isin(labels, (TOP, BOTTOM)) & (points.position[:, 1] < waist_height(marks))
    return fabric & points.is_part("hips", "upper_leg", "lower_leg", "torso")


def _skirt_drop(points: SurfacePoints, marks: Landmarks, identity: Identity) -> np.ndarray:
    """(N,) 0 at the waist to 1 at the skirt's hem."""
    return np.clip((waist_height(marks) - points.position[:, 1]) / identity.lower_length, 0.0, 1.0)


def _skirt_shift(points: SurfacePoints, labels: np.ndarray, marks: Landmarks, identity: Identity) -> np.ndarray:
    """(N, 3) horizontal shift that wraps hips and thighs in one skirt (a flared cone).

    The skirt's cross-section at height y is the ellipse (x / a, z / c) = (sin psi, cos psi)
    (z from the pelvis, psi = 0 at the front centre), whose semi-axes grow from the hips'
    by ``skirt_flare`` x drop^1.5 towards the hem. Trunk points inside it move radially
    onto it. Each thigh is unrolled onto its half of the skirt: with theta' its angle
    around the leg (0 front, pi/2 outwards, -pi/2 towards the other leg),

        psi = ((theta' + pi/2) mod 2 pi) / 2,   x = side a sin psi,   z = c cos psi,

    so the inner thigh closes the gap between the legs at the front (psi = 0) and the back
    (psi = pi). The seam along the inner thigh opens inside the skirt, out of sight.
    """
    p = points.position
    skirt = _skirt_region(points, labels, marks)
    hips = points.is_part("hips", "upper_leg") & (np.abs(p[:, 1] - marks.leg_chains[0, 0, 1]) < 0.04)
    half_width = float(np.abs(p[hips, 0]).max()) if hips.any() else 0.18
    half_depth = float(np.abs(p[hips, 2] - marks.pelvis[2]).max()) if hips.any() else 0.12
    grow = identity.skirt_flare * _skirt_drop(points, marks, identity) ** 1.5
    a, c = half_width + grow, half_depth + grow
    x, z = p[:, 0], p[:, 2] - marks.pelvis[2]
    rho = np.maximum(np.sqrt((x / a) ** 2 + (z / c) ** 2), SKIRT_MIN_RADIUS)
    trunk_scale = np.where(rho < 1, 1 / rho - 1, 0.0)
    shift = np.stack([x * trunk_scale, np.zeros(len(p)), z * trunk_scale], axis=1)
    # The crotch (hips points below the hip joints) unrolls with the thighs, else it
    # would stay on the skirt's axis and leave a hole at the front and back centre.
    legs = points.is_part("upper_leg", "lower_leg")
    crotch = points.is_part("hips", "torso") & (p[:, 1] < marks.leg_chains[:, 0, 1].mean())
    limb_angle = points.limb_angle.copy()
    for side_index, sign in enumerate((1, -1)):
        rows = crotch & (points.side == sign)
        if rows.any():
            limb_angle[rows] = chain_coordinates(p[rows], marks.leg_chains[side_index])[1]
    legs |= crotch
    # chain_coordinates puts +pi/2 at -x for both legs: theta' = -side x limb_angle.
    theta = -points.side * limb_angle
    psi = np.mod(theta + np.pi / 2, 2 * np.pi) / 2
    unrolled = np.stack([points.side * a * np.sin(psi) - x, np.zeros(len(p)), c * np.cos(psi) - z], axis=1)
    shift = np.where(legs[:, None], unrolled, shift)
    return shift * skirt[:, None]


def skirt_pelvis_weight(points: SurfacePoints, labels: np.ndarray, marks: Landmarks, identity: Identity) -> np.ndarray:
    """(N,) beta: how much of a skirt point's skinning moves to the pelvis.

    A skirt made of thigh surface would split open with every stride; blending its
    skinning weights towards the root, w' = (1 - beta) w + beta e_root with beta =
    SKIRT_PELVIS_BLEND x drop, makes it swing less than the legs, as cloth does.
    """
    if identity.skirt_flare <= 0:
        return np.zeros(len(labels))
    return SKIRT_PELVIS_BLEND * _skirt_drop(points, marks, identity) * _skirt_region(points, labels, marks)


def cloth_displacements(points: SurfacePoints, labels: np.ndarray, marks: Landmarks, identity: Identity) -> np.ndarray:
    """(N, 3) displacement of canonical points by the cloth, metres (module docstring)."""
    p = points.position
    offset = np.zeros(len(p))
    for material, thickness in FABRIC_THICKNESS.items():
        offset[labels == material] = thickness
    hair = labels == HAIR
    above = p[:, 1] - hairline_height(points, marks, identity)
    offset[hair] = identity.hair_volume * _smoothstep(0.0, 0.025, above[hair])

    arm_length = chain_lengths(marks.arm_chains[0])[1]
    sleeve = (labels == TOP) & points.is_part("upper_arm", "lower_arm")
    cuff = identity.sleeve * arm_length
    offset[sleeve] += identity.loose_sleeves * _smoothstep(0.0, cuff, points.limb_s[sleeve])

    knee_s, ankle_s = chain_lengths(marks.leg_chains[0])[:2]
    leg = (labels == BOTTOM) & points.is_part("upper_leg", "lower_leg")
    offset[leg] += identity.flare * np.clip((points.limb_s[leg] - knee_s) / (ankle_s - knee_s), 0.0, 1.0)

    if identity.hood:
        offset += HOOD_SIZE * _hood_weight(points, marks) * (labels == TOP)
    shift = offset[:, None] * points.normal
    if identity.skirt_flare > 0:
        shift += _skirt_shift(points, labels, marks, identity)
    return shift


def _joint_frame(joint: str, marks: Landmarks) -> tuple[int, float, tuple[str, ...]]:
    """(side index, arc length s_k of the joint along its chain, limb parts) of a fold joint."""
    side_name, kind = joint.split("_", 1)
    side = 0 if side_name == "left" else 1
    if kind in ("elbow", "shoulder"):
        s = 0.0 if kind == "shoulder" else float(chain_lengths(marks.arm_chains[side])[0])
        return side, s, ("upper_arm", "lower_arm")
    s = 0.0 if kind == "hip" else float(chain_lengths(marks.leg_chains[side])[0])
    return side, s, ("upper_leg", "lower_leg")


def crease_angle(joint: str) -> float:
    """phi_k: the side of the limb that folds in when the joint bends (limb angle 0 = front).

    Elbows and hips fold at the front, knees at the back, shoulders in the armpit, which
    for the left arm is at +pi/2 of :func:`~.regions.chain_coordinates`' frame and for the
    right arm at -pi/2 (the frame's second axis, axis x +z, mirrors between the arms).
    """
    side, kind = joint.split("_", 1)
    return {"elbow": 0.0, "hip": 0.0, "knee": np.pi}.get(kind, np.pi / 2 if side == "left" else -np.pi / 2)


def fold_patterns(
    points: SurfacePoints,
    labels: np.ndarray,
    marks: Landmarks,
    identity: Identity,
    phases: np.ndarray,
) -> np.ndarray:
    """(N, 8) static fold patterns G_k in [-1, 1] (module docstring).

    Args:
        points: canonical points.
        labels: (N,) their materials.
        marks: landmarks of the shaped body.
        identity: gives the fold wavelength and strength.
        phases: (8, 2) psi_k, psi'_k of every joint's ripple.
    """
    patterns = np.zeros((len(points.part), len(WRINKLE_JOINTS)))
    material = np.where(labels == SKIN, SKIN_FOLDS, np.where(np.isin(labels, (TOP, BOTTOM)), 1.0, 0.0))
    for k, joint in enumerate(WRINKLE_JOINTS):
        side, s_joint, parts = _joint_frame(joint, marks)
        on_limb = points.is_part(*parts) & (points.side == (1 if side == 0 else -1))
        d = points.limb_s - s_joint
        sigma = WRINKLE_FALLOFF[joint.split("_", 1)[1]]
        falloff = np.exp(-((d / sigma) ** 2))
        crease = CREASE_FLOOR + (1 - CREASE_FLOOR) * 0.5 * (1 + np.cos(points.limb_angle - crease_angle(joint)))
        ripple = np.sin(
            2 * np.pi * d / identity.wrinkle_wavelength
            + 1.4 * np.sin(2 * points.limb_angle + phases[k, 0])
            + phases[k, 1]
        )
        sharp = np.sign(ripple) * np.abs(ripple) ** FOLD_SHARPNESS
        patterns[:, k] = identity.wrinkle_strength * falloff * crease * material * sharp * on_limb
    return patterns


def wrinkle_amplitudes(rotations: np.ndarray, joint_map: dict[str, int]) -> np.ndarray:
    """(B, 8) fold amplitudes a_k = clip(theta_k / theta_full_k, 0, 1) of poses (B, J, 3)."""
    columns = []
    for joint in WRINKLE_JOINTS:
        angle = np.linalg.norm(rotations[:, joint_map[joint]], axis=-1)
        columns.append(np.clip(angle / FULL_BEND[joint.split("_", 1)[1]], 0.0, 1.0))
    return np.stack(columns, axis=1)
