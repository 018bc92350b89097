"""An avatar in one motion, baked for the web page (:mod:`pghm.web.page`): what each frame needs, and no more.

The page skins on the GPU (``shaders/web_skinning.vert.glsl``): per Gaussian a canonical point
c and weights w_k on up to SKIN_BONES bones j_k, per frame the bones' transforms B_j, and

    mu = M c,   M = sum_k w_k B_{j_k}.

The model's mean is not exactly that (a texel's point is blended from its triangle's skinned
corners, its offsets turned by the blended rotation, its weights not cut to SKIN_BONES), so the
bake keeps, per frame f, the canonical point that the page's own M_f maps onto the model's mean,

    c_f = M_f^{-1} mu_f,

and the frame's log-scale and colour (the view-dependent colour baked for the page's first
camera, :func:`front_centre`). Over a motion each attribute group x (points, log-scales,
colours) is a mean over the frames plus a residual of low rank: the pose-dependent part of I_d
(V_p^o and the scale and colour offsets) and what the skinning leaves. The residual's principal
directions b_k, stored as int8 with one scale each, and a frame's coefficients a_fk rebuild it:

    x_f ~ x_mean + sum_{k < r} a_fk q_k,

r the fewest components that bring every frame within the group's tolerance
(:class:`BakeConfig`), so a still motion stores none and a frame costs r numbers and its bones.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from pghm.errors import PghmError

SKIN_BONES = 4
"""Bones a Gaussian's skinning weights are cut to (the page's uvec4 attribute)."""
WEIGHT_STEPS = 255
"""Weights are stored as integers out of this (uint8) summing to it exactly."""
INT8_MAX = 127
MAX_WEB_FRAMES = 1800
"""Most motion frames one page holds (a minute at 30 fps): its attributes are baked per frame."""
MAX_WEB_BONES = 65535
"""Bones referenced by a uint16 index."""
BAKE_ASPECT = 16 / 9
"""The page's first view (960 x 540), whose camera the view-dependent colour is baked for."""


@dataclass(frozen=True)
class BakeConfig:
    """How closely the stored components rebuild each frame (worst frame, RMS over the Gaussians).

    Attributes:
        position_tolerance: metres of a canonical point (a tenth of a millimetre moves a
            splat 0.03 px at the page's first view).
        log_scale_tolerance: of the natural log of a Gaussian's scale (0.2 % of its size).
        color_tolerance: of an RGB channel in [0, 1] (a quarter of an 8-bit step).
        max_components: most components one group keeps; a motion that needs more is
            rebuilt as closely as that many allow.
    """

    position_tolerance: float = 1e-4
    log_scale_tolerance: float = 2e-3
    color_tolerance: float = 1.0 / 1024
    max_components: int = 64


@dataclass(frozen=True)
class Components:
    """One attribute group over the motion: ``mean + coefficients @ (basis * 1)``.

    Attributes:
        mean: (N, C) float32 the group's mean over the frames.
        basis: (r, N, C) int8 principal directions, each scaled to use the int8 range.
        coefficients: (F, r) float32 per frame, in units of the int8 steps.
        error: the worst frame's RMS error over the Gaussians, as rebuilt from what is stored.
    """

    mean: np.ndarray
    basis: np.ndarray
    coefficients: np.ndarray
    error: float

    @property
    def rank(self) -> int:
        return self.basis.shape[0]

    def frame(self, index: int) -> np.ndarray:
        """(N, C) float32 the group in frame ``index``, as the page rebuilds it."""
        coefficients = self.coefficients[index].astype(np.float32)
        return self.mean + np.tensordot(coefficients, self.basis.astype(np.float32), axes=1)


@dataclass(frozen=True)
class Skin:
    """Each Gaussian's bones and weights, as the page reads them.

    Attributes:
        bones: (B,) indices into the body's bones of those any Gaussian uses.
        index: (N, SKIN_BONES) uint16 into ``bones``.
        weights: (N, SKIN_BONES) uint8 summing to WEIGHT_STEPS per Gaussian.
    """

    bones: np.ndarray
    index: np.ndarray
    weights: np.ndarray

    def blended(self, transforms: np.ndarray) -> np.ndarray:
        """(N, 3, 4) float64 M = sum_k w_k B_{j_k} for (B, 3, 4) transforms of ``bones``."""
        weights = self.weights.astype(np.float64) / WEIGHT_STEPS
        return np.einsum("nk,nkij->nij", weights, transforms.astype(np.float64)[self.index])


