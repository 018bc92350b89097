"""Run time against error of the present default, from sweeps fitted one after another by hand.

Each sweep file (``benchmarks/results/sweep_*.json``) names its ``video`` and holds its default fit and its
``--minutes M`` fits (``fits``: ``default`` and ``minutes_M``, each with ``wall_s``, ``steps`` and the
held-out ``fit_poses`` and ``refined_90`` figures), measured with the commands it records. Prints one
table row per fit and plots held-out PSNR against wall minutes as ``bench_real.py --budgets`` does
(the default fit as a star), into ``docs/<name>.png``.

    python benchmarks/plot_sweeps.py sweep_dribble_zen4_records sweep_turn_zen4_present --name sweep_present
"""

from __future__ import annotations

import argparse
import json

from bench_real import plot_budgets
from common import DOCS, RESULTS, print_table

MINUTES_PREFIX = "minutes_"


def figures(fit: dict) -> dict:
    """A sweep fit's held-out figures as bench_real's rows hold them."""
    return {"fit": fit["fit_poses"], "refined": fit["refined_90"]}


def video_row(sweep: dict) -> dict:
    """One sweep as a bench_real row: the default fit and the budgets, shortest first."""
    fits = sweep["fits"]
    budgets = [
        {"minutes": float(key.removeprefix(MINUTES_PREFIX)), "fit": {"seconds": fit["wall_s"]}, "eval": figures(fit)}
        for key, fit in fits.items()
        if key.startswith(MINUTES_PREFIX)
    ]
    budgets.sort(key=lambda budget: budget["minutes"])
    default = fits["default"]
    return {
        "video": sweep["video"],
        "fit": {"seconds": default["wall_s"]},
        "eval": figures(default),
        "budgets": budgets,
    }


def table_rows(sweep: dict) -> list[dict]:
    """One line per fit of a sweep: minutes asked (the default: none), wall, stage-2 steps, figures."""
    lines = []
    for key, fit in sweep["fits"].items():
        line = {
            "video": sweep["video"],
            "fit": key,
            "wall_s": round(fit["wall_s"], 1),
            "stage2_steps": fit["steps"]["stage2"],
        }
        for kind in ("fit_poses", "refined_90"):
            line[f"psnr_{kind}"], line[f"ssim_{kind}"] = fit[kind]["psnr"], fit[kind]["ssim"]
        lines.append(line)
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("sweeps", nargs="+", help="names of sweep files under benchmarks/results/ (no .json)")
    parser.add_argument("--name", default="sweep_present", help="the plot's name under docs/ (no .png)")
    args = parser.parse_args()
    sweeps = {name: json.loads((RESULTS / f"{name}.json").read_text()) for name in args.sweeps}
    print_table([line for sweep in sweeps.values() for line in table_rows(sweep)])
    plot_budgets([video_row(sweep) for sweep in sweeps.values()], DOCS / f"{args.name}.png")
    print(f"wrote docs/{args.name}.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
