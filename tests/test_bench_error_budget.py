"""benchmarks/bench_error_budget.py's outline tables on frames made by hand, against what the
frames' construction fixes: the compositing identities, the distances of a straight edge, and
where an error was put."""

from __future__ import annotations

import importlib
from pathlib import Path

import numpy as np
import pytest

from pghm.capture.matte import outline_distance

H, W, EDGE = 24, 32, 12
"""A frame of H x W pixels whose matte covers the columns left of EDGE."""
EXACT_DB = 200.0
"""PSNR of images equal but for float64 rounding (C / A * A: relative 1e-16, 320 dB)."""


@pytest.fixture
def bench(monkeypatch):
    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parent.parent / "benchmarks"))
    return importlib.import_module("bench_error_budget")


def frame(bench, matte: np.ndarray, alpha: np.ndarray, colour: np.ndarray):
    """A held-out frame whose stored image is ``colour`` through ``matte`` and whose render is the
    same colours through ``alpha``, both on white."""
    a, alpha3 = matte[..., None], alpha[..., None]
    return bench.ScoredFrame(
        index=0,
        truth=colour * a + 1 - a,
        render=colour * alpha3 + 1 - alpha3,
        rgb=colour * alpha3,
        alpha=alpha,
        matte=matte,
    )


def straight_edge(ramp: float) -> tuple[np.ndarray, np.ndarray]:
    """The matte (1 left of EDGE) and an alpha falling linearly over ``ramp`` px about the same edge."""
    x = np.arange(W) + 0.5
    matte = np.broadcast_to((x < EDGE).astype(np.float64), (H, W)).copy()
    alpha = np.broadcast_to(np.clip(0.5 - (x - EDGE) / ramp, 0, 1), (H, W)).copy()
    return matte, alpha


def test_swapping_in_the_matte_gives_back_the_stored_image(bench):
    """With the render's colours equal to the stored ones, the matte's coverage makes the stored
    image exactly, and the stored colours through the render's alpha make the render."""
    rng = np.random.default_rng(0)
    matte, alpha = straight_edge(ramp=5.0)
    colour = rng.uniform(0, 1, (H, W, 3))
    f = frame(bench, matte, alpha, colour)
    psnr = bench.coverage_swaps([f])
    assert psnr["avatar colours, matte's coverage"] > EXACT_DB
    assert psnr["stored colours, avatar's coverage"] == pytest.approx(psnr["as rendered"], abs=1e-9)
    assert psnr["as rendered"] == pytest.approx(bench.psnr_of(float(f.error.mean())), abs=1e-12)


def test_the_profile_of_a_straight_edge(bench):
    """Column EDGE - 1 is 1 px inside the outline, column EDGE 1 px outside; the profile reads each
    side's alpha there and gives every error to the column it lies in."""
    matte, alpha = straight_edge(ramp=5.0)
    f = frame(bench, matte, alpha, np.zeros((H, W, 3)))
    rows = {r["distance px"]: r for r in bench.outline_profile([f], reach=3)}
    assert sorted(rows) == [-3, -2, -1, 1, 2, 3]
    for d, column in ((-1, EDGE - 1), (1, EDGE), (-3, EDGE - 3), (3, EDGE + 2)):
        assert rows[d]["pixels"] == H
        assert rows[d]["render alpha"] == pytest.approx(alpha[0, column])
        assert rows[d]["matte alpha"] == matte[0, column]
    assert np.array_equal(np.rint(outline_distance(f.mask))[0, EDGE - 3 : EDGE + 3], [3, 2, 1, 1, 2, 3])
    per_column = f.error.sum(0) / f.error.sum()
    assert rows[1]["error %"] == pytest.approx(100 * per_column[EDGE])
    assert sum(r["error %"] for r in rows.values()) == pytest.approx(100 * per_column[EDGE - 3 : EDGE + 3].sum())


def test_height_shares_put_an_error_in_its_tenth(bench):
    """The person spans rows 4..23 (20 rows, two per tenth): an error on row 21 lies in the ninth
    tenth, one above the person in the first."""
    matte = np.zeros((H, W))
    matte[4:, :EDGE] = 1.0
    f = frame(bench, matte, matte.copy(), np.zeros((H, W, 3)))
    render = f.render.copy()
    render[21, 3] = 0.5
    render[1, 20] = 0.5
    shares = bench.height_shares([bench.ScoredFrame(0, f.truth, render, f.rgb, f.alpha, f.matte)])
    assert len(shares) == bench.HEIGHT_BINS
    assert shares[8] == pytest.approx(50.0) and shares[0] == pytest.approx(50.0)
    assert sum(shares) == pytest.approx(100.0)
