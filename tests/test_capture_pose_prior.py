"""The body fit's pose prior learned from motion capture (pghm.capture.pose_prior)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
import torch

from pghm.body import load_body
from pghm.capture.bodyfit import FITTED_JOINTS, hinge_axes
from pghm.capture.metrics import camera_joints, mapped_joints
from pghm.capture.pose_prior import (
    PosePrior,
    build_pose_prior,
    load_pose_prior,
    mirror_rotations,
    project_hinges,
    robust_mahalanobis,
)

ROOT = Path(__file__).resolve().parent.parent
MOTION_DIR = ROOT / "assets" / "motion"


@pytest.fixture(scope="module")
def anny():
    return load_body("anny")


def _canonical_joints(body, rotations: np.ndarray) -> np.ndarray:
    """(F, J, 3) posed positions of FITTED_JOINTS for (F, J, 3) rotations of them, the rest at rest."""
    full = np.zeros((len(rotations), body.num_bones, 3))
    full[:, [body.joint_map[n] for n in FITTED_JOINTS]] = rotations
    joints = camera_joints(body, body.default_shape().numpy(), full, np.zeros((len(full), 3)), np.eye(4))
    names, _ = mapped_joints(body)
    return joints[:, [names.index(n) for n in FITTED_JOINTS]]


def test_mirror_reflects_forward_kinematics(anny):
    """The mirrored pose's joints are the pose's joints reflected through x = 0, sides swapped."""
    rng = np.random.default_rng(0)
    rotations = rng.normal(0.0, 0.4, (4, len(FITTED_JOINTS), 3))
    mirrored = mirror_rotations(rotations, FITTED_JOINTS)
    np.testing.assert_allclose(mirror_rotations(mirrored, FITTED_JOINTS), rotations)
    twin = [
        FITTED_JOINTS.index(n.replace("left_", "right_") if n.startswith("left_") else n.replace("right_", "left_"))
        for n in FITTED_JOINTS
    ]
    expected = _canonical_joints(anny, rotations)[:, twin] * np.array([-1.0, 1.0, 1.0])
    moved = np.abs(_canonical_joints(anny, rotations) - _canonical_joints(anny, np.zeros_like(rotations))).max()
    assert moved > 0.1  # the poses are far from rest, so the check has teeth
    np.testing.assert_allclose(_canonical_joints(anny, mirrored), expected, atol=2e-3)


def test_hinge_projection_keeps_the_component_about_the_axis():
    axis = np.array([0.6, 0.8, 0.0])
    rotations = np.array([[[1.0, 2.0, 3.0], [0.3, -0.1, 0.2]]])
    out = project_hinges(rotations, ("a", "b"), {"b": axis})
    np.testing.assert_allclose(out[0, 0], rotations[0, 0])
    np.testing.assert_allclose(out[0, 1], (0.3 * 0.6 - 0.1 * 0.8) * axis)


def test_robust_penalty_is_the_gaussian_near_the_mean_and_saturates():
    """rho(m) = (c/2) m / (m + c): m/2 for m << c, c/2 in the limit, monotone, zero at the mean."""
    mean, precision, scale = torch.zeros(3), torch.diag(torch.tensor([1.0, 4.0, 9.0])), 20.0
    x = torch.tensor([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.0, 0.5, 0.0], [0.0, 0.0, 1e3]])
    m = torch.tensor([0.0, 1e-4, 1.0, 9e6])
    rho = robust_mahalanobis(x, mean, precision, scale)
    torch.testing.assert_close(rho, 0.5 * scale * m / (m + scale))
    assert rho[0] == 0 and abs(rho[1] - 0.5e-4) < 1e-8 and abs(rho[3] - scale / 2) < 1e-3
    assert bool((rho[1:] > rho[:-1]).all())


def test_prior_is_symmetric_and_weighs_clips_equally():
    """A clip of constant pose a (100 frames) and one of b (3 frames): the mean is that of a, b and
    their mirrors, each a quarter, whatever the frame counts; the prior is its own mirror image."""
    joints = ("left_knee", "right_knee", "spine1")
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(len(joints), 3)), rng.normal(size=(len(joints), 3))
    prior = build_pose_prior({"a": np.repeat(a[None], 100, 0), "b": np.repeat(b[None], 3, 0)}, joints, shrinkage=0.0)
    poses = np.stack([a, b, mirror_rotations(a[None], joints)[0], mirror_rotations(b[None], joints)[0]])
    np.testing.assert_allclose(prior.mean, poses.reshape(4, -1).mean(0), atol=1e-12)
    mirrored_mean = mirror_rotations(prior.mean.reshape(1, -1, 3), joints).reshape(-1)
    np.testing.assert_allclose(mirrored_mean, prior.mean, atol=1e-12)
    reflect = mirror_rotations(np.eye(9).reshape(9, 3, 3), joints).reshape(9, 9)  # the linear map on x
    np.testing.assert_allclose(reflect @ prior.covariance @ reflect.T, prior.covariance, atol=1e-12)


def test_precision_follows_the_requested_joint_order():
    rng = np.random.default_rng(2)
    root = rng.normal(size=(6, 6))
    prior = PosePrior(("a", "b"), rng.normal(size=6), root @ root.T, 0.01, ("x",), (1,))
    x = torch.as_tensor(rng.normal(size=(5, 2, 3)), dtype=torch.float32)
    ab = robust_mahalanobis(x.reshape(5, -1), *prior.precision(("a", "b")), 1e9)
    ba = robust_mahalanobis(x[:, [1, 0]].reshape(5, -1), *prior.precision(("b", "a")), 1e9)
    torch.testing.assert_close(ab, ba)


def test_shipped_prior_is_the_one_the_clips_give(anny):
    """pose_prior.npz is what scripts/build_pose_prior.py makes of assets/motion's clips."""
    spec = importlib.util.spec_from_file_location("build_pose_prior", ROOT / "scripts" / "build_pose_prior.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    clips = {path.name: script.clip_rotations(path, anny) for path in sorted(MOTION_DIR.glob("*.bvh"))}
    rebuilt = build_pose_prior(clips, FITTED_JOINTS)
    shipped = load_pose_prior()
    assert shipped.joints == rebuilt.joints and shipped.sources == rebuilt.sources
    np.testing.assert_allclose(shipped.mean, rebuilt.mean, atol=1e-6)
    np.testing.assert_allclose(shipped.covariance, rebuilt.covariance, atol=1e-6)
    # Knees and elbows are hinges in the fit: the prior has no variance off their axes.
    axes = {name: axis.double().numpy() for name, axis in hinge_axes(anny).items()}
    for name, axis in axes.items():
        j = FITTED_JOINTS.index(name)
        block = shipped.covariance[3 * j : 3 * j + 3, 3 * j : 3 * j + 3]
        off = np.eye(3) - np.outer(axis, axis)
        assert np.abs(off @ block @ off).max() < 1e-9
