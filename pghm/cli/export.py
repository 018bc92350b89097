"""``pghm export``: posed Gaussians of an avatar as a standard 3DGS .ply.

pghm export avatar.pt --pose walk --frame 10 --out posed.ply [--view X,Y,Z]
"""

from __future__ import annotations

import argparse

from pghm.cli.options import INDEX, Integer
from pghm.io.export import FRONT_DISTANCE, export_posed_ply
from pghm.io.outputs import check_output
from pghm.motion.motion import MAX_FRAMES


def register(subparsers) -> None:
    parser = subparsers.add_parser("export", help="write posed Gaussians as a 3DGS .ply")
    parser.add_argument("avatar", help="avatar.pt (or prior.pt with --identity)")
    parser.add_argument("--pose", default="rest", help="a motion file (.npz, .bvh) or a name: rest, walk, squat, ...")
    parser.add_argument(
        "--frame",
        type=Integer(0, MAX_FRAMES - 1),
        default=0,
        help="frame of the motion (default %(default)s)",
    )
    parser.add_argument("--out", required=True, help="the .ply to write")
    parser.add_argument(
        "--view",
        default=None,
        help="camera centre X,Y,Z the view-dependent colour is baked for "
        f"(default: {FRONT_DISTANCE:g} m in front of the body)",
    )
    parser.add_argument("--identity", type=INDEX, default=0, help="identity of a prior's bank (default %(default)s)")
    parser.add_argument("--body-model-path", default=None)
    parser.set_defaults(func=cmd_export)


def cmd_export(args: argparse.Namespace) -> int:
    check_output(args.out, inputs=[args.avatar, args.pose])
    count = export_posed_ply(
        args.avatar, args.pose, args.frame, args.out, args.view, args.identity, args.body_model_path
    )
    print(f"wrote {args.out}: {count} Gaussians")
    return 0
