"""Every command's CUDA path run on a stand-in device (tests/standin_device.py), which refuses a CPU
tensor where CUDA's kernels would: train-prior, fit (both stages with pose corrections, the pose
settling, the detail stage, a checkpoint and its resumption), eval (with the fit's pose track and
with test-time pose refinement), render and export.

The stand-in keeps its values on the CPU, computes with the CPU's kernels and renders through the
CPU splatter, so each command on it must give exactly what it gives on the CPU: the same priors
and avatars bit for bit, the same metrics, images and .ply bytes. A device path that computed
something else (a value lost or changed on its way to the device) would show there too."""

from __future__ import annotations

import json
from dataclasses import fields
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch
import torch.nn.functional as F
from conftest import TINY_MODEL
from standin_device import MixedDevices, standin_cuda

from pghm.body.pose import BodyPose
from pghm.cli.main import main
from pghm.io.avatar import load_avatar
from pghm.model import ModelConfig
from pghm.train import evaluate as evaluate_module
from pghm.train import fit as fit_module
from pghm.train import loop as loop_module
from pghm.train import run_setup
from pghm.train.frames import on_background
from pghm.train.fit import FitConfig, fit
from pghm.train.data import TrainingData
from pghm.train.loop import LoopConfig
from pghm.train.losses import TargetSsim, image_losses, psnr, silhouette
from pghm.train.lpips import LPIPS
from pghm.train.person_crop import Crop, area_tensor
from pghm.train.prior import PriorConfig, train_prior

CUDA = torch.device("cuda", 0)
SUBJECT = "subject_000"
BACKGROUND = (0.2, 0.3, 0.4)


def random_lpips() -> LPIPS:
    """An LPIPS network with seeded random weights (the real ones are not on every machine): its
    buffers and layers on the device are what is checked."""
    torch.manual_seed(0)
    return LPIPS()


@pytest.fixture(scope="module")
def patches():
    """LPIPS always present, and torch told a CUDA device exists (for ``--device cuda``)."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(run_setup, "load_lpips", random_lpips)
        patch.setattr(evaluate_module, "load_lpips", random_lpips)
        patch.setattr(torch.cuda, "is_available", lambda: True)
        patch.setattr(torch.cuda, "device_count", lambda: 1)
        yield patch


def steps(count: int, **options) -> LoopConfig:
    return LoopConfig(steps=count, images_per_shard=2, checkpoint_every=0, progress=False, **options)


def same_tensors(path_a: Path, path_b: Path) -> bool:
    """Whether two avatar or prior files hold the same tensors, bit for bit (weights, latent,
    shapes, pose track)."""

    def tensors(avatar) -> dict[str, torch.Tensor]:
        found = {f"model.{name}": value for name, value in avatar.model.state_dict().items()}
        found.update({name: getattr(avatar, name) for name in ("shape", "shapes", "latent")})
        if avatar.pose_track is not None:
            found.update({f"track.{f.name}": getattr(avatar.pose_track, f.name) for f in fields(avatar.pose_track)})
        return {name: value for name, value in found.items() if isinstance(value, torch.Tensor)}

    a, b = tensors(load_avatar(path_a)), tensors(load_avatar(path_b))
    return a.keys() == b.keys() and all(torch.equal(a[name], b[name]) for name in a)


@pytest.fixture(scope="module")
def prior_files(tiny_dataset, tmp_path_factory, patches) -> dict[str, Path]:
    """A prior trained on the CPU and on the stand-in: bank, network and pose corrections,
    gradient backgrounds, LPIPS."""
    folder = tmp_path_factory.mktemp("priors")
    config = PriorConfig(model=ModelConfig(**TINY_MODEL), loop=steps(2, background="gradient"))
    train_prior(tiny_dataset, folder / "cpu.pt", config, device="cpu")
    with standin_cuda():
        train_prior(tiny_dataset, folder / "cuda.pt", config, device="cuda")
    return {device: folder / f"{device}.pt" for device in ("cpu", "cuda")}


@pytest.fixture(scope="module")
def avatar_files(tiny_dataset, prior_files, tmp_path_factory, patches) -> dict[str, Path]:
    """``pghm fit --device cpu`` and ``--device cuda`` with every stage: 1 step each of stage 1, the
    settling between the stages, stage 2 (pose corrections), the pose settling, the held-out
    frame's alignment and the detail stage, a checkpoint after every step, profiled."""
    folder = tmp_path_factory.mktemp("avatars")
    stages = ["--stage1-steps", "1", "--stage2-steps", "1", "--track-steps", "1", "--detail-steps", "1"]
    stages += ["--detail-validation", "0", "--early-track-steps", "1", "--held-out-steps", "1"]
    # One precision for both: "auto" is bfloat16 on a CPU that multiplies it natively, float32 on CUDA.
    options = [*stages, "--checkpoint-every", "1", "--precision", "float32"]
    for device in ("cpu", "cuda"):
        out = folder / f"{device}.pt"
        args = ["fit", str(tiny_dataset / SUBJECT), "--prior", str(prior_files[device]), "--out", str(out)]
        with standin_cuda():
            assert main([*args, *options, "--profile", str(out.with_suffix(".json")), "--device", device]) == 0
    return {device: folder / f"{device}.pt" for device in ("cpu", "cuda")}


