"""``pghm bench stress``: run the stress suite and the loader fuzzer, and write their record as docs/stress.md
(the guide: what each area attacks, its totals, the contract, the fuzzer) and docs/lab/stress-cases.md (every case).

The tables are the suite's own record, never hand-written: every case in ``tests/stress``
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
AREAS = {
    "splatter": "extreme scales, depths, focals and image sizes, NaN and inf inputs, invisible Gaussians",
    "splatter properties": "invariants: order, occlusion, translation, alpha in [0, 1]",
    "model and skinning": "huge and wrapped rotations, scaled latents, degenerate normals, float32 against float64",
    "training": "overflowing learning rates, NaN losses, non-finite Gaussians and updates",
    "bad avatar.pt": "truncated, random, mis-versioned, NaN and code-running avatar files, per command",
    "bad motion file": "broken BVH and motion .npz files, per command",
    "bad dataset": "missing and mis-sized images, NaN cameras, per command",
    "found and fixed": "inputs that once escaped the error contract, kept as regressions",
    "nothing lost": "SIGKILL at each state of every atomic save, and resume after it",
    "adversarial: numeric options": "every numeric option out of range, NaN, inf and not a number",
    "adversarial: outputs": "every output unwritable, a folder, /dev/full, an input or inside one",
    "adversarial: file contents": "valid files holding absurd values (rotations of 1e20, empty files)",
    "adversarial: sizes and memory": "sizes past the GL limit, the CPU's memory and the data set",
    "adversarial: training on nothing": "runs where no step could learn anything",
    "adversarial: Ctrl-C": "SIGINT at set points of every long command",
    "adversarial: SIGTERM": "SIGTERM at the same points, and resume after it",
    "adversarial: misc": "one kind of file passed where another is expected",
    "adversarial: leak classes": "one check per class: physical ranges, outputs in inputs, unreadable inputs",
    "adversarial: synth": "synth configs: bad JSON, unknown fields, non-finite and absurd values",
    "adversarial: train-prior": "data sets listing missing or incomplete subjects, --resume without a checkpoint",
    "adversarial: bench": "unknown benchmarks and outputs refused before the work",
    "adversarial: data sheet": "folders that are neither a subject nor a data set, wrong output formats",
    "adversarial: motion make": "unknown names and missing body models",
    "adversarial: concurrent writers": "two writers of one output at once",
    "adversarial: interrupted phases": "SIGINT or SIGTERM in each phase of a fit after a stage, then --resume",
    "adversarial: full disk": "every output on a full filesystem: one line naming it, all outputs or none",
    "adversarial: late refusals": "what can be refused before the work: options, image sizes, identities, pose tracks",
}
"""Report sections, in this order (an area not listed here follows them), and what each attacks."""
CASES = Path("lab") / "stress-cases.md"
"""The per-case listing, beside the report (relative to the report's folder)."""
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
        "every run; the case listing names the save and the point, and the checkpoint step the kill "
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


def _areas(rows: list[dict]) -> list[str]:
    """The areas the rows fall in, in report order."""
    areas = [area for area in AREAS if any(row["area"] == area for row in rows)]
    return areas + sorted({row["area"] for row in rows} - set(areas))


def _title(area: str) -> str:
    return f"{area[0].upper()}{area[1:]}"


def _totals(rows: list[dict], suite_status: int, seconds: float) -> str:
    passed = sum(row["passed"] for row in rows)
    return (
        f"**{len(rows)} cases, {passed} pass, {len(rows) - passed} fail**; the suite "
        f"{'passed' if suite_status == 0 else f'FAILED (pytest exit status {suite_status})'} in {seconds:.0f} s."
    )


def _area_table(rows: list[dict]) -> list[str]:
    """One line per area: what it attacks, its cases, passes and failures, linked to its listing."""
    lines = ["| Area | What is attacked | Cases | Pass | Fail |", "|---|---|---|---|---|"]
    for area in _areas(rows):
        mine = [row for row in rows if row["area"] == area]
        passed = sum(row["passed"] for row in mine)
        failed = len(mine) - passed
        anchor = re.sub(r"[^\w\- ]", "", _title(area).lower()).replace(" ", "-")
        lines.append(
            f"| [{_title(area)}]({CASES.as_posix()}#{anchor}) | {AREAS.get(area, '')} | {len(mine)} | {passed} | "
            f"{failed if not failed else f'**{failed}**'} |"
        )
    return lines + [""]


def _fuzz_section(fuzz: dict | None, fuzz_seconds: float) -> list[str]:
    lines = [f"## Fuzzing the loaders ({fuzz_seconds:g} s)", ""]
    if fuzz is None:
        return lines + ["The fuzzer did not produce results.", ""]
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
    return lines + [""]


def format_report(rows: list[dict], fuzz: dict | None, suite_status: int, seconds: float, fuzz_seconds: float) -> str:
    """The guide (docs/stress.md): what each area attacks and its totals, the contract, the fuzzer.

    Its length grows with the areas, not the cases; every case is in :func:`format_cases`.
    """
    lines = [
        "# Stress and bad-input report",
        "",
        f"Written by `pghm bench stress` ({platform.machine()}, "
        f"Python {platform.python_version()}, load average {os.getloadavg()[0]:.1f}); do not edit: rerun it. "
        "The stress suite (`tests/stress`) attacks each part of pghm with extreme values and bad inputs; every "
        "case records the input tried, what the spec or the error contract (pghm/errors.py: one line naming "
        "the file or value at fault, exit status 2, no output left behind) expects, and what happened. "
        f"Every case, with those three, is listed in [{CASES.name}]({CASES.as_posix()}).",
        "",
        _totals(rows, suite_status, seconds),
        "",
        "## What is attacked",
        "",
        *_area_table(rows),
        "## The contract",
        "",
    ]
    for area in (area for area in _areas(rows) if area in AREA_NOTES):
        lines += [f"### {_title(area)}", "", AREA_NOTES[area], ""]
    return "\n".join(lines + _fuzz_section(fuzz, fuzz_seconds))


def format_cases(rows: list[dict], report_name: str, suite_status: int, seconds: float) -> str:
    """The per-case listing (docs/lab/stress-cases.md): one table per area, one row per case."""
    back = Path(*[".."] * (len(CASES.parts) - 1), report_name).as_posix()
    lines = [
        "# Stress cases",
        "",
        f"Written by `pghm bench stress` with [{report_name}]({back}), which says what each area attacks; "
        "do not edit: rerun it. One row per case of the stress suite (`tests/stress`), recorded by the test "
        "that ran it.",
        "",
        _totals(rows, suite_status, seconds),
        "",
    ]
    for area in _areas(rows):
        lines += [f"## {_title(area)}", "", "| Case | Expected | Observed | Result |", "|---|---|---|---|"]
        for row in (r for r in rows if r["area"] == area):
            lines.append(
                f"| {_cell(row['case'])} | {_cell(row['expected'])} | {_cell(row['observed'])} | "
                f"{'pass' if row['passed'] else '**FAIL**'} |"
            )
        lines.append("")
    return "\n".join(lines)


def cases_path(report: Path) -> Path:
    """Where the per-case listing of ``report`` goes."""
    return report.parent / CASES


def run_stress(report: Path, out: Path, fuzz_seconds: float) -> int:
    """Run the suite and the fuzzer, write ``report`` and its case listing (Markdown) and ``out``/stress.json;
    0 when all pass."""
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
    cases = cases_path(report)
    cases.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(cases, format_cases(rows, report.name, suite.returncode, seconds).encode())
    atomic_write_bytes(out / "stress.json", json.dumps(without_paths({"rows": rows, "fuzz": fuzz}), indent=1).encode())
    failed = [row for row in rows if not row["passed"]]
    print(
        f"stress: {len(rows)} cases, {len(rows) - len(failed)} pass, {len(failed)} fail; "
        f"fuzzer: {'no' if fuzz and not fuzz['findings'] else 'SOME'} unexpected exceptions"
    )
    print(f"wrote {report}, {cases} and {out / 'stress.json'}")
    return 0 if suite.returncode == 0 and fuzzer.returncode == 0 and not failed else 1
