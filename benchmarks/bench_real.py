"""A real person's avatar, end to end: ``pghm capture`` -> ``pghm fit`` -> ``pghm eval`` on videos.

For each video (real ones given by path, and synthetic ones rendered like a person turning round
in front of a plain wall, :func:`turning_video`, and doing squats in a furnished room,
:func:`exercise_video`), in child processes so that each stage's wall time and peak memory are its own:

1. ``pghm capture VIDEO --out SUBJECT`` (defaults): frames kept, seconds, peak GB;
2. ``pghm fit SUBJECT --prior PRIOR --out AVATAR`` (defaults, plus ``--fit-option`` ones): seconds
   and peak GB on the machine as it is, and with ``--busy`` again with a CPU-bound busy loop beside
   it (as on a laptop running something else);
3. ``pghm eval AVATAR SUBJECT --split test`` with the stored poses, ``--fit-poses`` and
   ``--refine-poses 90``: PSNR, SSIM, silhouette IoU and halo on the held-out frames, and the
   strip of the refined evaluation, copied to ``docs/bench_real_<video>.png``;
4. what bounds the avatar (``bench_error_budget.coverage_swaps``, the fit's poses, or the stored
   ones for an avatar fitted without a pose track): the PSNR of its own colours composited through
   the stored mattes, against the render's;
5. with ``--budgets M ...``, run time against error: ``pghm fit --minutes M`` for each M, its wall
   time and the three evaluations, plotted with the default fit's in ``docs/bench_real_budget.png``.

    python benchmarks/bench_real.py [VIDEO ...] [--turning 1] [--exercise 0] [--frames 100] [--busy]
                                    [--budgets 2 5 10 20] [--prior assets/prior.pt]
                                    [--fit-option=--stage2-steps=200 ...] [--keep DIR] [--results bench_real]
                                    [--reuse bench_real_budget ...]

With ``--reuse NAME ...`` (and ``--keep``, where the avatars are), a video already measured in an
earlier results file keeps its default fit and the budgets it has; only the missing budgets run, so a
sweep can be extended without fitting again what it measured. ``--tabulate`` runs nothing: the
reused videos (later files win) are tabulated and plotted together, each with the budgets it holds.

Prints one row per video and writes benchmarks/results/<results>.json. The load average before each
timed stage is recorded: a time measured while other jobs share the cores is slower.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
from bench_error_budget import coverage_swaps, scored_frames
from common import DOCS, RESULTS, ROOT, load_average, print_table, timed_child, write_json

from pghm.io.avatar import load_avatar

PGHM = [sys.executable, "-m", "pghm.cli.main"]
"""The pghm command, run in a child process of this interpreter."""
REFINE_STEPS = 90
"""Test-time pose refinement steps of the refined evaluation (as evaluations of monocular avatars do;
the alignment is still moving at 30 steps and has converged to within 0.1 dB by 90: docs/lab/real-videos.md)."""
EVALUATIONS = {"stored": [], "fit": ["--fit-poses"], "refined": ["--refine-poses", str(REFINE_STEPS)]}
"""Name -> ``pghm eval`` options: the held-out frames' poses as captured, as the fit left them (a
capture's fit aligns them to their images, the avatar frozen), refined from the captured ones."""
WALL = ((196, 190, 178), (150, 140, 128))
"""A plain wall over a floor (top and bottom colours of the synthetic videos' background)."""
BUSY_LOOP = [sys.executable, "-c", "while True: pass"]


