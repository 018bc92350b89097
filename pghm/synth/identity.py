"""Random identities: a body shape, skin and hair, a face, an outfit and how it drapes.

An :class:`Identity` is a plain record of numbers and choices (JSON-serialisable, stored in
meta.json); :func:`sample_identity` draws one from a ``numpy.random.Generator``. The
painters (:mod:`.paint`) and cloth deformers (:mod:`.cloth`) turn it into textures and
geometry; nothing random happens after sampling.
"""

from __future__ import annotations

import colorsys
from dataclasses import asdict, dataclass
from typing import Literal

import numpy as np

from pghm.errors import PghmError

RGB = tuple[float, float, float]
Pattern = Literal["solid", "stripes", "vstripes", "checks", "plaid", "dots", "print", "denim"]
LogoKind = Literal["none", "ring", "star", "bars", "diamond", "band"]

SHIRT_PATTERNS: tuple[Pattern, ...] = ("solid", "solid", "stripes", "vstripes", "checks", "plaid", "dots", "print")
LOWER_PATTERNS: tuple[Pattern, ...] = ("solid", "solid", "denim", "denim", "denim", "plaid", "stripes")
"""Prints to draw from (repeats weight the choice): tops vary widely, bottoms are mostly
plain or denim, as wardrobes are."""
LOGO_KINDS: tuple[LogoKind, ...] = ("none", "ring", "star", "bars", "diamond", "band")

ANNY_SHAPE_RANGES: dict[str, tuple[float, float]] = {
    "gender": (0.0, 1.0),
    "age": (0.55, 0.9),
    "muscle": (0.2, 0.8),
    "weight": (0.2, 0.8),
    "height": (0.3, 0.62),
    "proportions": (0.3, 0.7),
}
"""Phenotype ranges of adult bodies about 1.5 to 2.0 m tall. Anny's ``age`` runs from a
newborn (0) to old age (1), with adult stature from about 0.55; ``height`` spans 1.3 to
2.4 m for adults over [0, 1]."""

SKIN_TONES: tuple[RGB, ...] = (
    (0.96, 0.82, 0.71),
    (0.90, 0.72, 0.60),
    (0.78, 0.58, 0.44),
    (0.62, 0.44, 0.31),
    (0.45, 0.30, 0.21),
    (0.30, 0.20, 0.14),
)
"""sRGB skin albedos from light to dark; identities interpolate between neighbours."""

HAIR_COLOURS: tuple[RGB, ...] = (
    (0.05, 0.04, 0.04),
    (0.16, 0.10, 0.06),
    (0.32, 0.20, 0.11),
    (0.62, 0.48, 0.28),
    (0.48, 0.20, 0.09),
    (0.55, 0.54, 0.52),
)
"""sRGB hair albedos: black, dark brown, brown, blond, red, grey."""

EYE_COLOURS: tuple[RGB, ...] = ((0.25, 0.15, 0.08), (0.12, 0.30, 0.45), (0.25, 0.35, 0.18), (0.10, 0.07, 0.05))


@dataclass(frozen=True)
class Garment:
    """Colours and print of one piece of clothing.

    Attributes:
        colour: sRGB base colour.
        accent: sRGB second colour of the pattern.
        detail: sRGB third colour (thin plaid lines, prints).
        pattern: the print.
        period: pattern repeat, metres.
        duty: fraction of a period in the accent colour (stripes, dots).
        gloss: specular strength of the fabric.
    """

    colour: RGB
    accent: RGB
    detail: RGB
    pattern: Pattern
    period: float
    duty: float
    gloss: float


