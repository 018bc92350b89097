"""The capture's colour-model matte (pghm.capture.matte) on analytic images: a disc of one colour over
another, its coverage by supersampling, and a binary mask that misses the outline by a pixel."""

from __future__ import annotations

import numpy as np
import pytest

from pghm.capture.matte import BAND, CONTRAST, colour_matte, on_white

SIZE = 96
RADIUS = 30.3
"""Off the pixel grid, so the outline's pixels are covered in part."""
SUPERSAMPLE = 16
PERSON = np.array([51, 77, 153]) / 255
WALL = np.array([204, 191, 153]) / 255
"""Colours a uint8 frame holds exactly (the matte sees only those)."""
QUANTUM = 0.5 / 255
"""Largest rounding error of a colour stored in uint8."""


def disc_coverage(radius: float) -> np.ndarray:
    """(SIZE, SIZE) covered fraction of each pixel by the centred disc, SUPERSAMPLE^2 samples a pixel."""
    offsets = (np.arange(SUPERSAMPLE) + 0.5) / SUPERSAMPLE
    samples = np.arange(SIZE)[:, None] + offsets[None, :]
    centre = SIZE / 2
    d = samples.reshape(-1) - centre  # sample coordinates along either axis, from the centre
    inside = d[:, None] ** 2 + d[None, :] ** 2 <= radius**2
    return inside.reshape(SIZE, SUPERSAMPLE, SIZE, SUPERSAMPLE).mean((1, 3))


def frame(coverage: np.ndarray, person: np.ndarray, wall: np.ndarray) -> np.ndarray:
    """(SIZE, SIZE, 3) uint8: the person's colour over the wall's through ``coverage``."""
    mixed = coverage[..., None] * person + (1 - coverage[..., None]) * wall
    return np.round(mixed * 255).astype(np.uint8)


def alpha_bound(person: np.ndarray, wall: np.ndarray) -> float:
    """Largest error of the matte where the mask is a pixel off: the colour alpha's, uint8 rounding
    through the projection (|dI| |F - B| / |F - B|^2 per channel, summed), plus its blend with the
    mask, at most 1 - c / (c + CONTRAST^2) of the mask's error of 1."""
    contrast = float(((person - wall) ** 2).sum())
    rounding = QUANTUM * float(np.abs(person - wall).sum()) / contrast
    return rounding + 1 - contrast / (contrast + CONTRAST**2)


@pytest.mark.parametrize("mask_shift", [-1.0, 0.0, 1.0])
def test_matte_recovers_the_disc_coverage(mask_shift):
    """A mask grown or shrunk by a pixel: the matte is the true coverage within the analytic bound."""
    coverage = disc_coverage(RADIUS)
    mask = disc_coverage(RADIUS + mask_shift) >= 0.5
    alpha, _ = colour_matte(frame(coverage, PERSON, WALL), mask)
    bound = alpha_bound(PERSON, WALL)
    assert np.abs(mask - coverage).max() > 10 * bound  # the mask alone is far off on the outline
    assert np.abs(alpha - coverage).max() <= bound


def test_on_white_is_the_person_over_white():
    """Through the recovered matte the frame on white is a F + (1 - a): the wall's colour is gone."""
    coverage = disc_coverage(RADIUS)
    image = frame(coverage, PERSON, WALL)
    alpha, background = colour_matte(image, disc_coverage(RADIUS + 1) >= 0.5)
    out = on_white(image, alpha, background).astype(np.float64) / 255
    ideal = coverage[..., None] * PERSON + (1 - coverage[..., None])
    # Rounding of the frame and of the result, and the matte's error times the colour it mixes: |1 - F| <= 1.
    tolerance = 2 * QUANTUM + alpha_bound(PERSON, WALL)
    assert np.abs(out - ideal).max() <= tolerance
    assert (out[alpha == 0] == 1.0).all()


def test_a_person_in_the_walls_colour_keeps_the_mask():
    """No colour contrast, no colour evidence: the matte is the mask within its blend's share."""
    coverage = disc_coverage(RADIUS)
    near_wall = WALL + 3 / 255
    mask = disc_coverage(RADIUS + 1) >= 0.5
    alpha, _ = colour_matte(frame(coverage, near_wall, WALL), mask)
    contrast = float(((near_wall - WALL) ** 2).sum())
    # float32 local means move the contrast in its fourth significant digit
    assert np.abs(alpha - mask).max() <= contrast / (contrast + CONTRAST**2) * 1.001


def test_matte_is_the_mask_away_from_its_outline():
    """Only the band around the mask's outline changes: deep inside 1, far outside 0."""
    coverage = disc_coverage(RADIUS)
    mask = disc_coverage(RADIUS + 1) >= 0.5
    alpha, _ = colour_matte(frame(coverage, PERSON, WALL), mask)
    centre = SIZE / 2
    distance = np.hypot(*np.meshgrid(np.arange(SIZE) + 0.5 - centre, np.arange(SIZE) + 0.5 - centre))
    assert (alpha[distance < RADIUS - BAND - 2] == 1).all() and (alpha[distance > RADIUS + BAND + 3] == 0).all()
