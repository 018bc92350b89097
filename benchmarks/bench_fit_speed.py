"""Where ``pghm fit``'s time goes, per part, and what a busy core beside it costs.

Each measurement is a ``pghm fit --profile`` child process (docs/training.md, "Speed"), so it
starts as a user's would (thread policy included) and its table is the fit's own:

- breakdown (default): short fits (``--steps`` stage 1, stage 2 and settling steps per frame),
  ``--repeats`` of them; per part, the median CPU and wall seconds per step of each phase (a
  settling step is one image's), and the default fit's time they extrapolate to;
- ``--full``: the default fit, once, its whole table and wall time; with ``--busy`` beside a
  busy loop (``python -c "while True: pass"``, started :data:`BUSY_WARMUP_S` before, so the
  load average the fit starts under shows it);
- ``--thread-cost``: whole default fits, ``--repeats`` of each of :data:`THREAD_COSTS` (idle; beside a
  busy loop on one thread, the count the former load-sampling policy chose there, and on the
  policy's one thread per core), interleaved: median wall and CPU seconds and their ratios;
- ``--policies``: idle, then beside a busy loop, short fits (stages 1 and 2 alone) under each
  thread setting of :data:`POLICIES`, interleaved ``--repeats`` times: median stage-2 seconds per
  step and its ratio to the first;
- ``--held-check AVATAR``: the subject's held-out frames after :data:`TRACK_STEPS` steps of pose
  refinement with the network run at every step and with its maps held;
- ``--settle-check AVATAR``: AVATAR fitted with ``--track-steps 0``; the training frames on either
  side of each held-out frame settled by each way of :data:`SETTLINGS` (one thread, seeds 0 and
  1), their CPU seconds per image and step, and the held-out frames' PSNR / SSIM with the track
  (``pghm eval --fit-poses``).

    python benchmarks/bench_fit_speed.py SUBJECT [SUBJECT ...] [--steps 5 10 2] [--repeats 3]
                                         [--threads 1] [--full] [--busy] [--policies] [--thread-cost]
                                         [--label NAME]
                                         [--held-check AVATAR] [--settle-check AVATAR]

Prints the tables and writes benchmarks/results/bench_fit_speed[_NAME].json. Every row records
the load averages it ran under: on a shared machine the wall times are what others left, the
CPU seconds closer to the work itself.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from common import ROOT, load_average, print_table, write_json

from pghm.cli.threads import POLICY_VARIABLES
from pghm.train.fit import TRACK_FINE_STEPS, TRACK_STEPS

PGHM = [sys.executable, "-m", "pghm.cli.main"]
PRIOR = ROOT / "assets" / "prior.pt"
BUSY_WARMUP_S = 60
"""Seconds the busy loop runs before a fit starts: the one-minute load average then reads about
0.6 of it, so the load a row records shows the loop."""
HELD_BATCH = 8
"""Frames refined together with the network's maps held: one evaluation of the maps serves them all."""
POLICIES = {
    "the policy: sleep, after a 3,000-round spin on free cores": {},
    "a 3,000-round spin, then sleep": {"OMP_WAIT_POLICY": "PASSIVE", "GOMP_SPINCOUNT": "3000"},
    "sleep at once": {"OMP_WAIT_POLICY": "PASSIVE"},
    "libgomp's default spin (300,000 rounds)": {"GOMP_SPINCOUNT": "300000"},
    "sleep at once, 1 thread": {"OMP_WAIT_POLICY": "PASSIVE", "OMP_NUM_THREADS": "1"},
}
"""Thread settings ``--policies`` compares, idle and beside a busy core (:mod:`pghm.cli.threads`: a
variable the user sets wins over the policy's; GOMP_SPINCOUNT alone leaves OMP_WAIT_POLICY unset,
which is libgomp's own default)."""
THREAD_COSTS = {
    "idle, the policy": (False, {}),
    "busy loop, 1 thread (the load policy's choice)": (True, {"OMP_NUM_THREADS": "1"}),
    "busy loop, the policy": (True, {}),
}
"""Name -> (beside a busy loop, environment) of ``--thread-cost``. Idle, the former policy (threads
from the cores' momentary load) chose what the affinity policy chooses, one thread per core."""
SETTLINGS = {
    "none": {"steps": 0},
    "all live, both renders": {"steps": TRACK_STEPS},
    "default: coarse, then 10 live, dynamic": {
        "steps": TRACK_STEPS, "coarse_steps": TRACK_STEPS - TRACK_FINE_STEPS, "dynamic_only": True
    },
    "coarse, then 6 live, dynamic": {"steps": TRACK_STEPS, "coarse_steps": TRACK_STEPS - 6, "dynamic_only": True},
    "coarse, then 10 live, both renders": {"steps": TRACK_STEPS, "coarse_steps": TRACK_STEPS - TRACK_FINE_STEPS},
    "coarse, then 3 live, dynamic": {"steps": TRACK_STEPS, "coarse_steps": TRACK_STEPS - 3, "dynamic_only": True},
    "10 live steps": {"steps": 10},
}
"""Ways of settling a pose track that ``--settle-check`` compares (:func:`pghm.train.pose_refine.refine_poses`'s
arguments; the learning rate is the fit's, :data:`pghm.train.fit.POSE_LR`)."""
SETTLE_SEEDS = (0, 1)
STAGES = ("stage 1", "stage 2", "pose settling")
DEFAULT_STEPS = {"stage 1": 50, "stage 2": 450}


