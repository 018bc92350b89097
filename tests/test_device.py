"""Device plumbing without a GPU: the resolver, ``--device cuda`` without CUDA, the torchrun device
and backend, and the meta device, which refuses to mix with CPU tensors, to catch a tensor made
on the CPU inside the model's forward pass or the pose corrections."""

from __future__ import annotations

import pytest
import torch
from conftest import TINY_MODEL

from pghm.body.pose import BodyPose
from pghm.cli.main import main
from pghm.device import move, resolve_device, resolve_precision
from pghm.errors import PghmError
from pghm.model import PGHM, ModelConfig, subject_geometry
from pghm.model.geometry import SubjectGeometry
from pghm.splat import Camera, render
from pghm.train import distributed
from pghm.train.data import PoseCorrections
from pghm.uv.atlas import build_atlas

CPU, META = torch.device("cpu"), torch.device("meta")


@pytest.fixture
def no_cuda(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 0)


@pytest.fixture
def two_gpus(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 2)


def test_resolver_without_cuda(no_cuda):
    assert resolve_device("cpu") == CPU
    assert resolve_device("auto") == CPU
    with pytest.raises(PghmError, match="CUDA is not available"):
        resolve_device("cuda")
    with pytest.raises(PghmError, match="--device must be one of"):
        resolve_device("tpu")


def test_resolver_with_cuda(two_gpus):
    assert resolve_device("auto") == torch.device("cuda")
    assert resolve_device("cuda:1") == torch.device("cuda", 1)
    assert resolve_device("cpu") == CPU
    with pytest.raises(PghmError, match="2 CUDA device"):
        resolve_device("cuda:2")


COMMANDS = {
    "fit": ["fit", "SUBJECT", "--prior", "scratch", "--out", "OUT.pt"],
    "train-prior": ["train-prior", "DATA", "--out", "OUT.pt"],
    "eval": ["eval", "assets/avatar.pt", "SUBJECT"],
    "render": ["render", "assets/avatar.pt", "--out", "OUT.png", "--backend", "cpu"],
    "export": ["export", "assets/avatar.pt", "--out", "OUT.ply"],
}


