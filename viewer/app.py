"""``pghm-view [avatar.pt]``: open the live viewer.

Exit status 2 with one line on stderr when there is no display (pointing to ``pghm
render``), when the avatar file is missing or bad, or when no OpenGL 3.3 window can be made.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from pghm.errors import EXIT_USER_ERROR, DisplayError, PghmError
from viewer.settings import DEFAULT_AVATAR

HEADLESS_HINT = "render without a window: pghm render AVATAR.pt --out out.mp4"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="pghm-view", description="Live viewer of pghm avatars and priors.")
    parser.add_argument("avatar", nargs="?", type=Path, help=f"avatar or prior file (default: {DEFAULT_AVATAR})")
    parser.add_argument("--size", default="1280x800", help="window size WxH (default 1280x800)")
    parser.add_argument("--motion", help="motion to open: a .npz / .bvh file or a procedural name")
    parser.add_argument("--body-model-path", help="the SMPL-X model file, for SMPL-X avatars")
    return parser


def _fail(message: str) -> int:
    print(f"pghm-view: error: {message}", file=sys.stderr)
    return EXIT_USER_ERROR


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from pghm.cli.render import parse_size
    from viewer.window import display_problem

    try:
        size = parse_size(args.size)
    except argparse.ArgumentTypeError as error:
        return _fail(str(error))
    problem = display_problem()
    if problem:
        return _fail(f"{problem}; {HEADLESS_HINT}")
    path = args.avatar
    if path is None:
        path = DEFAULT_AVATAR
        if not path.is_file():
            return _fail(f"no avatar given and the default {path} is missing; pass an avatar file")

    from viewer.viewer import Viewer

    try:
        viewer = Viewer(path, window_size=size, body_model_path=args.body_model_path)
        if args.motion:
            viewer.open_motion(args.motion)
    except PghmError as error:
        return _fail(str(error).splitlines()[0])
    try:
        viewer.run()
    except DisplayError as error:
        return _fail(f"{error}; {HEADLESS_HINT}")
    except KeyboardInterrupt:
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
