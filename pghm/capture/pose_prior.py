"""A pose prior learned from motion capture, for the body fit (:mod:`pghm.capture.bodyfit`).

MediaPipe's metric landmarks are 10-25 cm off at the knees, ankles and wrists, mostly in depth,
and the 2D landmarks do not tell a leg swinging forwards from one swinging back. Real people
move their joints together (a walk swings the arms against the legs; a knee bends as its hip
flexes), which a prior over the whole body's joint rotations knows and a per-joint L2 prior
does not. The prior is a Gaussian over the fitted joints' axis-angle vectors x (the 17 joints
of :data:`pghm.capture.bodyfit.FITTED_JOINTS`, D = 51, elbows and knees projected onto their
hinge axes as the fit parametrises them), with mean mu and covariance S estimated from
retargeted motion-capture clips (each clip and its mirror image weighted equally, so the
prior has no side and a long clip does not outweigh a short one), shrunk towards isotropy:

    m(x) = (x - mu)^T (S + lambda I)^-1 (x - mu)            (squared Mahalanobis distance)

and the fit's term is the robust (Geman-McClure) penalty of it,

    rho(m) = (c / 2) m / (m + c),

which is m / 2, the Gaussian's negative log-likelihood, near the data and saturates at c / 2 far
from it: a pose the clips never show (arms raised overhead) is left to the landmarks, while one
they know (a stride) is pulled towards how people hold it. The data: the two real clips in
``assets/motion`` (a walk and a stand-sit-stand; MIT-licensed, from the tests of
20tab/bvh-python; assets/motion/SOURCE.md), retargeted onto Anny by :func:`pghm.motion.retarget.import_bvh`; the
statistics ship in ``pose_prior.npz`` beside this module (``scripts/build_pose_prior.py``
rebuilds it). What it does, measured: docs/capture.md, "A pose prior from motion capture".
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from pghm.io.atomic import atomic_write_bytes

POSE_PRIOR_FILE = Path(__file__).with_name("pose_prior.npz")
"""The shipped prior (built from the two clips of ``assets/motion``)."""

SHRINKAGE = 0.01
"""lambda, in squared radians: the variance added to every direction, so that directions the
clips do not move in (a collar, a spine twist) are held with a 0.1 rad deviation, not frozen."""

SIDES = ("left_", "right_")


@dataclass(frozen=True)
class PosePrior:
    """A Gaussian over the axis-angle rotations of named joints.

    Attributes:
        joints: J joint names, the row order of ``mean`` (reshaped (J, 3)).
        mean: (J * 3,) mean rotation vector.
        covariance: (J * 3, J * 3) covariance of the clips, before shrinkage.
        shrinkage: lambda (radians^2) added to the covariance's diagonal.
        sources: the clips' file names.
        frames: frames per clip (before mirroring).
    """

    joints: tuple[str, ...]
    mean: np.ndarray
    covariance: np.ndarray
    shrinkage: float
    sources: tuple[str, ...]
    frames: tuple[int, ...]

    def precision(self, joints: list[str] | tuple[str, ...]) -> tuple[Tensor, Tensor]:
        """(D,) mean and (D, D) precision (S + lambda I)^-1, rows reordered to ``joints``."""
        index = [self.joints.index(name) for name in joints]
        rows = (np.asarray(index)[:, None] * 3 + np.arange(3)).reshape(-1)
        covariance = self.covariance[np.ix_(rows, rows)] + self.shrinkage * np.eye(len(rows))
        return torch.as_tensor(self.mean[rows], dtype=torch.float32), torch.as_tensor(
            np.linalg.inv(covariance), dtype=torch.float32
        )


def mirror_rotations(rotations: np.ndarray, joints: list[str] | tuple[str, ...]) -> np.ndarray:
    """(F, J, 3) the poses reflected through the body's sagittal plane (x = 0; x is the body's left).

    A rotation R reflects to M R M with M = diag(-1, 1, 1), whose axis-angle vector is
    (r_x, -r_y, -r_z); the reflected pose of a left joint is its right twin's, and the other way
    round. Exact for bones whose rest frames mirror each other, as Anny's do (tested by forward
    kinematics).
    """
    twin = []
    for name in joints:
        side = next((s for s in SIDES if name.startswith(s)), None)
        other = name if side is None else SIDES[1 - SIDES.index(side)] + name[len(side) :]
        twin.append(list(joints).index(other))
    mirrored = rotations[:, twin].copy()
    mirrored[..., 1:] *= -1.0
    return mirrored


def project_hinges(
    rotations: np.ndarray, joints: list[str] | tuple[str, ...], axes: dict[str, np.ndarray]
) -> np.ndarray:
    """(F, J, 3) with each hinge joint's rotation replaced by its component about its axis (3,)."""
    out = rotations.copy()
    for name, axis in axes.items():
        j = list(joints).index(name)
        out[:, j] = (out[:, j] @ axis)[:, None] * axis
    return out


def build_pose_prior(
    clips: dict[str, np.ndarray], joints: list[str] | tuple[str, ...], shrinkage: float = SHRINKAGE
) -> PosePrior:
    """The prior of clips {file name: (F, J, 3) rotations of ``joints``}, each mirrored too.

    Every clip and every mirror image has the same total weight (1 / F per frame).
    """
    samples, weights = [], []
    for rotations in clips.values():
        for pose in (rotations, mirror_rotations(rotations, joints)):
            samples.append(pose.reshape(len(pose), -1).astype(np.float64))
            weights.append(np.full(len(pose), 1.0 / len(pose)))
    x, w = np.concatenate(samples), np.concatenate(weights)
    w /= w.sum()
    mean = w @ x
    centred = x - mean
    covariance = (w[:, None] * centred).T @ centred
    return PosePrior(
        joints=tuple(joints),
        mean=mean,
        covariance=covariance,
        shrinkage=float(shrinkage),
        sources=tuple(clips),
        frames=tuple(len(r) for r in clips.values()),
    )


def save_pose_prior(prior: PosePrior, path: str | Path) -> None:
    buffer = io.BytesIO()
    np.savez(
        buffer,
        joints=np.array(prior.joints),
        mean=prior.mean,
        covariance=prior.covariance,
        shrinkage=prior.shrinkage,
        sources=np.array(prior.sources),
        frames=np.array(prior.frames),
    )
    atomic_write_bytes(path, buffer.getvalue())


@lru_cache(maxsize=4)
def load_pose_prior(path: str | Path = POSE_PRIOR_FILE) -> PosePrior:
    with np.load(path, allow_pickle=False) as data:
        return PosePrior(
            joints=tuple(str(name) for name in data["joints"]),
            mean=data["mean"],
            covariance=data["covariance"],
            shrinkage=float(data["shrinkage"]),
            sources=tuple(str(name) for name in data["sources"]),
            frames=tuple(int(n) for n in data["frames"]),
        )


def robust_mahalanobis(x: Tensor, mean: Tensor, precision: Tensor, scale: float) -> Tensor:
    """(F,) rho(m) = (c / 2) m / (m + c) of poses x (F, D), m their squared Mahalanobis distance."""
    centred = x - mean
    m = torch.einsum("fd,de,fe->f", centred, precision, centred)
    return 0.5 * scale * m / (m + scale)
