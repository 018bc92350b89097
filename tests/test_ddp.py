"""torchrun with 2 processes trains the same parameters as 1 process on the same global batch."""

from __future__ import annotations

import os
import socket
import subprocess
import sys

import torch

from pghm.io.avatar import load_avatar
from pghm.model import ModelConfig
from pghm.train.data import TrainingData
from pghm.train.prior import initial_model

ARGS = [
    "--steps",
    "3",
    "--shards",
    "2",
    "--images",
    "2",
    "--uv-resolution",
    "64",
    "--latent-channels",
    "8",
    "--no-lpips",
    "--checkpoint-every",
    "0",
]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run(command: list[str]) -> None:
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    result = subprocess.run(command, capture_output=True, text=True, env=env, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]


def test_two_processes_equal_one(tiny_dataset, tmp_path):
    single, double = tmp_path / "single.pt", tmp_path / "double.pt"
    run([sys.executable, "-m", "pghm.cli.main", "train-prior", str(tiny_dataset), "--out", str(single), *ARGS])
    run(
        [
            sys.executable,
            "-m",
            "torch.distributed.run",
            "--nproc_per_node",
            "2",
            "--master_port",
            str(free_port()),
            "-m",
            "pghm.cli.main",
            "train-prior",
            str(tiny_dataset),
            "--out",
            str(double),
            *ARGS,
        ]
    )
    one, two = (load_avatar(p).model.state_dict() for p in (single, double))
    model = ModelConfig(
        uv_resolution=int(ARGS[ARGS.index("--uv-resolution") + 1]),
        latent_channels=int(ARGS[ARGS.index("--latent-channels") + 1]),
    )
    start = initial_model(model, TrainingData(tiny_dataset).num_identities, seed=0).state_dict()  # step 0 of both runs
    assert load_avatar(double).metadata["processes"] == 2 and load_avatar(single).metadata["processes"] == 1
    moved = 0
    for name in one:
        # Gradient all-reduce sums the two halves in another order: float32 reassociation only.
        torch.testing.assert_close(one[name], two[name], atol=1e-5, rtol=1e-4, msg=name)
        moved += int((one[name] - start[name]).abs().max() > 1e-4)
    assert moved > len(one) // 2  # training really changed the parameters being compared
