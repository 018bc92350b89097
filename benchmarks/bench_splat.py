"""Speed of the splatter on the body scene, against a naive pure-PyTorch baseline, and its scaling.

    .venv/bin/python benchmarks/bench_splat.py [--repeats K] [--skip-sweep]

1. Scaling: native time against N (at 256^2) and against resolution (at 10k).
2. The approximation sweep of ``pghm bench splat`` (runtime against error, Pareto frontier).
3. Speed: forward and forward+backward medians (2 threads) of the native kernel, the torch
   twin and the baseline (per 64 x 64 tile, dense alpha matrix, cumprod, autograd) measured
   in the same run, at 10k / 40k Gaussians and 256^2 / 512^2, with ratios to the baseline.

Prints tables; writes benchmarks/results/bench_splat.json (and bench_splat_sweep.json),
docs/splat_scaling.png, docs/splat_pareto.png and docs/splat_body.png (the scene itself).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from PIL import Image
from splat_measure import (
    body_scene,
    format_table,
    plot_scaling,
    run_sweep,
    scaling_table,
    speed_table,
    write_json,
)

from pghm.splat import render

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
DOCS = ROOT / "docs"
THREADS = 2
"""The target machine's core count."""

SPEED_CASES = ((10_000, 256), (10_000, 512), (40_000, 256), (40_000, 512))
SCALING_COUNTS = (1_250, 2_500, 5_000, 10_000, 20_000, 40_000)
SCALING_RESOLUTIONS = (128, 256, 512, 1024)


def with_ratios(rows: list[dict]) -> list[dict]:
    """Adds each row's speed-up over the baseline of the same case."""
    baseline = {(r["gaussians"], r["resolution"]): r for r in rows if r["renderer"] == "baseline"}
    for row in rows:
        reference = baseline[(row["gaussians"], row["resolution"])]
        row["forward_speedup"] = reference["forward_ms"] / row["forward_ms"]
        row["forward_backward_speedup"] = reference["forward_backward_ms"] / row["forward_backward_ms"]
    return rows


def save_body_image(path: Path) -> None:
    scene = body_scene(10_000, 512)
    with torch.no_grad():
        rgb = render(scene.means, scene.scales, scene.colors, scene.opacities, scene.camera).rgb
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray((rgb.clamp(0, 1) * 255).round().to(torch.uint8).numpy().astype(np.uint8)).save(path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=15, help="timed repeats of the native kernel")
    parser.add_argument("--baseline-repeats", type=int, default=3, help="timed repeats of the slow renderers")
    parser.add_argument("--skip-sweep", action="store_true", help="skip the approximation sweep")
    args = parser.parse_args()
    torch.set_num_threads(THREADS)

    # The native-only measurements first: the slow renderers' gigabyte-sized temporaries come last.
    scaling = scaling_table(SCALING_COUNTS, SCALING_RESOLUTIONS, args.repeats)
    print("Native scaling (median ms, 2 threads)")
    print(format_table(scaling, ["gaussians", "resolution", "forward_ms", "forward_backward_ms"]))
    plot_scaling(scaling, DOCS / "splat_scaling.png")
    save_body_image(DOCS / "splat_body.png")

    if not args.skip_sweep:
        rows, front = run_sweep(
            repeats=args.repeats, output=RESULTS / "bench_splat_sweep.json", plot=DOCS / "splat_pareto.png"
        )
        print("\nApproximations (10k Gaussians, 256^2; error against the exact image)")
        print(format_table(rows, ["setting", "forward_ms", "forward_backward_ms", "max_abs", "psnr"]))
        print(f"Pareto frontier (forward+backward time vs max abs error): {', '.join(front)}")

    speed = with_ratios(speed_table(SPEED_CASES, args.repeats, args.baseline_repeats))
    print("\nSpeed on the body scene (median ms, 2 threads; speed-up = baseline / renderer)")
    print(
        format_table(
            speed,
            [
                "renderer",
                "gaussians",
                "resolution",
                "forward_ms",
                "forward_backward_ms",
                "forward_speedup",
                "forward_backward_speedup",
            ],
        )
    )
    write_json(
        RESULTS / "bench_splat.json",
        {"speed": speed, "scaling": scaling, "repeats": args.repeats, "baseline_repeats": args.baseline_repeats},
    )
    print(f"\nwrote {RESULTS / 'bench_splat.json'}, {DOCS / 'splat_scaling.png'}, {DOCS / 'splat_body.png'}")


if __name__ == "__main__":
    main()
