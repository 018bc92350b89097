"""Procedural painting of an identity's appearance, evaluated per canonical surface point.

:func:`paint_albedo` gives every point (texel) an sRGB albedo and a specular strength:
skin with a faint mottle, a hair cap with strands, eyes, brows and lips, and the outfit
with its print (stripes, checks, plaid, dots, scattered shapes, denim twill), fine weave
noise, darker hems with stitching, a belt with a buckle, a chest logo and shoes with soles.
Edges are left hard (no smoothing) and the weave varies per millimetre, so that a blurry
reconstruction loses PSNR, as it would on real clothing.

Patterns use the 3D-derived surface coordinates of :mod:`.regions`, so they run
continuously across UV seams. Random detail comes from an integer hash of lattice cells
and ``identity.texture_seed``: the same identity always paints the same texture.

:func:`texels_to_map` scatters per-texel values into an L x L image and dilates them into
the empty texels around the UV islands, so bilinear and mipmapped lookups near island
borders do not blend in the empty background.
"""

from __future__ import annotations

import numpy as np

from pghm.synth.cloth import (
    BOTTOM,
    HAIR,
    HEAD_DEPTH,
    SHOES,
    SKIN,
    TOP,
    hairline_height,
    hem_height,
    waist_height,
)
from pghm.synth.identity import Garment, Identity
from pghm.synth.regions import EYE_BELOW_CROWN, Landmarks, SurfacePoints, chain_lengths
from pghm.uv.atlas import UVAtlas

WEAVE_CELL = 0.0015
"""Metres: the cell of the fabric weave noise (finer than a texel at L = 1024 is ~ 2 mm)."""

WEAVE_CONTRAST = 0.12
"""Peak-to-peak relative brightness variation of the weave."""

SKIN_MOTTLE = 0.05
HAIR_STRAND_CONTRAST = 0.35

SPECULAR = {SKIN: 0.22, HAIR: 0.3, SHOES: 0.55}
"""Specular strength per material (fabrics use their garment's gloss)."""

EYE_SPECULAR = 0.8
BUCKLE_SPECULAR = 0.9
METAL = (0.78, 0.74, 0.6)

DILATION_STEPS = 6
"""Texel rings filled around each UV island (covers the 2x2 footprint of mip level 2)."""


def hash01(i: np.ndarray, j: np.ndarray, seed: int) -> np.ndarray:
    """Deterministic pseudo-random numbers in [0, 1) for integer lattice cells (i, j).

    A multiply-xorshift integer hash (as in PCG's output permutation) on uint64, so every
    platform and numpy version gives the same values.
    """
    with np.errstate(over="ignore"):
        x = (i.astype(np.int64).astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15)) ^ (
            j.astype(np.int64).astype(np.uint64) * np.uint64(0xC2B2AE3D27D4EB4F)
        )
        x ^= np.uint64(seed & 0xFFFFFFFF) * np.uint64(0x165667B19E3779F9)
        x ^= x >> np.uint64(31)
        x *= np.uint64(0xBF58476D1CE4E5B9)
        x ^= x >> np.uint64(29)
    return (x >> np.uint64(11)).astype(np.float64) / float(1 << 53)


def value_noise(u: np.ndarray, v: np.ndarray, cell: float, seed: int) -> np.ndarray:
    """Smooth noise in [0, 1]: hashed lattice values at ``cell`` spacing, bilinearly blended."""
    x, y = u / cell, v / cell
    i, j = np.floor(x), np.floor(y)
    fx, fy = x - i, y - j
    fx, fy = fx * fx * (3 - 2 * fx), fy * fy * (3 - 2 * fy)
    corners = [hash01(i + di, j + dj, seed) for di in (0, 1) for dj in (0, 1)]
    return (corners[0] * (1 - fx) + corners[2] * fx) * (1 - fy) + (corners[1] * (1 - fx) + corners[3] * fx) * fy


def _frac(x: np.ndarray) -> np.ndarray:
    return x - np.floor(x)


def _rgb(colour: tuple[float, float, float], n: int) -> np.ndarray:
    return np.broadcast_to(np.asarray(colour, dtype=np.float64), (n, 3)).copy()