def test_the_standin_refuses_what_cuda_refuses_and_takes_what_it_takes():
    with standin_cuda():
        x = torch.ones(2, 3, device="cuda")
        assert x.device == CUDA and x.is_cuda and torch.zeros(1, device=x.device).device == CUDA
        for mixed in (
            lambda: x + torch.ones(3),
            lambda: torch.stack([x, torch.ones(2, 3)]),
            lambda: F.conv2d(x[None, None], torch.ones(1, 1, 1, 1)),
            lambda: x.index_select(1, torch.tensor([0])),
            lambda: torch.tensor(1.0).add_(x[0, 0]),
        ):
            with pytest.raises(MixedDevices):
                mixed()
        with pytest.raises(TypeError, match="numpy"):
            x.numpy()
        # What CUDA takes: a CPU scalar tensor in arithmetic, CPU indices, a copy from the CPU.
        assert (x * torch.tensor(2.0)).device == CUDA
        assert x[torch.tensor([1])].device == CUDA
        x[0] = torch.arange(3.0)
        leaf = torch.ones(3, requires_grad=True)
        (leaf.cuda() * x[0]).cpu().sum().backward()
    assert type(x.cpu()) is torch.Tensor and x.cpu().tolist() == [[0.0, 1.0, 2.0], [1.0, 1.0, 1.0]]
    assert leaf.grad.tolist() == [0.0, 1.0, 2.0]


def test_losses_on_the_device_are_the_cpus():
    """SSIM's taps, the crops' area shares, silhouette and PSNR on the images' device: the same
    numbers as on the CPU (the stand-in computes with the CPU's kernels)."""
    gen = torch.Generator().manual_seed(0)
    render, target, alpha, mask = (torch.rand(2, c, 24, 20, generator=gen) for c in (3, 3, 1, 1))
    crops = [Crop(2, 3, 20, 24, 40, 30), None]

    def losses(device):
        area = area_tensor(crops).to(device)  # as the loop moves it
        moved = [t.to(device) for t in (render, target, alpha, mask)]
        terms = image_losses(moved[0], moved[1], area=area, target_ssim=TargetSsim(moved[1]))
        terms["sil"] = silhouette(moved[2], moved[3], area[:, 0])
        terms["psnr"] = psnr(moved[0], moved[1], area[:, 0])
        return {key: value.cpu() for key, value in terms.items()}

    on_cpu = losses("cpu")
    with standin_cuda():
        on_device = losses("cuda")
    assert on_device.keys() == on_cpu.keys()
    assert all(torch.equal(on_device[key], on_cpu[key]) for key in on_cpu)


def test_poses_and_eval_compositing_stay_on_the_device():
    with standin_cuda():
        pose = BodyPose.from_arrays(torch.zeros(2, 4, 3, device="cuda"), None, 4)
        rgb, alpha = torch.rand(3, 5, 4).cuda(), torch.rand(5, 4).cuda()
        sample = SimpleNamespace(image=torch.rand(3, 5, 4).cuda(), mask=alpha[None].round())
        target, image = on_background(sample, rgb, alpha, BACKGROUND)
    assert pose.translation.device == CUDA and target.device == CUDA and image.device == CUDA


def test_train_prior_on_the_device_is_the_cpus(prior_files):
    assert load_avatar(prior_files["cuda"]).device == torch.device("cpu")
    assert same_tensors(prior_files["cuda"], prior_files["cpu"])


def test_fit_on_the_device_is_the_cpus(avatar_files):
    avatar = load_avatar(avatar_files["cuda"])
    assert avatar.device == torch.device("cpu") and avatar.pose_track is not None
    assert avatar.metadata["steps"] == {"stage1": 1, "stage2": 1, "detail": 1}
    assert not avatar_files["cuda"].with_name("cuda.pt.ckpt").exists()
    phases = json.loads(avatar_files["cuda"].with_suffix(".json").read_text())["phases"]
    assert {"early settling", "pose settling", "held-out poses"} <= set(phases)
    assert avatar.pose_track.aligned.tolist() == [2]  # the tiny subject's test frame
    assert same_tensors(avatar_files["cuda"], avatar_files["cpu"])


