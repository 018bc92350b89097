"""Training: the prior learns, fit's two stages touch the right tensors, resume is exact,
eval's metrics are right at the extremes, and a bad learning rate leaves no NaN."""

from __future__ import annotations

import json
import math
import time
from dataclasses import replace

import numpy as np
import pytest
import torch
from conftest import TINY_MODEL, absolute_paths

from pghm.errors import PghmError
from pghm.model import ModelConfig
from pghm.train.data import TrainingData
from pghm.train.fit import FitConfig, fit, network_parameters
from pghm.train.loop import LoopConfig
from pghm.train.prior import PriorConfig, initial_model, train_prior

MODEL = ModelConfig(**TINY_MODEL)


def prior_config(steps: int, **loop) -> PriorConfig:
    return PriorConfig(
        model=MODEL,
        loop=LoopConfig(steps=steps, images_per_shard=2, checkpoint_every=0, **loop),
        network_lr=3e-3,
        latent_lr=5e-2,
        lpips=False,
    )


def fixed_loss(model, data: TrainingData) -> float:
    """The objective of ``model`` (a PGHM) on a fixed set of images (every training image of both identities)."""
    from pghm.train.loop import AvatarObjective
    from pghm.train.run_setup import GeometryCache

    geometries = GeometryCache(data, model.config, None)
    objective = AvatarObjective(model, None, None, LoopConfig().loss, None)
    with torch.no_grad():
        losses = [
            objective(data.load_group(i, list(data.images[i])), geometries(i))[0].item()
            for i in range(data.num_identities)
        ]
    return float(np.mean(losses))


def tiny_avatar(subject, prior_file, out, stage1: int, stage2: int):
    """A quick fit of the tiny subject: ``stage1`` + ``stage2`` steps, no checkpoints, no LPIPS."""
    stages = [LoopConfig(steps=n, checkpoint_every=0) for n in (stage1, stage2)]
    return fit(subject, prior_file, out, FitConfig(stage1=stages[0], stage2=stages[1], lpips=False))


@pytest.fixture(scope="module")
def prior_file(tiny_dataset, tmp_path_factory):
    path = tmp_path_factory.mktemp("prior") / "prior.pt"
    train_prior(tiny_dataset, path, prior_config(steps=12))
    return path


def test_two_identity_prior_loss_falls(tiny_dataset, tmp_path):
    data = TrainingData(tiny_dataset)
    assert data.num_identities == 2
    untrained = initial_model(MODEL, data.num_identities, prior_config(steps=15).loop.seed)
    trained = train_prior(tiny_dataset, tmp_path / "p1.pt", prior_config(steps=15))
    before, after = fixed_loss(untrained, data), fixed_loss(trained.model, data)
    assert after < 0.9 * before, (before, after)
    assert trained.kind == "prior" and trained.shapes.shape == (2, 6)
    assert trained.metadata["steps"] == 15 and trained.metadata["lpips"].startswith("LPIPS off")


def test_fit_stage1_changes_only_the_latent_stage2_also_the_unet(tiny_dataset, prior_file, tmp_path):
    from pghm.io.avatar import load_avatar

    subject = tiny_dataset / "subject_001"
    original = {k: v.clone() for k, v in load_avatar(prior_file).model.state_dict().items()}
    prior = load_avatar(prior_file)
    config = FitConfig(
        stage1=LoopConfig(steps=3, images_per_shard=2, checkpoint_every=0),
        stage2=LoopConfig(steps=0, images_per_shard=2, checkpoint_every=0),
        lpips=False,
    )
    stage1 = fit(subject, prior, tmp_path / "a1.pt", config)
    for name, value in stage1.model.state_dict().items():
        assert torch.equal(value, original[name]), f"stage 1 changed {name}"
    from pghm.train.fit import initial_latent

    assert not torch.equal(stage1.latent, initial_latent(load_avatar(prior_file).model))

    prior = load_avatar(prior_file)
    config.stage2 = LoopConfig(steps=3, images_per_shard=2, checkpoint_every=0)
    stage2 = fit(subject, prior, tmp_path / "a2.pt", config)
    changed = {name for name, value in stage2.model.state_dict().items() if not torch.equal(value, original[name])}
    tuned = {
        name for name, p in stage2.model.named_parameters() if any(p is q for q in network_parameters(stage2.model))
    }
    assert changed and changed <= tuned
    assert any(name.startswith("unet_encoder") for name in changed)
    assert not any(name.startswith(("identity_bank", "feature_decoder")) for name in changed)