def run_fit(subject: Path, out: Path, options: list[str], env: dict[str, str]) -> dict:
    """``pghm fit SUBJECT`` with ``options`` and ``--profile``: its profile record, wall time and load."""
    profile = out.with_suffix(".json")
    command = [*PGHM, "fit", str(subject), "--prior", str(PRIOR), "--out", str(out), "--profile", str(profile)]
    child_env = {k: v for k, v in os.environ.items() if k not in POLICY_VARIABLES} | env
    child_env["PYTHONPATH"] = str(ROOT)
    load = load_average()
    started = time.perf_counter()
    result = subprocess.run([*command, *options], env=child_env, capture_output=True, text=True, check=False)
    if result.returncode != 0:
        raise RuntimeError(f"pghm fit failed ({result.returncode}):\n{result.stderr[-1500:]}")
    record = json.loads(profile.read_text())
    record["process_s"] = round(time.perf_counter() - started, 1)
    record["load_before"] = round(load, 2)
    out.unlink(missing_ok=True)
    profile.unlink()
    return record


def phase_seconds(record: dict, phase: str, kind: str) -> dict[str, float]:
    return {part: value[kind] for part, value in record["phases"].get(phase, {}).items()}


def training_images(subject: Path) -> int:
    return len(json.loads((subject / "splits.json").read_text())["train"])


def breakdown(subject: Path, work: Path, steps: list[int], repeats: int, threads: int) -> dict:
    """Per part and phase, median seconds per step (per image-step for the settling) of short fits
    on ``threads`` threads (the work itself; :func:`policies` measures the threads)."""
    stage1, stage2, track = steps
    options = ["--stage1-steps", str(stage1), "--stage2-steps", str(stage2), "--track-steps", str(track)]
    env = {"OMP_NUM_THREADS": str(threads)}
    records = [run_fit(subject, work / f"b{i}.pt", options, env) for i in range(repeats)]
    per_step = {"stage 1": stage1, "stage 2": stage2, "pose settling": track * training_images(subject)}
    table = {}
    for kind in ("cpu_s", "wall_s"):
        for phase, count in per_step.items():
            if not count:
                continue
            parts = {p for r in records for p in r["phases"].get(phase, {})}
            table[kind, phase] = {
                part: statistics.median(phase_seconds(r, phase, kind).get(part, 0.0) for r in records) / count
                for part in sorted(parts)
            }
    return {
        "subject": subject.name,
        "steps": dict(zip(STAGES, steps)),
        "threads": records[0]["threads"],
        "load_average": [r["load_before"] for r in records],
        "per_step": {f"{phase} {kind}": parts for (kind, phase), parts in table.items()},
    }


def print_breakdown(row: dict) -> None:
    phases = [p for p in STAGES if f"{p} cpu_s" in row["per_step"]]
    parts = sorted({part for key in row["per_step"] for part in row["per_step"][key]})
    lines = []
    for part in [*parts, "total"]:
        line = {"part": part}
        for phase in phases:
            for kind in ("cpu_s", "wall_s"):
                values = row["per_step"][f"{phase} {kind}"]
                line[f"{phase} {kind[:-2]}"] = sum(values.values()) if part == "total" else values.get(part, 0.0)
        lines.append(line)
    print(f"\n{row['subject']}: seconds per step ({row['threads']} threads, load {row['load_average']})")
    print_table(lines)


def with_busy_loop(work):
    """Run ``work()`` beside a busy loop started :data:`BUSY_WARMUP_S` before; stop the loop after."""
    busy = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        time.sleep(BUSY_WARMUP_S)
        return work()
    finally:
        busy.kill()
        busy.wait()


def full(subject: Path, work: Path, busy: bool, threads: int | None) -> dict:
    """The default fit, whole, on ``threads`` threads (None: the thread policy's choice)."""
    env = {"OMP_NUM_THREADS": str(threads)} if threads else {}
    run = (lambda: run_fit(subject, work / "full.pt", [], env))
    record = with_busy_loop(run) if busy else run()
    return {"subject": subject.name, "busy_loop": busy, **record}


