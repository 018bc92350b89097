"""Fit quality against cost: UV resolution L x fitting steps x training image size.

For every (L, steps, image scale): fit the monocular subject with the default ``pghm fit``
configuration at that budget (stage 1 a tenth of the steps, as the default), then score the
avatar on the held-out novel poses of the full-size subject (512 x 384, exact poses, white, as
docs/results.md). The Gaussians live in 3D, so an avatar trained on smaller images is scored on
the same full-size frames as every other; the smaller training subject is the same person
(``pghm synth --config mono`` with the same seed; only the image size changes).

The prior has one L (128); a fit at another L starts from it all the same: its networks are
convolutional, so their weights carry over and only the identity bank is resampled
(``pghm fit --uv-resolution``, :meth:`PGHM.at_resolution`). ``--scratch-everywhere`` fits every
L from scratch instead. L is a power of two (the UV atlas halves it at every pyramid level).
Each finished run is cached as JSON in ``--work``, so a stopped sweep resumes where it was.

    python benchmarks/bench_resolution.py --subject /path/mono1/subject_000 \\
        --resolutions 128 256 --steps 250 500 1000 --scales 1.0 0.5

Prints the table, writes benchmarks/results/bench_resolution.json and docs/bench_resolution.png
(PSNR against fit minutes, one line per L and image scale). Minutes are optimisation time on this
machine under its load at the time (recorded), not a clean timing.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import tempfile
from pathlib import Path

from common import DOCS, load_average, print_table, setup_threads, write_json

from pghm.io.avatar import avatar_geometry
from pghm.model import ModelConfig
from pghm.synth.config import PRESETS
from pghm.synth.generate import generate
from pghm.train.evaluate import evaluate
from pghm.train.fit import FitConfig, fit

STAGE1_SHARE = 10
"""Stage 1 gets 1/STAGE1_SHARE of a budget, as the default fit (50 of 500)."""
SPLIT = "test_novel_pose"


def budget(steps: int, resolution: int) -> FitConfig:
    """The default fit configuration of the paper's model (no detail layer) at UV side ``resolution``
    with ``steps`` in all, split between the stages as the default."""
    config = FitConfig(uv_resolution=resolution)
    config.detail = dataclasses.replace(config.detail, steps=0)
    first = steps // STAGE1_SHARE
    config.stage1 = dataclasses.replace(config.stage1, steps=first, checkpoint_every=0)
    config.stage2 = dataclasses.replace(config.stage2, steps=steps - first, checkpoint_every=0)
    return config


def training_subject(subject: Path, seed: int, scale: float, work: Path) -> Path:
    """The subject itself at scale 1, else the same person synthesised at ``scale`` of its size."""
    if scale == 1.0:
        return subject
    preset = PRESETS["mono"]
    config = dataclasses.replace(preset, width=round(preset.width * scale), height=round(preset.height * scale))
    out = work / f"mono_{scale:g}"
    if not out.is_dir():
        generate(config, seed=seed, out=out, workers=1, progress=False)
    return out / subject.name


def run(args: argparse.Namespace) -> list[dict]:
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        work = Path(args.work) if args.work else Path(scratch)
        work.mkdir(parents=True, exist_ok=True)
        for scale in args.scales:
            train_on = training_subject(Path(args.subject), args.seed, scale, work)
            for resolution in args.resolutions:
                for steps in args.steps:
                    origin = "scratch" if args.scratch_everywhere else "prior"
                    name = f"L{resolution}_s{steps}_x{scale:g}_{origin}"
                    cached = work / f"{name}.json"
                    if cached.is_file():
                        rows.append(json.loads(cached.read_text()))
                        continue
                    source = ModelConfig() if args.scratch_everywhere else args.prior
                    load = load_average()
                    avatar = fit(train_on, source, work / f"{name}.pt", budget(steps, resolution))
                    result = evaluate(avatar, args.subject, split=SPLIT, true_poses=True).summary()
                    row = {
                        "L": resolution,
                        "gaussians": avatar_geometry(avatar).num_gaussians,
                        "steps": steps,
                        "image_scale": scale,
                        "from": origin,
                        "psnr": round(result["psnr"], 2),
                        "ssim": round(result["ssim"], 4),
                        "iou": round(result["iou"], 4),
                        "halo": round(result["halo_pixels"], 1),
                        "minutes": round(avatar.metadata["seconds"] / 60, 2),
                        "load": round(load, 1),
                    }
                    cached.write_text(json.dumps(row))
                    rows.append(row)
                    print_table(rows)
    return rows


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    figure, axes = plt.subplots(figsize=(6.4, 4.2))
    for key in sorted({(r["L"], r["image_scale"], r["from"]) for r in rows}):
        line = sorted((r for r in rows if (r["L"], r["image_scale"], r["from"]) == key), key=lambda r: r["steps"])
        axes.plot(
            [r["minutes"] for r in line],
            [r["psnr"] for r in line],
            marker="o",
            label=f"L = {key[0]}, images x{key[1]:g}, {key[2]}",
        )
        for r in line:
            axes.annotate(
                str(r["steps"]), (r["minutes"], r["psnr"]), fontsize=7, xytext=(3, 3), textcoords="offset points"
            )
    axes.set_xlabel("fit time (minutes, 2 cores)")
    axes.set_ylabel(f"PSNR on {SPLIT} (dB, white)")
    axes.grid(alpha=0.3)
    axes.legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    print(f"wrote {path}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--subject", required=True, help="the mono subject folder (pghm synth --config mono)")
    parser.add_argument("--seed", type=int, default=1, help="the synth seed that made --subject (default 1)")
    parser.add_argument("--prior", default="assets/prior.pt")
    parser.add_argument("--resolutions", type=int, nargs="+", default=[128, 256])
    parser.add_argument("--steps", type=int, nargs="+", default=[250, 500, 1000])
    parser.add_argument("--scales", type=float, nargs="+", default=[1.0])
    parser.add_argument("--scratch-everywhere", action="store_true", help="fit every L from scratch")
    parser.add_argument("--work", default=None, help="keep avatars and resized subjects here (default: a temp dir)")
    parser.add_argument("--name", default="bench_resolution", help="JSON and PNG file name")
    args = parser.parse_args()
    setup_threads()
    rows = run(args)
    write_json(args.name, {"subject": Path(args.subject).name, "split": SPLIT, "rows": rows})
    plot(rows, DOCS / f"{args.name}.png")


if __name__ == "__main__":
    main()
