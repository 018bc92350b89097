"""Ctrl-C during training saves a checkpoint and exits cleanly; --resume continues from it."""

from __future__ import annotations

import signal
import subprocess
import sys

import torch

from pghm.train.loop import load_checkpoint

ARGS = ["--uv-resolution", "64", "--latent-channels", "8", "--images", "2", "--no-lpips", "--checkpoint-every", "0"]


def test_sigint_saves_and_resume_continues(tiny_dataset, tmp_path):
    out = tmp_path / "prior.pt"
    command = [sys.executable, "-m", "pghm.cli.main", "train-prior", str(tiny_dataset), "--out", str(out), *ARGS]
    process = subprocess.Popen(  # SIGINT as in a terminal, even when the suite itself was started with it ignored
        [*command, "--steps", "100000"],
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    seen = ""
    while "psnr=" not in seen:  # a step has finished: the interrupt lands in the training loop
        character = process.stderr.read(1)
        assert character, f"the run ended before its first step: {seen[-2000:]}"
        seen += character
    process.send_signal(signal.SIGINT)
    _, rest = process.communicate(timeout=60)
    message = seen + rest
    assert process.returncode == 130, message[-2000:]
    assert "interrupted at step" in message and "Traceback" not in message
    checkpoint = load_checkpoint(out.with_name(out.name + ".ckpt"))
    reached = checkpoint["state"]["step"]
    assert reached >= 1 and not out.exists()
    resumed = subprocess.run(
        [*command, "--steps", str(reached + 2), "--resume"], capture_output=True, text=True, timeout=300
    )
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert out.is_file() and torch.load(out, weights_only=True)["metadata"]["steps"] == reached + 2
