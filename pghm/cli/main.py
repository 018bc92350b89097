"""``pghm``: one entry point, one subcommand per job.

Each subcommand lives in its own module under :mod:`pghm.cli` and exposes
``register(subparsers)``, which adds its parser and sets ``func`` to its handler, named
``cmd_<command>`` (``cmd_<command>_<subcommand>`` for nested ones: ``cmd_motion_import``),
taking the parsed arguments and returning the exit status. The subcommands are thin: they
parse, call a library function, print.

**Threads.** :func:`main` applies :mod:`pghm.cli.threads` before any subcommand imports torch:
waiting OpenMP threads sleep, and torch takes one thread per core other processes leave free.

**Errors.** :func:`main` is the one place a failure becomes what the user sees, for every
subcommand, including while the subcommand modules (and torch) are imported: a
:class:`PghmError` or an ``OSError`` (permission denied, disk full, a folder where a file
was expected) is one line ``pghm: error: ...`` and exit status 2, running out of memory
likewise, Ctrl-C is ``pghm: interrupted`` and exit status 130. SIGTERM (what a system shutdown
or a job scheduler sends) unwinds the same way, as a :class:`Terminated` raised where the program
is: outputs being built are discarded and a training run saves its checkpoint, as on Ctrl-C;
then ``pghm: terminated`` and exit status 143. ``pghm --debug ...`` or
``PGHM_DEBUG=1`` re-raises instead, to see the traceback. Anything else is a bug and keeps
its traceback.
"""

from __future__ import annotations

import argparse
import errno
import importlib
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from pghm.cli.threads import set_threads, set_wait_policy
from pghm.errors import EXIT_USER_ERROR, PghmError

SUBCOMMAND_MODULES = ("synth", "capture", "data", "motion", "train", "export", "bench", "render")
"""Modules under ``pghm.cli`` that register a subcommand, in ``pghm --help`` order."""
EXIT_INTERRUPTED = 130
"""Exit status after Ctrl-C (128 + SIGINT), as shells report it."""
EXIT_TERMINATED = 128 + signal.SIGTERM
"""Exit status after SIGTERM (143), as shells report it."""
DEBUG_VARIABLE = "PGHM_DEBUG"
"""Set to 1 to see tracebacks instead of one-line errors (as ``--debug`` does)."""
OUT_OF_MEMORY_TEXT = ("can't allocate memory", "out of memory", "not enough memory")
"""How torch's allocators say a RuntimeError is an allocation failure."""


def build_parser() -> argparse.ArgumentParser:
    from pghm._fault_injection import interrupt_point
    from pghm.cli.options import OneLineParser

    parser = OneLineParser(
        prog="pghm",
        description="Parametric Gaussian Human Model: train, personalise, render and inspect avatars.",
    )
    parser.add_argument(
        "--debug", action="store_true", help=f"show tracebacks instead of one-line errors (or {DEBUG_VARIABLE}=1)"
    )
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    subparsers.required = True
    interrupt_point("startup")
    for name in SUBCOMMAND_MODULES:
        importlib.import_module(f"pghm.cli.{name}").register(subparsers)
    return parser


def _os_error_line(error: OSError) -> str:
    """'path: reason' of an OSError, in one line."""
    reason = error.strerror or errno.errorcode.get(error.errno or 0) or str(error) or type(error).__name__
    names = [str(name) for name in (error.filename, error.filename2) if name is not None]
    return " ".join(f"{': '.join([*names, reason])}".split())


def user_error_line(error: BaseException) -> str | None:
    """The one line a user sees for ``error``, or None when it is a bug (keep the traceback)."""
    if isinstance(error, PghmError):
        return " ".join(str(error).split())
    if isinstance(error, OSError):
        return _os_error_line(error)
    if isinstance(error, MemoryError) or (
        isinstance(error, RuntimeError) and any(text in str(error) for text in OUT_OF_MEMORY_TEXT)
    ):
        return "out of memory; ask for less (a smaller --size, fewer --images) or free memory"
    return None


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the program is: a KeyboardInterrupt, so that everything that cleans up
    after Ctrl-C (staged outputs, pending files, a training checkpoint) does so after SIGTERM too."""


def _raise_terminated(signum: int, frame) -> None:
    signal.signal(signal.SIGTERM, signal.SIG_IGN)  # a second SIGTERM must not cut the clean-up short
    raise Terminated


@contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """SIGTERM raises :class:`Terminated` inside the block (the main thread only can set handlers)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def guarded(tool: str, work, debug: bool) -> int:
    """Run ``work()`` (returns an exit status) with the error contract of the module doc."""
    try:
        with sigterm_as_interrupt():
            return int(work() or 0)
    except KeyboardInterrupt as stop:
        if debug:
            raise
        terminated = isinstance(stop, Terminated)
        print(f"{tool}: {'terminated' if terminated else 'interrupted'}", file=sys.stderr)
        return EXIT_TERMINATED if terminated else EXIT_INTERRUPTED
    except Exception as error:  # noqa: BLE001 - sorted into user errors and bugs below
        line = user_error_line(error)
        if debug or line is None:
            raise
        print(f"{tool}: error: {line}", file=sys.stderr)
        return EXIT_USER_ERROR


def debug_requested(argv: list[str]) -> bool:
    """``--debug`` before the subcommand, or PGHM_DEBUG=1 (known before the parser is built)."""
    return os.environ.get(DEBUG_VARIABLE, "") not in ("", "0") or "--debug" in argv


def run(func, args: argparse.Namespace) -> int:
    """Call a subcommand under the error contract (for callers holding parsed arguments)."""
    return guarded("pghm", lambda: func(args), getattr(args, "debug", False))


def run_command(
    tool: str,
    build: Callable[[], argparse.ArgumentParser],
    execute: Callable[[argparse.Namespace], int],
    argv: list[str] | None,
) -> int:
    """Parse ``argv`` (default: the process's) with ``build()``'s parser and ``execute`` the result,
    all under :func:`guarded`: the entry point of every command (``pghm``, ``pghm-view``)."""
    argv = sys.argv[1:] if argv is None else [str(a) for a in argv]

    def work() -> int:
        try:
            args = build().parse_args(argv)
        except SystemExit as stop:  # --help, or a bad option (its one line already printed)
            return stop.code if isinstance(stop.code, int) else EXIT_USER_ERROR
        return execute(args)

    return guarded(tool, work, debug_requested(argv))


def _execute(args: argparse.Namespace) -> int:
    set_threads()
    return args.func(args)


def main(argv: list[str] | None = None) -> int:
    set_wait_policy()  # before the subcommands import torch
    return run_command("pghm", build_parser, _execute, argv)


if __name__ == "__main__":
    sys.exit(main())