def thread_cost(subject: Path, work: Path, repeats: int) -> dict:
    """Median wall and CPU seconds of whole default fits under each of :data:`THREAD_COSTS`, the
    settings interleaved in each repeat; the busy settings share one busy loop."""
    runs: dict[str, list[dict]] = {name: [] for name in THREAD_COSTS}
    idle = [name for name, (busy, _) in THREAD_COSTS.items() if not busy]
    busy = [name for name in THREAD_COSTS if name not in idle]

    def sweep(names: list[str]) -> None:
        for i in range(repeats):
            for name in names:
                runs[name].append(run_fit(subject, work / f"t{i}.pt", [], THREAD_COSTS[name][1]))

    sweep(idle)
    with_busy_loop(lambda: sweep(busy))
    rows = [
        {
            "setting": name,
            "threads": records[0]["threads"],
            "wall_s": statistics.median(r["process_s"] for r in records),
            "cpu_s": statistics.median(r["cpu_s"] for r in records),
            "wall_s_each": [r["process_s"] for r in records],
            "load": [r["load_before"] for r in records],
        }
        for name, records in runs.items()
    ]
    return {"subject": subject.name, "repeats": repeats, "rows": rows, "records": runs}


def policies(subject: Path, work: Path, steps: list[int], repeats: int) -> dict:
    """Median stage-2 wall seconds per step under each of :data:`POLICIES`, idle and beside a busy loop."""
    stage1, stage2, _ = steps
    options = ["--stage1-steps", str(stage1), "--stage2-steps", str(stage2), "--track-steps", "0",
               "--early-track-steps", "0", "--held-out-steps", "0", "--detail-steps", "0"]

    def sweep() -> dict[str, list[dict]]:
        runs: dict[str, list[dict]] = {name: [] for name in POLICIES}
        for i in range(repeats):
            for name, env in POLICIES.items():
                runs[name].append(run_fit(subject, work / f"p{i}.pt", options, env))
        return runs

    rows = []
    for busy, runs in ((False, sweep()), (True, with_busy_loop(sweep))):
        group = []
        for name, records in runs.items():
            wall = [sum(phase_seconds(r, "stage 2", "wall_s").values()) / stage2 for r in records]
            cpu = [sum(phase_seconds(r, "stage 2", "cpu_s").values()) / stage2 for r in records]
            group.append(
                {
                    "beside": "a busy loop" if busy else "nothing",
                    "policy": name,
                    "threads": records[0]["threads"],
                    "wall_s_per_step": statistics.median(wall),
                    "cpu_s_per_step": statistics.median(cpu),
                    "load": [r["load_before"] for r in records],
                }
            )
        for row in group:
            row["wall_ratio"] = row["wall_s_per_step"] / group[0]["wall_s_per_step"]
        rows += group
    return {"subject": subject.name, "steps": steps, "rows": rows}


def held_check(avatar: Path, subject: Path, steps: int) -> dict:
    """Held-out PSNR / SSIM after refining each test frame's pose for ``steps`` steps with the network
    run at every step (``pghm eval --refine-poses``, two frames at a time, then eight) and with its
    maps held, eight at a time (the fit's settling, :class:`pghm.train.pose_refine.HeldAppearance`):
    what holding them costs the alignment, on frames no fit saw."""
    import torch

    from pghm.train import pose_refine
    from pghm.train.evaluate import evaluate

    torch.set_num_threads(1)
    original = pose_refine.refine_poses
    rows = []
    for held, batch in ((False, pose_refine.IMAGES_PER_BATCH), (False, HELD_BATCH), (True, HELD_BATCH)):
        pose_refine.refine_poses = functools.partial(original, hold_appearance=held, batch=batch)
        try:
            started = time.process_time()
            result = evaluate(avatar, subject, refine_poses=steps)
            seconds = time.process_time() - started
        finally:
            pose_refine.refine_poses = original
        summary = result.summary()
        rows.append(
            {
                "network": "held" if held else "run every step",
                "frames at a time": batch,
                "psnr": summary["psnr"],
                "ssim": summary["ssim"],
                "cpu_s": round(seconds, 1),
            }
        )
    return {"subject": subject.name, "avatar": avatar.name, "steps": steps, "rows": rows}


