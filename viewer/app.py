"""``pghm-view [avatar.pt]``: open the live viewer.

Exit status 2 with one line on stderr when there is no display (pointing to ``pghm
render``), when the avatar file is missing or bad, or when no OpenGL 3.3 window can be made;
130 after Ctrl-C, also while the viewer's modules load. ``PGHM_DEBUG=1`` shows tracebacks
(the error contract of :mod:`pghm.cli.main`, shared through :func:`pghm.cli.main.guarded`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from pghm.cli.main import run_command
from pghm.cli.options import OneLineParser, Size
from pghm.errors import DisplayError, PghmError

HEADLESS_HINT = "render without a window: pghm render AVATAR.pt --out out.mp4"
DEFAULT_WINDOW = (1280, 800)


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(prog="pghm-view", description="Live viewer of pghm avatars and priors.")
    parser.add_argument(
        "avatar", nargs="?", type=Path, help="avatar or prior file (default: assets/real_avatar.pt, a real person)"
    )
    parser.add_argument("--size", type=Size(), default=DEFAULT_WINDOW, help="window size WxH (default 1280x800)")
    parser.add_argument("--motion", help="motion to open: a .npz / .bvh file, a procedural name or a subject folder")
    parser.add_argument("--body-model-path", help="the SMPL-X model file, for SMPL-X avatars")
    return parser


def _open_and_run(args: argparse.Namespace) -> int:
    from viewer.settings import DEFAULT_AVATAR
    from viewer.window import display_problem

    problem = display_problem()
    if problem:
        raise DisplayError(f"{problem}; {HEADLESS_HINT}")
    path = args.avatar
    if path is None:
        path = DEFAULT_AVATAR
        if not path.is_file():
            raise PghmError(f"no avatar given and the default {path} is missing; pass an avatar file")

    from viewer.viewer import Viewer

    viewer = Viewer(path, window_size=args.size, body_model_path=args.body_model_path)
    if args.motion:
        viewer.open_motion(args.motion)
    try:
        viewer.run()
    except DisplayError as error:
        raise DisplayError(f"{error}; {HEADLESS_HINT}") from None
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_command("pghm-view", build_parser, _open_and_run, argv)


if __name__ == "__main__":
    sys.exit(main())
