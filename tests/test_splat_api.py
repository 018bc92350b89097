"""The splatter's public surface: cameras, validation, batching, backend choice, the bench CLI."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import time
import warnings

import pytest
import torch

from benchmarks.splat_measure import SWEEP, body_scene, pareto_front, run_sweep
from pghm.cli.main import main as pghm_main
from pghm.errors import PghmError
from pghm.splat import Camera, SplatSettings, _render, native, render


def tiny_gaussians(num_gaussians: int = 6, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(num_gaussians, 3, generator=g) * 0.3 + torch.tensor([0.0, 0.0, 3.0])
    scales = 0.05 + 0.05 * torch.rand(num_gaussians, generator=g)
    colors = torch.rand(num_gaussians, 3, generator=g)
    return means, scales, colors, 0.2 + 0.8 * torch.rand(num_gaussians, generator=g)


def test_look_at_orientation_and_centre():
    camera = Camera.look_at(
        eye=(0.0, 0.0, 3.0), target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov_y_degrees=60.0, width=64, height=48
    )
    torch.testing.assert_close(camera.centre, torch.tensor([0.0, 0.0, 3.0]), atol=1e-6, rtol=0)
    pose = camera.world_to_camera.double()
    # World up is image up (v decreases), world +x is image right seen from +z; the target is straight ahead.
    for point, check in (
        ((0.0, 0.5, 0.0), lambda u, v: v < camera.cy),
        ((0.5, 0.0, 0.0), lambda u, v: u > camera.cx),
        ((0.0, 0.0, 0.0), lambda u, v: abs(u - camera.cx) < 1e-6 and abs(v - camera.cy) < 1e-6),
    ):
        t = pose[:3, :3] @ torch.tensor(point, dtype=torch.float64) + pose[:3, 3]
        assert t[2] > 0
        assert check(camera.fx * t[0] / t[2] + camera.cx, camera.fy * t[1] / t[2] + camera.cy), point
    assert camera.fy == pytest.approx(24 / math.tan(math.radians(30)))


def test_from_matrices_round_trip_and_intrinsic_matrix():
    K = torch.tensor([[100.0, 0.0, 31.0], [0.0, 90.0, 22.0], [0.0, 0.0, 1.0]])
    pose = torch.eye(4)
    pose[:3, 3] = torch.tensor([0.1, -0.2, 0.3])
    camera = Camera.from_matrices(K, pose, width=64, height=48)
    torch.testing.assert_close(camera.K.float(), K)
    torch.testing.assert_close(camera.centre, torch.tensor([-0.1, 0.2, -0.3]))


def test_a_stack_of_cameras_is_the_batch_their_matrices_make():
    """Camera.stack (no check of values already checked) against from_matrices of the stacked K and
    world_to_camera: the same batch, value for value; a stack of cameras of two sizes is refused."""
    cameras = [
        Camera.look_at(eye=(0.3 * i, 0.2, 3.0), target=(0.0, 0.0, 0.0), fov_y_degrees=40 + 5 * i, width=64, height=48)
        for i in range(3)
    ]
    stacked = Camera.stack(cameras)
    made = Camera.from_matrices(
        torch.stack([c.K for c in cameras]).float(), torch.stack([c.world_to_camera for c in cameras]).float(), 64, 48
    )
    assert stacked.batch_size == 3 and (stacked.width, stacked.height) == (64, 48)
    assert torch.equal(stacked.intrinsics(), made.intrinsics())
    assert torch.equal(stacked.world_to_camera, made.world_to_camera)
    gaussians = tiny_gaussians()
    assert torch.equal(render(*gaussians, stacked).rgb, render(*gaussians, made).rgb)
    other = Camera.look_at(eye=(0.0, 0.0, 3.0), target=(0.0, 0.0, 0.0), width=32, height=48)
    with pytest.raises(PghmError, match="one image size"):
        Camera.stack([cameras[0], other])


@pytest.mark.parametrize(
    "arguments, message",
    [
        ((100.0, 100.0, 32.0, 24.0, 0, 48, torch.eye(4)), "width"),
        ((100.0, 100.0, 32.0, 24.0, 64, -1, torch.eye(4)), "height"),
        ((-1.0, 100.0, 32.0, 24.0, 64, 48, torch.eye(4)), "fx"),
        ((100.0, float("nan"), 32.0, 24.0, 64, 48, torch.eye(4)), "fy"),
        ((100.0, 100.0, float("inf"), 24.0, 64, 48, torch.eye(4)), "cx"),
        ((100.0, 100.0, 32.0, 24.0, 64, 48, torch.eye(3)), "world_to_camera"),
        ((100.0, 100.0, 32.0, 24.0, 64, 48, torch.full((4, 4), float("nan"))), "world_to_camera"),
        ((100.0, 100.0, 32.0, 24.0, 64, 48, torch.ones(4, 4)), "bottom row"),
        ((torch.ones(2) * 100, 100.0, 32.0, 24.0, 64, 48, torch.eye(4).repeat(3, 1, 1)), "batch sizes"),
    ],
)
def test_camera_rejects_bad_input(arguments, message):
    with pytest.raises(PghmError, match=message):
        Camera(*arguments)


@pytest.mark.parametrize("argument", ["means", "scales", "colors", "opacities"])
def test_render_names_the_argument_with_a_bad_shape(argument):
    gaussians = dict(zip(("means", "scales", "colors", "opacities"), tiny_gaussians()))
    gaussians[argument] = gaussians[argument][:-1]
    camera = Camera(50.0, 50.0, 16.0, 16.0, 32, 32, torch.eye(4))
    with pytest.raises(PghmError, match=argument):
        render(**gaussians, camera=camera)


def test_render_rejects_other_bad_input():
    means, scales, colors, opacities = tiny_gaussians()
    camera = Camera(50.0, 50.0, 16.0, 16.0, 32, 32, torch.eye(4))
    with pytest.raises(PghmError, match="colors"):
        render(means, scales, colors.double(), opacities, camera)
    with pytest.raises(PghmError, match="background"):
        render(means, scales, colors, opacities, camera, background=(1.0, 1.0))
    with pytest.raises(PghmError, match="backend"):
        render(means, scales, colors, opacities, camera, backend="cuda")
    with pytest.raises(PghmError, match="alpha_cutoff"):
        SplatSettings(alpha_cutoff=1.0)


def test_background_as_tensor_and_empty_scene():
    means, scales, colors, opacities = tiny_gaussians()
    camera = Camera(50.0, 50.0, 16.0, 16.0, 32, 32, torch.eye(4))
    background = torch.tensor([0.1, 0.2, 0.3])
    out = render(means[:0], scales[:0], colors[:0], opacities[:0], camera, background=background)
    assert out.rgb.shape == (32, 32, 3)
    assert torch.equal(out.rgb, background.expand(32, 32, 3))
    assert torch.equal(out.alpha, torch.zeros(32, 32))
    assert torch.equal(
        render(means, scales, colors, opacities, camera, background=background).rgb,
        render(means, scales, colors, opacities, camera, background=(0.1, 0.2, 0.3)).rgb,
    )


@pytest.mark.parametrize("backend", ["native", "torch"])
def test_batched_cameras_and_gaussians_equal_single_renders(backend):
    means, scales, colors, opacities = tiny_gaussians(20)
    poses = torch.eye(4).repeat(3, 1, 1)
    poses[:, 0, 3] = torch.tensor([-0.2, 0.0, 0.3])
    fx = torch.tensor([40.0, 50.0, 60.0])
    cameras = Camera(fx, fx, 20.0, 15.0, 40, 30, poses)
    batched = render(means, scales, colors, opacities, cameras, backend=backend)
    assert batched.rgb.shape == (3, 30, 40, 3)
    for b in range(3):
        camera = Camera(float(fx[b]), float(fx[b]), 20.0, 15.0, 40, 30, poses[b])
        single = render(means, scales, colors, opacities, camera, backend=backend)
        for got, want in zip(
            (batched.rgb[b], batched.alpha[b], batched.depth[b]), (single.rgb, single.alpha, single.depth)
        ):
            # The native kernel composites each tile alone: bit-identical. The twin's float64
            # cumulative sum runs across the whole batch, which moves T by ~1e-16 before rounding.
            torch.testing.assert_close(got, want, rtol=0, atol=0 if backend == "native" else 1e-6)
    stacked = [x.expand(3, *x.shape) for x in (means, scales, colors, opacities)]
    assert torch.equal(render(*stacked, cameras, backend=backend).rgb, batched.rgb)


def test_auto_falls_back_to_torch_with_one_warning(monkeypatch):
    monkeypatch.setattr(native, "_build", lambda: RuntimeError("no compiler here"))
    monkeypatch.setattr(_render, "_warned", False)
    means, scales, colors, opacities = tiny_gaussians()
    camera = Camera(50.0, 50.0, 16.0, 16.0, 32, 32, torch.eye(4))
    with pytest.warns(RuntimeWarning, match="no compiler here"):
        fallback = render(means, scales, colors, opacities, camera)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        render(means, scales, colors, opacities, camera)
    assert torch.equal(fallback.rgb, render(means, scales, colors, opacities, camera, backend="torch").rgb)
    with pytest.raises(PghmError, match="no compiler here"):
        render(means, scales, colors, opacities, camera, backend="native")


def test_auto_uses_the_native_kernel():
    assert native.is_available(), native._build()
    assert native.build_directory().is_dir()


def test_each_torch_installation_builds_in_its_own_directory(monkeypatch):
    here = native.build_directory()
    monkeypatch.setattr(torch, "__file__", "/another/venv/site-packages/torch/__init__.py")
    assert native.build_directory() != here
    assert native.build_directory().parent == here.parent


def test_each_checkout_builds_in_its_own_directory(monkeypatch, tmp_path):
    """Two checkouts of one source in one environment: torch's build file names the source's path."""
    here = native.build_directory()
    copy = tmp_path / native.SOURCE.name
    copy.write_bytes(native.SOURCE.read_bytes())
    monkeypatch.setattr(native, "SOURCE", copy)
    assert native.build_directory() != here


# A builder in another process: takes the lock, makes torch's baton, reports, then holds it.
_BUILDER = """
import os, sys, time
from pathlib import Path
from pghm.splat.native import TORCH_BATON, build_lock
directory = Path(sys.argv[1])
with build_lock(directory):
    (directory / TORCH_BATON).touch()
    (directory / "ready").touch()
    time.sleep(float(sys.argv[2]))
    os.remove(directory / TORCH_BATON)
    (directory / "done").touch()
