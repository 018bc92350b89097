"""The person's alpha matte on the outline, from the frame's colours, and the image on white through it.

MediaPipe's segmentation is a low-resolution probability scaled up to the frame and cut at a
threshold: a binary mask whose outline wanders a pixel or two from the person's (docs/capture.md).
Stored as it is, the image on white takes background colour where the mask reaches past the
person and white where it falls short, and an outline pixel that the person covers in part is
all person or all white: the held-out truth and the fit's targets get a jagged, mis-coloured rim.

Colour-model matting on a band around the mask's outline. Each pixel I of the band is a mix
I = a F + (1 - a) B of the person's colour F and the background's B; near the outline F and B
are taken as the mean colours of the sure person (mask pixels farther than :data:`BAND` px from
the outline) and of the sure background (likewise outside), weighted by a Gaussian of
:data:`COLOUR_SIGMA` px around the pixel (normalised convolution). The least-squares alpha is
the projection

    a = (I - B) . (F - B) / |F - B|^2,     clipped to [0, 1],

trusted where the two colours differ: with contrast c = |F - B|^2 it is blended with the mask by
w = c / (c + CONTRAST^2), so a person in the wall's colour keeps the mask. Outside the band the
matte is the mask. On white the person is then I + (1 - a)(1 - B) (exact for the model: a F + (1 - a)),
and white where a = 0.
"""

from __future__ import annotations

import cv2
import numpy as np

BAND = 2.0
"""Half-width (px of the subject's images) of the band around the mask's outline whose alpha is
estimated from colour; MediaPipe's outline is within it on the synthetic truth (docs/capture.md)."""
COLOUR_SIGMA = 5.0
"""Gaussian (px) over which the sure person's and sure background's mean colours are taken."""
CONTRAST = 0.1
"""RGB distance |F - B| (colours in [0, 1]) at which the colour alpha and the mask weigh the same."""
MIN_WEIGHT = 1e-3
"""Least Gaussian weight of sure pixels for a local mean colour; the band keeps the mask elsewhere."""


def outline_distance(mask: np.ndarray) -> np.ndarray:
    """(H, W) float32: each pixel's distance (px) to the nearest pixel on the other side of ``mask`` (H, W) bool."""
    m = mask.astype(np.uint8)
    return np.where(mask, cv2.distanceTransform(m, cv2.DIST_L2, 5), cv2.distanceTransform(1 - m, cv2.DIST_L2, 5))


def local_mean(image: np.ndarray, weight: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """Normalised convolution: ((H, W, 3) Gaussian-weighted mean of ``image`` over the pixels ``weight``
    (H, W) float selects, (H, W) the summed weight)."""
    total = cv2.GaussianBlur(weight, (0, 0), sigma)
    summed = cv2.GaussianBlur(image * weight[..., None], (0, 0), sigma)
    return summed / np.maximum(total, MIN_WEIGHT)[..., None], total


def colour_matte(image: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(alpha (H, W) float32 in [0, 1], background (H, W, 3) float32) of ``image`` (H, W, 3) uint8 and its
    ``mask`` (H, W) bool: the module's colour-model alpha on the band, the mask elsewhere; the background
    is the local mean of the sure background (meaningful on the band only)."""
    pixels = image.astype(np.float32) / 255
    distance = outline_distance(mask)
    band = distance <= BAND
    sure_person = (mask & ~band).astype(np.float32)
    sure_background = (~mask & ~band).astype(np.float32)
    person, person_weight = local_mean(pixels, sure_person, COLOUR_SIGMA)
    background, background_weight = local_mean(pixels, sure_background, COLOUR_SIGMA)
    spread = person - background
    contrast = (spread * spread).sum(-1)
    projected = np.clip(((pixels - background) * spread).sum(-1) / np.maximum(contrast, 1e-12), 0.0, 1.0)
    trust = contrast / (contrast + CONTRAST**2)
    trust *= (person_weight > MIN_WEIGHT) & (background_weight > MIN_WEIGHT)
    alpha = mask.astype(np.float32)
    alpha[band] = (trust * projected + (1 - trust) * alpha)[band]
    return alpha, background


def on_white(image: np.ndarray, alpha: np.ndarray, background: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8: ``image`` (H, W, 3) uint8 = a F + (1 - a) B moved onto white, I + (1 - a)(1 - B),
    white where the matte ``alpha`` (H, W) is 0; ``background`` (H, W, 3) float B in [0, 1]."""
    pixels = image.astype(np.float32) / 255
    out = pixels + (1 - alpha)[..., None] * (1 - background)
    out = np.where(alpha[..., None] > 0, np.clip(out, 0.0, 1.0), 1.0)
    return np.round(out * 255).astype(np.uint8)