def test_fit_at_twice_the_priors_resolution_makes_an_avatar_at_that_resolution(tiny_dataset, prior_file, tmp_path):
    from pghm.io.avatar import avatar_geometry, load_avatar

    prior = load_avatar(prior_file)
    finer = 2 * prior.model.config.uv_resolution
    config = FitConfig(
        stage1=LoopConfig(steps=1, images_per_shard=2, checkpoint_every=0),
        stage2=LoopConfig(steps=1, images_per_shard=2, checkpoint_every=0),
        uv_resolution=finer,
        lpips=False,
    )
    fit(tiny_dataset / "subject_001", prior, tmp_path / "fine.pt", config)
    avatar = load_avatar(tmp_path / "fine.pt")
    assert avatar.model.config.uv_resolution == finer and avatar.latent.shape[-1] == finer
    geometry, coarse = avatar_geometry(avatar), avatar_geometry(prior)
    assert geometry.atlas.resolution == finer
    assert 3.5 < geometry.num_gaussians / coarse.num_gaussians < 4.5  # a texel per Gaussian, 4x the texels
    assert load_avatar(prior_file).model.config.uv_resolution == finer // 2  # the prior file is unchanged


def test_fit_detail_stage_trains_only_the_layer_and_saves_it(tiny_dataset, prior_file, tmp_path):
    from pghm.io.avatar import avatar_geometry, load_avatar

    stages = [LoopConfig(steps=n, images_per_shard=2, checkpoint_every=0) for n in (1, 1, 3)]
    config = FitConfig(stage1=stages[0], stage2=stages[1], lpips=False, detail_validation=0)
    config.detail = replace(stages[2], steps=0)
    plain = fit(tiny_dataset / "subject_001", load_avatar(prior_file), tmp_path / "plain.pt", config)
    config.detail = stages[2]
    fit(tiny_dataset / "subject_001", load_avatar(prior_file), tmp_path / "detail.pt", config)
    loaded = load_avatar(tmp_path / "detail.pt")
    assert plain.model.detail is None and loaded.model.config.detail
    assert loaded.metadata["steps"]["detail"] == 3 and not (tmp_path / "detail.pt.ckpt").exists()
    assert loaded.model.detail.maps.abs().sum() > 0
    # The stages before it are the same run: the latent and the network are those of the plain fit.
    assert torch.equal(loaded.latent, plain.latent)
    weights = loaded.model.state_dict()
    assert all(torch.equal(weights[name], value) for name, value in plain.model.state_dict().items())
    # Texels no Gaussian of the 2L atlas uses keep their zero.
    unused = ~avatar_geometry(loaded).detail.atlas.mask
    assert loaded.model.detail.maps[0][:, unused].abs().max() == 0


@pytest.mark.parametrize("decay", [0.0, 1.0])
def test_resume_gives_the_same_parameters(tiny_dataset, tmp_path, monkeypatch, decay):
    """Also with decaying rates: the resumed stage continues their schedule from the configured rates,
    not from the decayed ones its checkpoint's optimizer holds."""
    from pghm.train.data import TrainingData

    straight = train_prior(tiny_dataset, tmp_path / "straight.pt", prior_config(steps=6, decay=decay))
    assert not (tmp_path / "straight.pt.ckpt").exists()  # a finished run leaves only its result
    plan = TrainingData.plan

    def interrupted_at_step_3(self, seed, step, *rest):
        if step == 3:
            raise KeyboardInterrupt  # what Ctrl-C does there: the loop saves a checkpoint and re-raises
        return plan(self, seed, step, *rest)

    with monkeypatch.context() as patch:
        patch.setattr(TrainingData, "plan", interrupted_at_step_3)
        with pytest.raises(KeyboardInterrupt):
            train_prior(tiny_dataset, tmp_path / "resumed.pt", prior_config(steps=6, decay=decay))
    resumed = train_prior(tiny_dataset, tmp_path / "resumed.pt", prior_config(steps=6, decay=decay), resume=True)
    for (name, a), (_, b) in zip(straight.model.state_dict().items(), resumed.model.state_dict().items()):
        # The same batches and optimizer state: equal up to float reassociation in threaded kernels.
        torch.testing.assert_close(a, b, atol=1e-6, rtol=1e-5, msg=name)