@dataclass(frozen=True)
class MotionRig:
    """What a page's frames share besides the Gaussians' attributes: the skinning and the camera's path.

    Attributes:
        skin: the Gaussians' bones and weights.
        transforms: (F, B, 3, 4) float32 the used bones' transforms per frame.
        roots: (F, 3) float32 the posed root, which the page's camera follows.
        rest_root: (3,) the root at rest.
        rest_box: (2, 3) the rest surface's bounding box, low and high: the page's framing.
        fps: the motion's frame rate.
    """

    skin: Skin
    transforms: np.ndarray
    roots: np.ndarray
    rest_root: np.ndarray
    rest_box: np.ndarray
    fps: float

    @property
    def num_frames(self) -> int:
        return self.transforms.shape[0]

    def skinned(self, index: int, points: np.ndarray) -> np.ndarray:
        """(N, 3) float64 canonical ``points`` (N, 3) posed in frame ``index`` as the page skins them."""
        blended = self.skin.blended(self.transforms[index])
        return np.einsum("nij,nj->ni", blended[:, :, :3], points.astype(np.float64)) + blended[:, :, 3]


@dataclass(frozen=True)
class BakedMotion:
    """Everything the page draws, for N Gaussians over F frames.

    Attributes:
        rig: the skinning and the camera's path.
        points: canonical points c_f (C = 3).
        log_scales: natural logs of the scales (C = 1).
        colors: RGB (C = 3).
    """

    rig: MotionRig
    points: Components
    log_scales: Components
    colors: Components

    @property
    def num_frames(self) -> int:
        return self.rig.num_frames

    @property
    def num_gaussians(self) -> int:
        return self.points.mean.shape[0]

    def means(self, index: int) -> np.ndarray:
        """(N, 3) float64 frame ``index``'s posed means as the page skins them."""
        return self.rig.skinned(index, self.points.frame(index))


def skin_of(weights: torch.Tensor) -> Skin:
    """The SKIN_BONES largest of each Gaussian's (N, J) weights, renormalised and stored in
    WEIGHT_STEPS so that they sum to it exactly (largest remainders rounded up)."""
    values, index = torch.topk(weights.double(), min(SKIN_BONES, weights.shape[1]), dim=1)
    values, index = values.numpy(), index.numpy()
    if index.shape[1] < SKIN_BONES:  # a body of fewer bones: pad with weight 0 on bone 0
        pad = SKIN_BONES - index.shape[1]
        values = np.pad(values, ((0, 0), (0, pad)))
        index = np.pad(index, ((0, 0), (0, pad)))
    total = values.sum(axis=1, keepdims=True)
    if not np.all(total > 0):
        raise PghmError("a Gaussian has no skinning weight; the avatar's body cannot be baked for the web")
    scaled = values / total * WEIGHT_STEPS
    steps = np.floor(scaled).astype(np.int64)
    short = WEIGHT_STEPS - steps.sum(axis=1)
    order = np.argsort(-(scaled - steps), axis=1, kind="stable")
    for k in range(SKIN_BONES):  # the `short` largest remainders get one more step
        rows = np.nonzero(short > k)[0]
        steps[rows, order[rows, k]] += 1
    used, compact = np.unique(np.where(steps > 0, index, index[:, :1]), return_inverse=True)
    if used.size > MAX_WEB_BONES:
        raise PghmError(f"the avatar's Gaussians use {used.size} bones; a page holds at most {MAX_WEB_BONES}")
    return Skin(used.astype(np.int64), compact.reshape(index.shape).astype(np.uint16), steps.astype(np.uint8))


def components_of(frames: np.ndarray, tolerance: float, max_components: int) -> Components:
    """The mean of (F, N, C) ``frames`` and the fewest int8 directions of its residual that rebuild
    every frame within ``tolerance`` (RMS over the N Gaussians of the C-vector error).

    Greedy on what is stored: each direction is the residual's leading singular vector (from its
    F x F Gram matrix R R^T, kept up to date), quantised to int8, and each frame's coefficient is
    projected from what the earlier quantised ones left, so a later direction also takes up what
    an earlier one's rounding lost, and the error checked is the error of what is stored.
    """
    count, n, channels = frames.shape
    mean = frames.mean(axis=0, dtype=np.float64).astype(np.float32)
    residual = (frames - mean).reshape(count, -1).astype(np.float64)  # R (F, D)

    def worst(left: np.ndarray) -> float:
        return float(math.sqrt(max(np.max(np.einsum("fd,fd->f", left, left)), 0.0) / n)) if count else 0.0

    basis, coefficients = [], []
    error = worst(residual)
    gram = residual @ residual.T if error > tolerance and count > 1 else None
    while gram is not None and error > tolerance and len(basis) < max_components:
        _, vectors = np.linalg.eigh(gram)
        direction = residual.T @ vectors[:, -1]
        peak = np.abs(direction).max()
        if peak == 0:
            break
        quantised = np.round(direction / peak * INT8_MAX).astype(np.int8)
        q = quantised.astype(np.float64)
        projected = residual @ q  # (F,)
        a = projected / (q @ q)
        residual -= np.outer(a, q)
        # R' R'^T = R R^T - a (R q)^T - (R q) a^T + (q . q) a a^T
        gram += (q @ q) * np.outer(a, a) - np.outer(a, projected) - np.outer(projected, a)
        basis.append(quantised)
        coefficients.append(a)
        error = worst(residual)
    stacked = np.stack(basis).reshape(-1, n, channels) if basis else np.zeros((0, n, channels), np.int8)
    coefficient_array = np.stack(coefficients, axis=1) if coefficients else np.zeros((count, 0))
    return Components(mean, stacked, coefficient_array.astype(np.float32), error)


