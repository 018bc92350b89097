"""Synthetic data generation speed, and the contact sheet in docs/.

Target: the ``prior`` preset (16 identities x 8 views x 30 frames at 256 x 256, 3,840
images) in at most 3 minutes on 2 cores. Also times the ``mono`` preset, validates both
with the checker, and writes docs/synth_contact_sheet.png (every prior subject from the
front and the back, and a strip of the monocular walk). Prints the machine's load average
before and after, since other jobs on the 2 cores slow it down, and exits with status 1
when the verdict is FAIL, so a script or CI step running it notices.

    python benchmarks/bench_synth.py [--keep DIR]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

from common import DOCS, load_average, print_table, write_json

from pghm.subject import check
from pghm.synth import contact_sheet, generate, load_config

TARGET_S = 180.0
SEED = 0
MONO_SEED = 1
"""Another seed for the monocular set, so the sheet's strip shows another person."""
EXIT_FAIL = 1
"""Exit status when the prior preset misses the target or fails the checker."""


def _size_mb(folder: Path) -> float:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file()) / 1e6


def run(preset: str, seed: int, out: Path) -> dict:
    config = load_config(preset)
    report = generate(config, seed, out, workers=2, progress=True)
    started = time.perf_counter()
    problems = check(out)
    check_s = time.perf_counter() - started
    return {
        "preset": preset,
        "seed": seed,
        "subjects": len(report.subjects),
        "images": report.images,
        "size": f"{config.width}x{config.height}",
        "seconds": round(report.seconds, 1),
        "images_per_s": round(report.images / report.seconds, 1),
        "check_s": round(check_s, 1),
        "problems": len(problems),
        "disk_mb": round(_size_mb(out), 1),
        "target_s": TARGET_S if preset == "prior" else None,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--keep", help="write the datasets here instead of a temporary folder")
    args = parser.parse_args()
    load_before = load_average()
    with tempfile.TemporaryDirectory() as scratch:
        root = Path(args.keep) if args.keep else Path(scratch)
        rows = [run("prior", SEED, root / "prior"), run("mono", MONO_SEED, root / "mono")]
        contact_sheet(root / "prior", DOCS / "synth_contact_sheet.png", tile=256, mono_dir=root / "mono")
    load_after = load_average()
    print_table(rows)
    print(f"load average (1 min): {load_before:.2f} before, {load_after:.2f} after")
    prior = rows[0]
    verdict = "PASS" if prior["seconds"] <= TARGET_S and prior["problems"] == 0 else "FAIL"
    print(f"prior preset: {prior['seconds']} s for {prior['images']} images (target <= {TARGET_S:.0f} s): {verdict}")
    print(f"wrote {DOCS / 'synth_contact_sheet.png'}")
    write_json("synth", {"rows": rows, "verdict": verdict, "load_before": load_before, "load_after": load_after})
    return 0 if verdict == "PASS" else EXIT_FAIL


if __name__ == "__main__":
    sys.exit(main())