def test_eval_of_a_perfect_render(tiny_dataset, prior_file, tmp_path, monkeypatch):
    """When the render equals the ground truth, PSNR is +inf and SSIM is 1."""
    from pghm.train import evaluate as evaluate_module
    from pghm.train.background import composite_target

    BLACK_PIXEL = torch.zeros(3, 1, 1)

    avatar = tiny_avatar(tiny_dataset / "subject_000", prior_file, tmp_path / "a.pt", 1, 0)

    def opaque(avatar, data, indices, body_model_path=None, corrections=None):
        """The stored image itself, fully opaque: perfect on white, every pixel outside the mask a halo."""
        for index in indices:
            sample = data.load(0, index)
            yield sample, sample.image.clone(), torch.ones(sample.image.shape[1:])

    def cut_out(avatar, data, indices, body_model_path=None, corrections=None):
        """The subject exactly: its colour on black through its matte, the matte as alpha; perfect
        on any background."""
        for index in indices:
            sample = data.load(0, index)
            yield sample, composite_target(sample.image, sample.mask, BLACK_PIXEL), sample.mask[0].clone()

    monkeypatch.setattr(evaluate_module, "render_images", opaque)
    result = evaluate_module.evaluate(avatar, tiny_dataset / "subject_000", tmp_path / "r.json", tmp_path / "s.png")
    assert result.images and all(math.isinf(p) and p > 0 for p in result.psnr)
    assert result.ssim == pytest.approx([1.0] * len(result.ssim), abs=1e-6)
    assert math.isinf(result.summary()["psnr"])
    assert (tmp_path / "r.json").is_file() and (tmp_path / "s.png").is_file()
    data = TrainingData(tiny_dataset / "subject_000", split="test")
    masks = [data.load(0, i).mask[0] for i in result.images]
    # Outside the mask (matte <= 0.5) a white-background image is white or at most half covered
    # (mean >= 0.5): all halo. An opaque render covers everything: IoU = the person's share.
    assert result.halo == [int((m <= 0.5).sum()) for m in masks]
    assert result.iou == pytest.approx([float((m > 0.5).float().mean()) for m in masks])

    monkeypatch.setattr(evaluate_module, "render_images", cut_out)
    black = evaluate_module.evaluate(avatar, tiny_dataset / "subject_000", background=(0.0, 0.0, 0.0))
    assert all(math.isinf(p) for p in black.psnr)
    cut = [composite_target(data.load(0, i).image, data.load(0, i).mask, BLACK_PIXEL) for i in black.images]
    assert black.halo == [int(((c.mean(0) > 0.25) & (m <= 0.5)).sum()) for c, m in zip(cut, masks)]
    assert black.iou == [1.0] * len(masks)
    assert black.summary()["background"] == [0.0, 0.0, 0.0]


def test_eval_of_a_real_avatar_writes_reports(tiny_dataset, prior_file, tmp_path):
    from pghm.train.evaluate import evaluate

    avatar = tiny_avatar(tiny_dataset / "subject_000", prior_file, tmp_path / "a.pt", 1, 1)
    result = evaluate(avatar, tiny_dataset / "subject_000", tmp_path / "r.json", tmp_path / "s.png")
    summary = result.summary()
    assert 5 < summary["psnr"] < 60 and 0 < summary["ssim"] < 1
    # The report names files (the subject, the LPIPS weights) but no directory of this machine.
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["lpips"] and absolute_paths(report) == []
    # A chosen subset gives those images' own metrics, in the order asked.
    subset = [result.images[-1], result.images[0]]
    part = evaluate(avatar, tiny_dataset / "subject_000", images=subset)
    assert part.images == subset
    assert part.psnr == pytest.approx([result.psnr[-1], result.psnr[0]], abs=1e-5)
    with pytest.raises(PghmError, match="not in the subject's 'test' split"):
        evaluate(avatar, tiny_dataset / "subject_000", images=[10**6])


POSE_SHIFT = np.array([0.08, 0.05, 0.0], dtype=np.float32)
"""A known error of the stored root translation (metres): 2-3 pixels of the tiny subject's 64."""
REFINE_STEPS = 30


def shifted_subject(source, out, pose_noise: dict | None = None):
    """A copy of ``source`` whose stored root translations are off by POSE_SHIFT, stating
    ``pose_noise`` in its meta.json when given."""
    import shutil

    shutil.copytree(source, out)
    poses = dict(np.load(out / "poses.npz"))
    poses["translation"] = poses["translation"] + POSE_SHIFT
    np.savez(out / "poses.npz", **poses)
    if pose_noise is not None:
        meta = json.loads((out / "meta.json").read_text())
        (out / "meta.json").write_text(json.dumps({**meta, "pose_noise": pose_noise}))
    return out


def shift_left(corrections, data: TrainingData) -> float:
    """The largest remaining translation error (metres) of the data's frames after ``corrections``."""
    keys = torch.tensor([data.load(0, i).frame_key for i in data.images[0]])
    return float((torch.from_numpy(POSE_SHIFT) + corrections.translation[keys]).norm(dim=1).max())


def test_test_time_pose_refinement_moves_shifted_poses_back(tiny_dataset, prior_file, tmp_path):
    """The test frames' stored translations shifted by POSE_SHIFT: refining them against their images
    (avatar frozen) brings them closer to the poses the images were rendered with, and the
    evaluation's PSNR rises; the avatar's parameters are untouched."""
    from pghm.train.evaluate import evaluate
    from pghm.train.fit import POSE_LR, FitConfig
    from pghm.train.pose_refine import refine_poses

    avatar = tiny_avatar(tiny_dataset / "subject_000", prior_file, tmp_path / "a.pt", 4, 4)
    shifted = shifted_subject(tiny_dataset / "subject_000", tmp_path / "shifted")
    data = TrainingData(shifted, split="test")
    before = [p.detach().clone() for p in avatar.model.parameters()]
    corrections = refine_poses(avatar, data, REFINE_STEPS, FitConfig().stage2.loss, POSE_LR, progress=False)
    assert all(torch.equal(a, b) for a, b in zip(before, avatar.model.parameters()))
    assert shift_left(corrections, data) < 0.85 * float(np.linalg.norm(POSE_SHIFT))
    stored = evaluate(avatar, shifted).summary()["psnr"]
    refined = evaluate(avatar, shifted, refine_poses=REFINE_STEPS).summary()["psnr"]
    assert refined > stored + 0.5


