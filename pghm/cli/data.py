"""``pghm data``: validate subject folders and look at them.

    pghm data check DIR
    pghm data sheet DIR --out sheet.png [--mono SUBJECT_DIR] [--tile 256]

``check`` prints one line per problem and exits with status 2 when there is any.
"""

from __future__ import annotations

import argparse
import sys

from pghm.cli.options import Integer
from pghm.errors import EXIT_USER_ERROR
from pghm.io.outputs import PNG_SUFFIXES, check_output
from pghm.subject import check, count_images

MIN_TILE, MAX_TILE = 16, 2048
"""Contact-sheet tile sides accepted, in pixels."""


def cmd_data_check(args: argparse.Namespace) -> int:
    problems = check(args.dir)
    for problem in problems:
        print(problem)
    if problems:
        print(f"pghm: {len(problems)} problem(s) in {args.dir}", file=sys.stderr)
        return EXIT_USER_ERROR
    subjects, images = count_images(args.dir)
    print(f"{args.dir}: ok ({subjects} subject(s), {images} images)")
    return 0


def cmd_data_sheet(args: argparse.Namespace) -> int:
    from pghm.synth.sheet import contact_sheet

    check_output(args.out, inputs=[args.dir, args.mono], suffixes=PNG_SUFFIXES)
    sheet = contact_sheet(args.dir, args.out, tile=args.tile, mono_dir=args.mono)
    print(f"{args.out}: {sheet.shape[1]}x{sheet.shape[0]}")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("data", help="check and preview subject folders and datasets")
    commands = parser.add_subparsers(dest="data_command", metavar="ACTION")
    commands.required = True

    checker = commands.add_parser(
        "check",
        help="validate a subject folder or a dataset of them; one line per problem, exit status 2 if any",
    )
    checker.add_argument("dir", help="a subject folder or a dataset folder")
    checker.set_defaults(func=cmd_data_check)

    sheet = commands.add_parser("sheet", help="a contact sheet: every subject from the front and the back")
    sheet.add_argument("dir", help="a dataset (or subject) folder")
    sheet.add_argument("--out", required=True, help="the PNG to write")
    sheet.add_argument("--mono", help="a monocular subject (or dataset) to add as a strip of frames")
    sheet.add_argument(
        "--tile", type=Integer(MIN_TILE, MAX_TILE), default=256, help="tile size in pixels (default 256)"
    )
    sheet.set_defaults(func=cmd_data_sheet)
