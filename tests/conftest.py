"""Shared fixtures. Tests run on 2 threads, as the target machine has 2 cores."""

from __future__ import annotations

import pytest
import torch

torch.set_num_threads(2)


@pytest.fixture(scope="session")
def body():
    """The default Anny body (built once per session)."""
    from pghm.body import load_body

    return load_body()


@pytest.fixture(scope="session")
def rest(body):
    return body.rest()


@pytest.fixture(scope="session")
def atlas128(body):
    from pghm.uv.atlas import build_atlas

    return build_atlas(body, 128)