def test_refinement_moves_poses_further_when_the_subject_states_them_noisier(tiny_dataset, prior_file, tmp_path):
    """The same shifted poses, stated with the shift's own scale (8 cm, as a capture states its
    error) rather than the synthetic 1 cm: the prior holds the corrections back less, and the
    refinement removes more of the shift."""
    from pghm.train.fit import POSE_LR, FitConfig
    from pghm.train.pose_refine import refine_poses

    avatar = tiny_avatar(tiny_dataset / "subject_000", prior_file, tmp_path / "a.pt", 4, 4)
    left = {}
    for name, noise in (("default", None), ("stated", {"rotation_std_deg": 2.0, "translation_std_m": 0.08})):
        data = TrainingData(shifted_subject(tiny_dataset / "subject_000", tmp_path / name, noise), split="test")
        refined = refine_poses(avatar, data, REFINE_STEPS, FitConfig().stage2.loss, POSE_LR, progress=False)
        left[name] = shift_left(refined, data)
    assert left["stated"] < 0.8 * left["default"], left


def test_a_capture_fit_settles_its_pose_track_towards_the_true_poses(tiny_dataset, prior_file, tmp_path):
    """A subject whose training poses are all off by POSE_SHIFT and that states capture-sized noise:
    the fit's settled track (each training frame refined against the fitted avatar) cancels more of
    the shift than stage 2's corrections alone, and leaves the avatar itself as it was."""
    from pghm.train.fit import TRACK_STEPS

    noise = {"rotation_std_deg": 9.5, "translation_std_m": 0.08}
    shifted = shifted_subject(tiny_dataset / "subject_000", tmp_path / "shifted", noise)
    data = TrainingData(shifted)
    stages = [LoopConfig(steps=n, checkpoint_every=0) for n in (4, 4)]
    avatars = {
        steps: fit(
            shifted,
            prior_file,
            tmp_path / f"{steps}.pt",
            FitConfig(*stages, lpips=False, track_steps=steps, early_track_steps=0, held_out_steps=0),
        )
        for steps in (0, None)
    }
    assert avatars[None].metadata["config"]["track_steps"] == TRACK_STEPS
    assert "track_seconds" not in avatars[0].metadata
    assert torch.equal(avatars[0].latent, avatars[None].latent)
    left = {}
    for steps, avatar in avatars.items():
        track = avatar.pose_track
        assert track.frames.tolist() == sorted({data.load(0, int(i)).frame_key for i in data.images[0]})
        left[steps] = float((torch.from_numpy(POSE_SHIFT) + track.translation).norm(dim=1).max())
    assert left[None] < 0.85 * left[0], left


def test_a_capture_fit_settles_its_poses_on_the_stage_1_avatar(tiny_dataset, prior_file, tmp_path):
    """Every stored pose off by POSE_SHIFT, capture-sized noise stated, no stage 2: the coarse
    settling between the stages alone cancels part of the shift, where none is settled without it."""
    from pghm.train.fit import EARLY_TRACK_STEPS

    noise = {"rotation_std_deg": 9.5, "translation_std_m": 0.08}
    shifted = shifted_subject(tiny_dataset / "subject_000", tmp_path / "shifted", noise)
    data = TrainingData(shifted)
    stages = [LoopConfig(steps=n, checkpoint_every=0) for n in (4, 0)]
    left = {}
    for steps in (0, None):
        config = FitConfig(*stages, lpips=False, early_track_steps=steps, track_steps=0, held_out_steps=0)
        avatar = fit(shifted, prior_file, tmp_path / f"{steps}.pt", config)
        left[steps] = float((torch.from_numpy(POSE_SHIFT) + avatar.pose_track.translation).norm(dim=1).max())
    assert avatar.metadata["config"]["early_track_steps"] == EARLY_TRACK_STEPS
    assert "early_track_seconds" in avatar.metadata
    assert left[0] == pytest.approx(float(np.linalg.norm(POSE_SHIFT)))
    assert left[None] < 0.85 * left[0], left


HELD_OUT_SPLITS = {"train": [0, 1, 4, 5], "test": [2, 3]}
"""The tiny subject's images are frames 0, 1, 2 seen by cameras 0 and 1: train on frames 0 and 2,
hold out frame 1."""


