"""``pghm bench``: named benchmarks that print a table and write JSON (and a plot).

    pghm bench splat [--gaussians N --resolution R --repeats K --threads T --out DIR --plot PNG]
    pghm bench stress [--fuzz-seconds S --report docs/stress.md --out DIR]

Benchmarks live in :data:`BENCHMARKS` (name -> function of the parsed arguments); add one
by adding an entry. ``splat`` sweeps the splatter's optional approximations on the body
scene and reports, per setting, median time and error against the exact image. ``stress``
runs the stress suite (tests/stress) and the loader fuzzer and writes their record as
docs/stress.md, with every case in docs/lab/stress-cases.md.

The measuring code is lab code, not the library's: it lives in the source checkout's
``benchmarks/`` (``splat_measure.py``, ``stress_report.py``), which a wheel does not install,
so ``pghm bench`` runs from a source checkout (elsewhere: one line saying so, exit status 2).
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

from pghm.cli.options import MAX_IMAGE_SIDE, Integer, Real
from pghm.errors import PghmError
from pghm.io.outputs import FIGURE_SUFFIXES, check_output

MAX_GAUSSIANS = 100_000_000
MAX_REPEATS = 10_000
MAX_THREADS = 1024
MAX_FUZZ_SECONDS = 86_400.0
"""Bounds of bench's numeric options (far above any run this machine finishes)."""

DEFAULT_OUT = Path("benchmarks") / "results"
"""Where JSON results go unless --out says otherwise."""

LAB = Path(__file__).resolve().parents[2] / "benchmarks"
"""The source checkout's benchmarks/ beside the package (absent from an installed wheel)."""


def _lab_module(name: str) -> ModuleType:
    """``benchmarks/<name>.py`` of the source checkout, loaded; a PghmError when it is not there."""
    path = LAB / f"{name}.py"
    if not path.is_file():
        raise PghmError(f"pghm bench runs from a source checkout: {path} not found (benchmarks/ is not installed)")
    spec = importlib.util.spec_from_file_location(f"_pghm_bench_{name}", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def _splat(args: argparse.Namespace) -> int:
    import torch

    measure = _lab_module("splat_measure")
    torch.set_num_threads(args.threads)
    output = check_output(args.out / "bench_splat_sweep.json")
    plot_path = args.plot if args.plot is not None else Path("docs") / "splat_pareto.png"
    plot = check_output(plot_path, option="--plot", suffixes=FIGURE_SUFFIXES)
    rows, front = measure.run_sweep(args.gaussians or 10_000, args.resolution or 256, args.repeats or 15, output, plot)
    print(measure.format_table(rows, ["setting", "forward_ms", "forward_backward_ms", "max_abs", "psnr"]))
    print(f"Pareto frontier (forward+backward time vs max abs error): {', '.join(front)}")
    print(f"wrote {output} and {plot}")
    return 0


def _stress(args: argparse.Namespace) -> int:
    report = _lab_module("stress_report")
    check_output(args.report, option="--report")
    check_output(report.cases_path(args.report), option="--report")
    return report.run_stress(args.report, args.out, args.fuzz_seconds)


BENCHMARKS: dict[str, Callable[[argparse.Namespace], int]] = {"splat": _splat, "stress": _stress}
"""Benchmark name -> function of the parsed arguments returning an exit status."""


def cmd_bench(args: argparse.Namespace) -> int:
    if args.name not in BENCHMARKS:
        raise PghmError(f"unknown benchmark '{args.name}', expected one of {', '.join(sorted(BENCHMARKS))}")
    return BENCHMARKS[args.name](args)


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("bench", help="run a named benchmark (prints a table, writes JSON and a plot)")
    parser.add_argument("name", metavar="NAME", help=f"benchmark to run: {', '.join(sorted(BENCHMARKS))}")
    parser.add_argument("--gaussians", type=Integer(1, MAX_GAUSSIANS), help="scene size N (splat: 10000)")
    parser.add_argument("--resolution", type=Integer(1, MAX_IMAGE_SIDE), help="image side in pixels (splat: 256)")
    parser.add_argument("--repeats", type=Integer(1, MAX_REPEATS), help="timed repeats per measurement (splat: 15)")
    parser.add_argument(
        "--threads",
        type=Integer(1, MAX_THREADS),
        default=2,
        help="torch threads (default 2, the target machine)",
    )
    parser.add_argument(
        "--out", type=Path, default=DEFAULT_OUT, help=f"directory for JSON results (default {DEFAULT_OUT})"
    )
    parser.add_argument("--plot", type=Path, help="PNG path for the plot (splat: docs/splat_pareto.png)")
    parser.add_argument(
        "--report",
        type=Path,
        default=Path("docs") / "stress.md",
        help="stress: the Markdown report (default docs/stress.md; every case goes to lab/stress-cases.md beside it)",
    )
    parser.add_argument(
        "--fuzz-seconds",
        type=Real(0.0, MAX_FUZZ_SECONDS),
        default=30.0,
        help="stress: time budget of the loader fuzzer (default 30)",
    )
    parser.set_defaults(func=cmd_bench)
