"""``pghm bench stress``: run the stress suite and the loader fuzzer, and write their record as docs/stress.md.

The table is the suite's own record, never hand-written: every case in ``tests/stress``
reports what it tried, what the spec or the error contract expects, what it observed and
whether that holds (``stress_kit.check``), and the suite writes those rows as JSON when
``$PGHM_STRESS_RECORD`` names a file. This module runs the suite that way in a subprocess,
runs ``benchmarks/fuzz_loaders.py`` for a time budget, and renders both as Markdown.

It needs a source checkout (the suite and the fuzzer are not installed with the package)
and the ``test`` extra (pytest, hypothesis).
"""

from __future__ import annotations

import importlib.util
import json
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from pghm.errors import PghmError
from pghm.io.atomic import atomic_write_bytes

ROOT = Path(__file__).resolve().parent.parent
SUITE = ROOT / "tests" / "stress"
FUZZER = ROOT / "benchmarks" / "fuzz_loaders.py"
AREAS = (
    "splatter",
    "splatter properties",
    "model and skinning",
    "training",
    "bad avatar.pt",
    "bad motion file",
    "bad dataset",
    "found and fixed",
    "nothing lost",
    "adversarial: numeric options",
    "adversarial: outputs",
    "adversarial: file contents",
    "adversarial: sizes and memory",
    "adversarial: training on nothing",
    "adversarial: Ctrl-C",
    "adversarial: SIGTERM",
    "adversarial: misc",
    "adversarial: leak classes",
    "adversarial: synth",
    "adversarial: train-prior",
    "adversarial: bench",
    "adversarial: data sheet",
    "adversarial: motion make",
    "adversarial: concurrent writers",
)
"""Report sections, in this order (an area not listed here follows them)."""
AREA_NOTES = {
    "nothing lost": (
        "**How the kill tests choose their moment.** A kill must land where the test says, on any "
        "machine at any load, not at a moment the test hopes to catch by polling (a fast idle "
        "machine finishes a small save between two polls). The atomic writer (`pghm/io/atomic.py`) "
        "calls a fault-injection point (`pghm/_fault_injection.py`), off unless its environment "
        "variables are set: with "
        "`PGHM_TEST_PAUSE_SAVE=POINT:N:NAME` and `PGHM_TEST_PAUSE_MARKER=PATH`, the N-th save to a file "
        "named NAME that reaches POINT creates PATH and sleeps. The points are the three states a save "
        "can be interrupted in: `created` (empty temporary file), `written` (complete temporary file, "
        "fsynced, not renamed) and `renamed` (the save is done). The test starts the child with the "
        "point it wants, waits for the marker and sends SIGKILL, so each kill lands in that state on "
        "every run; the rows below name the save and the point, and the checkpoint step the kill "
        "implies is asserted exactly."
    ),
    "adversarial: leak classes": (
        "**One mechanism per class.** Physical quantities are checked against what the physics allows "
        "where they are read: `--focal` against a field of view of 1 to 179 degrees on the frames' size, "
        "body shapes against their body's domain (Anny's phenotypes in [0, 1]) in avatar files and "
        "subjects alike, synth configs field by field; nothing is clamped. No output lies inside an input "
        "folder or holds an input (`pghm.io.outputs.check_output`, for every command). Unreadable inputs are "
        "refused, never left out: a frame folder, or a subject's images, with a broken link, a link loop or "
        "a corrupt image stop the run before any output exists, every such file named in one line, as a "
        "corrupt video does; only pixels damaged behind a valid header, which a training run finds when it "
        "decodes them, are left out with a warning naming the frame (`pghm data check` decodes every image "
        "and lists them beforehand). A subject "
        "has one validator (`pghm.subject.check_subject`): `pghm data check` lists what it finds, "
        "and every reader (fit, eval, train-prior, data sheet, capture --polish) opens a subject through it "
        "and stops at its first line; each consumer checks the subject's body against the avatar's. "
        "Cheap refusals come first: an output's name, size and checkpoint are asked before any model loads."
    ),
    "adversarial: SIGTERM": (
        "SIGTERM (a shutdown, a job scheduler) is raised at the CLI entry (`pghm`, `pghm-view`) as a "
        "`Terminated`, a kind of KeyboardInterrupt, so it unwinds exactly as Ctrl-C does: staged outputs "
        "removed, a training run's checkpoint saved for `--resume`; then one line `pghm: terminated` and "
        "exit status 143 (128 + 15). A second SIGTERM during that clean-up is ignored."
    ),
}
"""A paragraph printed under a section's heading, before its table."""
_PATH = re.compile(r"(?<![\w.])/(?:[^\s/:'\"(),|]+/)+(?=[^\s/:'\"(),|]+)")


def _short_paths(text: str) -> str:
    """Absolute paths cut to their last folder and file: temporary directories say nothing."""

    def shorten(match: re.Match) -> str:
        parts = match.group(0).rstrip("/").split("/")
        return ("…/" + parts[-1] + "/") if len(parts) > 2 else match.group(0)

    return _PATH.sub(shorten, text)


def without_paths(value: object) -> object:
    """``value`` (JSON: dicts, lists, strings, numbers) with every string's absolute paths shortened,
    so the shipped record names no directory of the machine that ran the suite."""
    if isinstance(value, str):
        return _short_paths(value)
    if isinstance(value, list):
        return [without_paths(item) for item in value]
    if isinstance(value, dict):
        return {key: without_paths(item) for key, item in value.items()}
    return value


