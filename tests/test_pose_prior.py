"""The Gaussian prior on the pose corrections: its value by hand, its place in the objective, bad weights, defaults."""

from __future__ import annotations

import importlib
import json
import math
import shutil

import pytest
import torch
from conftest import TINY_MODEL

from pghm.cli.main import main
from pghm.device import resolve_device
from pghm.errors import DatasetError, PghmError
from pghm.model import PGHM, ModelConfig
from pghm.train.data import ESTIMATOR_ROTATION_SIGMA, ESTIMATOR_TRANSLATION_SIGMA, PoseCorrections, TrainingData
from pghm.train.fit import FIT_POSE_PRIOR, FitConfig
from pghm.train.loop import AvatarObjective
from pghm.train.losses import LossWeights
from pghm.train.prior import PriorConfig
from pghm.train.run_setup import GeometryCache


def test_prior_counts_the_corrections_in_units_of_the_noise():
    corrections = PoseCorrections(num_frames=4, bones=[1, 3])
    with torch.no_grad():
        corrections.rotations[2] = torch.tensor([[1.0, 0, 0], [0, 2.0, 0]]) * ESTIMATOR_ROTATION_SIGMA
        corrections.translation[2] = torch.tensor([0, 0, ESTIMATOR_TRANSLATION_SIGMA])
        corrections.translation[3] = torch.tensor([3.0, 0, 0])  # a frame outside the batch
    # Frame 0 is uncorrected (0); frame 2 has 1 + 4 + 1 noise units squared; the mean over both is 3.
    assert corrections.prior(torch.tensor([0, 2])).item() == pytest.approx(3.0, rel=1e-5)
    assert ESTIMATOR_ROTATION_SIGMA == pytest.approx(math.radians(2.0))


def test_objective_adds_the_weighted_prior_of_its_frames_only(tiny_dataset):
    data = TrainingData(tiny_dataset)
    model = PGHM(ModelConfig(**TINY_MODEL), num_identities=data.num_identities)
    geometries = GeometryCache(data, model.config, None)
    corrections = PoseCorrections.of_estimated_joints(data.num_frames, geometries.body)
    with torch.no_grad():
        corrections.rotations.normal_(0.0, 0.01, generator=torch.Generator().manual_seed(0))
        corrections.translation.normal_(0.0, 0.01, generator=torch.Generator().manual_seed(1))
    samples = data.load_group(0, list(data.images[0])[:2])
    keys = sorted({s.frame_key for s in samples})
    by_hand = sum(
        corrections.rotations[k].square().sum() / ESTIMATOR_ROTATION_SIGMA**2
        + corrections.translation[k].square().sum() / ESTIMATOR_TRANSLATION_SIGMA**2
        for k in keys
    ) / len(keys)

    losses = {}
    for weight in (0.0, 0.5):
        objective = AvatarObjective(model, None, corrections, LossWeights(pose_prior=weight), None)
        with torch.no_grad():
            losses[weight], terms = objective(samples, geometries(0))
    assert (losses[0.5] - losses[0.0]).item() == pytest.approx(0.5 * by_hand.item(), rel=1e-4)
    assert terms["pose_prior"] == pytest.approx(by_hand.item(), rel=1e-4)
    assert terms["loss"] == pytest.approx(losses[0.5].item())


def test_negative_weights_are_refused_with_one_message(tmp_path, capsys):
    with pytest.raises(PghmError, match="pose_prior"):
        LossWeights(pose_prior=-1.0)
    with pytest.raises(PghmError, match="l1"):
        LossWeights(l1=math.nan)
    code = main(["fit", str(tmp_path), "--prior", "scratch", "--out", str(tmp_path / "a.pt"), "--pose-prior", "-1"])
    assert code == 2
    (line,) = capsys.readouterr().err.splitlines()  # refused at the parser, before any file is read
    assert "--pose-prior" in line and "[0, 100]" in line