def room_background(width: int, height: int) -> np.ndarray:
    """(H, W, 3) uint8: a furnished room behind the person: a wall with a window and a picture, a
    door, a floor in boards and a low cabinet, in muted colours (a background a matte must cut
    around, unlike :data:`WALL`)."""
    y, x = np.mgrid[0:height, 0:width] / np.array([height, width])[:, None, None]
    floor = y > 0.72
    image = np.where(floor[..., None], [120, 92, 66], [205, 196, 176]).astype(np.float64)
    image[floor & ((x * 9 + (y - 0.72) * 4) % 1 < 0.04)] = [96, 72, 50]  # the boards' seams
    for (x0, y0, x1, y1), colour in (
        ((0.06, 0.14, 0.30, 0.50), (168, 196, 214)),  # window
        ((0.70, 0.18, 0.90, 0.40), (150, 60, 52)),  # picture
        ((0.74, 0.22, 0.86, 0.36), (214, 170, 90)),
        ((0.40, 0.10, 0.56, 0.72), (150, 120, 96)),  # door
        ((0.02, 0.58, 0.26, 0.78), (70, 80, 88)),  # cabinet
    ):
        image[(x >= x0) & (x < x1) & (y >= y0) & (y < y1)] = colour
    return np.round(image).astype(np.uint8)


def exercise_video(out: Path, frames: int, seed: int) -> Path:
    """A synthetic person doing squats on the spot in a furnished room, 512 x 512 H.264."""
    from pghm.synth.video import render_walk_video, walk_config

    config = walk_config(frames, width=512, height=512, motion="squat")
    render_walk_video(config, seed, out, room_background(config.width, config.height))
    return out


def turning_video(out: Path, frames: int, seed: int) -> Path:
    """A synthetic person turning round on the spot in front of a plain wall, 512 x 512 H.264."""
    from pghm.synth.video import graded_background, render_walk_video, walk_config

    config = walk_config(frames, width=512, height=512, motion="turn")
    render_walk_video(config, seed, out, graded_background(*WALL, config.width, config.height))
    return out


def run(command: list[str], log: Path, busy: bool = False) -> dict:
    """Run ``command`` (a pghm child) to completion: its seconds, peak GB and the load before it."""
    load = load_average()
    loop = subprocess.Popen(BUSY_LOOP) if busy else None
    try:
        seconds, peak_gb = timed_child(command, log)
    finally:
        if loop is not None:
            loop.kill()
            loop.wait()
    return {"seconds": round(seconds, 1), "peak_gb": round(peak_gb, 2), "load_before": round(load, 2)}


def frames_kept(subject: Path) -> int:
    counts = json.loads((subject / "meta.json").read_text())["counts"]
    return counts["person_found"] - counts["dropped"]


def evaluate(avatar: Path, subject: Path, work: Path, name: str | None) -> dict:
    """Each of :data:`EVALUATIONS` on the test split: its mean figures (and, given the video's
    ``name``, the refined strip into docs/)."""
    figures = {}
    for kind, options in EVALUATIONS.items():
        report, strip = work / f"eval_{kind}.json", work / f"eval_{kind}.png"
        command = [*PGHM, "eval", str(avatar), str(subject), "--split", "test", "--report", str(report)]
        run([*command, "--strip", str(strip), *options], work / f"eval_{kind}.log")
        mean = json.loads(report.read_text())["mean"]
        figures[kind] = {key: round(float(mean[key]), 4) for key in ("psnr", "ssim", "iou", "halo_pixels")}
        if kind == "refined" and name is not None:
            shutil.copyfile(strip, DOCS / f"bench_real_{name}.png")
    return figures


def bench_video(
    video: Path, name: str, work: Path, args: argparse.Namespace, save: Callable[[dict], None]
) -> dict:
    """The row of one video; ``save(row)`` is called after the default fit and after each budget
    fit, so a long sweep that is cut off keeps what it measured."""
    work.mkdir(parents=True, exist_ok=True)
    subject, avatar = work / "subject", work / "avatar.pt"
    if name in args.reused:
        row = {**args.reused[name], "budgets": list(args.reused[name]["budgets"])}
        return sweep_budgets(row, subject, work, args, save)
    row = {"video": name}
    if not subject.is_dir():
        row["capture"] = run([*PGHM, "capture", str(video), "--out", str(subject)], work / "capture.log")
    row["frames"] = frames_kept(subject)

    row["fit"] = run(fit_command(subject, avatar, args), work / "fit.log")
    if args.busy:
        row["fit_busy"] = run(fit_command(subject, work / "avatar_busy.pt", args), work / "fit_busy.log", busy=True)
    row["eval"] = evaluate(avatar, subject, work, name)
    fitted = load_avatar(avatar)
    row["steps"] = fitted.metadata["steps"]
    fit_poses = fitted.pose_track is not None  # none with --fit-option=--no-pose-refinement
    row["coverage"] = coverage_swaps(scored_frames(fitted, subject, steps=0, fit_poses=fit_poses))
    row["coverage"]["poses"] = "fit" if fit_poses else "stored"
    row["budgets"] = []
    save(row)
    return sweep_budgets(row, subject, work, args, save)