def canonical_points(linear: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """(N, 3) c with ``linear`` (N, 3, 3) c = ``offset`` (N, 3): least squares where a blend of
    opposite rotations leaves ``linear`` singular (the point then sits where the page puts it nearest)."""
    try:
        return np.linalg.solve(linear, offset[..., None])[..., 0]
    except np.linalg.LinAlgError:
        return np.einsum("nij,nj->ni", np.linalg.pinv(linear), offset)


def front_centre(target: np.ndarray, distance: float) -> np.ndarray:
    """(3,) the page's first camera: yaw 0, pitch 0, ``distance`` in front (+z) of ``target``."""
    return target + np.array([0.0, 0.0, distance])


@dataclass(frozen=True)
class MotionSamples:
    """The avatar in every frame of a motion, before compression: what :func:`compress` keeps.

    Attributes:
        rig: the skinning and the camera's path.
        points: (F, N, 3) float32 canonical points c_f = M_f^{-1} mu_f.
        log_scales: (F, N, 1) float32.
        colors: (F, N, 3) float32 (view-dependent colour for the page's first camera).
    """

    rig: MotionRig
    points: np.ndarray
    log_scales: np.ndarray
    colors: np.ndarray


def sample_motion(driver, motion) -> MotionSamples:
    """Every frame of ``motion`` (a :class:`~pghm.motion.motion.Motion`) for the avatar ``driver``
    drives (:class:`~pghm.render.driver.AvatarDriver`), as the page skins it (module docstring)."""
    from pghm.device import move
    from pghm.render.framing import DEFAULT_FOV_Y, floor_shift, frame_points

    if motion.num_frames > MAX_WEB_FRAMES:
        raise PghmError(
            f"the motion has {motion.num_frames} frames; a page holds at most {MAX_WEB_FRAMES} "
            f"({MAX_WEB_FRAMES / 30:g} s at 30 fps): cut the clip shorter"
        )
    geometry = driver.geometry
    surface = geometry.surface if geometry.detail is None else geometry.detail.surface
    skin = skin_of(surface.weights.cpu())
    identity_map = driver.avatar.identity_map(driver.index)
    rest_points = geometry.surface.positions.cpu().numpy()
    framing = frame_points(rest_points, DEFAULT_FOV_Y, BAKE_ASPECT)
    rest_root = driver.root_position(driver.rest_pose())
    frames, n = motion.num_frames, geometry.num_gaussians
    transforms = np.empty((frames, skin.bones.size, 3, 4), np.float32)
    points = np.empty((frames, n, 3), np.float32)
    log_scales = np.empty((frames, n, 1), np.float32)
    colors = np.empty((frames, n, 3), np.float32)
    roots = np.empty((frames, 3), np.float32)
    for f in range(frames):
        pose = motion.pose(f)
        root = driver.root_position(pose)
        target = np.asarray(framing.target) + floor_shift(root, rest_root)
        arrays = driver.evaluate(identity_map, pose, front_centre(target, framing.distance))
        bones = geometry.transforms(move(pose, geometry.joints.device))[0, :, :3, :].cpu().numpy()
        transforms[f] = bones[skin.bones]
        blended = skin.blended(transforms[f])
        points[f] = canonical_points(blended[:, :, :3], arrays.means.astype(np.float64) - blended[:, :, 3])
        log_scales[f, :, 0] = np.log(arrays.scales)
        colors[f] = arrays.colors
        roots[f] = root
    box = np.stack([rest_points.min(axis=0), rest_points.max(axis=0)]).astype(np.float32)
    rig = MotionRig(skin, transforms, roots, rest_root.astype(np.float32), box, float(motion.fps))
    return MotionSamples(rig, points, log_scales, colors)


def compress(samples: MotionSamples, config: BakeConfig | None = None) -> BakedMotion:
    """``samples`` with each attribute group cut to the components its tolerance needs."""
    config = config or BakeConfig()
    return BakedMotion(
        rig=samples.rig,
        points=components_of(samples.points, config.position_tolerance, config.max_components),
        log_scales=components_of(samples.log_scales, config.log_scale_tolerance, config.max_components),
        colors=components_of(samples.colors, config.color_tolerance, config.max_components),
    )


def bake_motion(driver, motion, config: BakeConfig | None = None) -> BakedMotion:
    """:func:`sample_motion` then :func:`compress`."""
    return compress(sample_motion(driver, motion), config)
