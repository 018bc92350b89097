"""``pghm synth``: generate a synthetic dataset (see docs/data.md).

    pghm synth --config tiny|prior|mono|CONFIG.json --seed S --out DIR [--workers N] [--quiet]

The same config and seed give the same bytes, whatever ``--workers``.
"""

from __future__ import annotations

import argparse

from pghm.cli.options import SEED, Integer
from pghm.io.outputs import check_output
from pghm.synth.config import PRESETS, load_config
from pghm.synth.generate import generate

MAX_WORKERS = 64
"""Most render processes (each holds a GL context and a body model)."""


def cmd_synth(args: argparse.Namespace) -> int:
    check_output(args.out, inputs=[args.config], folder=True)
    config = load_config(args.config)
    report = generate(config, args.seed, args.out, workers=args.workers, progress=not args.quiet)
    print(
        f"{report.out}: {len(report.subjects)} subject(s), {report.images} images "
        f"in {report.seconds:.1f} s on {report.workers} process(es)"
    )
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "synth",
        help="generate synthetic subjects: textured, lit meshes rendered from camera rings or a monocular camera",
        description="Generate a dataset of synthetic subjects in the pghm subject format (docs/data.md).",
    )
    parser.add_argument(
        "--config",
        default="tiny",
        help=f"a preset ({', '.join(PRESETS)}) or a JSON file of SynthConfig fields (default: tiny)",
    )
    parser.add_argument("--seed", type=SEED, default=0, help="dataset seed (default 0)")
    parser.add_argument("--out", required=True, help="new (or empty) output folder")
    parser.add_argument(
        "--workers",
        type=Integer(1, MAX_WORKERS),
        default=2,
        help="render processes (default 2, one per core)",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.set_defaults(func=cmd_synth)
