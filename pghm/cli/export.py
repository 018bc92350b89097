"""``pghm export``: posed Gaussians of an avatar as a standard 3DGS .ply or a .spz, or the
avatar in a motion as one web page.

pghm export avatar.pt --pose walk --frame 10 --out posed.ply|posed.spz [--view X,Y,Z]
pghm export avatar.pt --web avatar.html [--motion walk|clip.bvh|SUBJECT]   (or --out avatar.html)
"""

from __future__ import annotations

import argparse

from pghm.cli.options import INDEX, Integer, add_device_option
from pghm.errors import PghmError
from pghm.io.export import FRONT_DISTANCE, POSED_FORMATS, export_posed, parse_vector
from pghm.io.outputs import check_output
from pghm.motion.motion import MAX_FRAMES
from pghm.web import DEFAULT_MOTION

WEB_SUFFIX = ".html"
POSED_DEFAULTS = {"pose": "rest", "frame": 0, "view": None}
"""The posed frame's options as they are when not given (a web page refuses them given)."""


def _point(text: str) -> str:
    """An argparse type: ``text`` once :func:`parse_vector` accepts it (refused at the parser, before any load)."""
    try:
        parse_vector(text)
    except PghmError as error:
        raise argparse.ArgumentTypeError(str(error)) from None
    return text


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "export", help="write posed Gaussians as a 3DGS .ply or a .spz, or the avatar in a motion as a web page"
    )
    parser.add_argument("avatar", help="avatar.pt (or prior.pt with --identity)")
    parser.add_argument(
        "--pose", default=POSED_DEFAULTS["pose"], help="a motion file (.npz, .bvh) or a name: rest, walk, squat, ..."
    )
    parser.add_argument(
        "--frame",
        type=Integer(0, MAX_FRAMES - 1),
        default=0,
        help="frame of the motion (default %(default)s)",
    )
    parser.add_argument(
        "--out",
        help="the .ply or .spz to write (Spark, SuperSplat and Babylon.js read .spz), or a web page's .html",
    )
    parser.add_argument("--web", help="the web page to write (.html): the avatar playing --motion, in one file")
    parser.add_argument(
        "--motion",
        help=f"the web page's motion: a file (.npz, .bvh), a name (walk, squat, ...) or a subject folder "
        f"(default {DEFAULT_MOTION})",
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


def output_of(args: argparse.Namespace) -> tuple[str, bool]:
    """The file to write and whether it is a web page; PghmError for options that do not go together."""
    if args.web is not None and args.out is not None:
        raise PghmError("give --out or --web, not both (--web PAGE.html is --out PAGE.html)")
    out = args.web if args.web is not None else args.out
    if out is None:
        raise PghmError("give --out posed.ply|posed.spz (a posed frame) or --web page.html (the avatar in a motion)")
    web = args.web is not None or out.lower().endswith(WEB_SUFFIX)
    if args.web is not None and not out.lower().endswith(WEB_SUFFIX):
        raise PghmError(f"--web {out}: a web page's name ends in {WEB_SUFFIX}")
    posed_only = [f"--{name}" for name in ("pose", "frame", "view") if getattr(args, name) != POSED_DEFAULTS[name]]
    if web and posed_only:
        raise PghmError(f"{', '.join(posed_only)} choose a posed frame; a web page plays --motion")
    if not web and args.motion is not None:
        raise PghmError("--motion is a web page's (--web page.html); a posed frame takes --pose and --frame")
    return out, web


def cmd_export(args: argparse.Namespace) -> int:
    from pghm.device import resolve_device

    out, web = output_of(args)
    inputs = [args.avatar, args.pose, args.motion, args.body_model_path]
    check_output(out, inputs=inputs, suffixes=(*POSED_FORMATS, WEB_SUFFIX))
    device = resolve_device(args.device)
    if web:
        from pghm.web import export_web

        page = export_web(args.avatar, args.motion or DEFAULT_MOTION, out, args.identity, args.body_model_path, device)
        baked = page.baked
        print(
            f"wrote {out}: {baked.num_gaussians} Gaussians, {baked.num_frames} frames, {page.bytes / 1e6:.1f} MB "
            f"(components: points {baked.points.rank}, scales {baked.log_scales.rank}, colours {baked.colors.rank})"
        )
        return 0
    count = export_posed(
        args.avatar, args.pose, args.frame, out, args.view, args.identity, args.body_model_path, device
    )
    print(f"wrote {out}: {count} Gaussians")
    return 0
