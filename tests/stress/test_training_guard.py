"""Training under numerical trouble and bad frames: no NaN is ever left behind, and nothing stops
a run that can go on.

The loop's guard (pghm/train/loop.py): a step whose loss, gradients or update is not finite is
skipped (parameters and optimizer state as before it), the learning rate halved, and one
warning logged. Independent truth for "skipped": the run with the bad step injected ends with
exactly the parameters of the run that stopped before it. A learning rate high enough to make
the network overflow by itself (no injection) must be caught the same way.
"""

from __future__ import annotations

import json
import logging
import math
import shutil
from pathlib import Path

import pytest
import torch
from conftest import TINY_MODEL
from stress_kit import check, cli, one_error_line

from pghm.model import ModelConfig
from pghm.subject import image_name
from pghm.train import loop as loop_module
from pghm.train.data import TrainingData
from pghm.train.fit import FitConfig, fit
from pghm.train.loop import LR_BACKOFF, LoopConfig, load_checkpoint
from pghm.train.optim import LazyAdam
from pghm.train.prior import PriorConfig, train_prior
from pghm.train.run_setup import checkpoint_path

AREA = "training"
GUARD_LINE = "non-finite loss, gradient or update; step skipped, learning rate x0.50"


def config(steps: int, network_lr: float = 3e-3, latent_lr: float = 5e-2, pose_lr: float = 1e-3) -> PriorConfig:
    return PriorConfig(
        model=ModelConfig(**TINY_MODEL),
        loop=LoopConfig(steps=steps, images_per_shard=2, checkpoint_every=0),
        network_lr=network_lr,
        latent_lr=latent_lr,
        pose_lr=pose_lr,
        lpips=False,
    )


def all_finite(avatar) -> bool:
    return all(bool(torch.isfinite(v).all()) for v in avatar.model.state_dict().values())


def largest_difference(a, b) -> float:
    first, second = a.model.state_dict(), b.model.state_dict()
    return max(float((first[k] - second[k]).abs().max()) for k in first)


def guard_lines(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if GUARD_LINE in r.getMessage()]


DIVERGING_NETWORK_LR = 1e4
"""pghm fit's stage-2 network rate that overflows the network (default 2e-4). Measured: this
model's loss never goes non-finite at 10x its rates, nor in train-prior at any accepted rate
(the zero-initialised heads saturate their tanh/sigmoid at step 1, so nothing below them
moves); starting from a trained prior, every U-Net weight moves by the rate at once, and from
1e3 up the activations overflow at the next step (1e2 stays finite)."""
FIT_NETWORK_GROUP = 1
"""Index of the U-Net's group in fit's stage-2 optimizer (latent, network, pose corrections)."""


@pytest.fixture(scope="module")
def tiny_prior(tiny_dataset, tmp_path_factory) -> Path:
    """A prior trained 2 steps: heads no longer zero, so gradients reach every layer during fit."""
    path = tmp_path_factory.mktemp("tiny_prior") / "prior.pt"
    train_prior(tiny_dataset, path, config(2))
    return path


def fit_config(stage1: int, stage2: int, network_lr: float = FitConfig.network_lr) -> FitConfig:
    """Short fit stages, a checkpoint after every step (its optimizer state shows the rates in use)."""
    return FitConfig(
        stage1=LoopConfig(steps=stage1, images_per_shard=2, checkpoint_every=1),
        stage2=LoopConfig(steps=stage2, images_per_shard=2, checkpoint_every=1),
        network_lr=network_lr,
        lpips=False,
    )


TOO_HIGH = 10
"""The issue's case: every learning rate 10x its default."""


def test_learning_rates_ten_times_the_defaults_leave_no_nan(tiny_dataset, tmp_path, caplog):
    """train-prior at 10x every default rate: parameters stay finite, and any step the guard
    skips is logged (with this model 10x never overflows; the next test makes it)."""
    caplog.set_level(logging.WARNING)
    hot = config(
        4,
        network_lr=TOO_HIGH * PriorConfig.network_lr,
        latent_lr=TOO_HIGH * PriorConfig.latent_lr,
        pose_lr=TOO_HIGH * PriorConfig.pose_lr,
    )
    avatar = train_prior(tiny_dataset, tmp_path / "hot.pt", hot)
    skipped, lines = avatar.metadata["skipped_steps"], guard_lines(caplog)
    check(
        AREA,
        f"pghm train-prior, every learning rate {TOO_HIGH}x its default, 4 steps",
        "no NaN parameter left; any skipped step logged",
        f"parameters finite: {all_finite(avatar)}; skipped steps {skipped} ({len(lines)} logged)",
        all_finite(avatar) and skipped == len(lines),
    )


