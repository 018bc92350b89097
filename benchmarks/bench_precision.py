"""A training step's model part in each precision and layout: what ``pghm fit --precision auto`` picks.

The shipped real avatar's network, a forward and backward pass at two images (stage 2's batch: the
latent and every network weight with gradients), float32 and bfloat16 autocast, NCHW and
channels-last, each a median of 5 after a warm-up, the four interleaved over ``--rounds`` rounds so
that a drift of the machine moves every arm alike. Prints the table, the CPU's bfloat16 features as
torch sees them (:func:`pghm.device.bfloat16_features`) and what ``--precision auto`` resolves to here,
and writes benchmarks/results/bench_precision.json.

    python benchmarks/bench_precision.py [--rounds 2]
"""

from __future__ import annotations

import argparse
import statistics

import torch
from common import ROOT, load_average, median_ms, print_table, setup_threads, write_json

from pghm.body import BodyPose, load_body
from pghm.device import bfloat16_features, resolve_precision
from pghm.io.avatar import load_avatar
from pghm.model import subject_geometry
from pghm.model.pghm import set_conv_layout
from pghm.uv.atlas import build_atlas

IMAGES = 2
"""A stage-2 step's images (:class:`pghm.train.fit.FitConfig`)."""
ARMS = {
    "float32 NCHW": (torch.float32, torch.contiguous_format),
    "float32 channels-last": (torch.float32, torch.channels_last),
    "bfloat16 NCHW": (torch.bfloat16, torch.contiguous_format),
    "bfloat16 channels-last": (torch.bfloat16, torch.channels_last),
}
"""Name -> (compute dtype, convolution weights' layout); the fit trains float32 NCHW and bfloat16
channels-last (:meth:`pghm.model.PGHM.train`)."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=2, help="interleaved rounds of the four arms")
    args = parser.parse_args()
    setup_threads()
    avatar = load_avatar(ROOT / "assets" / "real_avatar.pt")
    model, body = avatar.model, load_body()
    geometry = subject_geometry(body, build_atlas(body, model.config.uv_resolution))
    generator = torch.Generator().manual_seed(1)
    pose = BodyPose(torch.randn(IMAGES, body.num_bones, 3, generator=generator) * 0.3, torch.zeros(IMAGES, 3))
    cameras = torch.tensor([[0.0, 0.2, 3.0]] * IMAGES)
    latent = avatar.latent.clone().requires_grad_(True)
    for p in model.parameters():
        p.requires_grad_(True)

    def step() -> None:
        out = model(latent, geometry, pose, cameras)
        (out.static.colors.mean() + out.dynamic.means.mean() + out.dynamic.colors.mean() + out.regularizer).backward()

    load = load_average()
    times: dict[str, list[float]] = {name: [] for name in ARMS}
    for _ in range(args.rounds):
        for name, (dtype, layout) in ARMS.items():
            model.set_precision(dtype).train()
            set_conv_layout(model, layout)
            times[name].append(median_ms(step, repeat=5, warmup=1))
    baseline = statistics.median(times["float32 NCHW"])
    rows = [
        {
            "arm": name,
            "ms (each round)": ", ".join(f"{t:.1f}" for t in measured),
            "median ms": statistics.median(measured),
            "speed vs float32 NCHW": baseline / statistics.median(measured),
        }
        for name, measured in times.items()
    ]
    print_table(rows)
    features = bfloat16_features()
    auto = str(resolve_precision("auto", torch.device("cpu"))).removeprefix("torch.")
    print(f"bfloat16 features: {features}; --precision auto here: {auto}; load average before: {load:.2f}")
    write_json("bench_precision", {"rows": rows, "bfloat16_features": features, "auto": auto, "load_average": load})


if __name__ == "__main__":
    main()
