"""benchmarks/bench_gpu.py runs end to end: one line and exit 2 without CUDA, and every part on
the CPU at toy sizes with ``--device cpu --quick`` (its numbers mean nothing; the script's
plumbing is what is checked here, as no GPU is available to the tests)."""

from __future__ import annotations

import importlib
import json
import sys
from pathlib import Path

import pytest
import torch
from standin_device import standin_cuda

BENCHMARKS = Path(__file__).resolve().parent.parent / "benchmarks"


@pytest.fixture
def bench(monkeypatch):
    """The script as a module, without CUDA even where there is a GPU."""
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    return importlib.import_module("bench_gpu")


def run_main(bench, monkeypatch, *args: str) -> int:
    monkeypatch.setattr(sys, "argv", ["bench_gpu.py", *args])
    return bench.main()


def test_without_cuda_one_line(bench, monkeypatch, tmp_path, capsys):
    assert run_main(bench, monkeypatch, "--json", str(tmp_path / "out.json")) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        "bench_gpu: error: no CUDA device here: this script measures the GPU "
        "(--device cpu --quick checks the script)"
    ]
    assert not (tmp_path / "out.json").exists()


def test_quick_on_cpu_writes_every_part(bench, monkeypatch, tmp_path):
    out = tmp_path / "out.json"
    assert run_main(bench, monkeypatch, "--device", "cpu", "--quick", "--work", str(tmp_path), "--json", str(out)) == 0
    payload = json.loads(out.read_text())
    assert payload["device"] == "cpu" and payload["quick"]
    assert payload["splat"][0]["psnr"] > 60  # float32 against float64 on the CPU: the same image
    assert payload["fit_speed"][0]["steps_per_s"] > 0
    assert payload["candidate"][0]["run"] == "gpu_fit_candidate on cpu"


def test_quick_on_a_standin_gpu_writes_every_part(bench, monkeypatch, tmp_path):
    """The script's CUDA path (gsplat, the fits and eval on the device) on the stand-in device of
    tests/standin_device.py, which refuses a CPU tensor where CUDA's kernels would."""
    for name, value in (("is_available", True), ("device_count", 1), ("get_device_name", "stand-in")):
        monkeypatch.setattr(torch.cuda, name, lambda device=None, value=value: value)
    monkeypatch.setattr(torch.cuda, "synchronize", lambda device=None: None)
    out = tmp_path / "out.json"
    args = ["--device", "cuda", "--quick", "--work", str(tmp_path), "--json", str(out)]
    with standin_cuda():
        assert run_main(bench, monkeypatch, *args) == 0
    payload = json.loads(out.read_text())
    assert payload["device"] == "stand-in"
    assert payload["splat"][0]["psnr"] > 60  # the stand-in's gsplat is the CPU splatter in float32
    assert payload["candidate"][0]["run"] == "gpu_fit_candidate on cuda"