def garment_colours(u: np.ndarray, v: np.ndarray, garment: Garment, seed: int) -> np.ndarray:
    """(N, 3) sRGB colour of a garment's print at surface coordinates (u, v), metres."""
    n = len(u)
    base, accent, detail = (_rgb(c, n) for c in (garment.colour, garment.accent, garment.detail))
    period, duty = garment.period, garment.duty
    colour = base
    if garment.pattern == "stripes":
        colour = np.where((_frac(v / period) < duty)[:, None], accent, base)
    elif garment.pattern == "vstripes":
        colour = np.where((_frac(u / period) < duty)[:, None], accent, base)
    elif garment.pattern == "checks":
        odd = (np.floor(u / period) + np.floor(v / period)) % 2 == 1
        colour = np.where(odd[:, None], accent, base)
    elif garment.pattern == "plaid":
        across, along = _frac(u / period) < 0.3, _frac(v / period) < 0.3
        weight = 0.5 * across + 0.5 * along
        colour = base * (1 - weight[:, None]) + accent * weight[:, None]
        thin = (np.abs(_frac(u / period) - 0.65) < 0.025) | (np.abs(_frac(v / period) - 0.65) < 0.025)
        colour = np.where(thin[:, None], detail, colour)
    elif garment.pattern == "dots":
        row = np.floor(v / period + 0.5)
        shift = 0.5 * (row % 2)
        du = _frac(u / period + shift + 0.5) - 0.5
        dv = _frac(v / period + 0.5) - 0.5
        colour = np.where((np.hypot(du, dv) < 0.5 * duty)[:, None], accent, base)
    elif garment.pattern == "print":
        ci, cj = np.floor(u / period), np.floor(v / period)
        kind = np.floor(hash01(ci, cj, seed) * 4)
        cx = 0.5 + 0.3 * (hash01(ci, cj, seed + 1) - 0.5)
        cy = 0.5 + 0.3 * (hash01(ci, cj, seed + 2) - 0.5)
        size = 0.18 + 0.2 * hash01(ci, cj, seed + 3)
        du, dv = _frac(u / period) - cx, _frac(v / period) - cy
        inside = np.select(
            [kind == 0, kind == 1, kind == 2],
            [
                np.hypot(du, dv) < size,
                np.maximum(np.abs(du), np.abs(dv)) < 0.8 * size,
                (dv > -size) & (np.abs(du) < (size - dv) * 0.6),
            ],
            False,
        )
        second = hash01(ci, cj, seed + 4) < 0.5
        colour = np.where(inside[:, None], np.where(second[:, None], accent, detail), base)
    elif garment.pattern == "denim":
        twill = np.sin(2 * np.pi * (u + v) / 0.004) > 0.3
        heather = value_noise(u, v * 0.2, 0.004, seed + 5)
        colour = base * (0.82 + 0.22 * heather[:, None] + 0.12 * twill[:, None])
    weave = hash01(np.floor(u / WEAVE_CELL), np.floor(v / WEAVE_CELL), seed + 6)
    return colour * (1 + WEAVE_CONTRAST * (weave[:, None] - 0.5))