"""


def _start_builder(directory, seconds: float) -> subprocess.Popen:
    builder = subprocess.Popen([sys.executable, "-c", _BUILDER, str(directory), str(seconds)])
    deadline = time.monotonic() + 60
    while not (directory / "ready").exists():
        assert builder.poll() is None and time.monotonic() < deadline, "the builder did not start"
        time.sleep(0.02)
    return builder


def test_a_dead_builders_baton_is_cleared(tmp_path):
    """torch waits forever on the baton a killed builder leaves; the OS lock dies with the builder."""
    builder = _start_builder(tmp_path, 600)
    builder.kill()
    builder.wait()
    assert (tmp_path / native.TORCH_BATON).exists() and not (tmp_path / "done").exists()
    with native.build_lock(tmp_path):
        assert not (tmp_path / native.TORCH_BATON).exists()


def test_a_living_builders_baton_is_waited_for(tmp_path):
    builder = _start_builder(tmp_path, 1.0)
    with native.build_lock(tmp_path):
        assert (tmp_path / "done").exists()  # entered only after the builder finished
    assert builder.wait(timeout=60) == 0


def test_sparse_memory_many_small_gaussians():
    """200k sub-pixel Gaussians at 256 x 256: a dense N x H x W float32 tensor would be 52 GB."""
    g = torch.Generator().manual_seed(0)
    num_gaussians = 200_000
    means = torch.cat([torch.rand(num_gaussians, 2, generator=g) * 4 - 2, torch.full((num_gaussians, 1), 2.0)], dim=1)
    camera = Camera(128.0, 128.0, 128.0, 128.0, 256, 256, torch.eye(4))
    colors = torch.rand(num_gaussians, 3, generator=g)
    scales, opacities = torch.full((num_gaussians,), 0.003), torch.full((num_gaussians,), 0.5)
    images = [render(means, scales, colors, opacities, camera, backend=backend) for backend in ("native", "torch")]
    assert images[0].alpha.min() > 0.2 and images[0].alpha.mean() > 0.9  # every pixel is covered
    torch.testing.assert_close(images[0].rgb, images[1].rgb, rtol=0, atol=2e-6)  # as in test_splat.py


def test_pareto_front():
    rows = [
        {"setting": "exact", "forward_backward_ms": 10.0, "max_abs": 0.0},
        {"setting": "fast", "forward_backward_ms": 5.0, "max_abs": 0.1},
        {"setting": "worse", "forward_backward_ms": 6.0, "max_abs": 0.2},
    ]
    assert pareto_front(rows) == ["exact", "fast"]
    assert "exact" in SWEEP and SWEEP["exact"].is_exact


def test_sweep_runs_small(tmp_path):
    scene = body_scene(300, 32)
    assert scene.means.shape == (300, 3)
    rows, front = run_sweep(300, 32, repeats=1, output=tmp_path / "sweep.json", plot=tmp_path / "sweep.png")
    by_name = {row["setting"]: row for row in rows}
    assert by_name["exact"]["max_abs"] == 0.0 and "exact" in front
    assert json.loads((tmp_path / "sweep.json").read_text())["pareto_front"] == front
    assert (tmp_path / "sweep.png").stat().st_size > 0


def test_bench_cli_rejects_unknown_name(capsys):
    assert pghm_main(["bench", "nonsense"]) == 2
    assert "unknown benchmark" in capsys.readouterr().err


def test_bench_cli_outside_a_source_checkout_says_so_in_one_line(tmp_path, monkeypatch, capsys):
    """An installed wheel has no benchmarks/: pghm bench names what is missing, exit status 2."""
    from pghm.cli import bench

    monkeypatch.setattr(bench, "LAB", tmp_path / "benchmarks")
    assert pghm_main(["bench", "splat", "--out", str(tmp_path / "out")]) == 2
    error = capsys.readouterr().err.strip()
    assert "source checkout" in error and "splat_measure.py" in error and len(error.splitlines()) == 1
