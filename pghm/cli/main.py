"""``pghm``: one entry point, one subcommand per job.

Each subcommand lives in its own module under :mod:`pghm.cli` and exposes
``register(subparsers)``, which adds its parser and sets ``func`` to a function taking the
parsed arguments. The subcommands are thin: they parse, call a library function, print.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from pghm.errors import EXIT_USER_ERROR, PghmError

SUBCOMMAND_MODULES = ("synth", "capture", "data", "motion", "train", "export", "bench", "render")
"""Modules under ``pghm.cli`` that register a subcommand, in ``pghm --help`` order."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pghm",
        description="Parametric Gaussian Human Model: train, personalise, render and inspect avatars.",
    )
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    subparsers.required = True
    for name in SUBCOMMAND_MODULES:
        importlib.import_module(f"pghm.cli.{name}").register(subparsers)
    return parser


def run(func, args: argparse.Namespace) -> int:
    """Call a subcommand; a :class:`PghmError` becomes one line on stderr and exit status 2."""
    try:
        result = func(args)
    except PghmError as error:
        print(f"pghm: error: {error}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        print("pghm: interrupted", file=sys.stderr)
        return 130
    return int(result or 0)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run(args.func, args)


if __name__ == "__main__":
    sys.exit(main())
