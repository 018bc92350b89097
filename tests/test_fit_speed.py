"""What makes ``pghm fit`` cheaper must not change what it computes: the profile accounts for every
moment once, a crop renders and scores exactly as its frame, the thread policy counts the cores it may use,
and the pose settling's held appearance is the network's at the starting pose."""

from __future__ import annotations

import math
import os
import shutil
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from pghm.splat import Camera, render
from pghm.train import profile
from pghm.train.data import TrainingData
from pghm.train.losses import objective, psnr, silhouette
from pghm.train.person_crop import Crop, area_tensor, crop_size, mask_box, place


def _sleep_backward(seconds: float):
    """An identity whose backward pass sleeps ``seconds``: a stand-in of known cost."""

    class Sleep(torch.autograd.Function):
        @staticmethod
        def forward(ctx, x):
            return x.clone()

        @staticmethod
        def backward(ctx, grad):
            time.sleep(seconds)
            return grad

    return Sleep.apply


def test_the_profile_charges_every_moment_to_one_part():
    started = time.perf_counter()
    with profile.profiled() as timing:
        with profile.phase("stage 1"):
            with profile.part(profile.DATA):
                time.sleep(0.02)
            with profile.part(profile.LOSSES):
                time.sleep(0.01)
                with profile.part(profile.GUARD):  # nested: its time is the guard's, not the losses'
                    time.sleep(0.02)
            x = torch.ones(3, requires_grad=True)
            gaussians = _sleep_backward(0.02)(x * 2)  # the "network" behind the Gaussians
            image = _sleep_backward(0.03)(gaussians * 3)  # the "splatter"
            profile.mark_backward([image], [gaussians])
            with profile.part(profile.LOSSES_BACKWARD):
                image.sum().backward()
        time.sleep(0.01)
    elapsed = time.perf_counter() - started
    wall, cpu = timing.totals()
    # Exclusive accounting: the parts sum to the total (float summation only), which the
    # independent clock around the block bounds.
    assert math.fsum(timing.wall.values()) == pytest.approx(wall, rel=1e-12)
    assert math.fsum(timing.cpu.values()) == pytest.approx(cpu, rel=1e-12)
    assert 0.1 <= wall <= elapsed
    # Sleeps are lower bounds of the parts they ran in.
    assert timing.wall["stage 1", profile.DATA] >= 0.02
    assert timing.wall["stage 1", profile.GUARD] >= 0.02
    assert timing.wall["stage 1", profile.LOSSES] >= 0.01
    assert timing.wall["stage 1", profile.SPLAT_BACKWARD] >= 0.03
    assert timing.wall["stage 1", profile.NETWORK_BACKWARD] >= 0.02
    assert timing.wall["setup", profile.OTHER] >= 0.01
    record = timing.record()
    summed = sum(v["wall_s"] for parts in record["phases"].values() for v in parts.values())
    assert summed == pytest.approx(record["wall_s"], abs=1e-3 * len(profile.PARTS) * 2)
    assert timing.table().splitlines()[-1].split()[0] == "total"


def test_without_a_profile_the_marks_do_nothing():
    with profile.part(profile.DATA), profile.phase("stage 1"):
        x = torch.ones(2, requires_grad=True)
        y = x * 2
        profile.mark_backward([y], [x])
        assert not y._backward_hooks


_POLICY_PROBE = (
    "import os; os.environ.pop('OMP_NUM_THREADS', None); import torch; "
    "from pghm.cli.threads import set_threads; print(set_threads(), torch.get_num_threads())"
)
"""A child that applies the policy with no OMP_NUM_THREADS set and prints the count it chose and torch's."""