def fit_command(subject: Path, out: Path, args: argparse.Namespace) -> list[str]:
    return [*PGHM, "fit", str(subject), "--prior", str(args.prior), "--out", str(out), *args.fit_option]


def sweep_budgets(
    row: dict, subject: Path, work: Path, args: argparse.Namespace, save: Callable[[dict], None]
) -> dict:
    """``row`` with a fit and its evaluations for each of ``args.budgets`` it does not hold yet."""
    done = {b["minutes"] for b in row["budgets"]}
    for minutes in [] if args.tabulate else [m for m in args.budgets if m not in done]:
        out = work / f"avatar_{minutes:g}min.pt"
        timing = run([*fit_command(subject, out, args), "--minutes", f"{minutes:g}"], work / f"fit_{minutes:g}min.log")
        budget_work = work / f"{minutes:g}min"
        budget_work.mkdir(exist_ok=True)
        figures = evaluate(out, subject, budget_work, None)
        steps = load_avatar(out).metadata["steps"]
        row["budgets"].append({"minutes": minutes, "fit": timing, "steps": steps, "eval": figures})
        row["budgets"].sort(key=lambda b: b["minutes"])
        save(row)
    return row


def table_rows(rows: list[dict]) -> list[dict]:
    out = []
    for row in rows:
        flat = {"video": row["video"], "frames": row["frames"]}
        if "capture" in row:
            flat["capture_s"] = row["capture"]["seconds"]
        flat["fit_s"] = row["fit"]["seconds"]
        if "fit_busy" in row:
            flat["fit_busy_s"] = row["fit_busy"]["seconds"]
        flat["peak_gb"] = row["fit"]["peak_gb"]
        for kind, figures in row["eval"].items():
            flat[f"psnr_{kind}"] = figures["psnr"]
            flat[f"ssim_{kind}"] = figures["ssim"]
        flat["psnr_matte_coverage"] = round(row["coverage"]["avatar colours, matte's coverage"], 2)
        flat["iou"] = row["eval"]["refined"]["iou"]
        flat["halo"] = row["eval"]["refined"]["halo_pixels"]
        out.append(flat)
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("videos", nargs="*", type=Path, help="real videos of one person (default: the shared one)")
    parser.add_argument("--turning", type=int, default=1, help="synthetic turning videos to add (default %(default)s)")
    parser.add_argument("--exercise", type=int, default=0, help="synthetic squat videos to add (default %(default)s)")
    parser.add_argument("--frames", type=int, default=100, help="frames of each synthetic video (default %(default)s)")
    parser.add_argument("--budgets", type=float, nargs="*", default=[], help="fit minutes of the budget sweep")
    parser.add_argument("--busy", action="store_true", help="fit each video again with a busy loop beside it")
    parser.add_argument("--prior", type=Path, default=ROOT / "assets" / "prior.pt")
    parser.add_argument("--fit-option", action="append", default=[], help="an option passed on to pghm fit")
    parser.add_argument(
        "--keep", type=Path, help="keep videos, subjects and avatars here (and reuse captured subjects)"
    )
    parser.add_argument("--results", default="bench_real", help="name of the JSON under benchmarks/results/")
    parser.add_argument("--reuse", nargs="*", default=[], help="earlier results whose videos' fits are kept")
    parser.add_argument("--tabulate", action="store_true", help="fit nothing: tabulate and plot the reused videos")
    args = parser.parse_args()
    if args.reuse and args.keep is None:
        parser.error("--reuse needs --keep: the folder that holds the earlier fits' subjects")
    if args.tabulate and not args.reuse:
        parser.error("--tabulate needs --reuse: the results to tabulate")
    args.reused = {
        row["video"]: row
        for name in args.reuse
        for row in json.loads((RESULTS / f"{name}.json").read_text())["videos"]
    }
    shared = ROOT.parent / "shared" / "data" / "video"
    videos = args.videos or sorted(shared.glob("*.mp4"))
    work = args.keep or Path(tempfile.mkdtemp(prefix="bench_real_"))
    rows = []

    def save(row: dict) -> None:
        write_json(args.results, {"fit_options": args.fit_option, "videos": [*rows, row], "partial": True})

    if args.tabulate:
        rows = [bench_video(Path(name), name, work / name, args, save) for name in args.reused]
        videos, args.turning, args.exercise = [], 0, 0
    try:
        for video in videos:
            rows.append(bench_video(video.resolve(), video.stem, work / video.stem, args, save))
        synthetic = [("turning", turning_video, args.turning), ("exercise", exercise_video, args.exercise)]
        for kind, make, count in synthetic:
            for seed in range(count):
                name = f"{kind}_{seed}"
                video = work / f"{name}.mp4"
                if not video.is_file():
                    make(video, args.frames, seed)
                rows.append(bench_video(video, name, work / name, args, save))
    finally:
        if args.keep is None:
            shutil.rmtree(work, ignore_errors=True)
    print_table(table_rows(rows))
    if args.budgets or args.tabulate:
        print_table(budget_rows(rows))
        plot_budgets(rows, DOCS / f"{args.results}_budget.png")
    write_json(args.results, {"fit_options": args.fit_option, "videos": rows})
    return 0


