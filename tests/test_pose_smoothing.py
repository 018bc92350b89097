"""Temporal pose smoothing: exact on tracks it must not change, reduces i.i.d. jitter against a
known clean track, never blends across a gap in the frame numbers, and reaches the samples."""

from __future__ import annotations

import math

import numpy as np
import pytest
import roma
import torch

from pghm.errors import PghmError
from pghm.train.data import TrainingData
from pghm.train.fit import FitConfig, fit
from pghm.train.pose_smoothing import consecutive_runs, smooth_track


def geodesic_degrees(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return torch.rad2deg(roma.rotmat_geodesic_distance(roma.rotvec_to_rotmat(a), roma.rotvec_to_rotmat(b)))


def constant_velocity_track(frames: int, joints: int = 4) -> tuple[torch.Tensor, torch.Tensor]:
    """(F, J, 3) rotations exp(f w a_j) R_j about fixed axes, and a (F, 3) linear translation."""
    gen = torch.Generator().manual_seed(0)
    axes = torch.nn.functional.normalize(torch.randn(joints, 3, generator=gen, dtype=torch.float64), dim=-1)
    base = roma.rotvec_to_rotmat(torch.randn(joints, 3, generator=gen, dtype=torch.float64))
    speed = torch.tensor([0.05, 0.2, -0.11, 0.3], dtype=torch.float64)[:joints]
    f = torch.arange(frames, dtype=torch.float64)[:, None, None]
    spin = roma.rotvec_to_rotmat(f * speed[None, :, None] * axes[None])
    rotations = roma.rotmat_to_rotvec(spin @ base[None])
    translation = torch.tensor([0.3, 0.0, -0.1], dtype=torch.float64) + 0.07 * f[:, 0] * torch.tensor([1.0, 0.2, 0.5])
    return rotations, translation


@pytest.mark.parametrize("sigma", [0.7, 1.0, 2.5])
def test_constant_velocity_is_unchanged_inside_a_run(sigma):
    rotations, translation = constant_velocity_track(30)
    out_r, out_t = smooth_track(np.arange(30), rotations, translation, sigma)
    half = math.ceil(3 * sigma)
    inner = slice(half, 30 - half)
    assert geodesic_degrees(out_r[inner], rotations[inner]).max() < 1e-6
    torch.testing.assert_close(out_t[inner], translation[inner], atol=1e-12, rtol=0)


def test_jitter_is_reduced_against_the_clean_track():
    clean_r, clean_t = constant_velocity_track(200)
    gen = torch.Generator().manual_seed(1)
    jitter = roma.rotvec_to_rotmat(torch.randn(clean_r.shape, generator=gen, dtype=torch.float64) * math.radians(2))
    noisy_r = roma.rotmat_to_rotvec(jitter @ roma.rotvec_to_rotmat(clean_r))
    noisy_t = clean_t + 0.01 * torch.randn(clean_t.shape, generator=gen, dtype=torch.float64)
    out_r, out_t = smooth_track(np.arange(200), noisy_r, noisy_t, 1.0)
    # A normalised Gaussian window of sigma 1 frame keeps sqrt(sum w^2) ~ 0.53 of i.i.d. noise.
    assert geodesic_degrees(out_r, clean_r).mean() < 0.65 * geodesic_degrees(noisy_r, clean_r).mean()
    assert (out_t - clean_t).norm(dim=-1).mean() < 0.65 * (noisy_t - clean_t).norm(dim=-1).mean()


def test_runs_are_never_blended_across_a_gap():
    frames = np.array([0, 1, 2, 7, 8, 9, 20])
    assert [r.tolist() for r in consecutive_runs(frames)] == [[0, 1, 2], [3, 4, 5], [6]]
    # Constant within each run, very different across runs: smoothing must leave every frame as it is.
    levels = torch.tensor([0.1, 1.4, -2.0], dtype=torch.float64)
    run_of = torch.tensor([0, 0, 0, 1, 1, 1, 2])
    rotations = levels[run_of][:, None, None] * torch.tensor([0.0, 0.6, 0.8], dtype=torch.float64)
    translation = levels[run_of][:, None].expand(7, 3).clone()
    out_r, out_t = smooth_track(frames, rotations, translation, 2.0)
    assert geodesic_degrees(out_r, rotations).max() < 1e-6
    torch.testing.assert_close(out_t, translation)


def test_sigma_zero_is_the_identity_and_bad_sigmas_are_refused():
    rotations, translation = constant_velocity_track(5)
    out_r, out_t = smooth_track(np.arange(5), rotations, translation, 0.0)
    assert torch.equal(out_r, rotations) and torch.equal(out_t, translation)
    for bad in (-1.0, math.nan, math.inf):
        with pytest.raises(ValueError, match="sigma"):
            smooth_track(np.arange(5), rotations, translation, bad)


def test_training_data_trains_on_the_smoothed_track(tiny_dataset):
    subject = sorted(p for p in tiny_dataset.iterdir() if p.is_dir())[0]
    stored = TrainingData(subject)
    smoothed = TrainingData(subject, pose_smoothing=1.0)
    exact = TrainingData(subject, pose_smoothing=1.0, true_poses=True)
    arrays = stored.subjects[0].arrays
    images = stored.images[0]
    frame_of = arrays.frame_index[images]
    frames, first = np.unique(frame_of, return_index=True)
    want_r, want_t = smooth_track(
        frames,
        torch.from_numpy(arrays.rotations[images[first]]),
        torch.from_numpy(arrays.translation[images[first]]),
        1.0,
    )
    assert len(frames) > 1
    for index, frame in zip(images.tolist(), frame_of.tolist()):
        row = int(np.searchsorted(frames, frame))
        sample = smoothed.load(0, index)
        # Every view of a frame gets its frame's smoothed pose.
        torch.testing.assert_close(sample.rotations, want_r[row].float())
        torch.testing.assert_close(sample.translation, want_t[row].float())
        assert torch.equal(stored.load(0, index).rotations, torch.from_numpy(arrays.rotations[index]).float())
        assert torch.equal(exact.load(0, index).rotations, torch.from_numpy(arrays.rotations_true[index]).float())
    assert not torch.allclose(smoothed.load(0, int(images[0])).rotations, stored.load(0, int(images[0])).rotations)


def test_fit_refuses_a_bad_smoothing(tiny_dataset, tmp_path):
    subject = sorted(p for p in tiny_dataset.iterdir() if p.is_dir())[0]
    with pytest.raises(PghmError, match="pose smoothing"):
        fit(subject, "unused.pt", tmp_path / "a.pt", FitConfig(pose_smoothing=-1.0))
