"""Shared argparse pieces: every numeric option has a declared range, and a bad one is one line.

**Numbers.** A numeric option's ``type`` is an :class:`Integer` or a :class:`Real`, never bare
``int`` or ``float``: the value must parse, be finite, and lie in the declared range, else
argparse stops with ``pghm: error: argument --fps: must be a number in [0.001, 1000], got
'1e300'``. ``tests/stress/test_adversarial.py`` walks every parser, fails on a bare ``int`` or
``float``, and feeds each declared range its out-of-range and non-finite values, so a command
added tomorrow is held to the same promise by adding nothing but its options.

**Errors.** :class:`OneLineParser` replaces argparse's usage dump (usage, then the error, two
lines or more) by one line, ``<tool>: error: <message> (see <prog> --help)``, and keeps
argparse's exit status 2. Sub-parsers inherit the class (``add_subparsers`` uses the parent's).
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass

from pghm.errors import EXIT_USER_ERROR

MAX_SEED = 2**32 - 1
"""Seeds are unsigned 32-bit (numpy's and torch's generators accept them)."""
MAX_STEPS = 10_000_000
"""Most optimisation steps of one stage: years on this machine, yet a bounded loop."""
MAX_INDEX = 1_000_000
"""Largest identity or frame index an option accepts (the loaders bound banks and clips below it)."""
MAX_IMAGE_SIDE = 32_768
"""Largest image side any option accepts; the GL renderer refuses beyond its context's own limit
(16,384 on llvmpipe) and the CPU splatter beyond a pixel budget (pghm.render.job)."""


class OneLineParser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line on stderr and exit status 2 (no usage dump)."""

    def error(self, message: str) -> None:  # type: ignore[override]
        tool = self.prog.split()[0]
        line = " ".join(message.split())
        sys.stderr.write(f"{tool}: error: {line} (see {self.prog} --help)\n")
        sys.exit(EXIT_USER_ERROR)


def _bound(value: float | None, unbounded: str) -> str:
    if value is None:
        return unbounded
    return str(value) if isinstance(value, int) else f"{value:g}"


def _range_text(low: float | None, high: float | None, open_low: bool) -> str:
    return f"{'(' if open_low else '['}{_bound(low, '-inf')}, {_bound(high, 'inf')}]"


@dataclass(frozen=True)
class Integer:
    """An argparse ``type``: a whole number in [low, high] (None: unbounded on that side)."""

    low: int | None
    high: int | None

    @property
    def range(self) -> str:
        return _range_text(self.low, self.high, False)

    def __call__(self, text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be a whole number in {self.range}, got {text!r}") from None
        if (self.low is not None and value < self.low) or (self.high is not None and value > self.high):
            raise argparse.ArgumentTypeError(f"must be a whole number in {self.range}, got {text!r}")
        return value


@dataclass(frozen=True)
class Real:
    """An argparse ``type``: a finite number in [low, high] ((low, high] when ``open_low``)."""

    low: float | None
    high: float | None
    open_low: bool = False

    @property
    def range(self) -> str:
        return _range_text(self.low, self.high, self.open_low)

    def __call__(self, text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        too_low = self.low is not None and (value <= self.low if self.open_low else value < self.low)
        too_high = self.high is not None and value > self.high
        if not math.isfinite(value) or too_low or too_high:
            raise argparse.ArgumentTypeError(f"must be a finite number in {self.range}, got {text!r}")
        return value


@dataclass(frozen=True)
class Size:
    """An argparse ``type``: 'WxH' with both sides whole numbers in [1, max_side]."""

    max_side: int = MAX_IMAGE_SIDE

    def __call__(self, text: str) -> tuple[int, int]:
        side = Integer(1, self.max_side)
        parts = text.lower().split("x")
        try:
            if len(parts) != 2:
                raise argparse.ArgumentTypeError("")
            width, height = (side(part) for part in parts)
        except argparse.ArgumentTypeError:
            raise argparse.ArgumentTypeError(
                f"must look like 640x480, each side a whole number in {side.range}, got {text!r}"
            ) from None
        return width, height


def add_device_option(parser: argparse.ArgumentParser) -> None:
    """``--device {auto,cpu,cuda}``, resolved by :func:`pghm.device.resolve_device` when the command runs."""
    from pghm.device import DEVICE_CHOICES

    parser.add_argument(
        "--device",
        choices=DEVICE_CHOICES,
        default="auto",
        help="where to compute: cpu, cuda (rendering through gsplat, pip install 'pghm[gpu]') "
        "or auto (default: cuda when available)",
    )


def rendering_device(name: str):
    """:func:`pghm.device.resolve_device` of ``name``, and on CUDA gsplat checked before any work:
    a missing extra is one line at the start, not after the set-up."""
    from pghm.device import resolve_device

    device = resolve_device(name)
    if device.type == "cuda":
        from pghm.splat.gsplat_backend import load_gsplat

        load_gsplat()
    return device


SEED = Integer(0, MAX_SEED)
STEPS = Integer(0, MAX_STEPS)
POSITIVE_STEPS = Integer(1, MAX_STEPS)
INDEX = Integer(0, MAX_INDEX)