@dataclass(frozen=True)
class Identity:
    """Everything that makes one synthetic person (all lengths in metres).

    Attributes:
        shape: body shape parameters (S,), the body model's phenotypes.
        skin: sRGB skin albedo.
        hair_colour: sRGB hair albedo.
        hair_length: 0 (cropped above the ears) to 1 (to the shoulders); < 0 is bald.
        hair_volume: outward offset of the hair cap.
        fringe: how far the front hairline drops towards the brows, 0 to 1.
        eye_colour: sRGB iris colour.
        lip_colour: sRGB lip colour.
        brow_thickness: eyebrow height.
        shirt: the top.
        sleeve: sleeve length as a fraction of the shoulder-to-wrist length.
        neckline: "round", "v" or "crew".
        logo: chest print of the top.
        logo_colour: sRGB colour of the chest print.
        logo_size: half-size of the chest print.
        loose_sleeves: extra offset at the cuff of a loose sleeve.
        hood: whether the top has a hood lying on the upper back.
        lower: trousers, shorts or skirt.
        lower_kind: "trousers", "shorts" or "skirt".
        lower_length: trouser leg or skirt length from the hip joint along the leg.
        flare: extra offset at the ankle of flared trousers.
        skirt_flare: outward offset at the hem of a skirt.
        untucked: the top's hem hangs below the waistband.
        belt: whether a belt with a buckle is worn.
        belt_colour: sRGB belt colour.
        shoe_colour: sRGB upper of the shoes.
        sole_colour: sRGB soles.
        shoe_height: how high the shoes reach above the ankle joint (boots are higher).
        wrinkle_strength: amplitude scale of the pose-dependent folds, 0 to 1.
        wrinkle_wavelength: spacing of the folds.
        texture_seed: seed of the fabric noise, prints and fold phases.
    """

    shape: tuple[float, ...]
    skin: RGB
    hair_colour: RGB
    hair_length: float
    hair_volume: float
    fringe: float
    eye_colour: RGB
    lip_colour: RGB
    brow_thickness: float
    shirt: Garment
    sleeve: float
    neckline: Literal["round", "v", "crew"]
    logo: LogoKind
    logo_colour: RGB
    logo_size: float
    loose_sleeves: float
    hood: bool
    lower: Garment
    lower_kind: Literal["trousers", "shorts", "skirt"]
    lower_length: float
    flare: float
    skirt_flare: float
    untucked: bool
    belt: bool
    belt_colour: RGB
    shoe_colour: RGB
    sole_colour: RGB
    shoe_height: float
    wrinkle_strength: float
    wrinkle_wavelength: float
    texture_seed: int

    def to_json(self) -> dict:
        """A JSON-ready dict (tuples become lists)."""
        return asdict(self)


def _hsv(h: float, s: float, v: float) -> RGB:
    return tuple(round(float(c), 4) for c in colorsys.hsv_to_rgb(h % 1.0, s, v))  # type: ignore[return-value]


def _fabric_colour(rng: np.random.Generator) -> RGB:
    """A clothing colour: saturated, pastel, dark or neutral, as wardrobes are."""
    kind = rng.choice(["saturated", "pastel", "dark", "neutral"], p=[0.35, 0.2, 0.25, 0.2])
    hue = rng.uniform()
    if kind == "saturated":
        return _hsv(hue, rng.uniform(0.55, 0.95), rng.uniform(0.55, 0.95))
    if kind == "pastel":
        return _hsv(hue, rng.uniform(0.15, 0.4), rng.uniform(0.8, 0.97))
    if kind == "dark":
        return _hsv(hue, rng.uniform(0.3, 0.8), rng.uniform(0.12, 0.35))
    return _hsv(hue, rng.uniform(0.0, 0.08), rng.uniform(0.1, 0.95))


def _contrast(rng: np.random.Generator, base: RGB) -> RGB:
    """A colour that stands out against ``base`` (value difference >= 0.35)."""
    for _ in range(16):
        colour = _fabric_colour(rng)
        if abs(max(colour) - max(base)) >= 0.35:
            return colour
    return (0.95, 0.95, 0.95) if max(base) < 0.5 else (0.08, 0.08, 0.1)


def _garment(rng: np.random.Generator, patterns: tuple[Pattern, ...], denim_blue: bool = False) -> Garment:
    pattern: Pattern = patterns[int(rng.integers(len(patterns)))]
    colour = _fabric_colour(rng)
    if pattern == "denim" or (denim_blue and rng.uniform() < 0.3):
        pattern = "denim"
        colour = _hsv(rng.uniform(0.57, 0.63), rng.uniform(0.35, 0.7), rng.uniform(0.25, 0.6))
    accent = _contrast(rng, colour)
    return Garment(
        colour=colour,
        accent=accent,
        detail=_contrast(rng, accent),
        pattern=pattern,
        period=float(rng.uniform(0.025, 0.09)),
        duty=float(rng.uniform(0.2, 0.5)),
        gloss=float(rng.choice([0.05, 0.1, 0.15, 0.35])),
    )


