"""What leaving pghm costs: a posed frame of the shipped real avatar written as .ply and .spz.

For frames of the 69-frame walk, the avatar's dynamic Gaussians (colour baked for a camera 3 m in
front of the body) are written in each format, read back, and drawn by the CPU splatter at
540 x 960 from that camera: file size, and PSNR of the read-back render against the model's,
over the whole frame and within the silhouette (alpha > 0.01), with the largest channel error.

    python benchmarks/bench_export.py [--avatar assets/real_avatar.pt] [--frames 0 20 40 60]

Prints a table and writes benchmarks/results/bench_export.json.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from pathlib import Path

import torch
from common import ROOT, print_table, setup_threads, write_json

from pghm.body import load_body
from pghm.io.avatar import avatar_geometry, load_avatar
from pghm.io.ply import read_ply, write_ply
from pghm.io.spz import read_spz, write_spz
from pghm.model.evaluator import CachedEvaluator
from pghm.motion.open_motion import open_motion
from pghm.splat import Camera, render

FORMATS = {"ply": (write_ply, read_ply), "spz": (write_spz, read_spz)}
VIEW_DISTANCE = 3.0
"""Metres in front of the posed root of the camera the colour is baked for and the frame drawn from."""
WIDTH, HEIGHT = 540, 960
SILHOUETTE_ALPHA = 0.01


def psnr(mse: float) -> float:
    return 10 * math.log10(1 / mse) if mse > 0 else math.inf


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--avatar", type=Path, default=ROOT / "assets" / "real_avatar.pt")
    parser.add_argument("--motion", type=Path, default=ROOT / "assets" / "motion" / "mixamo_walk_69f.bvh")
    parser.add_argument("--frames", type=int, nargs="+", default=[0, 20, 40, 60])
    args = parser.parse_args()
    setup_threads()
    avatar = load_avatar(args.avatar)
    geometry = avatar_geometry(avatar)
    motion = open_motion(str(args.motion), load_body(avatar.body_name), avatar.shape_of(0), avatar.pose_track)
    evaluator = CachedEvaluator(avatar.model, geometry)
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        for frame in args.frames:
            pose = motion.pose(frame)
            root = evaluator.model.skin(geometry, pose).root[0]
            centre = root + torch.tensor([0.0, 0.0, VIEW_DISTANCE])
            gaussians = evaluator.evaluate(avatar.identity_map(), pose, centre).dynamic
            model = (gaussians.means[0], gaussians.scales[0], gaussians.colors[0], gaussians.opacities[0])
            camera = Camera.look_at(eye=tuple(centre.tolist()), target=tuple(root.tolist()), width=WIDTH, height=HEIGHT)
            reference = render(*model, camera)
            inside = reference.alpha > SILHOUETTE_ALPHA
            for name, (write, read) in FORMATS.items():
                path = Path(scratch) / f"posed.{name}"
                write(path, *model)
                error = render(*read(path), camera).rgb - reference.rgb
                rows.append(
                    {
                        "frame": frame,
                        "format": name,
                        "gaussians": model[0].shape[0],
                        "kb": round(path.stat().st_size / 1024, 1),
                        "psnr": round(psnr(error.square().mean().item()), 2),
                        "psnr_silhouette": round(psnr(error[inside].square().mean().item()), 2),
                        "max_abs": round(error.abs().max().item(), 4),
                    }
                )
    print_table(rows)
    write_json("bench_export", {"avatar": args.avatar.name, "size": [WIDTH, HEIGHT], "rows": rows})
    return 0


if __name__ == "__main__":
    sys.exit(main())