@pytest.mark.parametrize("command", COMMANDS)
def test_cuda_asked_without_cuda_is_one_line(command, no_cuda, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "assets").mkdir()
    (tmp_path / "assets" / "avatar.pt").write_bytes(b"")
    assert main([*COMMANDS[command], "--device", "cuda"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("pghm: error: --device cuda: CUDA is not available here")
    assert not any(tmp_path.glob("OUT*"))


def test_torchrun_device_and_backend(two_gpus, monkeypatch):
    monkeypatch.setenv("WORLD_SIZE", "2")
    monkeypatch.setenv("LOCAL_RANK", "1")
    assert distributed.process_device(torch.device("cuda")) == torch.device("cuda", 1)
    assert distributed.process_device(CPU) == CPU
    assert distributed.backend_for(torch.device("cuda", 1)) == "nccl"
    assert distributed.backend_for(CPU) == "gloo"
    monkeypatch.setenv("LOCAL_RANK", "2")
    with pytest.raises(PghmError, match="no GPU of its own"):
        distributed.process_device(torch.device("cuda"))
    monkeypatch.setenv("WORLD_SIZE", "1")
    assert distributed.process_device(torch.device("cuda")) == torch.device("cuda")


def test_move_keeps_what_is_already_there():
    camera = Camera(50.0, 50.0, 16.0, 12.0, 32, 24, torch.eye(4))
    assert move(camera, CPU) is camera
    assert move(None, META) is None
    assert move(torch.ones(2), META).device == META


@pytest.fixture(scope="module")
def geometry(body) -> SubjectGeometry:
    return subject_geometry(body, build_atlas(body, TINY_MODEL["uv_resolution"]))


def test_model_forward_stays_on_its_device(body, geometry):
    """The whole forward pass (skinning, U-Net, assembly, regulariser) and the pose corrections
    on the meta device: a tensor made on the CPU in between raises or shows in the outputs."""
    model = PGHM(ModelConfig(**TINY_MODEL), num_identities=2).to(META)
    on_meta = move(geometry, META)
    assert all(level.device == META for level in on_meta._levels)
    corrections = PoseCorrections.of_estimated_joints(3, body).to(META)
    rest = move(BodyPose.rest(body.num_bones, batch_size=2), META)
    frames = torch.tensor([0, 2], device=META)
    rotations, translation = corrections(frames, rest.rotations, rest.translation)
    prior = corrections.prior(frames)
    out = model(
        model.decode_identity(1), on_meta, BodyPose(rotations, translation), torch.zeros(2, 3, device=META)
    )
    tensors = [prior, out.regularizer] + [
        getattr(gaussians, name)
        for gaussians in (out.static, out.dynamic)
        for name in ("means", "scales", "colors", "opacities")
    ]
    assert all(tensor.device == META for tensor in tensors)


def test_render_refuses_devices_it_cannot_splat_on():
    means, scales = torch.zeros(1, 3, device=META), torch.ones(1, device=META)
    colors, opacities = torch.ones(1, 3, device=META), torch.ones(1, device=META)
    camera = Camera(50.0, 50.0, 16.0, 12.0, 32, 24, torch.eye(4))
    with pytest.raises(PghmError, match="cannot be splatted"):
        render(means, scales, colors, opacities, camera)
    with pytest.raises(PghmError, match="means on cpu; use one device"):
        render(torch.zeros(1, 3), scales, colors, opacities, camera)


def test_render_and_export_with_the_cpu_given(tmp_path):
    """Naming the CPU changes nothing: the same PNG and .ply bytes as the defaults."""
    from dataclasses import replace
    from pathlib import Path

    from pghm.io.export import export_posed
    from pghm.render import RenderJob, render_video

    avatar = Path(__file__).resolve().parent.parent / "assets" / "avatar.pt"
    job = RenderJob(avatar=avatar, out=tmp_path / "default.png", size=(48, 36), backend="cpu")
    render_video(job, log=lambda line: None)
    render_video(replace(job, out=tmp_path / "cpu.png", device="cpu"), log=lambda line: None)
    assert (tmp_path / "default.png").read_bytes() == (tmp_path / "cpu.png").read_bytes()
    export_posed(str(avatar), "rest", 0, str(tmp_path / "default.ply"))
    export_posed(str(avatar), "rest", 0, str(tmp_path / "cpu.ply"), device=CPU)
    assert (tmp_path / "default.ply").read_bytes() == (tmp_path / "cpu.ply").read_bytes()


def test_optimizer_state_follows_its_parameters():
    """A checkpoint's optimiser state (saved from any device, read on the CPU) lands on the device
    of the parameters it resumes: the moments by torch, the lazy rows' step counts by LazyAdam."""
    from pghm.train.optim import LazyAdam

    saved = torch.nn.Parameter(torch.ones(3, 2))
    optimizer = LazyAdam([{"params": [saved], "lr": 0.1, "lazy": True}])
    saved.grad = torch.tensor([[1.0, 0.0], [0.0, 0.0], [0.0, 2.0]])
    optimizer.step()
    resumed = LazyAdam([{"params": [torch.nn.Parameter(torch.ones(3, 2, device=META))], "lr": 0.1, "lazy": True}])
    resumed.load_state_dict(optimizer.state_dict())
    (state,) = resumed.state.values()
    assert {state[key].device for key in ("exp_avg", "exp_avg_sq", "step")} == {META}


@pytest.mark.parametrize("command", ["fit", "train-prior", "eval", "render"])
def test_cuda_without_gsplat_says_how_to_install(command, two_gpus, tmp_path, monkeypatch, capsys):
    import importlib

    real = importlib.import_module
    monkeypatch.setattr(importlib, "import_module", lambda name, *a: _no_gsplat(name) or real(name, *a))
    monkeypatch.chdir(tmp_path)
    (tmp_path / "assets").mkdir()
    (tmp_path / "assets" / "avatar.pt").write_bytes(b"")
    assert main([*COMMANDS[command], "--device", "cuda"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line == "pghm: error: rendering on CUDA needs gsplat, which is not installed: pip install 'pghm[gpu]'"


def _no_gsplat(name: str) -> None:
    if name == "gsplat":
        raise ImportError("No module named 'gsplat'")


def test_train_prior_with_the_cpu_given(tiny_dataset, tmp_path):
    """train_prior with ``device=torch.device("cpu")`` trains the same weights as without."""
    from pghm.train.loop import LoopConfig
    from pghm.train.prior import PriorConfig, train_prior

    loop = LoopConfig(steps=2, images_per_shard=1, checkpoint_every=0, progress=False)
    config = PriorConfig(model=ModelConfig(**TINY_MODEL), loop=loop, lpips=False)
    default = train_prior(tiny_dataset, tmp_path / "default.pt", config).model.state_dict()
    given = train_prior(tiny_dataset, tmp_path / "cpu.pt", config, device=CPU).model.state_dict()
    assert all(torch.equal(default[name], given[name]) for name in default)


@pytest.mark.parametrize("amx, avx512_bf16", [(True, False), (False, True), (True, True), (False, False)])
def test_auto_precision_is_bfloat16_only_on_a_cpu_that_multiplies_it(monkeypatch, amx, avx512_bf16):
    monkeypatch.setattr(torch.cpu, "_is_amx_tile_supported", lambda: amx, raising=False)
    monkeypatch.setattr(torch.cpu, "_is_avx512_bf16_supported", lambda: avx512_bf16, raising=False)
    assert resolve_precision("auto", CPU) == (torch.bfloat16 if amx or avx512_bf16 else torch.float32)
    assert resolve_precision("auto", torch.device("cuda")) == torch.float32  # not measured there
    assert resolve_precision("float32", CPU) == torch.float32
    assert resolve_precision("bfloat16", CPU) == torch.bfloat16
    with pytest.raises(PghmError, match="--precision must be one of auto, float32, bfloat16"):
        resolve_precision("half", CPU)