def budget_rows(rows: list[dict]) -> list[dict]:
    """One line per video and fit: its minutes asked (the default: none), wall seconds, steps, figures."""
    out = []
    for row in rows:
        fits = [("default", row["fit"], row["steps"], row["eval"])]
        fits += [(f"{b['minutes']:g}", b["fit"], b["steps"], b["eval"]) for b in row["budgets"]]
        for minutes, timing, steps, figures in fits:
            line = {"video": row["video"], "minutes": minutes, "fit_s": timing["seconds"]}
            line["stage2_steps"] = steps["stage2"]
            for kind in EVALUATIONS:
                line[f"psnr_{kind}"], line[f"ssim_{kind}"] = figures[kind]["psnr"], figures[kind]["ssim"]
            out.append(line)
    return out


def plot_budgets(rows: list[dict], path: Path) -> None:
    """PSNR of the held-out frames (fit's poses, refined) against the fit's wall minutes, per video;
    the default fit as a star."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pghm.io.atomic import save_figure

    figure, axes = plt.subplots(1, len(rows), figsize=(4.2 * len(rows), 3.6), squeeze=False)
    for axis, row in zip(axes[0], rows):
        minutes = [b["fit"]["seconds"] / 60 for b in row["budgets"]]
        for kind, style in (("fit", "o-"), ("refined", "s--")):
            axis.plot(minutes, [b["eval"][kind]["psnr"] for b in row["budgets"]], style, label=f"{kind} poses")
            axis.plot(row["fit"]["seconds"] / 60, row["eval"][kind]["psnr"], "k*", markersize=11)
        axis.set(title=row["video"], xlabel="fit wall minutes (2 cores)", ylabel="held-out PSNR (dB)")
        axis.grid(alpha=0.3)
    axes[0][0].legend(title="star: the default fit")
    figure.tight_layout()
    save_figure(figure, path, dpi=110)


if __name__ == "__main__":
    sys.exit(main())
