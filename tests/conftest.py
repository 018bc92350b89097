"""Shared fixtures. Tests run on 2 threads, as the target machine has 2 cores, unless
OMP_NUM_THREADS says otherwise (a verdict must not depend on the thread count: the suite is run
with 1 and 2)."""

from __future__ import annotations

import os
from pathlib import PureWindowsPath

import pytest
import torch

from pghm.model import ModelConfig

torch.set_num_threads(int(os.environ.get("OMP_NUM_THREADS", "2")))


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
