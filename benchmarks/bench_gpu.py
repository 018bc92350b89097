"""pghm on a GPU in one command: gsplat against the CPU splatter, fit speed, and a short GPU fit.

    pip install 'pghm[gpu]'
    MAX_JOBS=16 TORCH_CUDA_ARCH_LIST=9.0 python benchmarks/bench_gpu.py [--subject DIR] [--work DIR]

Three parts, each a table, all in benchmarks/results/bench_gpu.json:

1. **Splat**: gsplat (float32, on the GPU) against the CPU splatter's exact float64 image on the
   body scene at the Gaussian counts of L = 128 and 256 (the atlas's texels; opacity 1, as pghm's
   avatars), 512 and 1024 px: PSNR, mean and max abs difference of rgb, and gsplat's forward +
   backward time. The first call builds gsplat's CUDA kernels (timed apart, "build_s").
2. **Fit speed**: steps per second of stage 2 of ``pghm fit`` (the default model, 2 images per step)
   at L = 128, 256 and 512 on the monocular subject.
3. **Two-minute fit**: :func:`pghm.train.fit.gpu_fit_candidate` (unmeasured until this runs) on
   the monocular subject, scored on its held-out novel poses (exact poses, white, as
   docs/results.md), against the CPU default fit's PSNR read from
   benchmarks/results/bench_resolution.json (L = 128, 500 steps; not re-run here).

``--subject`` is subject_000 of ``pghm synth --config mono --seed 1`` (the CPU results' subject);
without it that subject is synthesised into ``--work`` first. With no CUDA device the script
stops with one line (exit 2); ``--device cpu --quick`` runs every part on the CPU at toy sizes in
seconds, to check the script itself: its numbers measure nothing.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import torch
from common import RESULTS, machine, print_table

from pghm.body import load_body
from pghm.cli.options import rendering_device
from pghm.errors import EXIT_USER_ERROR, PghmError
from pghm.splat import Camera, render
from pghm.train.evaluate import evaluate
from pghm.train.fit import FitConfig, fit, gpu_fit_candidate
from pghm.uv.atlas import build_atlas
from pghm.uv.maps import texel_surface

PRIOR = Path(__file__).resolve().parent.parent / "assets" / "prior.pt"
SPLIT = "test_novel_pose"
SUBJECT_SEED = 1
"""``pghm synth --config mono --seed 1``: the subject of docs/results.md and bench_resolution.json."""
CPU_RESULTS = RESULTS / "bench_resolution.json"
CPU_ROW = {"L": 128, "steps": 500, "image_scale": 1.0, "from": "prior"}
"""The row of CPU_RESULTS that is the CPU default fit (its metadata: 50 + 450 steps at L = 128)."""
PARTS = ("splat", "fit_speed", "candidate")
SPLAT_SIZES = ((128, 512), (256, 512), (256, 1024))
"""(L whose texel count sets N, image side) of the splat comparison."""
FIT_RESOLUTIONS = (128, 256, 512)
SPEED_STEPS = 50
"""Timed stage-2 steps per L, after WARMUP_STEPS untimed ones."""
WARMUP_STEPS = 5
FOV_DEGREES = 35.0
CAMERA_DISTANCE = 3.0
SCALE_RANGE = (0.005, 0.013)
"""Isotropic standard deviations of the splat scene, metres (a texel's Gaussian at L = 128-256)."""
TIMING_REPEATS = 20
QUICK = {"splat": ((32, 64),), "fit": (64,), "speed_steps": 2, "warmup": 1, "repeats": 2}
"""Toy sizes of ``--quick``: the script's plumbing, not a measurement."""


def synchronize(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def body_scene(resolution: int, side: int, seed: int = 0) -> tuple[torch.Tensor, ...]:
    """(means (N, 3), scales (N,), colors (N, 3), opacities (N,), camera): one Gaussian per texel of
    the body's atlas at ``resolution``, opacity 1, seen from CAMERA_DISTANCE in front."""
    body = load_body()
    surface = texel_surface(body, build_atlas(body, resolution), body.rest())
    generator = torch.Generator().manual_seed(seed)
    count = surface.positions.shape[0]
    low, high = SCALE_RANGE
    scales = low + (high - low) * torch.rand(count, generator=generator)
    colors = torch.rand(count, 3, generator=generator)
    centre = 0.5 * (surface.positions.amin(0) + surface.positions.amax(0))
    eye = centre + torch.tensor([0.0, 0.0, CAMERA_DISTANCE])
    camera = Camera.look_at(eye, centre, (0.0, 1.0, 0.0), FOV_DEGREES, side, side)
    return surface.positions.float(), scales, colors, torch.ones(count), camera


def image_errors(got: torch.Tensor, want: torch.Tensor) -> dict:
    error = (got.double().cpu() - want).abs()
    mse = float(error.square().mean())
    return {
        "psnr": round(-10 * math.log10(mse), 1) if mse > 0 else math.inf,
        "mean_abs": float(f"{float(error.mean()):.2g}"),
        "max_abs": float(f"{float(error.max()):.2g}"),
    }


def forward_backward_ms(inputs: list[torch.Tensor], camera: Camera, device: torch.device, repeats: int) -> float:
    """Median ms of render + backward of a random cotangent on ``device``."""
    leaves = [value.detach().clone().requires_grad_(True) for value in inputs]
    cotangent = torch.rand(camera.height, camera.width, 3, device=device)
    times = []
    for _ in range(repeats + 1):
        synchronize(device)
        start = time.perf_counter()
        (render(*leaves, camera).rgb * cotangent).sum().backward()
        synchronize(device)
        times.append((time.perf_counter() - start) * 1e3)
    return round(sorted(times[1:])[len(times[1:]) // 2], 2)


def splat_rows(device: torch.device, sizes, repeats: int) -> list[dict]:
    """gsplat (or, on the CPU, the float32 splatter) against the float64 CPU splatter."""
    rows = []
    for resolution, side in sizes:
        means, scales, colors, opacities, camera = body_scene(resolution, side)
        exact = render(means.double(), scales.double(), colors.double(), opacities.double(), camera).rgb
        inputs = [value.to(device) for value in (means, scales, colors, opacities)]
        synchronize(device)
        start = time.perf_counter()
        with torch.no_grad():
            fast = render(*inputs, camera).rgb
        synchronize(device)
        first = time.perf_counter() - start
        row = {"L": resolution, "gaussians": len(means), "pixels": f"{side}x{side}", **image_errors(fast, exact)}
        row["fwd_bwd_ms"] = forward_backward_ms(inputs, camera, device, repeats)
        row["first_call_s"] = round(first, 1)
        rows.append(row)
        print_table(rows)
    return rows


def stage2_only(resolution: int, steps: int) -> FitConfig:
    """The default fit at L = ``resolution`` with no stage 1, ``steps`` stage-2 steps and no detail
    stage, no checkpoints."""
    config = FitConfig(uv_resolution=resolution, track_steps=0, lpips=False)
    config.detail = dataclasses.replace(config.detail, steps=0)
    config.stage1 = dataclasses.replace(config.stage1, steps=0, checkpoint_every=0, progress=False)
    config.stage2 = dataclasses.replace(config.stage2, steps=steps, checkpoint_every=0, progress=False)
    return config


def speed_rows(subject: Path, work: Path, device: torch.device, resolutions, steps: int, warmup: int) -> list[dict]:
    """Stage-2 steps per second at each L (after ``warmup`` untimed steps at that L)."""
    rows = []
    for resolution in resolutions:
        fit(subject, PRIOR, work / f"warmup_{resolution}.pt", stage2_only(resolution, warmup), device=device)
        avatar = fit(subject, PRIOR, work / f"speed_{resolution}.pt", stage2_only(resolution, steps), device=device)
        seconds = avatar.metadata["seconds"]
        rows.append({"L": resolution, "steps": steps, "seconds": seconds, "steps_per_s": round(steps / seconds, 2)})
        print_table(rows)
    return rows


def cpu_default_fit() -> dict | None:
    """The CPU default fit's row of CPU_RESULTS, or None when that file lacks it."""
    if not CPU_RESULTS.is_file():
        return None
    rows = json.loads(CPU_RESULTS.read_text()).get("rows", [])
    return next((row for row in rows if all(row.get(k) == v for k, v in CPU_ROW.items())), None)


def candidate_rows(subject: Path, work: Path, device: torch.device, config: FitConfig) -> list[dict]:
    """The candidate fit on ``device`` and the CPU default fit, on the held-out novel poses."""
    config = dataclasses.replace(config, lpips=False)
    for name in ("stage1", "stage2"):
        setattr(config, name, dataclasses.replace(getattr(config, name), checkpoint_every=0))
    avatar = fit(subject, PRIOR, work / "candidate.pt", config, device=device)
    scores = evaluate(avatar, subject, split=SPLIT, true_poses=True, device=device).summary()
    steps = f"{config.stage1.steps} + {config.stage2.steps}"
    rows = [
        {
            "run": f"gpu_fit_candidate on {device.type}",
            "L": config.uv_resolution,
            "steps": steps,
            "images": config.stage2.images_per_shard,
            "psnr": round(scores["psnr"], 2),
            "ssim": round(scores["ssim"], 4),
            "minutes": round(avatar.metadata["seconds"] / 60, 2),
        }
    ]
    cpu = cpu_default_fit()
    if cpu is not None:
        rows.append(
            {
                "run": f"CPU default fit (read from {CPU_RESULTS.name})",
                "L": cpu["L"],
                "steps": "50 + 450",
                "images": 2,
                "psnr": cpu["psnr"],
                "ssim": cpu["ssim"],
                "minutes": cpu["minutes"],
            }
        )
    print_table(rows)
    return rows


def monocular_subject(work: Path, quick: bool) -> Path:
    """subject_000 of ``pghm synth --config mono --seed 1`` (a toy-sized one for ``--quick``)."""
    from pghm.synth.config import PRESETS
    from pghm.synth.generate import generate

    config = PRESETS["mono"]
    if quick:
        config = dataclasses.replace(
            config, frames=4, test_frames=2, novel_views=0, width=64, height=48, texture_size=128
        )
    out = work / ("mono_quick" if quick else "mono")
    if not out.is_dir():
        generate(config, seed=SUBJECT_SEED, out=out, workers=max(1, torch.get_num_threads()), progress=False)
    return out / "subject_000"


def quick_candidate() -> FitConfig:
    """:func:`gpu_fit_candidate` cut to toy size, for ``--quick``."""
    config = gpu_fit_candidate()
    config.uv_resolution = QUICK["fit"][0]
    for name in ("stage1", "stage2"):
        setattr(config, name, dataclasses.replace(getattr(config, name), steps=1, images_per_shard=1, progress=False))
    return config


def run(args: argparse.Namespace) -> dict:
    """The three parts in turn; the JSON is rewritten after each, so a run cut short keeps its parts."""
    device = rendering_device(args.device)
    if device.type != "cuda" and not args.quick:
        raise PghmError("no CUDA device here: this script measures the GPU (--device cpu --quick checks the script)")
    sizes = QUICK["splat"] if args.quick else SPLAT_SIZES
    repeats = QUICK["repeats"] if args.quick else TIMING_REPEATS
    with tempfile.TemporaryDirectory() as scratch:
        work = Path(args.work or scratch)
        work.mkdir(parents=True, exist_ok=True)
        started = time.perf_counter()
        device_name = torch.cuda.get_device_name(device) if device.type == "cuda" else "cpu"
        payload = {"device": device_name, "quick": args.quick}

        def record(part: str, rows: list[dict]) -> None:
            payload.update({part: rows, "seconds": round(time.perf_counter() - started, 1)})
            Path(args.json).write_text(json.dumps({"machine": machine(), **payload}, indent=2))

        if "splat" in args.parts:
            record("splat", splat_rows(device, sizes, repeats))
        subject = Path(args.subject) if args.subject else monocular_subject(work, args.quick)
        if "fit_speed" in args.parts:
            resolutions = QUICK["fit"] if args.quick else FIT_RESOLUTIONS
            steps, warmup = (QUICK["speed_steps"], QUICK["warmup"]) if args.quick else (SPEED_STEPS, WARMUP_STEPS)
            record("fit_speed", speed_rows(subject, work, device, resolutions, steps, warmup))
        if "candidate" in args.parts:
            config = quick_candidate() if args.quick else gpu_fit_candidate()
            record("candidate", candidate_rows(subject, work, device, config))
    return payload


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto")
    parser.add_argument(
        "--parts", nargs="+", choices=PARTS, default=list(PARTS), help="which parts to run (default: all)"
    )
    parser.add_argument("--quick", action="store_true", help="toy sizes, to check the script (numbers mean nothing)")
    parser.add_argument("--subject", help="subject_000 of `pghm synth --config mono --seed 1` (default: made here)")
    parser.add_argument("--work", help="folder for the subject and the avatars (default: a temporary one)")
    parser.add_argument("--json", default=str(RESULTS / "bench_gpu.json"), help="where to write the results")
    args = parser.parse_args()
    try:
        run(args)
    except PghmError as error:
        print(f"bench_gpu: error: {error}", file=sys.stderr)
        return EXIT_USER_ERROR
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
