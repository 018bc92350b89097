"""Timing and reporting shared by the benchmark scripts.

Benchmarks print a table and write JSON (benchmarks/results/) and PNG (docs/); they are
never timed tests. Times are medians over repeats after warm-up, on the thread count the
target machine has (2), with ratios against a baseline measured in the same run.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
DOCS = ROOT / "docs"
THREADS = 2


def setup_threads(threads: int = THREADS) -> None:
    torch.set_num_threads(threads)


def median_ms(fn: Callable[[], object], repeat: int = 20, warmup: int = 3) -> float:
    """Median wall time of ``fn()`` in milliseconds."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append((time.perf_counter() - start) * 1e3)
    return statistics.median(times)


def machine() -> dict:
    return {
        "python": platform.python_version(),
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
        "cpu": platform.processor() or platform.machine(),
    }


def load_average() -> float:
    """The 1-minute load average: a time measured while other jobs share the 2 cores is
    slower, and the reader of a table needs to know."""
    return os.getloadavg()[0]


BYTES_PER_GB = 1e9
KB = 1024
"""ru_maxrss is in kilobytes on Linux."""


def timed_child(command: list[str], log: Path) -> tuple[float, float]:
    """Run ``command`` with its output in ``log``: its wall seconds and peak resident GB.

    ``os.wait4`` gives the child's resource usage: ru_maxrss (kB) is the largest resident set
    of the child and the processes it waited for. Raises RuntimeError with the log's tail if
    the child fails.
    """
    started = time.perf_counter()
    with open(log, "w") as sink:
        process = subprocess.Popen(command, stdout=sink, stderr=sink)
        _, status, usage = os.wait4(process.pid, 0)
    seconds = time.perf_counter() - started
    code = os.waitstatus_to_exitcode(status)
    if code != 0:
        raise RuntimeError(f"{' '.join(command[2:5])} failed (status {code}):\n{log.read_text()[-1500:]}")
    return seconds, usage.ru_maxrss * KB / BYTES_PER_GB


def print_table(rows: list[dict], columns: list[str] | None = None) -> None:
    columns = columns or list(rows[0])
    cells = [[_fmt(row.get(c, "")) for c in columns] for row in rows]
    widths = [max(len(c), *(len(r[i]) for r in cells)) for i, c in enumerate(columns)]
    print("  ".join(c.ljust(w) for c, w in zip(columns, widths)))
    print("  ".join("-" * w for w in widths))
    for row in cells:
        print("  ".join(v.ljust(w) for v, w in zip(row, widths)))


def write_json(name: str, payload: dict) -> Path:
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / f"{name}.json"
    path.write_text(json.dumps({"machine": machine(), **payload}, indent=2))
    print(f"wrote {path.relative_to(ROOT)}")
    return path


def _fmt(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.3g}" if abs(value) < 1000 else f"{value:.0f}"
    return str(value)