def test_a_capture_fit_aligns_its_held_out_frames_and_eval_says_so(tiny_dataset, prior_file, tmp_path):
    """Frame 1 held out, its stored pose alone off by POSE_SHIFT (an error of its own, as a
    capture's), capture-sized noise stated: the fit aligns frame 1 to its image after training,
    which cancels more of the shift than the training frames' corrections interpolated onto it;
    the avatar's weights are those of the fit without the alignment; the track lists frame 1 as
    aligned, through the file, and eval --fit-poses counts it."""
    from pghm.body import load_body
    from pghm.io.avatar import load_avatar
    from pghm.train.evaluate import evaluate
    from pghm.train.fit import HELD_OUT_STEPS
    from pghm.train.pose_track import track_corrections

    noise = {"rotation_std_deg": 9.5, "translation_std_m": 0.08}
    shifted = shifted_subject(tiny_dataset / "subject_000", tmp_path / "shifted", noise)
    (shifted / "splits.json").write_text(json.dumps(HELD_OUT_SPLITS))
    poses = dict(np.load(shifted / "poses.npz"))
    poses["translation"][HELD_OUT_SPLITS["train"]] -= POSE_SHIFT  # the training frames as rendered
    np.savez(shifted / "poses.npz", **poses)
    stages = [LoopConfig(steps=n, checkpoint_every=0) for n in (4, 4)]
    avatars = {
        steps: fit(shifted, prior_file, tmp_path / f"{steps}.pt", FitConfig(*stages, lpips=False, held_out_steps=steps))
        for steps in (0, None)
    }
    assert avatars[None].metadata["config"]["held_out_steps"] == HELD_OUT_STEPS
    assert avatars[None].metadata["held_out_frames"] == 1 and "held_out_seconds" not in avatars[0].metadata
    assert torch.equal(avatars[0].latent, avatars[None].latent)
    weights = [avatar.model.state_dict() for avatar in avatars.values()]
    assert all(torch.equal(weights[0][k], weights[1][k]) for k in weights[0])
    aligned = load_avatar(tmp_path / "None.pt").pose_track
    assert aligned.frames.tolist() == [0, 1, 2] and aligned.aligned.tolist() == [1]
    assert torch.equal(aligned.rotations[[0, 2]], avatars[0].pose_track.rotations)
    test = TrainingData(shifted, split="test")
    left = {}
    for steps, avatar in avatars.items():
        corrections, _ = track_corrections(avatar.pose_track, test, load_body("anny"))
        left[steps] = shift_left(corrections, test)
    assert left[None] < 0.85 * left[0], left
    evaluate(avatars[None], shifted, fit_poses=True, report=tmp_path / "r.json")
    poses = json.loads((tmp_path / "r.json").read_text())["poses"]
    assert "0 frames trained on, 1 held out and aligned to their images after the fit, 0 interpolated" in poses


def test_coarse_settling_steps_run_no_network_and_leave_the_avatar(tiny_dataset, prior_file, tmp_path):
    """Each batch's coarse steps evaluate the pose and view decoders once (the held maps), its fine
    steps once each; the avatar's parameters stay as they were."""
    from pghm.train.fit import POSE_LR, FitConfig
    from pghm.train.pose_refine import refine_poses

    avatar = tiny_avatar(tiny_dataset / "subject_000", prior_file, tmp_path / "a.pt", 2, 2)
    data = TrainingData(tiny_dataset / "subject_000", split="test")
    images = data.images[0][:2].tolist()
    before = [p.detach().clone() for p in avatar.model.parameters()]
    runs = {}
    for coarse in (0, 3):
        avatar.model.run_counts.clear()
        refine_poses(
            avatar, data, 5, FitConfig().stage2.loss, POSE_LR, images=images, progress=False, batch=2,
            coarse_steps=coarse, dynamic_only=True,
        )
        runs[coarse] = avatar.model.run_counts["pose_decoder"], avatar.model.run_counts["view_decoder"]
    assert runs == {0: (5, 5), 3: (1 + 2, 1 + 2)}
    assert all(torch.equal(a, b) for a, b in zip(before, avatar.model.parameters()))


@pytest.fixture(scope="module")
def monocular_settling(tiny_dataset, prior_file, tmp_path_factory):
    """A tiny avatar, its subject's data and one image of each frame (a monocular video)."""
    avatar = tiny_avatar(tiny_dataset / "subject_000", prior_file, tmp_path_factory.mktemp("settle") / "a.pt", 2, 2)
    data = TrainingData(tiny_dataset / "subject_000")
    frames = data.subjects[0].arrays.frame_index
    images = [int(i) for i in data.images[0]]
    one_view = [i for n, i in enumerate(images) if frames[i] not in frames[images[:n]]]
    assert len(one_view) >= 2  # a batch for each worker
    return avatar, data, one_view


def _settle(monocular_settling, workers: int, progress: bool = False):
    from pghm.train.fit import POSE_LR, FitConfig
    from pghm.train.pose_refine import refine_poses

    avatar, data, one_view = monocular_settling
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return refine_poses(
            avatar, data, 3, FitConfig().stage2.loss, POSE_LR, images=one_view, progress=progress, batch=1,
            coarse_steps=2, dynamic_only=True, workers=workers,
        )
    finally:
        torch.set_num_threads(threads)


def test_settling_in_two_workers_is_settling_in_one(monocular_settling):
    """Each frame's row depends on its own batch alone (lazy Adam rows, backgrounds drawn from the
    batch's position): two worker processes, each on one thread, give the rows one gives, bit for bit."""
    rows = [_settle(monocular_settling, workers) for workers in (1, 2)]
    assert torch.count_nonzero(rows[0].rotations) > 0
    assert torch.equal(rows[0].rotations, rows[1].rotations)
    assert torch.equal(rows[0].translation, rows[1].translation)


