"""Two profiles of whole fits (``pghm fit --profile P.json``) side by side, as Markdown tables.

Per phase: wall seconds before and after; per part (data, network forward, ..., summed over the
phases): CPU seconds before and after, and the ratio.

    python benchmarks/profile_compare.py BEFORE.json AFTER.json [--label NAME]
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path


def phase_walls(profile: dict) -> dict[str, float]:
    return {phase: sum(part["wall_s"] for part in parts.values()) for phase, parts in profile["phases"].items()}


def part_cpus(profile: dict) -> dict[str, float]:
    totals: dict[str, float] = defaultdict(float)
    for parts in profile["phases"].values():
        for name, part in parts.items():
            totals[name] += part["cpu_s"]
    return dict(totals)


def side_by_side(before: dict[str, float], after: dict[str, float], what: str, unit: str) -> list[str]:
    names = list(dict.fromkeys([*before, *after]))
    lines = [f"| {what} | before ({unit}) | after ({unit}) | after / before |", "|---|---:|---:|---:|"]
    for name in names:
        b, a = before.get(name, 0.0), after.get(name, 0.0)
        ratio = f"{a / b:.2f}" if b > 0 else "new"
        lines.append(f"| {name} | {b:.1f} | {a:.1f} | {ratio} |")
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("before", type=Path)
    parser.add_argument("after", type=Path)
    parser.add_argument("--label", default="")
    args = parser.parse_args()
    before, after = (json.loads(path.read_text()) for path in (args.before, args.after))
    walls = side_by_side(phase_walls(before), phase_walls(after), "phase", "wall s")
    walls.append(f"| whole fit | {before['wall_s']:.1f} | {after['wall_s']:.1f} | {after['wall_s'] / before['wall_s']:.2f} |")
    cpus = side_by_side(part_cpus(before), part_cpus(after), "part", "CPU s")
    cpus.append(f"| whole fit | {before['cpu_s']:.1f} | {after['cpu_s']:.1f} | {after['cpu_s'] / before['cpu_s']:.2f} |")
    print(f"{args.label}\n\n" + "\n".join(walls) + "\n\n" + "\n".join(cpus))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
