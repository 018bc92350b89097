"""The fit's pose track: bracketing in time, exact interpolation of a linear correction, the
fit's record of it, eval with it undoing a known pose error; the pose learning rate."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace

import numpy as np
import pytest
import torch
from conftest import TINY_MODEL

from pghm.body import load_body
from pghm.cli.main import main
from pghm.errors import PghmError
from pghm.io.avatar import bracket, load_avatar, save_avatar
from pghm.model import ModelConfig
from pghm.train.data import TrainingData
from pghm.train.fit import FitConfig, fit
from pghm.train.loop import LoopConfig
from pghm.train.pose_track import learned_track, track_corrections

SPLITS = {"train": [0, 1, 4, 5], "test": [2, 3], "own": [1]}
"""The tiny subject's images are frames 0, 1, 2 seen by cameras 0 and 1: train on frames 0 and 2,
hold out frame 1 ("test", between them) and, as "own", a trained frame's image."""
SHIFT = np.array([0.06, -0.04, 0.0], dtype=np.float32)
"""A known error (metres) of the stored root translations: a few pixels of the tiny subject's 64."""


def test_bracket_of_known_frames():
    known = np.array([0, 1, 2, 4, 5, 10])
    lower, upper, weight = bracket(known, np.array([1, 3, 7, 12, -1]), max_gap=3)
    # 1 is known; 3 lies between 2 and 4 (halfway); 7 between 5 and 10, too far apart; 12 and -1 outside.
    assert lower.tolist() == [1, 2, -1, -1, -1]
    assert upper.tolist() == [1, 3, -1, -1, -1]
    assert weight.tolist() == [0.0, 0.5, 0.0, 0.0, 0.0]
    lower, upper, weight = bracket(np.array([10, 14]), np.array([11, 13]), max_gap=4)
    assert (lower.tolist(), upper.tolist()) == ([0, 0], [1, 1]) and weight == pytest.approx([0.25, 0.75])
    lower, upper, weight = bracket(np.array([], dtype=np.int64), np.array([1, 2]), max_gap=3)
    assert lower.tolist() == upper.tolist() == [-1, -1]


@pytest.fixture
def subject(tiny_dataset, tmp_path):
    """The tiny subject_000 with :data:`SPLITS`."""
    out = tmp_path / "subject"
    shutil.copytree(tiny_dataset / "subject_000", out)
    (out / "splits.json").write_text(json.dumps(SPLITS))
    return out


def test_a_correction_linear_in_time_is_carried_exactly(subject, body):
    """Corrections c_f = f v learned on frames 0 and 2 give frame 1 exactly v; a trained frame's
    other view takes its own."""
    train = TrainingData(subject)
    learned = train.pose_corrections(body)
    v_rot, v_trans = torch.randn(len(learned.bones), 3) * 0.05, torch.tensor([0.01, -0.02, 0.03])
    with torch.no_grad():
        for frame in (0, 2):
            learned.rotations[frame], learned.translation[frame] = frame * v_rot, frame * v_trans
    track = learned_track(learned, train)
    assert track.frames.tolist() == [0, 2]
    held_out, counts = track_corrections(track, TrainingData(subject, split="test"), body)
    assert counts == {"trained": 0, "aligned": 0, "interpolated": 1, "stored": 0}
    torch.testing.assert_close(held_out.rotations[1], v_rot)
    torch.testing.assert_close(held_out.translation[1], v_trans)
    own, counts = track_corrections(track, TrainingData(subject, split="own"), body)
    assert counts == {"trained": 1, "aligned": 0, "interpolated": 0, "stored": 0}
    assert torch.equal(own.rotations[0], learned.rotations[0])


def test_a_frame_aligned_to_its_image_keeps_its_stored_pose(subject, body):
    """meta.json's aligned_frames (a polished capture's held-out frames): the track interpolates
    nothing onto them, in eval and in the subject played as a motion; a trained frame listed there
    keeps its own correction."""
    from pghm.motion.open_motion import subject_motion

    train = TrainingData(subject)
    learned = train.pose_corrections(body)
    with torch.no_grad():
        learned.translation[0], learned.translation[2] = torch.tensor([0.02, 0.0, 0.0]), torch.tensor([0.04, 0.0, 0.0])
    track = learned_track(learned, train)
    meta = json.loads((subject / "meta.json").read_text())
    played = subject_motion(subject, track).translation
    np.testing.assert_allclose(played[1] - played_stored(subject)[1], [0.03, 0.0, 0.0], atol=1e-6)  # interpolated
    (subject / "meta.json").write_text(json.dumps({**meta, "aligned_frames": [1, 2]}))
    held_out, counts = track_corrections(track, TrainingData(subject, split="test"), body)
    assert counts == {"trained": 0, "aligned": 0, "interpolated": 0, "stored": 1}
    assert not held_out.translation[1].any() and not held_out.rotations[1].any()
    played = subject_motion(subject, track).translation
    np.testing.assert_allclose(played - played_stored(subject), [[0.02, 0, 0], [0, 0, 0], [0.04, 0, 0]], atol=1e-6)


def played_stored(subject) -> np.ndarray:
    """(3, 3) the tiny subject's frames' stored root translations, as a motion plays them untracked."""
    from pghm.motion.open_motion import subject_motion

    return subject_motion(subject).translation