def test_a_diverging_learning_rate_is_skipped_lowered_and_logged(
    tiny_dataset, tiny_prior, tmp_path, caplog, monkeypatch
):
    """The truth for "rate lowered" is the optimizer's own state in the last checkpoint (read as it
    is written: a finished fit removes its checkpoint)."""
    caplog.set_level(logging.WARNING)
    out = tmp_path / "hot.pt"
    saved = []
    real_save = loop_module.save_checkpoint

    def keep_a_copy(path, objective, optimizer, state, extra):
        real_save(path, objective, optimizer, state, extra)
        saved.append(load_checkpoint(path))

    monkeypatch.setattr(loop_module, "save_checkpoint", keep_a_copy)
    avatar = fit(tiny_dataset / "subject_000", tiny_prior, out, fit_config(1, 3, DIVERGING_NETWORK_LR))
    skipped = avatar.metadata["skipped_steps"]
    network_group = saved[-1]["optimizer"]["param_groups"][FIT_NETWORK_GROUP]
    lines = guard_lines(caplog)
    finite = all_finite(avatar) and bool(torch.isfinite(avatar.latent).all())
    ok = (
        skipped >= 1
        and len(lines) == skipped
        and network_group["initial_lr"] == DIVERGING_NETWORK_LR  # the configured rate, kept to resume from
        and saved[-1]["state"]["lr_scale"] == LR_BACKOFF**skipped  # times the backed-off scale
        and finite
    )
    check(
        AREA,
        f"pghm fit, stage-2 network learning rate {DIVERGING_NETWORK_LR:g} (default "
        f"{FitConfig.network_lr:g}): the loss overflows",
        "non-finite steps skipped, each logged and halving the rate; no NaN parameter left",
        f"skipped steps {skipped} ({len(lines)} logged); network rate scale now {saved[-1]['state']['lr_scale']:g}; "
        f"parameters finite: {finite}; first log: {lines[0] if lines else 'none'}",
        ok,
    )


def _poison(monkeypatch, at_call: int, where: str) -> None:
    """Make the ``at_call``-th group evaluation non-finite: its loss ("loss") or the network's Gaussians ("model")."""
    calls = {"n": 0}
    if where == "loss":
        real = loop_module.objective

        def objective(*args, **kwargs):
            loss, terms = real(*args, **kwargs)
            calls["n"] += 1
            return (loss * math.nan if calls["n"] == at_call else loss), terms

        monkeypatch.setattr(loop_module, "objective", objective)
    else:
        from pghm.model.pghm import PGHM

        real = PGHM.assemble

        def assemble(self, *args, **kwargs):
            out = real(self, *args, **kwargs)
            calls["n"] += 1
            if calls["n"] == at_call:
                out.dynamic = type(out.dynamic)(
                    out.dynamic.means * math.nan, *(getattr(out.dynamic, f) for f in ("scales", "colors", "opacities"))
                )
            return out

        monkeypatch.setattr(PGHM, "assemble", assemble)