def _face(
    points: SurfacePoints, marks: Landmarks, identity: Identity, colour: np.ndarray, specular: np.ndarray
) -> None:
    """Paint eyes, brows, lips and cheeks onto the front of the head, in place."""
    p = points.position
    k = (marks.head_top - marks.eye_height) / EYE_BELOW_CROWN
    facing = points.is_part("head") & (points.normal[:, 2] > 0.2) & (p[:, 2] > marks.face_front - 0.05)
    dx = np.abs(p[:, 0]) - marks.eye_offset
    dy = p[:, 1] - marks.eye_height
    sclera = facing & ((dx / (0.0125 * k)) ** 2 + (dy / (0.0062 * k)) ** 2 < 1)
    colour[sclera] = (0.93, 0.91, 0.88)
    iris = sclera & (np.hypot(dx, dy) < 0.0058 * k)
    colour[iris] = identity.eye_colour
    colour[iris & (np.hypot(dx, dy) < 0.0025 * k)] = (0.02, 0.02, 0.02)
    lid = sclera & (dy > 0) & ((dx / (0.0125 * k)) ** 2 + (dy / (0.0062 * k)) ** 2 > 0.55)
    colour[lid] = (0.08, 0.05, 0.04)
    specular[sclera] = EYE_SPECULAR

    brow_dx = dx - 0.002 * k
    half_width = 0.021 * k
    arch = marks.eye_height + 0.017 * k + 0.005 * k * (1 - (brow_dx / half_width) ** 2)
    brow = facing & (np.abs(brow_dx) < half_width) & (np.abs(p[:, 1] - arch) < identity.brow_thickness / 2)
    colour[brow] = np.asarray(identity.hair_colour) * 0.7

    mouth_y = marks.eye_height - 0.07 * k
    across = np.clip(1 - (p[:, 0] / (0.024 * k)) ** 2, 0.0, 1.0)
    upper = (p[:, 1] >= mouth_y) & (p[:, 1] < mouth_y + 0.0055 * k * np.sqrt(across))
    lower = (p[:, 1] < mouth_y) & (p[:, 1] > mouth_y - 0.0075 * k * np.sqrt(across))
    lips = facing & (across > 0) & (upper | lower)
    colour[lips] = identity.lip_colour
    colour[lips & (np.abs(p[:, 1] - mouth_y) < 0.0011 * k)] = np.asarray(identity.lip_colour) * 0.45
    specular[lips] = 0.35

    cheek = np.exp(-((dx - 0.012 * k) ** 2 + (dy + 0.035 * k) ** 2) / (0.016 * k) ** 2) * facing
    colour[:] = colour * (1 - 0.12 * cheek[:, None]) + np.array([0.8, 0.3, 0.3]) * 0.12 * cheek[:, None]


def _logo(points: SurfacePoints, marks: Landmarks, identity: Identity, seed: int) -> np.ndarray:
    """(N,) bool: the chest print of the top."""
    p = points.position
    size = identity.logo_size
    # Centred, or a little off to one side, as chest prints are.
    centre_x = 0.0 if identity.logo in ("band", "bars") else size * np.random.default_rng(seed).uniform(-0.25, 0.25)
    centre_y = marks.spine[2, 1] - 0.03
    a, b = (p[:, 0] - centre_x) / size, (p[:, 1] - centre_y) / size
    front = (p[:, 2] > marks.spine[2, 2]) & (points.normal[:, 2] > 0.2) & points.is_part("torso")
    r, theta = np.hypot(a, b), np.arctan2(b, a)
    if identity.logo == "ring":
        shape = (r < 1) & (r > 0.6) | (r < 0.25)
    elif identity.logo == "star":
        shape = r < 0.42 + 0.58 * (0.5 + 0.5 * np.cos(5 * (theta - np.pi / 2))) ** 4
    elif identity.logo == "bars":
        column = np.floor((a + 1.8) / 0.18)
        shape = (np.abs(a) < 1.8) & (np.abs(b) < 0.3) & (hash01(column, np.zeros_like(column), seed + 7) < 0.6)
    elif identity.logo == "diamond":
        shape = (np.abs(a) + np.abs(b) < 1) & ~(np.abs(a) + np.abs(b) < 0.65) | (np.abs(a) + np.abs(b) < 0.3)
    elif identity.logo == "band":
        return (np.abs(b) < 0.35) & points.is_part("torso")
    else:
        return np.zeros(len(p), dtype=bool)
    return front & shape


