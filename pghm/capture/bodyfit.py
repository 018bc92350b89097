"""Fit Anny to a video's landmarks and masks: one shape, per-frame pose, a static camera.

All frames are fitted at once (vectorised torch, Adam), in stages as SMPLify does:

1. camera and root: root rotation and translation (and the focal length when the
   intrinsics are unknown) against the torso landmarks, the body at rest;
2. pose: the body bones join, with every landmark, the metric 3D landmarks, temporal
   smoothness and the pose prior;
3. shape and silhouette: the 6 phenotypes join, with the mask terms.

Before them, MediaPipe's left/right label swaps are found over the video and undone
(:mod:`pghm.capture.swaps`).

The objective, over frames f and body landmarks l (:mod:`pghm.capture.landmarks`),

    E = w_2d   sum c_fl rho(|pi(p_fl) - x_fl| / h)                  2D reprojection
      + w_3d   sum c_fl huber(|(p_fl - p_f,hips) - X_fl|)           metric 3D, root-relative
      + w_out  sum_v D_f(pi(v_fv)) / h                              vertices outside the mask
      + w_cov  sum_m rho(min_v |pi(v_fv) - m_fm| / h)               mask pixels the body misses
      + w_acc  sum |p_f-1 - 2 p_f + p_f+1|^2                        temporal smoothness
      + w_pose |theta|^2 + w_limit relu(hinge outside its range)^2  pose prior, joint limits
      + w_mocap rho_c(m(theta))                                     learned pose prior
      + w_shape |s - s_average|^2                                   shape prior

with pi the pinhole projection, c the landmark confidences, h the person's height in
pixels, rho(r) = r^2 / (r^2 + sigma^2) (Geman-McClure), X MediaPipe's world landmarks
(hip-centred, camera-aligned: OpenCV axes), D_f the distance transform of frame f's mask
complement and m_fm pixels sampled inside the mask; m(theta) is the squared Mahalanobis
distance of a frame's joint rotations under a Gaussian learned from motion capture and rho_c
its saturating penalty (:mod:`pghm.capture.pose_prior`).

Speed: bones whose rotation stays at rest move rigidly with their nearest fitted
ancestor (their local transform is the identity), so skinning weights are folded onto the
~18 fitted bones and forward kinematics runs on those only; only the landmark vertices and
a subsample of the mesh are skinned; the rest body is linear in the shape around the
current estimate (re-linearised during stage 3), so Anny's full shape model runs a few
times, not every step.

World frame (the subject format's): y up, the camera static at world_to_camera, looking
along -z at the body, which faces +z at rest; the world is re-centred so the mean root
translation is zero (the person stands about the origin on y = 0). All camera motion ends
up in the root.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import roma
import torch
from scipy.ndimage import distance_transform_edt
from torch import Tensor

from pghm.body import BodyModel, load_body
from pghm.body.model import CANONICAL_JOINTS
from pghm.body.skinning import forward_kinematics, kinematic_levels, lbs
from pghm.capture.config import HEIGHT_RANGE_M, BodyFitConfig
from pghm.capture.landmarks import BODY_LANDMARKS, LANDMARK_NAMES, NUM_LANDMARKS, landmark_regressor
from pghm.capture.pose_prior import load_pose_prior, robust_mahalanobis
from pghm.capture.swaps import Landmarks, repair_swaps
from pghm.errors import PghmError

if TYPE_CHECKING:
    from pghm.capture.frontend import Observations

UNFITTED_JOINTS = ("pelvis", "left_wrist", "right_wrist", "left_foot", "right_foot")
"""Canonical joints not fitted as bones: the pelvis is the root (its rotation is the root's); the
wrist and foot joints turn the hands and toes, which the fit keeps at rest."""
FITTED_JOINTS = tuple(name for name in CANONICAL_JOINTS if name not in UNFITTED_JOINTS)
"""Canonical joints whose rotation is fitted (besides the root); hands, toes, face and the
limbs' twist bones stay at rest."""

HINGES = {
    "left_elbow": "left_shoulder",
    "right_elbow": "right_shoulder",
    "left_knee": "left_hip",
    "right_knee": "right_hip",
}
"""Hinge joint -> the joint heading the segment before it. The hinge turns about
d x z / |d x z|, d that segment's rest direction (the synthetic poses' forward swing)."""

HINGE_RANGE = {"elbow": (0.0, 2.6), "knee": (-2.6, 0.0)}
"""Allowed hinge angles (radians): elbows flex forwards (positive), knees backwards (negative)."""

CAMERA_LOOK = np.diag([1.0, -1.0, -1.0])
"""Rotation of the fitted camera: OpenCV axes (x right, y down, z forward) with the world's
y up and the camera looking along -z (at a body facing +z)."""

TORSO = ("left_shoulder", "right_shoulder", "left_hip", "right_hip")
HIPS = ("left_hip", "right_hip")

PRIOR_WEIGHTS = {
    "spine1": 4.0,
    "spine2": 4.0,
    "spine3": 4.0,
    "neck": 2.0,
    "head": 1.0,
    "left_collar": 8.0,
    "right_collar": 8.0,
    "left_ankle": 2.0,
    "right_ankle": 2.0,
}
"""Relative pose-prior weight per fitted joint (1 for the others): the spine, collars and
ankles are weakly observed by the landmarks and move little."""


@dataclass
class BodyFit:
    """The fitted body (the subject format's poses and camera).

    Attributes:
        shape: (S,) the body's shape for the whole video (Anny: 6 phenotypes in [0, 1]).
        rotations: (F, J, 3) axis-angle per bone (J = body.num_bones).
        translation: (F, 3) root translation, metres, world frame (y up).
        world_to_camera: (4, 4) the static camera, OpenCV axes.
        K: (3, 3) intrinsics, given or estimated.
        residuals: final value of each term (2D error in pixels, 3D error in metres, ...).
    """

    shape: np.ndarray
    rotations: np.ndarray
    translation: np.ndarray
    world_to_camera: np.ndarray
    K: np.ndarray
    residuals: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class _Skeleton:
    """The fitted bones: the root plus :data:`FITTED_JOINTS`, with folded skinning weights.

    Attributes:
        bones: (B,) Anny bone index of each fitted bone (root first).
        parents: B parent indices into ``bones`` (-1 for the root).
        fold: (J, B) one-hot: Anny bone -> its nearest fitted ancestor (itself if fitted).
        hinge_rows: row (1..B-1, in FITTED_JOINTS order + 1) of each hinge joint.
        hinge_axes: (H, 3) unit hinge axes in rest axes (from the average body).
    """

    bones: list[int]
    parents: list[int]
    fold: Tensor
    hinge_rows: list[int]
    hinge_axes: Tensor


def _skeleton(body: BodyModel) -> _Skeleton:
    bones = [0] + [body.joint_map[name] for name in FITTED_JOINTS]
    order = sorted(bones)
    fitted = {bone: order.index(bone) for bone in order}

    def fitted_ancestor(bone: int) -> int:
        while bone not in fitted:
            bone = body.parents[bone]
        return fitted[bone]

    fold = torch.zeros(body.num_bones, len(order))
    for bone in range(body.num_bones):
        fold[bone, fitted_ancestor(bone)] = 1.0
    parents = [-1] + [fitted_ancestor(body.parents[bone]) for bone in order[1:]]
    axes = hinge_axes(body)
    rows = [order.index(body.joint_map[hinge]) for hinge in HINGES]
    return _Skeleton(order, parents, fold, rows, torch.stack([axes[hinge] for hinge in HINGES]))


def hinge_axes(body: BodyModel) -> dict[str, Tensor]:
    """Hinge joint -> (3,) unit axis d x z / |d x z| in rest axes, d the rest direction of the
    segment before it (:data:`HINGES`), on the average body."""
    joints = body.rest().joints
    axes = {}
    for hinge, before in HINGES.items():
        d = joints[body.joint_map[hinge]] - joints[body.joint_map[before]]
        axis = torch.linalg.cross(d, torch.tensor([0.0, 0.0, 1.0]))
        axes[hinge] = axis / axis.norm()
    return axes


@dataclass
class _Frames:
    """Observations as tensors, and the per-video constants derived from them."""

    points: Tensor  # (F, L, 2) body landmarks, pixels
    weights: Tensor  # (F, L) confidences, zero below min_confidence
    world3d: Tensor  # (F, L, 3) MediaPipe world landmarks in the fit's world axes, hip-centred
    height_px: float  # the person's height in pixels (loss normaliser)
    outside: Tensor  # (F, 1, h, w) distance (in full-size pixels) to the mask, zero inside
    mask_step: int  # full-size pixels per distance-map pixel: map pixel k is full-size pixel step k
    inside: Tensor  # (F, M, 2) pixels sampled inside each mask (full-size pixel coordinates)
    inside_valid: Tensor  # (F, M) whether the frame had mask pixels to sample
    gaps: Tensor  # (F - 1,) source-frame gaps between consecutive kept frames
    repaired: dict[str, int]  # frames relabelled per kind of left/right swap (pghm.capture.swaps)


def _check(observations: Observations) -> int:
    frames = len(observations.frame_index)
    height, width = observations.image_size
    expected = {
        "landmarks_2d": (frames, NUM_LANDMARKS, 2),
        "confidence": (frames, NUM_LANDMARKS),
        "landmarks_3d": (frames, NUM_LANDMARKS, 3),
        "masks": (frames, height, width),
    }
    if frames == 0:
        raise PghmError("body fit: no frames to fit (no person was found in any kept frame)")
    for name, shape in expected.items():
        value = np.asarray(getattr(observations, name))
        if value.shape != shape:
            raise PghmError(f"body fit: observations.{name} has shape {value.shape}, expected {shape}")
        if name != "masks" and not np.isfinite(value).all():
            bad = np.unique(np.nonzero(~np.isfinite(value))[0])
            frames_bad = np.asarray(observations.frame_index)[bad].tolist()
            raise PghmError(f"body fit: observations.{name} is not finite in frames {frames_bad}")
    box = observations.frame_box
    valid = box is None or (np.shape(box) == (4,) and np.isfinite(box).all() and box[0] < box[2] and box[1] < box[3])
    if not valid:
        raise PghmError(f"body fit: observations.frame_box must be finite x0, y0, x1, y1 with x0 < x1, y0 < y1: {box}")
    return frames


def _prepare(observations: Observations, config: BodyFitConfig, rng: np.random.Generator) -> _Frames:
    index = list(BODY_LANDMARKS)
    marks = Landmarks(
        np.asarray(observations.landmarks_2d, np.float32),
        np.asarray(observations.confidence, np.float32),
        np.asarray(observations.landmarks_3d, np.float32),
    )
    masks = np.asarray(observations.masks, bool)
    heights = [np.ptp(np.nonzero(m.any(1))[0]) + 1 for m in masks if m.any()]
    if not heights:  # no mask anywhere: the landmarks' vertical extent
        seen = marks.confidence[:, index] >= config.min_confidence
        heights = [float(np.ptp(p[v, 1])) for p, v in zip(marks.points[:, index], seen) if v.sum() > 2]
    height_px = max(float(np.median(heights)) if heights else 1.0, 1.0)
    repaired = {}
    if config.repair_swaps:
        marks, repair = repair_swaps(marks, height_px, np.asarray(observations.frame_index))
        repaired = {f"swapped_frames_{kind}": int(flags.sum()) for kind, flags in vars(repair).items()}
    points = torch.as_tensor(marks.points[:, index])
    confidence = torch.as_tensor(marks.confidence[:, index])
    weights = confidence * (confidence >= config.min_confidence)
    world3d = torch.as_tensor(marks.world[:, index]) @ torch.as_tensor(CAMERA_LOOK, dtype=torch.float32)

    step = max(1, int(np.ceil(max(masks.shape[1:]) / config.mask_size)))
    small = masks[:, ::step, ::step]
    outside = np.stack([distance_transform_edt(~m) * step if m.any() else np.zeros(m.shape) for m in small])
    inside = np.zeros((len(masks), config.coverage_samples, 2), np.float32)
    inside_valid = np.zeros((len(masks), config.coverage_samples), bool)
    for f, m in enumerate(small):
        rows, cols = np.nonzero(m)
        if len(rows):
            pick = rng.integers(0, len(rows), config.coverage_samples)
            inside[f] = np.stack([cols[pick], rows[pick]], 1) * step + 0.5  # the sampled pixel's centre
            inside_valid[f] = True
    frame_index = np.asarray(observations.frame_index, np.float64)
    gaps = np.maximum(np.diff(frame_index), 1.0) if len(frame_index) > 1 else np.ones(0)
    return _Frames(
        points,
        weights,
        world3d,
        height_px,
        torch.as_tensor(outside, dtype=torch.float32)[:, None],
        step,
        torch.as_tensor(inside),
        torch.as_tensor(inside_valid),
        torch.as_tensor(gaps, dtype=torch.float32),
        repaired,
    )


HEIGHT_PHENOTYPE = "height"
"""Anny's phenotype that sets the body's height (the rest body's height is linear in it: 1.12 m at
0, 1.63 at 0.5, 2.13 at 1, the other phenotypes at their average)."""

HEIGHT_SCALE_M = 0.01
"""The given height's term is 1 (times its weight) a centimetre off."""

HEIGHT_BISECTIONS = 16
"""Bisection steps of :func:`shape_of_height`: the phenotype to 2^-16, about 0.02 mm of height."""


def rest_height(body: BodyModel, shape: Tensor) -> float:
    """The rest body's height in metres: its vertices' extent along y (up)."""
    vertices = body.rest(shape).vertices
    return float(vertices[:, 1].max() - vertices[:, 1].min())


def shape_of_height(body: BodyModel, height_m: float) -> Tensor:
    """(S,) the body's default shape with its height phenotype set so that the rest body is
    ``height_m`` tall (bisection: the height grows with the phenotype); :class:`PghmError` outside
    :data:`HEIGHT_RANGE_M`."""
    low_m, high_m = HEIGHT_RANGE_M
    if not low_m <= height_m <= high_m:
        raise PghmError(f"--height {height_m:g} m: the body model spans {low_m:g}-{high_m:g} m")
    shape = body.default_shape()
    k = body.shape_names.index(HEIGHT_PHENOTYPE)
    low, high = 0.0, 1.0
    for _ in range(HEIGHT_BISECTIONS):
        shape[k] = (low + high) / 2
        low, high = (float(shape[k]), high) if rest_height(body, shape) < height_m else (low, float(shape[k]))
    shape[k] = (low + high) / 2
    return shape


class _ShapeModel:
    """The rest body's needed vertices and fitted joints, linear in the shape around ``centre``.

    rest(s) = rest(s0) + J (s - s0), J by forward differences of Anny's shape model.
    """

    STEP = 0.05
    """Phenotype step of the forward differences (Anny blends its targets piecewise linearly)."""

    def __init__(self, body: BodyModel, vertices: Tensor, bones: list[int]) -> None:
        self.body, self.vertices, self.bones = body, vertices, bones

    def linearise(self, centre: Tensor) -> None:
        self.centre = centre.detach().clone()
        base = self._evaluate(self.centre)
        columns = []
        for k in range(len(self.centre)):
            step = self.STEP if self.centre[k] + self.STEP <= 1.0 else -self.STEP
            shifted = self.centre.clone()
            shifted[k] += step
            columns.append((self._evaluate(shifted) - base) / step)
        self.base, self.jacobian = base, torch.stack(columns, -1)  # (N, 3), (N, 3, S)

    def _evaluate(self, shape: Tensor) -> Tensor:
        rest = self.body.rest(shape)
        return torch.cat([rest.vertices[self.vertices], rest.joints[self.bones]])

    def __call__(self, shape: Tensor) -> tuple[Tensor, Tensor]:
        """(N_v, 3) rest vertices and (B, 3) rest joints at ``shape`` (S,)."""
        flat = self.base + self.jacobian @ (shape - self.centre)
        return flat[: len(self.vertices)], flat[len(self.vertices) :]


def _geman_mcclure(squared: Tensor, sigma: float) -> Tensor:
    return squared / (squared + sigma**2)


def _map_grid(pixels: Tensor, step: int, size: tuple[int, int]) -> Tensor:
    """(..., 2) ``grid_sample`` coordinates (align_corners=False) of full-size pixel positions
    (centres at half-integers) in a map that keeps every ``step``-th pixel, (h, w) = ``size``.

    Map pixel k is full-size pixel step k, centred at step k + 1/2: index x_s = (x - 1/2) / step,
    and grid_sample reads index x_s at x_n = (2 x_s + 1) / w - 1.
    """
    index = (pixels - 0.5) / step
    extent = torch.tensor([size[1], size[0]], dtype=pixels.dtype)
    return (2 * index + 1) / extent - 1


def _project(points: Tensor, focal: Tensor, centre: Tensor, camera: Tensor) -> Tensor:
    """(F, N, 2) pixels of world points (F, N, 3): camera (4, 4) world_to_camera, shared focal."""
    cam = points @ camera[:3, :3].T + camera[:3, 3]
    return cam[..., :2] / cam[..., 2:].clamp_min(1e-3) * focal + centre


def _procrustes_rotation(source: Tensor, target: Tensor, weights: Tensor) -> Tensor:
    """(F, 3, 3) rotations R minimising sum_i w_i |R s_i - t_i|^2 for centred (F, N, 3) point sets."""
    covariance = torch.einsum("fn,fni,fnj->fij", weights, target, source)
    u, _, vt = torch.linalg.svd(covariance + 1e-9 * torch.eye(3))
    d = torch.ones(len(u), 3)
    d[:, -1] = torch.sign(torch.linalg.det(u @ vt))
    return u @ torch.diag_embed(d) @ vt


def fit_body(observations: Observations, config: BodyFitConfig | None = None) -> BodyFit:
    """Fit one Anny shape, per-frame poses and a static camera to the observations.

    Args:
        observations: the front end's output for F kept frames (pghm.capture.frontend).
        config: options (defaults: :class:`BodyFitConfig`).

    Returns:
        the fit, F frames in the observations' order.
    """
    config = (config or BodyFitConfig()).validate()
    threads = torch.get_num_threads()
    # The tensors are small (F x ~800 points): with two threads each of the thousands of
    # small ops waits on the other, and on a loaded 2-core machine the fit of 300 frames
    # took 527 s instead of 20 s with one.
    torch.set_num_threads(1)
    try:
        return _fit(observations, config)
    finally:
        torch.set_num_threads(threads)


def _fit(observations: Observations, config: BodyFitConfig) -> BodyFit:
    problem = _BodyFitProblem(observations, config)
    terms = problem.minimise()
    return problem.result(terms)


class _BodyFitProblem:
    """The body fit as an optimisation problem (SMPLify's layout): the observations' tensors, the
    free parameters, and one method per term of the objective in the module docstring.

    Free parameters: ``root`` (F, 3) and ``pose`` (F, B - 1, 3) axis-angle, ``translation`` (F, 3)
    metres, ``shape_logit`` (S,) (the phenotypes through a sigmoid) and ``log_focal`` (a scalar,
    optimised only when the intrinsics are unknown and ``config.fit_focal``).
    """

    def __init__(self, observations: Observations, config: BodyFitConfig) -> None:
        self.config = config
        self.frames = _check(observations)
        self.rng = np.random.default_rng(config.seed)
        self.body = body = load_body(config.body)
        self.skeleton = _skeleton(body)
        self.data = _prepare(observations, config, self.rng)
        self._build_body_models()
        self.levels = kinematic_levels(self.skeleton.parents)
        self.hips = [BODY_LANDMARKS.index(LANDMARK_NAMES.index(name)) for name in HIPS]
        self.torso = [BODY_LANDMARKS.index(LANDMARK_NAMES.index(name)) for name in TORSO]
        self._set_camera(observations)
        self._initialise()
        self._build_pose_priors()

    def _build_body_models(self) -> None:
        """The skinned vertices (landmark regressor's, then a silhouette subsample), their folded
        weights, and the rest body (and its height) linear in the shape around the start shape."""
        body, config = self.body, self.config
        self.regressor_index, self.regressor_weights = landmark_regressor(body.num_vertices)
        silhouette = torch.as_tensor(
            np.sort(self.rng.choice(body.num_vertices, config.silhouette_vertices, replace=False))
        )
        vertex_ids = torch.cat([self.regressor_index.reshape(-1), silhouette])
        self.weights = (body.skin_weights[vertex_ids] @ self.skeleton.fold).contiguous()
        self.num_marks = self.regressor_index.numel()
        self.shape_model = _ShapeModel(body, vertex_ids, self.skeleton.bones)
        self.shape0 = body.default_shape() if config.height_m is None else shape_of_height(body, config.height_m)
        self.shape_model.linearise(self.shape0)
        # The crown and the lowest sole of the rest body: its height, linear in the shape as the rest is.
        self.height_model = None
        if config.height_m is not None:
            rest_y = body.rest(self.shape0).vertices[:, 1]
            self.height_model = _ShapeModel(body, torch.stack([rest_y.argmax(), rest_y.argmin()]), [])
            self.height_model.linearise(self.shape0)

    def _set_camera(self, observations: Observations) -> None:
        """The static camera looking at the body, and the intrinsics: given, or the default's to refine."""
        self.camera = torch.eye(4)
        self.camera[:3, :3] = torch.as_tensor(CAMERA_LOOK, dtype=torch.float32)
        if observations.K is not None:
            K = torch.as_tensor(np.asarray(observations.K, np.float32))  # noqa: N806
            self.focal0 = float(K[0, 0] + K[1, 1]) / 2
            self.centre = K[:2, 2].clone()
        else:
            self.focal0, principal = default_intrinsics(observations, self.config.default_fov_deg)
            self.centre = torch.as_tensor(principal, dtype=torch.float32)
        self.log_focal = torch.tensor(np.log(self.focal0), dtype=torch.float32, requires_grad=True)
        self.fit_focal = observations.K is None and self.config.fit_focal

    def _initialise(self) -> None:
        """Root rotation from MediaPipe's torso (Procrustes against the rest body's torso landmarks),
        root position from the 2D-3D correspondence at the default focal; pose at rest."""
        frames, hips, bones = self.frames, self.hips, len(self.skeleton.bones)
        rest_marks, _ = self.posed(torch.zeros(frames, bones, 3), torch.zeros(frames, 3), self.shape0)
        rest_rel = rest_marks - rest_marks[:, hips].mean(1, keepdim=True)
        torso_w = self.data.weights[:, self.torso] + 1e-3
        rotation0 = _procrustes_rotation(rest_rel[:, self.torso], self.data.world3d[:, self.torso], torso_w)
        position = _hip_positions(self.data, self.focal0, self.centre)  # (F, 3) camera frame
        hip_world = (position - self.camera[:3, 3]) @ self.camera[:3, :3]
        rest_hip = rest_marks[0, hips].mean(0)
        root_joint = self.shape_model(self.shape0)[1][0]
        # posed hip = R (rest_hip - root_joint) + root_joint + t.
        translation0 = hip_world - (rotation0 @ (rest_hip - root_joint)) - root_joint
        self.root = roma.rotmat_to_rotvec(rotation0).clone().requires_grad_(True)
        self.translation = translation0.clone().requires_grad_(True)
        self.pose = torch.zeros(frames, bones - 1, 3, requires_grad=True)
        self.shape_logit = torch.logit(self.shape0.clamp(0.02, 0.98)).clone().requires_grad_(True)

    def _build_pose_priors(self) -> None:
        """Per-joint L2 weights, the learned pose prior (None when its weight is 0), hinge ranges."""
        fitted_names = {self.body.joint_map[name]: name for name in FITTED_JOINTS}
        fitted = [fitted_names[bone] for bone in self.skeleton.bones[1:]]
        self.prior = torch.tensor([PRIOR_WEIGHTS.get(name, 1.0) for name in fitted])
        self.motion_prior = None
        if self.config.weight_motion_prior > 0:
            self.motion_prior = load_pose_prior().precision(fitted)
        self.hinge_rows = [r - 1 for r in self.skeleton.hinge_rows]
        self.hinge_low = torch.tensor([HINGE_RANGE[n.split("_")[1]][0] for n in HINGES])
        self.hinge_high = torch.tensor([HINGE_RANGE[n.split("_")[1]][1] for n in HINGES])

    def posed(
        self, rotvecs: Tensor, translation: Tensor, shape: Tensor, subset: Tensor | None = None
    ) -> tuple[Tensor, Tensor]:
        """(F, L, 3) world landmarks, and (F_subset, N, 3) silhouette vertices of the frames ``subset``."""
        rest_vertices, rest_joints = self.shape_model(shape)
        rotmats = roma.rotvec_to_rotmat(rotvecs)
        transforms = forward_kinematics(rotmats, rest_joints, translation, self.skeleton.parents, self.levels)
        n = self.num_marks
        marks = lbs(rest_vertices[:n], self.weights[:n], transforms).reshape(self.frames, len(BODY_LANDMARKS), -1, 3)
        marks = (self.regressor_weights[None, ..., None] * marks).sum(-2)
        if subset is None:
            return marks, marks[:0]
        return marks, lbs(rest_vertices[n:], self.weights[n:], transforms[subset])

    # ------------------------------------------------------------- the terms

    def energy_2d(self, pixels: Tensor, used: Tensor) -> Tensor:
        """Robust 2D reprojection error of the landmarks, in person heights."""
        squared = ((pixels - self.data.points) ** 2).sum(-1) / self.data.height_px**2
        return self.config.weight_2d * (used * _geman_mcclure(squared, self.config.robust_sigma)).sum() / self.frames

    def energy_3d(self, marks: Tensor, used: Tensor) -> Tensor:
        """Huber error of the hip-centred landmarks against MediaPipe's metric world landmarks."""
        relative = marks - marks[:, self.hips].mean(1, keepdim=True)
        huber = self.config.huber_3d_m
        error3d = torch.nn.functional.huber_loss(relative, self.data.world3d, reduction="none", delta=huber)
        error3d = error3d.sum(-1)
        return self.config.weight_3d * (used * error3d).sum() / self.frames / huber

    def energy_focal(self) -> Tensor:
        """log f held to the default focal length."""
        return self.config.weight_focal * (self.log_focal - np.log(self.focal0)) ** 2

    def energy_smooth(self, marks: Tensor) -> Tensor:
        """Squared acceleration of the landmarks over time (frame gaps accounted for)."""
        gaps = self.data.gaps[1:, None, None] * self.data.gaps[:-1, None, None]
        accel = (marks[2:] - 2 * marks[1:-1] + marks[:-2]) / gaps
        return self.config.weight_smooth * (accel**2).sum() / self.frames

    def energy_pose(self) -> Tensor:
        """Per-joint weighted L2 pose prior."""
        return self.config.weight_pose * (self.prior[:, None] * self.pose**2).sum() / self.frames

    def energy_motion_prior(self) -> Tensor:
        """The learned pose prior's saturating Mahalanobis penalty."""
        config = self.config
        nll = robust_mahalanobis(self.pose.reshape(self.frames, -1), *self.motion_prior, config.motion_prior_scale)
        return config.weight_motion_prior * nll.sum() / self.frames

    def hinge_angles(self) -> Tensor:
        """(F, H) each hinge's rotation about its axis, radians."""
        return (self.pose[:, self.hinge_rows] * self.skeleton.hinge_axes).sum(-1)

    def energy_limits(self, hinge: Tensor) -> Tensor:
        """Hinges (``hinge``: :meth:`hinge_angles`) outside their range, and any hinge rotation off
        its axis (twist)."""
        twist = self.pose[:, self.hinge_rows] - hinge[..., None] * self.skeleton.hinge_axes
        limits = torch.relu(self.hinge_low - hinge) + torch.relu(hinge - self.hinge_high)
        return self.config.weight_limits * ((limits**2).sum() + (twist**2).sum()) / self.frames

    def energy_shape(self, shape: Tensor) -> Tensor:
        """The phenotypes held to the start shape (Anny's average, or the given height's)."""
        return self.config.weight_shape * ((shape - self.shape0) ** 2).sum()

    def energy_height(self, shape: Tensor) -> Tensor:
        """The rest body's crown-to-sole height held to the given one."""
        ends = self.height_model(shape)[0][:, 1]
        height = (ends[0] - ends[1] - self.config.height_m) / HEIGHT_SCALE_M
        return self.config.weight_height * height**2

    def energy_outside(self, vpix: Tensor, subset: Tensor) -> Tensor:
        """Silhouette vertices outside the mask: the mask complement's distance map read at them."""
        grid = _map_grid(vpix, self.data.mask_step, self.data.outside.shape[-2:])
        outside = torch.nn.functional.grid_sample(
            self.data.outside[subset], grid[:, None], align_corners=False, padding_mode="border"
        )
        return self.config.weight_outside * (outside[:, 0, 0] / self.data.height_px).mean()

    def energy_coverage(self, vpix: Tensor, subset: Tensor) -> Tensor:
        """Mask pixels far from every silhouette vertex (robust, in person heights)."""
        inside = self.data.inside[subset]
        with torch.no_grad():  # only the nearest vertex of each mask pixel carries gradient
            nearest = torch.cdist(inside, vpix).argmin(-1)
        gap = (inside - torch.gather(vpix, 1, nearest[..., None].expand(-1, -1, 2))).square().sum(-1)
        cover = _geman_mcclure(gap / self.data.height_px**2, self.config.robust_sigma) * self.data.inside_valid[subset]
        return self.config.weight_coverage * cover.mean()

    # ------------------------------------------------------------- stages

    def objective(self, stage: int) -> tuple[Tensor, dict[str, Tensor]]:
        """The sum of the terms stage 0 (camera, root), 1 (+ pose) or 2 (+ shape, masks) uses, and each term."""
        shape = torch.sigmoid(self.shape_logit)
        rotvecs = torch.cat([self.root[:, None], self.pose if stage > 0 else torch.zeros_like(self.pose)], 1)
        subset = None
        if stage > 1:
            subset = torch.as_tensor(
                self.rng.choice(self.frames, min(self.frames, self.config.silhouette_frames), replace=False)
            )
        marks, verts = self.posed(rotvecs, self.translation, shape, subset)
        focal = self.log_focal.exp()
        pixels = _project(marks, focal, self.centre, self.camera)
        used = self.data.weights
        if stage == 0:  # the body is at rest: only the torso's landmarks are meaningful
            used = used * torch.isin(torch.arange(len(BODY_LANDMARKS)), torch.tensor(self.torso))
        terms = {"2d": self.energy_2d(pixels, used), "3d": self.energy_3d(marks, used)}
        if self.fit_focal:
            terms["focal"] = self.energy_focal()
        if stage > 0:
            if self.frames > 2:
                terms["smooth"] = self.energy_smooth(marks)
            # Made before the pose terms: autograd sums the gradients reaching the pose in the order
            # their ops were made, so moving this line changes the fit in its last bits.
            hinge = self.hinge_angles()
            terms["pose"] = self.energy_pose()
            if self.motion_prior is not None:
                terms["motion_prior"] = self.energy_motion_prior()
            terms["limits"] = self.energy_limits(hinge)
        if stage > 1:
            terms["shape"] = self.energy_shape(shape)
            if self.height_model is not None:
                terms["height"] = self.energy_height(shape)
            vpix = _project(verts, focal, self.centre, self.camera)
            terms["outside"] = self.energy_outside(vpix, subset)
            terms["coverage"] = self.energy_coverage(vpix, subset)
        return sum(terms.values()), terms

    def stage_parameters(self) -> list[list[Tensor]]:
        """The parameters each stage optimises: camera and root, then pose, then shape."""
        focal = [self.log_focal] if self.fit_focal else []
        root = [self.root, self.translation]
        return [root + focal, [*root, self.pose, *focal], [*root, self.pose, self.shape_logit, *focal]]

    def minimise(self) -> dict[str, Tensor]:
        """Adam through the three stages; the last step's terms."""
        config = self.config
        terms: dict[str, Tensor] = {}
        for stage, (params, steps) in enumerate(zip(self.stage_parameters(), config.steps)):
            groups = [
                {"params": [p], "lr": config.learning_rate * (0.1 if p is self.translation else 1.0)} for p in params
            ]
            optimiser = torch.optim.Adam(groups)
            for step in range(steps):
                if stage == 2 and step == steps // 2:
                    for model in (self.shape_model, self.height_model):
                        if model is not None:
                            model.linearise(torch.sigmoid(self.shape_logit).detach())
                loss, terms = self.objective(stage)
                optimiser.zero_grad()
                loss.backward()
                optimiser.step()
        return terms

    def result(self, terms: dict[str, Tensor]) -> BodyFit:
        """The fit in the subject format's world (re-centred on the mean root position), with residuals."""
        frames, data = self.frames, self.data
        with torch.no_grad():
            shape = torch.sigmoid(self.shape_logit)
            rotvecs = torch.cat([self.root[:, None], self.pose], 1)
            rotations = torch.zeros(frames, self.body.num_bones, 3)
            rotations[:, self.skeleton.bones] = rotvecs
            focal = float(self.log_focal.exp())
            marks, _ = self.posed(rotvecs, self.translation, shape)
            pixels = _project(marks, self.log_focal.exp(), self.centre, self.camera)
            visible = data.weights > 0
            error_px = float((pixels - data.points).norm(dim=-1)[visible].mean()) if visible.any() else float("nan")
            # Re-centre the world on the mean root position: X' = X - c, so world_to_camera gains R c.
            offset = self.translation.mean(0)
            camera_out = self.camera.clone()
            camera_out[:3, 3] = self.camera[:3, 3] + self.camera[:3, :3] @ offset
            cx, cy = float(self.centre[0]), float(self.centre[1])
            K_out = np.array([[focal, 0.0, cx], [0.0, focal, cy], [0.0, 0.0, 1.0]], np.float32)  # noqa: N806
            residuals = {f"term_{k}": float(v) for k, v in terms.items()}
            residuals["landmark_error_px"] = error_px
            residuals["person_height_px"] = data.height_px
            residuals.update(data.repaired)
        return BodyFit(
            shape=shape.numpy().astype(np.float32),
            rotations=rotations.numpy().astype(np.float32),
            translation=(self.translation - offset).detach().numpy().astype(np.float32),
            world_to_camera=camera_out.numpy().astype(np.float32),
            K=K_out,
            residuals=residuals,
        )


def default_intrinsics(observations: Observations, fov_deg: float) -> tuple[float, np.ndarray]:
    """Focal length (pixels) and (2,) principal point of the subject images when K is unknown.

    A camera's field of view spans its whole frame, not the crop the subject images were cut
    from: with the source frame at x0..x1, y0..y1 in subject pixels (``frame_box``),
    f = (max(x1 - x0, y1 - y0) / 2) / tan(fov / 2) and the principal point is the frame's
    centre ((x0 + x1) / 2, (y0 + y1) / 2). Without ``frame_box`` the images are the frame.
    """
    height, width = observations.image_size
    box = observations.frame_box
    x0, y0, x1, y1 = (0.0, 0.0, float(width), float(height)) if box is None else (float(v) for v in box)
    focal = 0.5 * max(x1 - x0, y1 - y0) / np.tan(np.radians(fov_deg) / 2)
    return focal, np.array([(x0 + x1) / 2, (y0 + y1) / 2])


def _hip_positions(data: _Frames, focal: float, centre: Tensor) -> Tensor:
    """(F, 3) camera-frame position of the hip centre explaining the 2D landmarks given the 3D ones.

    With camera-aligned 3D landmarks X_l (hip-centred; camera axes = world axes flipped by
    CAMERA_LOOK) and pixels x_l, the hip centre t solves, linearly in least squares,
    (x_l - c) (X_l,z + t_z) = f (X_l,xy + t_xy) for every confident landmark. Frames
    without enough landmarks take the median of the others.
    """
    look = torch.as_tensor(CAMERA_LOOK, dtype=torch.float32)
    cam3d = data.world3d @ look  # back to camera axes (CAMERA_LOOK is its own inverse)
    uv = data.points - centre
    w = data.weights.sqrt()
    frames, landmarks = uv.shape[:2]
    # Rows for u: f t_x - u t_z = u Z - f X ; for v: f t_y - v t_z = v Z - f Y.
    a = torch.zeros(frames, landmarks, 2, 3)
    a[..., 0, 0] = focal
    a[..., 1, 1] = focal
    a[..., :, 2] = -uv
    b = uv * cam3d[..., 2:] - focal * cam3d[..., :2]
    a = (a * w[..., None, None]).reshape(frames, -1, 3)
    b = (b * w[..., None]).reshape(frames, -1, 1)
    ok = (data.weights > 0).sum(1) >= 4
    solution = torch.linalg.lstsq(a.double() + 0.0, b.double()).solution[..., 0].float()
    fallback = solution[ok].median(0).values if ok.any() else torch.tensor([0.0, 0.0, 3.0])
    solution = torch.where(ok[:, None] & (solution[:, 2:] > 0.3), solution, fallback)
    return solution