def settle_check(avatar_path: Path, subject: Path) -> dict:
    """Per way of :data:`SETTLINGS` and seed, the CPU of settling the training frames next to the
    held-out ones (the frames ``--fit-poses`` reads) and the held-out PSNR / SSIM with the track."""
    import torch

    from pghm.body import load_body
    from pghm.io.avatar import load_avatar
    from pghm.train.data import TrainingData
    from pghm.train.evaluate import evaluate
    from pghm.train.fit import POSE_LR, FitConfig
    from pghm.train.person_crop import CROP_MARGIN
    from pghm.train.pose_refine import refine_poses
    from pghm.train.pose_track import learned_track, track_corrections

    torch.set_num_threads(1)
    avatar = load_avatar(avatar_path)
    data = TrainingData(subject, crop_margin=CROP_MARGIN)  # as the fit settles
    test = json.loads((subject / "splits.json").read_text())["test"]
    images = [int(i) for i in data.images[0] if any(abs(int(i) - t) == 1 for t in test)]
    body = load_body(data.body_name)
    rows = []
    for name, options in SETTLINGS.items():
        for seed in SETTLE_SEEDS if options["steps"] else (0,):
            corrections, _ = track_corrections(avatar.pose_track, data, body)
            started = time.process_time()
            refine_poses(
                avatar, data, weights=FitConfig().stage2.loss, lr=POSE_LR, corrections=corrections, images=images,
                seed=seed, progress=False, **options,
            )
            seconds = time.process_time() - started
            settled = replace(avatar, pose_track=learned_track(corrections, data))
            summary = evaluate(settled, subject, fit_poses=True).summary()
            rows.append(
                {
                    "settling": name,
                    "seed": seed,
                    "psnr": round(summary["psnr"], 3),
                    "ssim": round(summary["ssim"], 4),
                    "cpu_s": round(seconds, 1),
                    "cpu_ms_per_image_step": round(1000 * seconds / (len(images) * max(options["steps"], 1)), 1),
                }
            )
    return {"subject": subject.name, "avatar": avatar_path.name, "frames": len(images), "rows": rows}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("subjects", nargs="+", type=Path)
    parser.add_argument("--steps", nargs=3, type=int, default=[5, 10, 2], metavar=("STAGE1", "STAGE2", "TRACK"))
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument(
        "--threads", type=int, default=None, help="threads of the fits (default: 1 in the breakdown, else the policy's)"
    )
    parser.add_argument("--full", action="store_true", help="the default fit, whole")
    parser.add_argument("--busy", action="store_true", help="with --full: beside a busy loop")
    parser.add_argument("--policies", action="store_true", help="thread settings, idle and beside a busy loop")
    parser.add_argument("--thread-cost", action="store_true", help="whole default fits: idle, busy on 1 thread, busy")
    parser.add_argument("--label", default=None, help="results file suffix")
    parser.add_argument(
        "--held-check", type=Path, default=None, metavar="AVATAR",
        help="refine the held-out poses of the (one) subject against AVATAR with the network run and held",
    )
    parser.add_argument(
        "--settle-check", type=Path, default=None, metavar="AVATAR",
        help="settle the track of AVATAR (fitted with --track-steps 0) in each way of SETTLINGS; score held-out frames",
    )
    args = parser.parse_args()
    payload: dict = {
        "breakdown": [], "full": [], "policies": [], "thread_cost": [], "held_check": [], "settle_check": []
    }
    with tempfile.TemporaryDirectory() as temporary:
        work = Path(temporary)
        for subject in args.subjects:
            if args.settle_check:
                result = settle_check(args.settle_check, subject)
                print(f"\n{subject.name}: held-out frames with the track settled ({result['frames']} frames)")
                print_table(result["rows"])
                payload["settle_check"].append(result)
            elif args.held_check:
                result = held_check(args.held_check, subject, TRACK_STEPS)
                print(f"\n{subject.name}: held-out frames after {TRACK_STEPS} refinement steps")
                print_table(result["rows"])
                payload["held_check"].append(result)
            elif args.thread_cost:
                result = thread_cost(subject, work, args.repeats)
                print(f"\n{subject.name}: whole default fits, medians of {args.repeats}")
                print_table([{k: v for k, v in row.items() if k != "wall_s_each"} for row in result["rows"]])
                payload["thread_cost"].append(result)
            elif args.policies:
                result = policies(subject, work, args.steps, args.repeats)
                print(f"\n{subject.name}: stage 2, idle and beside a busy loop")
                print_table(result["rows"])
                payload["policies"].append(result)
            elif args.full:
                result = full(subject, work, args.busy, args.threads)
                print(f"\n{subject.name}: default fit{' beside a busy loop' if args.busy else ''}, "
                      f"{result['wall_s']:.0f} s wall, {result['cpu_s']:.0f} s CPU, load {result['load_average']}")
                payload["full"].append(result)
            else:
                result = breakdown(subject, work, args.steps, args.repeats, args.threads or 1)
                print_breakdown(result)
                payload["breakdown"].append(result)
    write_json("bench_fit_speed" + (f"_{args.label}" if args.label else ""), payload)


if __name__ == "__main__":
    main()