def _policy_threads(prefix: list[str] = ()) -> tuple[int, int]:
    env = {k: v for k, v in os.environ.items() if k != "OMP_NUM_THREADS"}
    result = subprocess.run([*prefix, sys.executable, "-c", _POLICY_PROBE], env=env, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr[-2000:]
    chosen, in_use = map(int, result.stdout.split())
    return chosen, in_use


def test_the_thread_count_is_the_affinity_masks_whatever_the_load():
    """One thread per core the process may use, idle or with a CPU-bound process beside it: the
    count, and with it the order of every reduction's sums, is not the machine's momentary load."""
    cores = len(os.sched_getaffinity(0))
    assert _policy_threads() == (cores, cores)
    loop = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        time.sleep(0.3)  # the loop holds a core
        assert _policy_threads() == (cores, cores)
    finally:
        loop.kill()
        loop.wait()


@pytest.mark.skipif(not shutil.which("taskset"), reason="taskset (util-linux) is not installed")
def test_the_thread_count_follows_the_affinity_mask():
    assert _policy_threads(["taskset", "-c", "0"]) == (1, 1)


def _scene(seed: int = 0):
    generator = torch.Generator().manual_seed(seed)
    count = 60
    means = torch.rand(count, 3, generator=generator, dtype=torch.float64) * torch.tensor([0.8, 0.8, 0.5])
    means = means + torch.tensor([-0.4, -0.4, 2.0], dtype=torch.float64)
    scales = 0.01 + 0.04 * torch.rand(count, generator=generator, dtype=torch.float64)
    colors = torch.rand(count, 3, generator=generator, dtype=torch.float64)
    opacities = 0.2 + 0.7 * torch.rand(count, generator=generator, dtype=torch.float64)
    return means, scales, colors, opacities


def test_a_cropped_camera_renders_the_crop_of_the_full_render():
    camera = Camera(fx=70.0, fy=72.0, cx=33.5, cy=22.25, width=64, height=48, world_to_camera=torch.eye(4))
    crop = Crop(x0=13, y0=7, width=30, height=25, frame_width=64, frame_height=48)
    full = render(*_scene(), camera, background=(0.2, 0.3, 0.4))
    part = render(*_scene(), crop.camera(camera), background=(0.2, 0.3, 0.4))
    box = (slice(7, 32), slice(13, 43))
    assert full.alpha[box].sum() > 10  # the crop sees the scene
    # The same pixels in float64: only the rounding of (j + 0.5) - u with the shifted cx differs.
    torch.testing.assert_close(part.rgb, full.rgb[box], atol=1e-9, rtol=0)
    torch.testing.assert_close(part.alpha, full.alpha[box], atol=1e-9, rtol=0)


def test_a_crops_loss_is_its_frames_when_the_render_outside_is_background():
    generator = torch.Generator().manual_seed(1)
    width, height, background = 64, 48, torch.tensor([0.2, 0.5, 0.7])
    crops = [Crop(5, 3, 40, 30, width, height), Crop(20, 15, 40, 30, width, height)]
    frames = {name: background[None, :, None, None].repeat(2, 1, height, width) for name in ("s", "d", "t")}
    alphas = {name: torch.zeros(2, 1, height, width) for name in ("s", "d", "m")}
    # The frame's SSIM windows that see the person (centres within 5 pixels of it) must be the
    # crop's (centres 5 pixels inside its edge): 10 pixels of flat background around the person.
    margin = 10
    for b, crop in enumerate(crops):
        inner = (slice(crop.y0 + margin, crop.y0 + 30 - margin), slice(crop.x0 + margin, crop.x0 + 40 - margin))
        for name in frames:
            frames[name][(b, slice(None), *inner)] = torch.rand(3, 10, 20, generator=generator)
        for name in alphas:
            alphas[name][(b, slice(None), *inner)] = torch.rand(1, 10, 20, generator=generator)
    regularizer = torch.tensor(0.3)

    def cut(images):
        boxes = [c.image(images[b].permute(1, 2, 0).numpy()) for b, c in enumerate(crops)]
        return torch.stack([torch.from_numpy(box).permute(2, 0, 1) for box in boxes])

    area = area_tensor(crops)
    whole, _ = objective(frames["s"], frames["d"], frames["t"], regularizer)
    cropped, _ = objective(cut(frames["s"]), cut(frames["d"]), cut(frames["t"]), regularizer, area=area)
    torch.testing.assert_close(cropped, whole, rtol=1e-5, atol=0)
    whole_silhouette = silhouette(alphas["s"], alphas["m"])
    cropped_silhouette = silhouette(cut(alphas["s"]), cut(alphas["m"]), area[:, 0])
    torch.testing.assert_close(cropped_silhouette, whole_silhouette, rtol=1e-5, atol=0)
    torch.testing.assert_close(psnr(cut(frames["d"]), cut(frames["t"]), area[:, 0]), psnr(frames["d"], frames["t"]))


def test_crop_boxes_hold_every_mask_in_one_size():
    mask = np.zeros((48, 64), dtype=np.float32)
    mask[10:20, 30:41] = 1.0
    assert mask_box(mask) == (30, 10, 41, 20)
    assert mask_box(np.zeros((4, 4))) is None
    size = crop_size([(30, 10, 41, 20), (0, 0, 5, 30)], 64, 48, margin=4)
    assert size == (19, 38)
    for box in [(30, 10, 41, 20), (0, 0, 5, 30), (60, 40, 64, 48)]:
        crop = place(box, size, 64, 48)
        assert 0 <= crop.x0 <= box[0] and box[2] <= crop.x0 + crop.width <= 64
        assert 0 <= crop.y0 <= box[1] and box[3] <= crop.y0 + crop.height <= 48
    assert crop_size([(0, 0, 64, 48)], 64, 48, margin=16) == (64, 48)


def test_training_samples_are_crops_of_their_frames(tiny_dataset):
    subject = tiny_dataset / "subject_000"
    whole, cropped = TrainingData(subject), TrainingData(subject, crop_margin=3)
    sizes = set()
    for index in whole.images[0].tolist():
        full, crop = whole.load(0, index), cropped.load(0, index)
        box = crop.crop
        sizes.add((box.width, box.height))
        window = (slice(None), slice(box.y0, box.y0 + box.height), slice(box.x0, box.x0 + box.width))
        assert torch.equal(crop.image, full.image[window]) and torch.equal(crop.mask, full.mask[window])
        assert torch.count_nonzero(crop.mask) == torch.count_nonzero(full.mask)  # all of the person is inside
        assert float(crop.camera.cx) == pytest.approx(float(full.camera.cx) - box.x0)
        assert float(crop.camera.cy) == pytest.approx(float(full.camera.cy) - box.y0)
        assert torch.equal(crop.camera.world_to_camera, full.camera.world_to_camera)
    assert len(sizes) == 1  # one size per subject: a group renders as one batch


def test_a_frozen_avatars_objective_runs_its_identity_once_and_holds_the_maps_when_asked(tiny_dataset):
    from conftest import TINY_MODEL

    from pghm.body.pose import BodyPose
    from pghm.model import PGHM, ModelConfig
    from pghm.train.loop import LoopConfig
    from pghm.train.pose_refine import HeldAppearance
    from pghm.train.prior import GeometryCache

    data = TrainingData(tiny_dataset / "subject_000")
    torch.manual_seed(0)
    model = PGHM(ModelConfig(**TINY_MODEL), num_identities=1).eval()
    with torch.no_grad():  # heads that answer the pose and the view (a new model's are zero)
        for decoder in (model.static_decoder, model.pose_decoder, model.view_decoder):
            decoder.head.weight.normal_(0.0, 0.3)
    geometry = GeometryCache(data, model.config, None)(0)
    latent = model.decode_identity(0).detach()
    samples = data.load_group(0, data.images[0][:2].tolist())
    held = HeldAppearance(model, latent, None, LoopConfig().loss, None)
    pose = BodyPose(torch.stack([s.rotations for s in samples]), torch.stack([s.translation for s in samples]))
    turned = BodyPose(pose.rotations + 0.05, pose.translation)
    centres = torch.stack([s.camera.centre.float() for s in samples])
    index = torch.arange(len(samples))

    def assert_same(found, expected):
        for which in ("dynamic", "static"):
            for name in ("means", "scales", "colors", "opacities"):
                torch.testing.assert_close(
                    getattr(getattr(found, which), name), getattr(getattr(expected, which), name), rtol=0, atol=0
                )

    with torch.no_grad():
        exact, exact_turned = (model(latent, geometry, p, centres, index) for p in (pose, turned))
        model.run_counts.clear()
        for _ in range(2):  # live: the network's at each pose
            assert_same(held.avatar(0, geometry, pose, centres, index), exact)
            assert_same(held.avatar(0, geometry, turned, centres, index), exact_turned)
        held.holding = True
        first = held.avatar(0, geometry, pose, centres, index)
        assert_same(first, exact)
        moved = held.avatar(0, geometry, turned, centres, index)
    # The identity's networks once for the live steps and once for the held maps, not once a step.
    assert model.run_counts["unet_encoder"] == model.run_counts["static_decoder"] == 2
    assert model.run_counts["pose_decoder"] == model.run_counts["view_decoder"] == 4 + 1
    # Held: a moved pose moves the Gaussians through the skinning, their colours stay the first pose's.
    assert not torch.allclose(moved.dynamic.means, first.dynamic.means)
    assert torch.equal(moved.dynamic.colors, first.dynamic.colors)
    assert not torch.allclose(exact_turned.dynamic.colors, first.dynamic.colors)


def test_the_losses_ssim_is_pytorch_msssims_with_the_targets_statistics_shared():
    from pghm.train.losses import TargetSsim, ssim

    generator = torch.Generator().manual_seed(2)
    renders = torch.rand(2, 2, 3, 40, 31, generator=generator, requires_grad=True)
    target = torch.rand(2, 3, 40, 31, generator=generator)
    shared = TargetSsim(target)
    for image in renders:
        reference = ssim(image, target)
        value = shared(image)
        # Float32 rounding of the same sums in another grouping: a few ulps of values near 1.
        torch.testing.assert_close(value, reference, rtol=0, atol=1e-6)
        (expected,) = torch.autograd.grad(reference.sum(), image)
        (found,) = torch.autograd.grad(value.sum(), image)
        torch.testing.assert_close(found, expected, rtol=1e-4, atol=1e-9)


@pytest.mark.parametrize("others, spins", [(0, True), (1, False)])
def test_threads_spin_briefly_on_free_cores_then_sleep_unless_the_user_chose_how(monkeypatch, others, spins):
    from pghm.cli import threads

    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    monkeypatch.setattr(threads, "usable_cores", lambda: 2)
    monkeypatch.setattr(threads, "others_running", lambda: others)
    for name in threads.POLICY_VARIABLES:
        monkeypatch.delenv(name, raising=False)
    threads.set_wait_policy()
    assert os.environ["OMP_WAIT_POLICY"] == threads.WAIT_POLICY == "PASSIVE"
    # libgomp's default is 300,000 rounds (about 3 ms): the spin must stay far below it.
    assert os.environ.get("GOMP_SPINCOUNT") == (str(threads.SPIN_COUNT) if spins else None)
    assert 0 < threads.SPIN_COUNT <= 10_000
    for chosen in ({"OMP_WAIT_POLICY": "ACTIVE"}, {"GOMP_SPINCOUNT": "0"}):
        monkeypatch.delenv("OMP_WAIT_POLICY", raising=False)
        monkeypatch.delenv("GOMP_SPINCOUNT", raising=False)
        for name, value in chosen.items():
            monkeypatch.setenv(name, value)
        threads.set_wait_policy()
        assert {name: os.environ.get(name) for name in threads.WAIT_VARIABLES} == {
            "OMP_WAIT_POLICY": None,
            "GOMP_SPINCOUNT": None,
        } | chosen


def test_one_thread_on_a_second_core_still_spins(monkeypatch):
    from pghm.cli import threads

    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    for name in threads.WAIT_VARIABLES:
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    monkeypatch.setattr(threads, "others_running", lambda: 1)
    threads.set_wait_policy()
    assert os.environ.get("GOMP_SPINCOUNT") == str(threads.SPIN_COUNT)


def test_a_busy_process_is_seen_in_the_run_queue():
    from pghm.cli.threads import others_running

    if not Path("/proc/stat").is_file():
        pytest.skip("no /proc/stat")
    loop = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        time.sleep(0.3)
        assert others_running() >= 1  # runnable in every read, whatever else passes
    finally:
        loop.kill()
        loop.wait()


def test_a_users_thread_count_wins(monkeypatch):
    from pghm.cli.threads import set_threads

    before = torch.get_num_threads()
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    assert set_threads() == before == torch.get_num_threads()


def test_a_coarse_sample_averages_its_pixels_and_scales_its_camera(tiny_dataset):
    """The coarse image and mask are the means of 2 x 2 blocks (brute force), and the coarse camera
    draws a Gaussian where the full one does, halved: the alpha-weighted centroids of one Gaussian's
    renders agree. Sampling a Gaussian of a pixel's deviation moves its centroid by about
    exp(-2 pi^2) of a pixel, but the splatter drops alpha below 1/255: the mass beyond radius
    R = sigma sqrt(2 ln(255 o)) (o = 0.9: R = 3.29 sigma), a share q = 1 / (255 o) = 0.0044, cut
    unevenly by the pixel grid moves a centroid by at most q R / (1 - q) = 0.0144 sigma; sigma is
    2.1 pixels at full resolution (0.06 m at 2 m, fx 70), so 0.03 pixel each, 0.06 both. A wrong
    pixel-centre convention would be off by half a pixel."""
    from pghm.train.coarse import COARSE_FACTOR, coarse_sample

    sample = TrainingData(tiny_dataset / "subject_000").load(0, 0)
    coarse = coarse_sample(sample)
    f = COARSE_FACTOR
    height, width = sample.camera.height // f, sample.camera.width // f
    assert (coarse.camera.width, coarse.camera.height) == (width, height)
    for name in ("image", "mask"):
        fine, small = getattr(sample, name), getattr(coarse, name)
        for y, x in ((0, 0), (height - 1, width - 1), (height // 2, width // 3)):
            block = fine[:, f * y : f * y + f, f * x : f * x + f]
            torch.testing.assert_close(small[:, y, x], block.mean((1, 2)), rtol=0, atol=1e-6)

    camera = Camera(fx=70.0, fy=72.0, cx=33.5, cy=22.25, width=64, height=48, world_to_camera=torch.eye(4))
    blank = replace(sample, image=torch.zeros(3, 48, 64), mask=torch.zeros(1, 48, 64), camera=camera, crop=None)
    small = coarse_sample(blank).camera
    gaussian = (
        torch.tensor([[0.05, -0.03, 2.0]], dtype=torch.float64),
        torch.tensor([0.06], dtype=torch.float64),
        torch.ones(1, 3, dtype=torch.float64),
        torch.tensor([0.9], dtype=torch.float64),
    )

    def centroid(cam: Camera) -> torch.Tensor:
        alpha = render(*gaussian, cam).alpha
        rows, columns = torch.meshgrid(
            torch.arange(cam.height, dtype=torch.float64) + 0.5,
            torch.arange(cam.width, dtype=torch.float64) + 0.5,
            indexing="ij",
        )
        return torch.stack([(alpha * columns).sum(), (alpha * rows).sum()]) / alpha.sum()

    torch.testing.assert_close(f * centroid(small), centroid(camera), rtol=0, atol=0.06)


def test_the_dynamic_render_alone_stands_in_for_both():
    """objective(None, d) is objective(d, d): the dynamic render's terms counted twice."""
    generator = torch.Generator().manual_seed(4)
    dynamic, target = torch.rand(2, 2, 3, 20, 24, generator=generator)
    regularizer = torch.tensor(0.2)
    alone, terms = objective(None, dynamic, target, regularizer)
    both, _ = objective(dynamic, dynamic, target, regularizer)
    torch.testing.assert_close(alone, both, rtol=1e-6, atol=0)
    assert "l1_d" in terms and "l1_s" not in terms


def test_a_sample_is_read_from_its_files_once_while_the_kept_ones_fit(tiny_dataset, monkeypatch):
    from pghm.subject import reader
    from pghm.train import data as data_module

    reads = []
    read_rgb = reader.read_rgb
    monkeypatch.setattr(reader, "read_rgb", lambda path: reads.append(path) or read_rgb(path))
    data = TrainingData(tiny_dataset / "subject_000")
    first, second = (int(i) for i in data.images[0][:2])
    sample = data.load(0, first)
    monkeypatch.setattr(data_module, "SAMPLE_CACHE_BYTES", sample.image.nbytes + sample.mask.nbytes)
    for _ in range(3):
        assert data.load(0, first) is sample
        again = data.load(0, second)  # past the limit: read at each use
    assert len(reads) == 1 + 3
    fresh = TrainingData(tiny_dataset / "subject_000").load(0, second)
    assert torch.equal(again.image, fresh.image) and torch.equal(again.mask, fresh.mask)
    assert data.restricted([first]).load(0, first) is sample  # a restricted copy shares what is kept