def shifted(source, out):
    """A copy of ``source`` with every stored root translation off by SHIFT."""
    shutil.copytree(source, out)
    poses = dict(np.load(out / "poses.npz"))
    poses["translation"] = poses["translation"] + SHIFT
    np.savez(out / "poses.npz", **poses)
    return out


def test_fit_records_its_track_and_eval_with_it_undoes_a_known_error(subject, tmp_path, capsys):
    """A fit saves its track (round trip through the file); a track that cancels SHIFT on the
    training frames renders the held-out frame exactly as the unshifted poses do."""
    from pghm.train.evaluate import evaluate

    stages = [LoopConfig(steps=n, images_per_shard=2, checkpoint_every=0) for n in (1, 2)]
    config = FitConfig(stage1=stages[0], stage2=stages[1], lpips=False)
    avatar = fit(subject, ModelConfig(**TINY_MODEL), tmp_path / "a.pt", config)
    loaded = load_avatar(tmp_path / "a.pt")
    assert loaded.pose_track.frames.tolist() == [0, 2]
    for name in ("bones", "rotations", "translation"):
        assert torch.equal(getattr(loaded.pose_track, name), getattr(avatar.pose_track, name))
    assert loaded.pose_track.poses == TrainingData(subject).subjects[0].arrays.poses_digest()

    moved = shifted(subject, tmp_path / "shifted")
    track = learned_track(TrainingData(moved).pose_corrections(load_body("anny")), TrainingData(moved))
    track.translation[:] = -torch.from_numpy(SHIFT)
    avatar.pose_track = track
    truth = evaluate(avatar, subject).summary()["psnr"]
    assert evaluate(avatar, moved).summary()["psnr"] != pytest.approx(truth, abs=1e-2)
    assert evaluate(avatar, moved, fit_poses=True).summary()["psnr"] == pytest.approx(truth, abs=1e-4)
    with pytest.raises(PghmError, match="learned on other poses"):
        evaluate(avatar, subject, fit_poses=True)
    avatar.pose_track = None
    with pytest.raises(PghmError, match="holds no pose track"):
        evaluate(avatar, moved, fit_poses=True)
    save_avatar(tmp_path / "untracked.pt", avatar)
    capsys.readouterr()  # the fit's progress bars
    assert main(["eval", str(tmp_path / "untracked.pt"), str(moved), "--fit-poses"]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert "no pose track" in line and not list(tmp_path.glob("untracked.pt.eval*"))


def test_the_pose_learning_rate_and_the_track_settling_follow_the_stated_noise(subject, tmp_path):
    """sigma_0 / sigma times the synthetic data's rate, never above it; the poses settled (between
    the stages, else after stage 2) and the held-out frames aligned only for poses noisier than
    sigma_0; a fit of a subject that states 8 degrees records them."""
    import math

    from pghm.train.data import ESTIMATOR_ROTATION_SIGMA
    from pghm.train.fit import (
        EARLY_TRACK_STEPS,
        HELD_OUT_STEPS,
        POSE_LR,
        TRACK_MIN_VISITS,
        TRACK_STEPS,
        early_track_steps,
        held_out_steps,
        pose_learning_rate,
        resolved,
        track_steps,
    )

    assert pose_learning_rate(ESTIMATOR_ROTATION_SIGMA) == POSE_LR
    assert track_steps(ESTIMATOR_ROTATION_SIGMA, 1.0, 0) == 0 and track_steps(math.radians(9.5), 1.0, 0) == TRACK_STEPS
    assert track_steps(math.radians(9.5), TRACK_MIN_VISITS, 0) == 0
    assert track_steps(math.radians(9.5), 1.0, EARLY_TRACK_STEPS) == 0  # settled between the stages
    assert early_track_steps(ESTIMATOR_ROTATION_SIGMA) == held_out_steps(ESTIMATOR_ROTATION_SIGMA) == 0
    assert early_track_steps(math.radians(9.5)) == EARLY_TRACK_STEPS
    assert held_out_steps(math.radians(9.5)) == HELD_OUT_STEPS
    assert pose_learning_rate(ESTIMATOR_ROTATION_SIGMA / 4) == POSE_LR
    assert pose_learning_rate(math.radians(8.0)) == pytest.approx(POSE_LR / 4)
    meta = json.loads((subject / "meta.json").read_text())
    stated = {"rotation_std_deg": 8.0, "translation_std_m": 0.01}
    (subject / "meta.json").write_text(json.dumps({**meta, "pose_noise": stated}))
    stages = [LoopConfig(steps=n, images_per_shard=2, checkpoint_every=0) for n in (1, 1)]
    config = FitConfig(*stages, lpips=False, detail=LoopConfig(steps=0))
    data = TrainingData(subject)
    assert resolved(replace(config, early_track_steps=0), data).track_steps == TRACK_STEPS
    assert resolved(replace(config, pose_lr=1e-3), data).pose_lr == 1e-3
    # The fit records what the resolution gives.
    recorded = fit(subject, ModelConfig(**TINY_MODEL), tmp_path / "a.pt", config).metadata["config"]
    assert recorded["pose_lr"] == pytest.approx(POSE_LR / 4)
    assert recorded["early_track_steps"] == EARLY_TRACK_STEPS and recorded["track_steps"] == 0