def test_a_settling_process_that_fails_fails_the_settling(monocular_settling, monkeypatch):
    """A forked child's error is raised in the parent, whose children are gone after it, and a child
    that dies without a word is reported, not waited for."""
    import multiprocessing
    import os

    from pghm.train import pose_refine

    batch = pose_refine._Settling._batch

    def failing(self, objective, optimizer, samples, position):
        if position == 1:  # the child's first batch (every second batch from the second)
            raise RuntimeError("a failure in batch 1")
        return batch(self, objective, optimizer, samples, position)

    monkeypatch.setattr(pose_refine._Settling, "_batch", failing)
    with pytest.raises(RuntimeError, match="a failure in batch 1"):
        _settle(monocular_settling, 2)
    assert not multiprocessing.active_children()

    def dying(self, objective, optimizer, samples, position):
        if position == 1:
            os._exit(3)
        return batch(self, objective, optimizer, samples, position)

    monkeypatch.setattr(pose_refine._Settling, "_batch", dying)
    with pytest.raises(PghmError, match="exit status 3"):
        _settle(monocular_settling, 2)
    assert not multiprocessing.active_children()


def test_a_profiled_settling_counts_its_childrens_cpu_and_steps(monocular_settling, capsys):
    """The profile's CPU seconds include the forked child's, charged to the parts it ran (the parts
    still sum to the total), and the progress bar counts every batch's steps."""
    from pghm.train import profile

    with profile.profiled() as timing, profile.phase("pose settling"):
        _settle(monocular_settling, 2, progress=True)
    wall, cpu = timing.totals()
    assert timing.children_cpu > 0
    assert math.fsum(timing.cpu.values()) == pytest.approx(cpu, rel=1e-12)
    assert math.fsum(timing.wall.values()) == pytest.approx(wall, rel=1e-12)
    phase = math.fsum(seconds for (name, _), seconds in timing.cpu.items() if name == "pose settling")
    assert phase > timing.children_cpu
    steps = 3 * len(monocular_settling[2])
    assert f"{steps}/{steps}" in capsys.readouterr().err


def test_learning_rate_ten_times_too_high_leaves_no_nan(tiny_dataset, tmp_path, caplog):
    config = prior_config(steps=8)
    config.network_lr = 10.0
    config.latent_lr = 100.0
    avatar = train_prior(tiny_dataset, tmp_path / "hot.pt", config)
    for name, value in avatar.model.state_dict().items():
        assert torch.isfinite(value).all(), name


def test_validation_images_are_the_middle_of_each_run_of_training_images():
    from pghm.train.detail import validation_images

    assert validation_images(list(range(10, 20)), 4) == [12, 16]
    assert validation_images([3, 5, 8], 1) == [3, 5, 8] and validation_images([3, 5, 8], 0) == []


def test_a_long_video_holds_at_most_the_most_validation_images_spread_over_it():
    from pghm.train.detail import MAX_VALIDATION_IMAGES, validation_images

    for count in (47, 48, 49, 88, 100, 1000):
        held = validation_images(list(range(count)), 4)
        gaps = np.diff(held)
        # k = ceil(n / 12) < n / 12 + 1 frames a run, so n / k > 12 n / (n + 12) >= 9.6 runs for n >= 48
        assert 9 <= len(held) <= MAX_VALIDATION_IMAGES
        assert (gaps == gaps[0]).all() and held[0] < gaps[0] and count - 1 - held[-1] < gaps[0]  # even, end to end
    assert validation_images(list(range(48)), 4) == list(range(2, 48, 4))  # up to 48 frames: every 4th, as before


def test_detail_squared_error_is_evals_mean_squared_error_summed(tiny_dataset, prior_file, tmp_path):
    from pghm.io.avatar import load_avatar
    from pghm.train.detail import squared_error
    from pghm.train.evaluate import evaluate

    subject = tiny_dataset / "subject_001"
    stages = [LoopConfig(steps=1, images_per_shard=2, checkpoint_every=0) for _ in range(2)]
    config = FitConfig(stage1=stages[0], stage2=stages[1], lpips=False)
    avatar = fit(subject, load_avatar(prior_file), tmp_path / "a.pt", config)
    data = TrainingData(subject, split="train")  # whole frames, stored poses: what eval renders
    images = [int(i) for i in data.images[0]]
    result = evaluate(avatar, subject, split="train", images=images)
    pixels = 3 * 64 * 64
    expected = sum(pixels * 10 ** (-p / 10) for p in result.psnr)
    assert squared_error(avatar, data, images, None) == pytest.approx(expected, rel=1e-4)  # eval sums in float32