@pytest.mark.parametrize(
    ("command", "module", "call", "expected", "weight"),
    [
        (["fit", "subject", "--prior", "p.pt", "--out", "a.pt"], "pghm.train.fit", "fit", FitConfig(), FIT_POSE_PRIOR),
        (["train-prior", "data", "--out", "p.pt"], "pghm.train.prior", "train_prior", PriorConfig(), 0.0),
    ],
)
def test_commands_without_options_run_the_library_defaults(monkeypatch, command, module, call, expected, weight):
    """The CLI passes the library's default configs through, loss weights included: ``fit`` holds
    the corrections with the pose prior (FIT_POSE_PRIOR), ``train-prior`` leaves it off."""
    seen = {}

    class Recorded(Exception):
        pass

    def record(*positional, resume, device, **_):
        seen["config"], seen["device"] = positional[-1], device
        raise Recorded

    monkeypatch.setattr(importlib.import_module(module), call, record)
    with pytest.raises(Recorded):
        main(command)
    assert seen["config"] == expected
    assert seen["device"] == resolve_device("auto")
    stages = [expected.stage1, expected.stage2] if isinstance(expected, FitConfig) else [expected.loop]
    assert all(stage.loss.pose_prior == weight for stage in stages)


def _state_pose_noise(subject, noise) -> None:
    meta_path = subject / "meta.json"
    meta = json.loads(meta_path.read_text())
    meta["pose_noise"] = noise
    meta_path.write_text(json.dumps(meta))


def test_each_subject_scales_its_frames_prior_by_its_stated_noise(tiny_dataset, tmp_path):
    """meta.json's pose_noise sets the width of the prior on that subject's frames only: a correction
    of one stated sigma costs 1 on either subject, whatever their sigmas."""
    data_dir = tmp_path / "data"
    shutil.copytree(tiny_dataset, data_dir)
    _state_pose_noise(data_dir / "subject_001", {"rotation_std_deg": 6.0, "translation_std_m": 0.03})
    data = TrainingData(data_dir)
    rotation_sigma, translation_sigma = data.pose_sigmas()
    first, second = data.load(0, 0).frame_key, data.load(1, 0).frame_key
    # The generator states its own noise in subject_000 (the preset's 2 degrees, 1 cm).
    assert rotation_sigma[first].item() == pytest.approx(ESTIMATOR_ROTATION_SIGMA)
    assert translation_sigma[first].item() == pytest.approx(ESTIMATOR_TRANSLATION_SIGMA)
    assert rotation_sigma[second].item() == pytest.approx(math.radians(6.0))
    assert translation_sigma[second].item() == pytest.approx(0.03)

    corrections = PoseCorrections(data.num_frames, bones=[1, 3], sigmas=(rotation_sigma, translation_sigma))
    with torch.no_grad():
        corrections.rotations[first, 0, 0] = ESTIMATOR_ROTATION_SIGMA
        corrections.rotations[second, 1, 2] = math.radians(6.0)
        corrections.translation[second, 1] = 0.03
    assert corrections.prior(torch.tensor([first])).item() == pytest.approx(1.0, rel=1e-5)
    assert corrections.prior(torch.tensor([second])).item() == pytest.approx(2.0, rel=1e-5)


@pytest.mark.parametrize(
    "noise", ["loud", {"rotation_std_deg": -1.0, "translation_std_m": 0.01}, {"rotation_std_deg": 2}]
)
def test_a_bad_stated_pose_noise_is_one_line_naming_the_file(tiny_dataset, tmp_path, noise):
    subject = tmp_path / "subject"
    shutil.copytree(tiny_dataset / "subject_000", subject)
    _state_pose_noise(subject, noise)
    with pytest.raises(DatasetError, match=r"meta\.json: 'pose_noise' must give numbers >= 0") as raised:
        TrainingData(subject)
    assert "\n" not in str(raised.value)


def test_zero_stated_noise_keeps_the_default_width(tiny_dataset, tmp_path):
    subject = tmp_path / "subject"
    shutil.copytree(tiny_dataset / "subject_000", subject)
    _state_pose_noise(subject, {"rotation_std_deg": 0, "translation_std_m": 0.0})
    rotation_sigma, translation_sigma = TrainingData(subject).pose_sigmas()
    assert torch.allclose(rotation_sigma, torch.tensor(ESTIMATOR_ROTATION_SIGMA))
    assert torch.allclose(translation_sigma, torch.tensor(ESTIMATOR_TRANSLATION_SIGMA))
