"""Backgrounds for training and evaluation: targets composited through their masks, renders on the same.

The splatter composites front to back onto a background b (pghm.splat, step 6):

    rgb_b = sum_i c_i alpha_i T_i + (1 - alpha) b,     alpha = 1 - T_N,

so a render on any background image B (3, H, W) is the render on black plus (1 - alpha) B,
exactly: one render serves every background. A target stored on white (the subject format)
with its alpha matte a (the covered fraction of each pixel, 0 outside the person, 1 inside,
in between on the outline) is I = a c + (1 - a) with c the person's colour, so on B it is

    I_B = a c + (1 - a) B = I - (1 - a)(1 - B)     where a > 0,   B where a = 0

(exact; for a binary mask m it is m I + (1 - m) B). A binary mask instead of the matte would
leave the white (1 - a) of the outline's pixels in every target: an opaque whitish rim the
avatar learns, which on a dark background shows as a one-pixel halo (docs/training.md).

Training on white alone lets a semi-transparent white fringe around the silhouette cost nothing
(it is invisible on white and glows on a dark background); a background that changes every step
makes any colour the fringe has wrong most of the time, and the silhouette term
(:func:`pghm.train.losses.silhouette`) asks the accumulated alpha to match the mask directly.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from pghm.errors import PghmError

WHITE = (1.0, 1.0, 1.0)
"""The paper's background: its targets are the stored images, its renders on white."""
BLACK = (0.0, 0.0, 0.0)
NAMED_COLOURS = {"white": WHITE, "black": BLACK}

BACKGROUND_KINDS = ("white", "colour", "gradient")
"""How a training step's backgrounds are drawn: ``white`` (the paper: stored targets, renders on
white), ``colour`` (one uniform random colour per image), ``gradient`` (per image, a linear ramp
between two random colours along a random direction)."""

TRAINING_BACKGROUND = "colour"
"""The default of ``pghm fit`` and ``pghm train-prior`` (docs/training.md, "Backgrounds")."""
SILHOUETTE_WEIGHT = 1.0
"""The default weight of the silhouette term in ``pghm train-prior`` (``pghm fit`` has its own,
:data:`pghm.train.fit.FIT_SILHOUETTE_WEIGHT`)."""

BACKGROUND_SALT = 0xB6
"""Separates the backgrounds' random stream from the batch plan's (same seed and step)."""


def parse_colour(text: str) -> tuple[float, float, float]:
    """'white', 'black', '0.2,0.3,0.4' (floats in [0, 1]) or '#334455' -> an (r, g, b) tuple.

    Raises PghmError naming the text for anything else.
    """
    text = text.strip().lower()
    if text in NAMED_COLOURS:
        return NAMED_COLOURS[text]
    if text.startswith("#"):
        digits = text[1:]
        if len(digits) == 6 and all(c in "0123456789abcdef" for c in digits):
            return tuple(int(digits[i : i + 2], 16) / 255 for i in (0, 2, 4))
        raise PghmError(f"background {text!r}: a hex colour has six hex digits, like #334455")
    try:
        values = tuple(float(part) for part in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not all(math.isfinite(v) and 0.0 <= v <= 1.0 for v in values):
        raise PghmError(f"background {text!r}: expected white, black, r,g,b in [0, 1] (0.2,0.3,0.4) or #334455")
    return values


def composite_target(image: Tensor, matte: Tensor, background: Tensor) -> Tensor:
    """(B, 3, H, W) targets I on white (B, 3, H, W) moved through their alpha mattes a
    (B, 1, H, W) in [0, 1] onto backgrounds B (B, 3, H, W) or (3, 1, 1):
    I - (1 - a)(1 - B) where a > 0, B elsewhere (module doc)."""
    return torch.where(matte > 0, image - (1.0 - matte) * (1.0 - background), background)


def composite_render(rgb_on_black: Tensor, alpha: Tensor, background: Tensor) -> Tensor:
    """(B, 3, H, W) renders on black (B, 3, H, W) with accumulated alpha (B, 1, H, W) moved onto
    backgrounds (B, 3, H, W) or (3, 1, 1): rgb_black + (1 - alpha) background (exact, module doc)."""
    return rgb_on_black + (1.0 - alpha) * background


def draw_backgrounds(kind: str, count: int, height: int, width: int, seed: tuple[int, ...]) -> Tensor | None:
    """(count, 3, H, W) float32 backgrounds of one group of a step, or None for ``white`` (the
    paper's stored targets). ``seed`` (e.g. (seed, step, group)) alone decides them, so a resumed
    or distributed run draws the same ones.

    ``colour``: c ~ U[0, 1]^3 per image. ``gradient``: c0 + (c1 - c0) t(x), t the pixel's
    position along a random unit direction, scaled to [0, 1] over the image.
    """
    if kind not in BACKGROUND_KINDS:
        raise PghmError(f"background kind must be one of {', '.join(BACKGROUND_KINDS)}, got {kind!r}")
    if kind == "white":
        return None
    gen = np.random.default_rng((*seed, BACKGROUND_SALT))
    first = torch.from_numpy(gen.random((count, 3, 1, 1))).float()
    if kind == "colour":
        return first.expand(count, 3, height, width).contiguous()
    last = torch.from_numpy(gen.random((count, 3, 1, 1))).float()
    angle = torch.from_numpy(gen.uniform(0.0, 2.0 * math.pi, count)).float()
    rows = torch.linspace(0.0, 1.0, height).view(1, height, 1)
    cols = torch.linspace(0.0, 1.0, width).view(1, 1, width)
    along = angle.cos().view(-1, 1, 1) * cols + angle.sin().view(-1, 1, 1) * rows
    low = along.flatten(1).amin(1).view(-1, 1, 1)
    high = along.flatten(1).amax(1).view(-1, 1, 1)
    t = ((along - low) / (high - low)).unsqueeze(1)
    return first + (last - first) * t