@pytest.mark.parametrize("damage", [False, True])
def test_fit_keeps_a_detail_layer_only_when_it_draws_the_held_frames_closer(
    tiny_dataset, prior_file, tmp_path, monkeypatch, damage
):
    import pghm.train.detail as detail_module
    import pghm.train.fit as fit_module
    from pghm.io.avatar import load_avatar

    trained_on = []

    def run_stage(**stage):
        trained_on.extend(int(i) for i in stage["data"].images[0])
        state = real_run_stage(**stage)
        if damage:  # colour logits pushed far off: every held frame drawn worse
            stage["trainable"][0].data[:, 1:4] += 5.0
        return state

    real_run_stage = detail_module.run_stage
    monkeypatch.setattr(detail_module, "run_stage", run_stage)
    monkeypatch.setattr(fit_module, "MIN_VALIDATION_IMAGES", 1)
    stages = [LoopConfig(steps=n, images_per_shard=2, checkpoint_every=0) for n in (1, 1, 3)]
    config = FitConfig(stage1=stages[0], stage2=stages[1], detail=stages[2], detail_validation=2, lpips=False)
    subject = tiny_dataset / "subject_001"
    fit(subject, load_avatar(prior_file), tmp_path / "a.pt", config)
    avatar = load_avatar(tmp_path / "a.pt")
    record = avatar.metadata["detail"]
    train = [int(i) for i in TrainingData(subject).images[0]]
    assert sorted(trained_on) == train[0::2] and record["validation_images"] == len(train[1::2])
    assert record["kept"] == (record["error_with"] < record["error_without"])
    assert (avatar.model.detail is not None) == record["kept"] and avatar.metadata["steps"]["detail"] == 3
    assert [step for step, _ in record["errors"]] == [0, 3]  # validated before the first step and at the end
    if damage:
        assert not record["kept"] and record["error_with"] > 2 * record["error_without"]


def test_fit_trains_no_detail_layer_on_too_few_frames_to_validate_it(tiny_dataset, prior_file, tmp_path):
    from pghm.io.avatar import load_avatar
    from pghm.train.detail import MIN_VALIDATION_IMAGES, VALIDATION_EVERY

    stages = [LoopConfig(steps=1, images_per_shard=2, checkpoint_every=0) for _ in range(2)]
    fit(tiny_dataset / "subject_001", load_avatar(prior_file), tmp_path / "a.pt", FitConfig(*stages, lpips=False))
    avatar = load_avatar(tmp_path / "a.pt")
    assert len(TrainingData(tiny_dataset / "subject_001").images[0]) < MIN_VALIDATION_IMAGES * VALIDATION_EVERY
    assert avatar.model.detail is None and "detail" not in avatar.metadata["steps"]
    assert avatar.metadata["detail"]["kept"] is False and "too few" in avatar.metadata["detail"]["why"]


def test_a_fit_with_a_budget_spends_it_and_records_its_plan(tiny_dataset, prior_file, tmp_path):
    """``minutes``: the stages' steps scale to the time (from 3 + 6 given), every phase's record is
    in the metadata, and the whole fit ends near the budget: a 6 s budget on steps of tens of ms
    leaves the plan's last re-sizing a few steps off. The bounds (half to one and a half times) hold
    on a machine shared with the other test worker, whose load the measured costs absorb."""
    from pghm.io.avatar import load_avatar

    stages = [LoopConfig(steps=n, images_per_shard=2, checkpoint_every=0, progress=False) for n in (3, 6)]
    config = FitConfig(*stages, lpips=False, minutes=0.1, detail=replace(stages[1], steps=0))
    started = time.perf_counter()
    fit(tiny_dataset / "subject_001", load_avatar(prior_file), tmp_path / "a.pt", config)
    seconds = time.perf_counter() - started
    metadata = load_avatar(tmp_path / "a.pt").metadata
    assert metadata["budget_seconds"] == 6.0 and 3.0 <= seconds <= 9.0, seconds
    steps = metadata["steps"]
    # Both scaled up; stage 1 is sized before stage 2's own cost is measured, so their ratio drifts.
    assert steps["stage1"] > 3 and steps["stage2"] > 6
    from pghm.train.plan import PHASES

    assert list(metadata["plan"]) == list(PHASES)
    assert metadata["plan"]["stage 2"]["steps"] == steps["stage2"] and metadata["plan"]["detail"]["steps"] == 0


def test_refusals_come_before_the_work(tiny_dataset, prior_file, tmp_path, monkeypatch):
    """More identities than the data set holds, and a detail layer past the largest atlas, are one
    line each before any step runs (no silent clamp, no minutes of stages first)."""
    import pghm.train.fit as fit_module
    from pghm.errors import DatasetError, PghmError
    from pghm.uv.atlas import MAX_RESOLUTION

    def no_step(**_):
        raise AssertionError("a step ran before the refusal")

    monkeypatch.setattr(fit_module, "run_stage", no_step)
    with pytest.raises(DatasetError, match="asked for 3 identities, the data set holds 2"):
        TrainingData(tiny_dataset, max_identities=3)
    stages = [LoopConfig(steps=1, images_per_shard=2, checkpoint_every=0) for _ in range(2)]
    config = FitConfig(*stages, lpips=False, uv_resolution=MAX_RESOLUTION, detail_validation=0)
    with pytest.raises(PghmError, match=f"a detail layer needs 2L <= {MAX_RESOLUTION}"):
        fit(tiny_dataset / "subject_001", prior_file, tmp_path / "a.pt", config)
    assert not (tmp_path / "a.pt").exists()


