"""``pghm capture --polish``: each held-out frame's stored pose moved by the correction it settled to
against an avatar fitted on all of the subject's images; the training frames and everything else of
the subject unchanged, nothing of the fit left behind."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from conftest import TINY_MODEL

import pghm.capture.polish as polish
from pghm.model import ModelConfig
from pghm.subject import ALL_SPLIT, Subject, check
from pghm.train.fit import FitConfig
from pghm.train.loop import LoopConfig


def test_every_image_is_a_split_of_its_own(tiny_dataset):
    subject = Subject.open(tiny_dataset / "subject_000")
    assert subject.split(ALL_SPLIT).indices == list(range(len(subject)))
    train, test = (set(subject.split(name).indices) for name in ("train", "test"))
    assert train | test == set(range(len(subject))) and not train & test


def test_polish_moves_the_held_out_frames_only(tiny_dataset, tmp_path, monkeypatch, capsys):
    subject_dir = tmp_path / "subject"
    shutil.copytree(tiny_dataset / "subject_000", subject_dir)
    before = Subject.open(subject_dir)
    fitted, settled = [], []
    monkeypatch.setattr(polish, "fit", _recording(fitted))
    monkeypatch.setattr(polish, "refine_poses", _recording_refine(settled))
    stages = [LoopConfig(steps=n, images_per_shard=2, checkpoint_every=1) for n in (1, 2)]
    record = polish.polish_poses(
        subject_dir, ModelConfig(**TINY_MODEL), FitConfig(*stages, lpips=False), progress=False
    )
    assert "fit" not in capsys.readouterr().err  # no bar of its stages or of the settling

    (avatar,) = fitted
    assert avatar.metadata["training_images"] == len(before)  # both splits: every image
    assert avatar.metadata["config"]["track_steps"] == 0  # pghm fit settles the training frames itself
    test = before.split("test").indices
    assert test and polish.held_out_images(before) == test
    ((images, steps, start, end),) = settled
    assert images == test and steps == polish.POLISH_TRACK_STEPS
    track = avatar.pose_track
    frames = before.arrays.frame_index
    rows = [track.frames.tolist().index(f) for f in frames[test]]
    np.testing.assert_allclose(start[0], track.rotations.numpy()[rows])  # settling starts at stage 2's rows
    assert np.abs(end[0] - start[0]).max() > 0  # and moves them

    after = Subject.open(subject_dir)
    bones = track.bones.numpy()
    expected_r, expected_t = before.arrays.rotations.copy(), before.arrays.translation.copy()
    expected_r[np.ix_(test, bones)] += end[0]
    expected_t[test] += end[1]
    np.testing.assert_allclose(after.arrays.rotations, expected_r, atol=1e-6)
    np.testing.assert_allclose(after.arrays.translation, expected_t, atol=1e-6)
    train = before.split("train").indices
    assert np.array_equal(after.arrays.rotations[train], before.arrays.rotations[train])
    assert np.array_equal(after.arrays.translation[train], before.arrays.translation[train])
    for name in ("K", "world_to_camera", "shape", "rotations_true", "translation_true"):
        assert np.array_equal(getattr(after.arrays, name), getattr(before.arrays, name)), name
    assert after.arrays.splits == before.arrays.splits
    meta = json.loads((subject_dir / "meta.json").read_text())
    assert meta["polish"] == record and meta["aligned_frames"] == sorted(set(frames[test].tolist()))
    assert after.aligned_frames() == set(frames[test].tolist())
    assert record["prior"] == "(in memory)" and record["frames"] == len(set(frames[test].tolist()))
    assert record["fit_images"] == len(before)
    assert record["mean_rotation_change_deg"] == pytest.approx(
        np.degrees(np.linalg.norm(end[0], axis=-1).mean()), abs=1e-3
    )
    names = sorted(p.name for p in subject_dir.iterdir())
    assert names == sorted(p.name for p in (tiny_dataset / "subject_000").iterdir())  # the fit's scratch is gone
    assert check(subject_dir) == []


def _recording(fitted: list):
    """polish's ``fit``, keeping each avatar it returns."""
    fit = polish.fit

    def recorded(*args, **kwargs):
        fitted.append(fit(*args, **kwargs))
        return fitted[-1]

    return recorded


def _recording_refine(settled: list):
    """polish's ``refine_poses``, keeping the images it settled, its steps, and the held-out rows'
    corrections (rotations (H, K, 3), translation (H, 3)) before and after."""
    refine = polish.refine_poses

    def recorded(avatar, data, steps, weights, lr, corrections, images, **kwargs):
        rows = [data.load(0, i).frame_key for i in images]
        start = _rows(corrections, rows)
        out = refine(avatar, data, steps, weights, lr, corrections, images, **kwargs)
        settled.append((list(images), steps, start, _rows(corrections, rows)))
        return out

    return recorded


def _rows(corrections, rows: list[int]) -> tuple[np.ndarray, np.ndarray]:
    return corrections.rotations.detach()[rows].numpy().copy(), corrections.translation.detach()[rows].numpy().copy()