@pytest.mark.parametrize("where", ["loss", "model"], ids=["NaN loss", "NaN Gaussians from the network"])
def test_a_non_finite_step_is_skipped_halved_and_logged(where, tiny_dataset, tmp_path, monkeypatch, caplog):
    """Step 2 of 3 poisoned: the run must end exactly where a 2-step run ends, at half the rate."""
    before = train_prior(tiny_dataset, tmp_path / "two.pt", config(2))
    caplog.clear()
    caplog.set_level(logging.WARNING)
    _poison(monkeypatch, at_call=3, where=where)  # one group per step: the third evaluation is step index 2
    poisoned = train_prior(tiny_dataset, tmp_path / "three.pt", config(3))
    lines = guard_lines(caplog)
    difference = largest_difference(before, poisoned)
    ok = (
        difference == 0.0
        and poisoned.metadata["skipped_steps"] == 1
        and all_finite(poisoned)
        and len(lines) == 1
        and lines[0].startswith("step 2: ")
        and "now scale 0.5" in lines[0]
    )
    check(
        AREA,
        f"{'NaN loss' if where == 'loss' else 'NaN Gaussians from the network'} at step 2 of 3",
        "step skipped (parameters exactly those of a 2-step run), rate halved, one warning naming the step",
        f"parameter difference {difference:g}; skipped {poisoned.metadata['skipped_steps']}; "
        f"log: {lines[0] if lines else 'none'}",
        ok,
    )


def test_a_non_finite_update_is_undone(tiny_dataset, tmp_path, monkeypatch, caplog):
    """The update of step 1 of 2 turns one parameter infinite: the step must be undone exactly."""
    before = train_prior(tiny_dataset, tmp_path / "one.pt", config(1))
    real_step = LazyAdam.step
    calls = {"n": 0}

    def step(self, *args, **kwargs):
        result = real_step(self, *args, **kwargs)
        calls["n"] += 1
        if calls["n"] == 2:
            with torch.no_grad():
                self.param_groups[0]["params"][0].view(-1)[0] = math.inf
        return result

    monkeypatch.setattr(LazyAdam, "step", step)
    caplog.set_level(logging.WARNING)
    blown = train_prior(tiny_dataset, tmp_path / "two.pt", config(2))
    difference = largest_difference(before, blown)
    lines = guard_lines(caplog)
    check(
        AREA,
        "an update that leaves a parameter infinite (step 1 of 2)",
        "parameters restored exactly, rate halved, logged",
        f"parameter difference to the 1-step run {difference:g}; log: {lines[0] if lines else 'none'}",
        difference == 0.0 and len(lines) == 1 and lines[0].startswith("step 1: ") and all_finite(blown),
    )


def test_an_absurd_learning_rate_is_one_clear_error(tiny_dataset, tmp_path):
    result = cli(
        "train-prior",
        tiny_dataset,
        "--out",
        tmp_path / "p.pt",
        "--steps",
        "1",
        "--uv-resolution",
        "64",
        "--no-lpips",
        "--lr",
        "1e39",
    )
    ok, observed = one_error_line(result)
    check(
        AREA,
        "pghm train-prior --lr 1e39 (torch's Adam raises on it)",
        "exit 2 at the parser, one line naming --lr and its range",
        observed,
        ok and "--lr" in result.stderr and "1e+06" in result.stderr,
    )


def _first_drawn_image(data: TrainingData, steps: int) -> tuple[int, int, int]:
    """(step, identity, image) of the first image the batch plan draws (the plan is a function of seed and step)."""
    for step in range(steps):
        for identity, images in data.plan(0, step, 1, 2):
            return step, identity, images[0]
    raise AssertionError("empty plan")