def paint_albedo(points: SurfacePoints, labels: np.ndarray, marks: Landmarks, identity: Identity) -> np.ndarray:
    """(N, 4) float in [0, 1]: sRGB albedo and specular strength of every point."""
    n = len(labels)
    seed = identity.texture_seed
    p = points.position
    colour = _rgb(identity.skin, n)
    specular = np.full(n, SPECULAR[SKIN])
    mottle = value_noise(points.u, points.v, 0.006, seed + 10) - 0.5
    colour *= 1 + SKIN_MOTTLE * mottle[:, None]
    _face(points, marks, identity, colour, specular)

    hair = labels == HAIR
    centre = np.array([0.0, marks.eye_height, marks.face_front - HEAD_DEPTH])
    q = p[hair] - centre
    around = np.arctan2(q[:, 0], q[:, 2])
    strands = value_noise(around * 0.09, q[:, 1] * 0.08, 0.0012, seed + 11)
    colour[hair] = np.asarray(identity.hair_colour) * (1 + HAIR_STRAND_CONTRAST * (strands[:, None] - 0.5))
    colour[hair & (p[:, 1] - hairline_height(points, marks, identity) < 0.002)] *= 0.8
    specular[hair] = SPECULAR[HAIR]

    for material, garment, salt in ((TOP, identity.shirt, 20), (BOTTOM, identity.lower, 30)):
        rows = labels == material
        colour[rows] = garment_colours(points.u[rows], points.v[rows], garment, seed + salt)
        specular[rows] = garment.gloss

    top = labels == TOP
    logo = top & _logo(points, marks, identity, seed + 40)
    colour[logo] = identity.logo_colour

    # Hems: a darker band with a dashed stitch just inside every edge of the garments.
    arm_length = chain_lengths(marks.arm_chains[0])[1]
    limbs = points.is_part("upper_arm", "lower_arm", "upper_leg", "lower_leg")
    hem = hem_height(marks, identity)
    dash = np.sin(2 * np.pi * points.u / 0.005) > 0
    edges = [
        (top & ~limbs, np.abs(p[:, 1] - hem)),
        (top & limbs, np.abs(points.limb_s - identity.sleeve * arm_length)),
        (labels == BOTTOM, np.where(limbs, np.abs(points.limb_s - identity.lower_length), np.inf)),
    ]
    for rows, distance in edges:
        colour[rows & (distance < 0.012)] *= 0.78
        colour[rows & (np.abs(distance - 0.008) < 0.0012) & dash] *= 0.6

    waist = waist_height(marks)
    trunk = points.is_part("torso", "hips")
    band = (labels == BOTTOM) & trunk & (p[:, 1] < waist) & (p[:, 1] > waist - 0.035)
    if identity.belt:
        colour[band] = identity.belt_colour
        specular[band] = 0.3
        buckle = band & (np.abs(p[:, 0]) < 0.024) & (p[:, 2] > marks.pelvis[2])
        hole = (np.abs(p[:, 0]) < 0.012) & (np.abs(p[:, 1] - (waist - 0.0175)) < 0.008)
        colour[buckle & ~hole] = METAL
        specular[buckle & ~hole] = BUCKLE_SPECULAR
    else:
        colour[band & (np.abs(p[:, 1] - (waist - 0.033)) < 0.0015)] *= 0.6

    shoes = labels == SHOES
    colour[shoes] = identity.shoe_colour
    specular[shoes] = SPECULAR[SHOES]
    colour[shoes & (p[:, 1] < marks.feet + 0.02)] = identity.sole_colour
    stripe = shoes & (np.abs(p[:, 1] - (marks.feet + 0.045)) < 0.006) & (np.abs(points.normal[:, 0]) > 0.5)
    colour[stripe] = identity.sole_colour
    return np.concatenate([np.clip(colour, 0.0, 1.0), specular[:, None]], axis=1)


def texels_to_map(values: np.ndarray, atlas: UVAtlas) -> np.ndarray:
    """(L, L, C) image of per-texel ``values`` (N, C), dilated around the UV islands.

    Each of :data:`DILATION_STEPS` passes gives every empty texel with a filled 4-neighbour
    the mean of its filled 4-neighbours; texels still empty afterwards get the mean value.
    """
    size = atlas.resolution
    channels = values.shape[1]
    image = np.zeros((size * size, channels))
    filled = np.zeros(size * size, dtype=bool)
    flat = atlas.flat_index.numpy()
    image[flat] = values
    filled[flat] = True
    image = image.reshape(size, size, channels)
    filled = filled.reshape(size, size)
    for _ in range(DILATION_STEPS):
        padded = np.pad(image * filled[..., None], ((1, 1), (1, 1), (0, 0)))
        count = np.pad(filled.astype(np.float64), 1)
        total = padded[:-2, 1:-1] + padded[2:, 1:-1] + padded[1:-1, :-2] + padded[1:-1, 2:]
        neighbours = count[:-2, 1:-1] + count[2:, 1:-1] + count[1:-1, :-2] + count[1:-1, 2:]
        grow = ~filled & (neighbours > 0)
        image[grow] = total[grow] / neighbours[grow][:, None]
        filled = filled | grow
    image[~filled] = values.mean(0)
    return image