def test_a_checkpoint_with_non_finite_values_is_refused_on_resume(tiny_dataset, prior_file, tmp_path, monkeypatch):
    """A run that diverged before its checkpoint was written must not continue as if it had not."""
    import pghm.train.loop as loop_module
    from pghm.errors import PghmError
    from pghm.io.avatar import load_avatar

    def interrupt(name: str) -> None:
        raise KeyboardInterrupt

    stages = [LoopConfig(steps=3, images_per_shard=2, checkpoint_every=0, progress=False) for _ in range(2)]
    config = FitConfig(*stages, lpips=False, detail=replace(stages[1], steps=0))
    out = tmp_path / "a.pt"
    monkeypatch.setattr(loop_module, "interrupt_point", interrupt)
    with pytest.raises(KeyboardInterrupt):
        fit(tiny_dataset / "subject_001", load_avatar(prior_file), out, config)
    monkeypatch.undo()
    checkpoint = out.with_name(out.name + ".ckpt")
    payload = torch.load(checkpoint, weights_only=True)
    payload["objective"]["latent"].fill_(math.nan)
    torch.save(payload, checkpoint)
    with pytest.raises(PghmError, match=r"checkpoint holds non-finite values \(latent"):
        fit(tiny_dataset / "subject_001", load_avatar(prior_file), out, config, resume=True)
    assert not out.exists()


@pytest.mark.parametrize("phase", ["early settling", "held-out poses", "detail"])
def test_a_fit_interrupted_after_a_stage_resumes_to_the_same_avatar(
    tiny_dataset, prior_file, tmp_path, monkeypatch, phase
):
    """Ctrl-C part-way through a phase after a stage leaves the checkpoint of that stage's end (the
    detail stage's own never replaces it), and --resume continues from there to the avatar an
    uninterrupted fit gives, bit for bit: weights, latent and pose track."""
    import pghm.train.detail as detail_module
    import pghm.train.fit as fit_module

    stages = [LoopConfig(steps=2, images_per_shard=2, checkpoint_every=0, progress=False) for _ in range(2)]
    config = FitConfig(
        *stages, lpips=False, early_track_steps=1, held_out_steps=1, detail_validation=0,
        detail=replace(stages[1], steps=2),
    )
    subject = tiny_dataset / "subject_000"
    fit(subject, prior_file, tmp_path / "straight.pt", config)

    def interrupted(real):
        def run(*args, **kwargs):
            real(*args, **kwargs)  # the phase's work done, and its state changed in memory
            raise KeyboardInterrupt

        return run

    module, name = {
        "early settling": (fit_module, "settle"),
        "held-out poses": (fit_module, "align_held_out"),
        "detail": (detail_module, "run_stage"),
    }[phase]
    out = tmp_path / "resumed.pt"
    with monkeypatch.context() as patch:
        patch.setattr(module, name, interrupted(getattr(module, name)))
        with pytest.raises(KeyboardInterrupt):
            fit(subject, prior_file, out, config)
    checkpoint = torch.load(out.with_name(out.name + ".ckpt"), weights_only=True)
    assert checkpoint["extra"] == {"stage": 1 if phase == "early settling" else 2} and not out.exists()
    fit(subject, prior_file, out, config, resume=True)
    straight, resumed = (torch.load(tmp_path / f, weights_only=True) for f in ("straight.pt", "resumed.pt"))
    assert straight["weights"].keys() == resumed["weights"].keys()
    assert all(torch.equal(straight["weights"][k], resumed["weights"][k]) for k in straight["weights"])
    assert torch.equal(straight["latent"], resumed["latent"])
    for key, value in straight["pose_track"].items():
        other = resumed["pose_track"][key]
        assert value == other if isinstance(value, str) else torch.equal(value, other)


def test_a_stages_coarse_steps_render_at_half_the_resolution_then_full(tiny_dataset, tmp_path, monkeypatch):
    """--coarse 0.5 of 4 steps: steps 0 and 1 see every image halved (and its camera with it), 2 and 3 whole."""
    from pghm.train import coarse
    from pghm.train.loop import AvatarObjective

    monkeypatch.setattr(coarse, "COARSE_MIN_SIDE", 8)  # the tiny subject's 64-pixel images halve
    seen = []
    forward = AvatarObjective.forward

    def recording(self, samples, *rest):
        seen.append({(s.image.shape[1:], (s.camera.height, s.camera.width)) for s in samples})
        return forward(self, samples, *rest)

    monkeypatch.setattr(AvatarObjective, "forward", recording)
    train_prior(tiny_dataset, tmp_path / "coarse.pt", prior_config(steps=4, coarse=0.5))
    full = TrainingData(tiny_dataset / "subject_000").load(0, 0).image.shape[1:]
    half = tuple(side // 2 for side in full)
    per_step = len(seen) // 4
    for step in range(4):
        (size, camera), *others = set().union(*seen[step * per_step : (step + 1) * per_step])
        assert not others and tuple(size) == tuple(camera) == (half if step < 2 else tuple(full)), step