def _mix(a: RGB, b: RGB, t: float) -> RGB:
    return tuple(round((1 - t) * x + t * y, 4) for x, y in zip(a, b, strict=True))  # type: ignore[return-value]


def sample_shape(rng: np.random.Generator, shape_names: list[str]) -> tuple[float, ...]:
    """Phenotype parameters of an adult: uniform within :data:`ANNY_SHAPE_RANGES`."""
    unknown = [name for name in shape_names if name not in ANNY_SHAPE_RANGES]
    if unknown:
        raise PghmError(f"synthetic identities need the anny body's phenotypes; this body has {', '.join(unknown)}")
    return tuple(round(float(rng.uniform(*ANNY_SHAPE_RANGES[name])), 4) for name in shape_names)


def sample_identity(rng: np.random.Generator, shape_names: list[str]) -> Identity:
    """Draw one identity; every random choice comes from ``rng``, in a fixed order."""
    shape = sample_shape(rng, shape_names)
    tone = rng.uniform(0, len(SKIN_TONES) - 1)
    low = int(np.floor(tone))
    skin = _mix(SKIN_TONES[low], SKIN_TONES[min(low + 1, len(SKIN_TONES) - 1)], tone - low)
    hair = HAIR_COLOURS[int(rng.integers(len(HAIR_COLOURS)))]
    hair_length = float(rng.uniform(-0.15, 1.0))
    shirt = _garment(rng, SHIRT_PATTERNS)
    lower_kind = str(rng.choice(["trousers", "shorts", "skirt"], p=[0.6, 0.2, 0.2]))
    lower = _garment(rng, LOWER_PATTERNS, denim_blue=lower_kind == "trousers")
    lengths = {"trousers": (0.78, 0.86), "shorts": (0.16, 0.32), "skirt": (0.25, 0.55)}
    boots = rng.uniform() < 0.25
    return Identity(
        shape=shape,
        skin=skin,
        hair_colour=hair,
        hair_length=hair_length,
        hair_volume=float(rng.uniform(0.004, 0.02)),
        fringe=float(rng.uniform(0.0, 1.0)),
        eye_colour=EYE_COLOURS[int(rng.integers(len(EYE_COLOURS)))],
        lip_colour=_mix(skin, (0.65, 0.25, 0.25), float(rng.uniform(0.3, 0.7))),
        brow_thickness=float(rng.uniform(0.003, 0.0065)),
        shirt=shirt,
        sleeve=float(rng.choice([0.25, 0.45, 0.7, 1.0]) + rng.uniform(-0.05, 0.05)),
        neckline=str(rng.choice(["round", "v", "crew"])),  # type: ignore[arg-type]
        logo=LOGO_KINDS[int(rng.integers(len(LOGO_KINDS)))],
        logo_colour=_contrast(rng, shirt.colour),
        logo_size=float(rng.uniform(0.035, 0.075)),
        loose_sleeves=float(rng.choice([0.0, 0.0, rng.uniform(0.01, 0.035)])),
        hood=bool(rng.uniform() < 0.2),
        lower=lower,
        lower_kind=lower_kind,  # type: ignore[arg-type]
        lower_length=float(rng.uniform(*lengths[lower_kind])),
        flare=float(rng.uniform(0.01, 0.04)) if lower_kind == "trousers" and rng.uniform() < 0.35 else 0.0,
        skirt_flare=float(rng.uniform(0.04, 0.12)) if lower_kind == "skirt" else 0.0,
        untucked=bool(rng.uniform() < 0.5),
        belt=bool(rng.uniform() < 0.4),
        belt_colour=_hsv(rng.uniform(0.02, 0.1), rng.uniform(0.3, 0.7), rng.uniform(0.08, 0.45)),
        shoe_colour=_fabric_colour(rng),
        sole_colour=(0.92, 0.92, 0.9) if rng.uniform() < 0.6 else (0.1, 0.1, 0.1),
        shoe_height=float(rng.uniform(0.08, 0.16)) if boots else float(rng.uniform(0.0, 0.03)),
        wrinkle_strength=float(rng.uniform(0.6, 1.0)),
        wrinkle_wavelength=float(rng.uniform(0.022, 0.034)),
        texture_seed=int(rng.integers(2**31)),
    )