def test_a_fit_step_waits_for_the_device_at_most_twice(tiny_dataset, prior_files, tmp_path, monkeypatch):
    """Once its images are on the device, a stage-2 step (pose corrections, crops' areas, random
    backgrounds, LPIPS) makes the host wait for the device twice: the guard's one read of whether
    the loss and every gradient are finite, and the read of the step's terms with the update's
    finiteness. A read per parameter, per term or per copy of a sample would show here."""
    from standin_device import counting_syncs

    from pghm.train.data import TrainingData

    marks, loaded = [], []
    load_group = TrainingData.load_group

    def logged_group(self, identity, images):
        loaded.append((identity, tuple(images)))
        return load_group(self, identity, images)

    monkeypatch.setattr(TrainingData, "load_group", logged_group)
    config = FitConfig(
        stage1=steps(1),
        stage2=steps(12),
        early_track_steps=0,
        track_steps=0,
        held_out_steps=0,
        detail=LoopConfig(steps=0),
    )
    with standin_cuda(), counting_syncs() as syncs:
        monkeypatch.setattr(loop_module, "interrupt_point", lambda name: marks.append((len(syncs), len(loaded))))
        fit(tiny_dataset / SUBJECT, prior_files["cuda"], tmp_path / "a.pt", config, device="cuda")
    seen, counted = set(), 0
    for (before, first), (after, last) in zip(marks, marks[1:]):
        images = {(identity, image) for identity, group in loaded[first:last] for image in group}
        if images <= seen:  # every image of the step already on the device
            assert after - before <= 2, syncs[before:after]
            counted += 1
        seen |= images
    assert counted >= 3


def test_fit_resumed_on_the_device_is_the_cpus_uninterrupted(tiny_dataset, prior_files, tmp_path, monkeypatch):
    """A fit interrupted in stage 2 (its checkpoint written from the device) resumes on the device
    where it stopped: the CPU's uninterrupted fit. At a finer UV resolution, the pose track
    settled with the held appearance."""
    config = FitConfig(
        stage1=steps(1),
        stage2=LoopConfig(steps=2, images_per_shard=2, checkpoint_every=1, progress=False),
        track_steps=1,
        hold_appearance=True,
        uv_resolution=2 * TINY_MODEL["uv_resolution"],
        lpips=False,
        precision="float32",  # as the device's "auto"
    )
    fit(tiny_dataset / SUBJECT, prior_files["cpu"], tmp_path / "cpu.pt", config)
    calls = []

    def interrupt_second_step(name: str) -> None:
        calls.append(name)
        if len(calls) == 2:
            raise KeyboardInterrupt

    monkeypatch.setattr(loop_module, "interrupt_point", interrupt_second_step)
    out = tmp_path / "cuda.pt"
    with standin_cuda():
        with pytest.raises(KeyboardInterrupt):
            fit(tiny_dataset / SUBJECT, prior_files["cuda"], out, config, device="cuda")
        assert fit_module.load_checkpoint(out.with_name(out.name + ".ckpt"))["extra"] == {"stage": 2}
        fit(tiny_dataset / SUBJECT, prior_files["cuda"], out, config, resume=True, device="cuda")
    assert load_avatar(out).metadata["steps"] == {"stage1": 1, "stage2": 2}
    assert same_tensors(out, tmp_path / "cpu.pt")


@pytest.mark.parametrize("poses", [[], ["--fit-poses"], ["--refine-poses", "2"], ["--true-poses"]])
def test_eval_on_the_device_is_the_cpus(poses, tiny_dataset, avatar_files, tmp_path, patches):
    reports = {}
    for device in ("cpu", "cuda"):
        report = tmp_path / f"{device}.json"
        args = ["eval", str(avatar_files["cuda"]), str(tiny_dataset / SUBJECT), *poses, "--report", str(report)]
        with standin_cuda():
            assert main([*args, "--background", ",".join(map(str, BACKGROUND)), "--device", device]) == 0
        reports[device] = json.loads(report.read_text())
    assert "lpips" in reports["cpu"]["per_image"][0]
    assert reports["cuda"]["per_image"] == reports["cpu"]["per_image"]


def test_render_and_export_on_the_device_are_the_cpus(tiny_dataset, avatar_files, tmp_path, patches):
    """The avatar replaying its video (its pose track) rendered, and a posed export, byte for byte."""
    motion = ["--motion", str(tiny_dataset / SUBJECT)]
    render = ["render", str(avatar_files["cuda"]), *motion, "--size", "48x36", "--backend", "cpu"]
    export = ["export", str(avatar_files["cuda"]), "--pose", "walk", "--frame", "3"]
    for device in ("cpu", "cuda"):
        with standin_cuda():
            assert main([*render, "--out", str(tmp_path / f"{device}.png"), "--device", device]) == 0
            assert main([*export, "--out", str(tmp_path / f"{device}.ply"), "--device", device]) == 0
    assert (tmp_path / "cuda.png").read_bytes() == (tmp_path / "cpu.png").read_bytes()
    assert (tmp_path / "cuda.ply").read_bytes() == (tmp_path / "cpu.ply").read_bytes()


def test_a_coarse_image_on_the_device_is_its_own_sample(tiny_dataset):
    """The device keeps each sample once, so a coarse step's image (half the size) and the same image
    at full resolution must be two entries: either one in the other's place renders the wrong size."""
    from pghm.train.coarse import coarse_sample
    from pghm.train.resident import Resident

    full = TrainingData(tiny_dataset / SUBJECT).load(0, 0)
    coarse = coarse_sample(full)
    with standin_cuda():
        resident = Resident(CUDA)
        for sample in (coarse, full, coarse):
            kept = resident.sample(sample)
            assert kept.image.shape == sample.image.shape and kept.camera.width == sample.camera.width
