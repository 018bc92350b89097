"""``pghm capture --polish``: every frame's stored pose moved by the correction a fit on all of the
subject's images settled for it, nothing else of the subject changed, nothing of the fit left behind."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from conftest import TINY_MODEL

import pghm.capture.polish as polish
from pghm.data.subject import ALL_SPLIT, Subject, check
from pghm.model import ModelConfig
from pghm.train.fit import FitConfig
from pghm.train.loop import LoopConfig


def test_every_image_is_a_split_of_its_own(tiny_dataset):
    subject = Subject.open(tiny_dataset / "subject_000")
    assert subject.split(ALL_SPLIT).indices == list(range(len(subject)))
    train, test = (set(subject.split(name).indices) for name in ("train", "test"))
    assert train | test == set(range(len(subject))) and not train & test


def test_polish_adds_each_frames_settled_correction(tiny_dataset, tmp_path, monkeypatch, capsys):
    subject_dir = tmp_path / "subject"
    shutil.copytree(tiny_dataset / "subject_000", subject_dir)
    before = Subject.open(subject_dir)
    fitted = []
    monkeypatch.setattr(polish, "fit", _recording(fitted))
    stages = [LoopConfig(steps=n, images_per_shard=2, checkpoint_every=1) for n in (1, 2)]
    record = polish.polish_poses(
        subject_dir, ModelConfig(**TINY_MODEL), FitConfig(*stages, lpips=False), progress=False
    )
    assert "fit" not in capsys.readouterr().err  # no bar of its stages or of the settling

    (avatar,) = fitted
    assert avatar.metadata["training_images"] == len(before)  # both splits: every image
    assert avatar.metadata["config"]["track_steps"] == polish.POLISH_TRACK_STEPS
    track = avatar.pose_track
    frames = before.arrays.frame_index
    assert track.frames.tolist() == sorted(set(frames.tolist()))
    after = Subject.open(subject_dir)
    bones = track.bones.numpy()
    rows = [track.frames.tolist().index(f) for f in frames]  # each image: its instant's correction
    expected = before.arrays.rotations.copy()
    expected[:, bones] += track.rotations.numpy()[rows]
    np.testing.assert_allclose(after.arrays.rotations, expected, atol=1e-6)
    others = np.setdiff1d(np.arange(expected.shape[1]), bones)
    assert np.array_equal(after.arrays.rotations[:, others], before.arrays.rotations[:, others])
    np.testing.assert_allclose(
        after.arrays.translation, before.arrays.translation + track.translation.numpy()[rows], atol=1e-6
    )
    assert np.abs(after.arrays.rotations - before.arrays.rotations).max() > 0  # the fit did move them
    for name in ("K", "world_to_camera", "shape", "rotations_true", "translation_true"):
        assert np.array_equal(getattr(after.arrays, name), getattr(before.arrays, name)), name
    assert after.arrays.splits == before.arrays.splits
    assert json.loads((subject_dir / "meta.json").read_text())["polish"] == record
    assert record["prior"] == "(in memory)" and record["frames"] == len(before)
    assert record["mean_rotation_change_deg"] == pytest.approx(
        np.degrees(np.linalg.norm(track.rotations.numpy()[rows], axis=-1).mean()), abs=1e-3
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
