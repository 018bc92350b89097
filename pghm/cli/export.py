"""``pghm export``: posed Gaussians of an avatar as a standard 3DGS .ply or a .spz.

pghm export avatar.pt --pose walk --frame 10 --out posed.ply|posed.spz [--view X,Y,Z]
"""

from __future__ import annotations

import argparse

from pghm.cli.options import INDEX, Integer, add_device_option
from pghm.errors import PghmError
from pghm.io.export import FRONT_DISTANCE, POSED_FORMATS, export_posed, parse_vector
from pghm.io.outputs import check_output
from pghm.motion.motion import MAX_FRAMES


def _point(text: str) -> str:
    """An argparse type: ``text`` once :func:`parse_vector` accepts it (refused at the parser, before any load)."""
    try:
        parse_vector(text)
    except PghmError as error:
        raise argparse.ArgumentTypeError(str(error)) from None
    return text


def register(subparsers) -> None:
    parser = subparsers.add_parser("export", help="write posed Gaussians as a 3DGS .ply or a .spz")
    parser.add_argument("avatar", help="avatar.pt (or prior.pt with --identity)")
    parser.add_argument("--pose", default="rest", help="a motion file (.npz, .bvh) or a name: rest, walk, squat, ...")
    parser.add_argument(
        "--frame",
        type=Integer(0, MAX_FRAMES - 1),
        default=0,
        help="frame of the motion (default %(default)s)",
    )
    parser.add_argument(
        "--out", required=True, help="the .ply or .spz to write (Spark, SuperSplat and Babylon.js read .spz)"
    )
    parser.add_argument(
        "--view",
        type=_point,
        default=None,
        help="camera centre X,Y,Z the view-dependent colour is baked for "
        f"(default: {FRONT_DISTANCE:g} m in front of the body)",
    )
    parser.add_argument("--identity", type=INDEX, default=0, help="identity of a prior's bank (default %(default)s)")
    parser.add_argument("--body-model-path", default=None)
    add_device_option(parser)
    parser.set_defaults(func=cmd_export)


def cmd_export(args: argparse.Namespace) -> int:
    from pghm.device import resolve_device

    check_output(args.out, inputs=[args.avatar, args.pose, args.body_model_path], suffixes=POSED_FORMATS)
    device = resolve_device(args.device)
    count = export_posed(
        args.avatar, args.pose, args.frame, args.out, args.view, args.identity, args.body_model_path, device
    )
    print(f"wrote {args.out}: {count} Gaussians")
    return 0
