"""The Gaussian prior on the pose corrections: its value by hand, its place in the objective, bad weights, defaults."""

from __future__ import annotations

import importlib
import math

import pytest
import torch
from conftest import TINY_MODEL

from pghm.cli.main import main
from pghm.errors import PghmError
from pghm.model import PGHM, ModelConfig
from pghm.train.data import ESTIMATOR_ROTATION_SIGMA, ESTIMATOR_TRANSLATION_SIGMA, PoseCorrections, TrainingData
from pghm.train.fit import FIT_POSE_PRIOR, FitConfig
from pghm.train.loop import AvatarObjective
from pghm.train.losses import LossWeights
from pghm.train.prior import GeometryCache, PriorConfig


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

    def record(*positional, resume):
        seen["config"] = positional[-1]
        raise Recorded

    monkeypatch.setattr(importlib.import_module(module), call, record)
    with pytest.raises(Recorded):
        main(command)
    assert seen["config"] == expected
    stages = [expected.stage1, expected.stage2] if isinstance(expected, FitConfig) else [expected.loop]
    assert all(stage.loss.pose_prior == weight for stage in stages)