def _truncate_first_drawn(folder: Path, steps: int) -> tuple[int, int, int, Path]:
    """Cut in half (header intact, pixels cut) the first image the batch plan of ``folder`` (a data
    set, or one subject for fit) draws, so the run meets it at once; (step, identity, image, subject folder)."""
    data = TrainingData(folder)
    step, identity, image = _first_drawn_image(data, steps)
    path = data.subjects[identity].image_path(image)
    path.write_bytes(path.read_bytes()[: len(path.read_bytes()) // 2])
    return step, identity, image, data.subjects[identity].directory


def skip_warnings(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if "skipping image" in r.getMessage()]


PRIOR_STEPS = 4
FIT_STEPS = (2, 2)
"""Stage 1 and stage 2 steps: the frame is drawn in stage 1 and must not be reported again in stage 2."""


def test_a_truncated_frame_is_reported_once_and_training_goes_on(tiny_dataset, tmp_path, caplog):
    data_dir = Path(shutil.copytree(tiny_dataset, tmp_path / "data"))
    step, identity, image, subject = _truncate_first_drawn(data_dir, PRIOR_STEPS)
    caplog.set_level(logging.WARNING)
    avatar = train_prior(data_dir, tmp_path / "p.pt", config(PRIOR_STEPS))
    warnings = skip_warnings(caplog)
    ok = (
        len(warnings) == 1
        and f"image {image} of {subject}" in warnings[0]
        and avatar.metadata["steps"] == PRIOR_STEPS
        and avatar.metadata["skipped_images"] == [[identity, image]]
        and all_finite(avatar)
    )
    check(
        AREA,
        f"pghm train-prior: one truncated PNG in the data (drawn at step {step})",
        "reported once naming the frame; all steps run",
        f"{len(warnings)} warning(s): {warnings[0][:150] if warnings else 'none'}; steps {avatar.metadata['steps']}; "
        f"skipped images {avatar.metadata['skipped_images']}",
        ok,
    )


def test_a_truncated_frame_in_fit_is_reported_once_and_fitting_goes_on(tiny_dataset, tiny_prior, tmp_path, caplog):
    """fit's metadata lists the skipped images (its checkpoint is removed once the avatar is written)."""
    subject_dir = Path(shutil.copytree(tiny_dataset / "subject_000", tmp_path / "subject"))
    step, identity, image, subject = _truncate_first_drawn(subject_dir, FIT_STEPS[0])
    caplog.set_level(logging.WARNING)
    out = tmp_path / "a.pt"
    avatar = fit(subject_dir, tiny_prior, out, fit_config(*FIT_STEPS))
    warnings = skip_warnings(caplog)
    recorded = avatar.metadata["skipped_images"]
    steps = avatar.metadata["steps"]
    ok = (
        len(warnings) == 1
        and f"image {image} of {subject}" in warnings[0]
        and (steps["stage1"], steps["stage2"]) == FIT_STEPS
        and recorded == [[identity, image]]
        and not checkpoint_path(out).exists()
        and all_finite(avatar)
    )
    check(
        AREA,
        f"pghm fit: one truncated PNG in the subject (drawn at stage-1 step {step})",
        "reported once naming the frame; both stages run all their steps",
        f"{len(warnings)} warning(s): {warnings[0][:150] if warnings else 'none'}; steps {steps}; "
        f"skipped images {recorded}",
        ok,
    )


def test_every_frame_unreadable_is_one_clear_error(tiny_dataset, tmp_path):
    data_dir = Path(shutil.copytree(tiny_dataset, tmp_path / "data"))
    for path in sorted((data_dir / "subject_000" / "images").glob("*.png")):
        path.write_bytes(path.read_bytes()[:10])  # not even a header
    result = cli(
        "train-prior", data_dir, "--out", tmp_path / "p.pt", "--steps", "2", "--uv-resolution", "64", "--no-lpips"
    )
    ok, observed = one_error_line(result)
    train = json.loads((data_dir / "subject_000" / "splits.json").read_text())["train"]
    first = f"images/{image_name(train[0])}"
    check(
        AREA,
        "every image of a subject unreadable (pghm train-prior)",
        f"exit 2 before any step, one line naming them: {len(train)} file(s) ... cannot be opened ({first}, ...)",
        observed,
        ok and f"{len(train)} file(s)" in result.stderr and first in result.stderr and not (tmp_path / "p.pt").exists(),
    )


def test_an_image_drawn_after_others_failed_mid_run_stops_cleanly(tiny_dataset, tmp_path):
    """When the last readable image of a subject fails while training, the run stops with a DatasetError."""
    from pghm.errors import DatasetError

    data = TrainingData(Path(shutil.copytree(tiny_dataset, tmp_path / "data")))
    images = [int(i) for i in data.images[0]]
    for index in images:
        path = data.subjects[0].image_path(index)
        path.write_bytes(path.read_bytes()[: len(path.read_bytes()) // 2])
    loaded = sum(len(data.load_group(0, [index])) for index in images[:-1])
    try:
        data.load_group(0, [images[-1]])
        observed, ok = "no error", False
    except DatasetError as error:
        observed, ok = str(error), "none of its" in str(error) and "\n" not in str(error)
    check(
        AREA,
        "all frames of a subject found truncated during training",
        "DatasetError once the last one fails",
        f"{loaded} loaded before; then: {observed[-120:]}",
        ok and loaded == 0,
    )
