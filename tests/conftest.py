"""Shared fixtures, and the threads tests run on.

The suite runs as ``pytest -n 2`` (pytest-xdist: one worker per core of the 2-core target), so
each worker takes one intra-op thread, and its OpenMP threads sleep rather than spin when they
wait: two threads per worker would contend for the two cores, and a parallel region whose second
thread is descheduled waits for it, tens of times slower on small tensors.

The count is pinned through OMP_NUM_THREADS, which every ``pghm`` command honours
(:mod:`pghm.cli.threads`), so the commands a test runs in its own process and those it starts as
children compute on the same count. That is what lets a test compare two float computations of the
same work bit for bit (a device stand-in against the CPU, a resumed fit against an uninterrupted one,
the same command twice): torch adds a reduction's partial sums in an order set by the thread count,
so only a difference in the code under test can make them differ. Comparisons between two different
computations (GL against the CPU splatter, the C++ kernel against its torch twin, float32 against
float64) carry tolerances derived where they are stated. A user's OMP_NUM_THREADS wins: the suite's
verdicts must not depend on the count (it is run with 1 and 2).
"""

from __future__ import annotations

import os

WORKERS = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
CORES = 2
"""The target machine's cores, shared by the workers."""
# Both before torch loads its OpenMP runtime.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
os.environ.setdefault("OMP_NUM_THREADS", str(max(1, CORES // WORKERS)))

from pathlib import PureWindowsPath  # noqa: E402

import pytest  # noqa: E402
import torch  # noqa: E402

from pghm.model import ModelConfig  # noqa: E402

torch.set_num_threads(int(os.environ["OMP_NUM_THREADS"]))


@pytest.fixture(scope="session")
def body():
    """The default Anny body (built once per test run)."""
    from pghm.body import load_body

    return load_body()


@pytest.fixture(scope="session")
def rest(body):
    return body.rest()


@pytest.fixture(scope="session")
def atlas128(body):
    from pghm.uv.atlas import build_atlas

    return build_atlas(body, 128)


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory):
    """2 synthetic subjects x 2 views x 3 frames at 64 px, rendered once per test run."""
    from pghm.synth.config import PRESETS
    from pghm.synth.generate import generate

    out = tmp_path_factory.mktemp("data") / "tiny"
    generate(PRESETS["tiny"], seed=0, out=out, workers=1, progress=False)
    return out


SMALL_MODEL = ModelConfig(
    uv_resolution=64,
    latent_channels=8,
    encoder_channels=(8, 12, 16, 24),
    decoder_channels=(16, 12, 8),
    condition_channels=(4, 4, 8, 8),
)
"""A small network on a 64 x 64 atlas (~3k Gaussians): every branch, fast on 2 cores."""

TINY_MODEL = dict(
    uv_resolution=32,
    latent_channels=4,
    encoder_channels=(8, 12, 16),
    decoder_channels=(12, 8),
    condition_channels=(4, 4, 4),
)
"""A model small enough to train for a few steps inside a test."""


def absolute_paths(value: object) -> list[str]:
    """The strings inside nested dicts and lists (JSON, metadata) that contain a word naming an
    absolute path (POSIX, home or a Windows drive): what a shipped file must not record."""
    if isinstance(value, dict):
        return [text for item in value.values() for text in absolute_paths(item)]
    if isinstance(value, (list, tuple)):
        return [text for item in value for text in absolute_paths(item)]
    if isinstance(value, str) and any(
        word.startswith(("/", "~")) or PureWindowsPath(word).drive for word in value.split()
    ):
        return [value]
    return []
