"""A command's result is a function of its inputs, seed and options, not of the machine's load.

The same fit of the tiny subject (every phase: stage 1, the settling between the stages, stage 2
with pose corrections, the held-out frames' alignment, the detail stage), its evaluation with
test-time pose refinement and a CPU render, run as a user runs them (no OMP_NUM_THREADS, no wait
policy: the thread policy of :mod:`pghm.cli.threads` decides), once on an idle machine and once
beside a CPU-bound process with threads that sleep at once at a barrier (``GOMP_SPINCOUNT=0``),
give the same bytes: the avatar's tensors and metadata (its wall-clock times apart), the report's
figures, the strip's and the render's PNGs. A policy that chose the thread count from the load
would sum reductions in another order beside the busy process (torch splits them over the
threads) and change the last bits; how long a thread waits must change nothing.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from conftest import TINY_MODEL

from pghm.cli.threads import POLICY_VARIABLES
from pghm.model import ModelConfig
from pghm.train.loop import LoopConfig
from pghm.train.prior import PriorConfig, train_prior

SUBJECT = "subject_000"
COMMANDS = """
import sys
from pghm.cli.main import main
subject, prior, out = sys.argv[1:]
phases = ["--stage1-steps", "2", "--stage2-steps", "2", "--early-track-steps", "1", "--held-out-steps", "2",
          "--detail-steps", "2", "--detail-validation", "0", "--no-lpips"]
runs = [
    ["fit", subject, "--prior", prior, "--out", f"{out}/avatar.pt", *phases],
    ["eval", f"{out}/avatar.pt", subject, "--refine-poses", "2", "--report", f"{out}/report.json",
     "--strip", f"{out}/strip.png"],
    ["render", f"{out}/avatar.pt", "--motion", "walk", "--frames", "1", "--size", "48x36", "--backend", "cpu",
     "--out", f"{out}/frame.png"],
]
for args in runs:
    if main(args) != 0:
        sys.exit(f"pghm {args[0]} failed")
"""
"""The user's commands, in one child process (one interpreter start): fit, eval, render."""
BUSY_LOOP = [sys.executable, "-c", "while True: pass"]


def without_times(value: object) -> object:
    """``value`` (JSON-like) without the wall-clock figures a run records (keys ending in "seconds")."""
    if isinstance(value, dict):
        return {k: without_times(v) for k, v in value.items() if not k.endswith("seconds")}
    if isinstance(value, list):
        return [without_times(v) for v in value]
    return value


def same_payload(a: object, b: object) -> bool:
    """Whether two loaded avatar files are equal: tensors bit for bit, other values by ``==``."""
    if isinstance(a, torch.Tensor):
        return isinstance(b, torch.Tensor) and a.dtype == b.dtype and torch.equal(a, b)
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(same_payload(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return type(a) is type(b) and len(a) == len(b) and all(map(same_payload, a, b))
    return a == b


def run_commands(subject: Path, prior: Path, out: Path, **variables: str) -> None:
    """The user's commands in a child process with the thread settings the policy chooses, but for
    the environment ``variables`` given."""
    out.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in POLICY_VARIABLES} | variables
    command = [sys.executable, "-c", COMMANDS, str(subject), str(prior), str(out)]
    result = subprocess.run(command, env=env, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]


@pytest.mark.slow
def test_the_same_fit_eval_and_render_beside_a_busy_process(tiny_dataset, tmp_path):
    prior = tmp_path / "prior.pt"
    loop = LoopConfig(steps=2, images_per_shard=2, checkpoint_every=0, progress=False)
    config = PriorConfig(model=ModelConfig(**TINY_MODEL), loop=loop)
    train_prior(tiny_dataset, prior, config)
    subject = tiny_dataset / SUBJECT
    run_commands(subject, prior, tmp_path / "idle")
    loop = subprocess.Popen(BUSY_LOOP)
    try:
        time.sleep(0.3)  # the loop holds a core before the commands start
        run_commands(subject, prior, tmp_path / "busy", GOMP_SPINCOUNT="0")
    finally:
        loop.kill()
        loop.wait()

    idle, busy = (torch.load(tmp_path / run / "avatar.pt", weights_only=True) for run in ("idle", "busy"))
    assert idle["metadata"]["threads"] == busy["metadata"]["threads"] == len(os.sched_getaffinity(0))
    idle["metadata"], busy["metadata"] = without_times(idle["metadata"]), without_times(busy["metadata"])
    assert idle["pose_track"] is not None and idle["metadata"]["held_out_frames"] > 0
    assert "detail.maps" in idle["weights"]
    assert same_payload(idle, busy)

    reports = [without_times(json.loads((tmp_path / run / "report.json").read_text())) for run in ("idle", "busy")]
    assert reports[0]["threads"] == len(os.sched_getaffinity(0))
    assert reports[0] == reports[1]
    for image in ("strip.png", "frame.png"):
        assert (tmp_path / "idle" / image).read_bytes() == (tmp_path / "busy" / image).read_bytes()