def _cell(text: object) -> str:
    return _short_paths(str(text)).replace("|", "\\|").replace("\n", " ")


def format_report(rows: list[dict], fuzz: dict | None, suite_status: int, seconds: float, fuzz_seconds: float) -> str:
    """The Markdown of docs/stress.md from the suite's rows and the fuzzer's JSON."""
    passed = sum(row["passed"] for row in rows)
    lines = [
        "# Stress and bad-input report",
        "",
        f"Written by `pghm bench stress` ({platform.machine()}, "
        f"Python {platform.python_version()}, load average {os.getloadavg()[0]:.1f}); do not edit: rerun it. "
        "Each row is one case of the stress suite (`tests/stress`), recorded by the test that ran it: "
        "the input tried, what the spec or the error contract (pghm/errors.py: one line, exit status 2) "
        "expects, and what happened.",
        "",
        f"**{len(rows)} cases, {passed} pass, {len(rows) - passed} fail**; the suite "
        f"{'passed' if suite_status == 0 else f'FAILED (pytest exit status {suite_status})'} in {seconds:.0f} s.",
        "",
    ]
    areas = [a for a in AREAS if any(r["area"] == a for r in rows)]
    areas += sorted({r["area"] for r in rows} - set(areas))
    for area in areas:
        lines += [f"## {area[0].upper()}{area[1:]}", ""]
        if area in AREA_NOTES:
            lines += [AREA_NOTES[area], ""]
        lines += ["| Case | Expected | Observed | Result |", "|---|---|---|---|"]
        for row in (r for r in rows if r["area"] == area):
            lines.append(
                f"| {_cell(row['case'])} | {_cell(row['expected'])} | {_cell(row['observed'])} | "
                f"{'pass' if row['passed'] else '**FAIL**'} |"
            )
        lines.append("")
    lines += [f"## Fuzzing the loaders ({fuzz_seconds:g} s)", ""]
    if fuzz is None:
        lines += ["The fuzzer did not produce results.", ""]
        return "\n".join(lines)
    lines += [
        "`benchmarks/fuzz_loaders.py` mutates valid BVH clips, motion files, avatar files, subject "
        "folders and videos (structure-aware edits and raw byte damage) and runs each loader on them; any exception "
        "other than `PghmError` is a finding. Seed "
        f"{fuzz['seed']}; the counts depend on the machine's speed.",
        "",
        "| Target | Cases | Loaded | Rejected (PghmError) | Error types | Unexpected |",
        "|---|---|---|---|---|---|",
    ]
    for row in fuzz["rows"]:
        lines.append(
            f"| {row['target']} | {row['cases']} | {row['loaded']} | {row['rejected (PghmError)']} | "
            f"{_cell(row['error types'])} | {row['unexpected']} |"
        )
    lines.append("")
    if fuzz["findings"]:
        lines += ["Unexpected exceptions (bugs):", ""]
        lines += [
            f"- {f['target']}: {_cell(f['exception'])} x{f['count']}: {_cell(f['message'])}" for f in fuzz["findings"]
        ]
    else:
        lines.append("No unexpected exception: every rejected input raised one `PghmError` line.")
    lines.append("")
    return "\n".join(lines)


def run_stress(report: Path, out: Path, fuzz_seconds: float) -> int:
    """Run the suite and the fuzzer, write ``report`` (Markdown) and ``out``/stress.json; 0 when all pass."""
    if not SUITE.is_dir() or not FUZZER.is_file():
        raise PghmError(f"pghm bench stress runs {SUITE} and {FUZZER} of a source checkout; they are not here")
    for module in ("pytest", "hypothesis"):
        if importlib.util.find_spec(module) is None:
            raise PghmError(f"pghm bench stress needs {module}: pip install -e '.[test]'")
    if not fuzz_seconds > 0:
        raise PghmError(f"--fuzz-seconds must be positive, got {fuzz_seconds}")
    with tempfile.TemporaryDirectory(prefix="pghm-stress-") as scratch:
        record, fuzz_json = Path(scratch) / "rows.json", Path(scratch) / "fuzz.json"
        started = time.perf_counter()
        suite = subprocess.run(
            [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(SUITE)],
            cwd=ROOT,
            env={**os.environ, "PGHM_STRESS_RECORD": str(record)},
        )
        seconds = time.perf_counter() - started
        fuzzer = subprocess.run(
            [sys.executable, str(FUZZER), "--budget", str(fuzz_seconds), "--json", str(fuzz_json)],
            cwd=ROOT,
        )
        rows = json.loads(record.read_text()) if record.is_file() else []
        fuzz = json.loads(fuzz_json.read_text()) if fuzz_json.is_file() else None
    if not rows:
        raise PghmError("the stress suite recorded no cases (did it start?); see the pytest output above")
    atomic_write_bytes(report, format_report(rows, fuzz, suite.returncode, seconds, fuzz_seconds).encode())
    atomic_write_bytes(out / "stress.json", json.dumps(without_paths({"rows": rows, "fuzz": fuzz}), indent=1).encode())
    failed = [row for row in rows if not row["passed"]]
    print(
        f"stress: {len(rows)} cases, {len(rows) - len(failed)} pass, {len(failed)} fail; "
        f"fuzzer: {'no' if fuzz and not fuzz['findings'] else 'SOME'} unexpected exceptions"
    )
    print(f"wrote {report} and {out / 'stress.json'}")
    return 0 if suite.returncode == 0 and fuzzer.returncode == 0 and not failed else 1
