"""``pghm render``: frames of an avatar without a window (EGL offscreen GL, or the CPU splatter).

    pghm render avatar.pt [--motion FILE_OR_NAME] [--orbit] [--size WxH] [--fps F]
                          [--frames N] [--backend auto|gl|cpu] --out out.mp4|out.png|dir/

A thin wrapper over :func:`pghm.render.job.render_video`; see docs/viewer.md.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from pghm.cli.options import INDEX, Integer, Real, Size, add_device_option, rendering_device
from pghm.errors import PghmError
from pghm.motion.motion import MAX_FPS, MIN_FPS
from pghm.render import DEFAULT_FPS, DEFAULT_SIZE, MAX_RENDER_FRAMES, RenderJob, render_video

MAX_SECONDS = 1e6
"""Largest --start in seconds (11 days into a clip, which loops)."""
MAX_ANGLE = 3600.0
"""Largest |--yaw| in degrees (ten turns)."""
PITCH_LIMIT = 90.0
"""Largest |--pitch| in degrees: straight above or below the body."""


def parse_colour(text: str) -> tuple[float, float, float]:
    """An argparse type: :func:`pghm.train.background.parse_colour` ('1,1,1', 'black', '#334455')."""
    from pghm.train.background import parse_colour as parse

    try:
        return parse(text)
    except PghmError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "render",
        help="render an avatar to an MP4, a PNG or a PNG sequence (headless)",
        description="Render an avatar through the viewer's GL path on an offscreen EGL context "
        "(no display needed), or through the CPU splatter with --backend cpu.",
    )
    parser.add_argument("avatar", type=Path, help="avatar or prior file (.pt)")
    parser.add_argument("--out", type=Path, required=True, help="out.mp4, out.png (one frame) or a directory")
    parser.add_argument(
        "--motion",
        help="motion file (.npz, .bvh), procedural name (walk, squat, ...) or subject folder (its video's poses)",
    )
    parser.add_argument("--orbit", action="store_true", help="turn the camera once around the body")
    parser.add_argument("--size", type=Size(), default=DEFAULT_SIZE, help="WxH pixels (default 640x480)")
    parser.add_argument(
        "--fps",
        type=Real(MIN_FPS, MAX_FPS),
        default=DEFAULT_FPS,
        help="frames per second (default 30)",
    )
    parser.add_argument(
        "--frames",
        type=Integer(1, MAX_RENDER_FRAMES),
        help="number of frames (default: the motion once / one orbit / 1)",
    )
    parser.add_argument(
        "--start",
        type=Real(-MAX_SECONDS, MAX_SECONDS),
        default=0.0,
        help="seconds into the motion of the first frame",
    )
    parser.add_argument(
        "--backend",
        choices=("auto", "gl", "cpu"),
        default="auto",
        help="gl (OpenGL through EGL), cpu (the CPU splatter) or auto (default: gl if EGL works, else cpu)",
    )
    parser.add_argument("--identity", type=INDEX, default=0, help="identity of a prior's bank")
    parser.add_argument("--static", action="store_true", help="render the static Gaussians (I_s)")
    parser.add_argument("--no-view-dependent", action="store_true", help="leave out the view-dependent colour")
    parser.add_argument(
        "--background", type=parse_colour, default=(1.0, 1.0, 1.0), help="r,g,b in [0, 1], #rrggbb, white or black"
    )
    parser.add_argument("--pitch", type=Real(-PITCH_LIMIT, PITCH_LIMIT), default=0.0, help="camera elevation, degrees")
    parser.add_argument(
        "--yaw",
        type=Real(-MAX_ANGLE, MAX_ANGLE),
        default=0.0,
        help="camera azimuth, degrees (0: front)",
    )
    parser.add_argument("--no-follow", action="store_true", help="keep the camera still when the body moves")
    parser.add_argument("--body-model-path", help="the SMPL-X model file, for SMPL-X avatars")
    add_device_option(parser)
    parser.set_defaults(func=cmd_render)


def cmd_render(args: argparse.Namespace) -> int:
    job = RenderJob(
        avatar=args.avatar,
        out=args.out,
        motion=args.motion,
        orbit=args.orbit,
        size=args.size,
        fps=args.fps,
        frames=args.frames,
        start=args.start,
        backend=args.backend,
        identity=args.identity,
        gaussians="static" if args.static else "dynamic",
        view_dependent=not args.no_view_dependent,
        background=args.background,
        pitch=args.pitch,
        yaw=args.yaw,
        follow=not args.no_follow,
        body_model_path=args.body_model_path,
        device=str(rendering_device(args.device)),
    )
    summary = render_video(job, log=lambda line: print(f"pghm render: {line}", file=sys.stderr))
    width, height = summary.size
    per_frame = ", ".join(f"{name[:-3]} {value:.1f}" for name, value in summary.timings.items())
    print(
        f"wrote {summary.path}: {summary.frames} frame(s) {width}x{height} at {summary.fps:g} fps "
        f"in {summary.seconds:.1f} s ({summary.driver}; ms per frame: {per_frame})"
    )
    return 0
