"""Export posed Gaussians as Niantic's SPZ (``.spz``), the compressed layout Spark, SuperSplat and
Babylon.js read.

A gzip stream of a 16-byte little-endian header (magic ``NGSP``, version, count, SH degree,
fractional bits, flags, a reserved byte) and then each attribute for all Gaussians in turn:

    positions  3 x 24-bit signed fixed point, FRACTIONAL_BITS fractional bits (1/4096 m)
    alphas     round(255 opacity)
    colours    round(255 (COLOR_SCALE f_dc + 0.5)),  f_dc = (rgb - 0.5) / SH_C0
    scales     3 x round(16 (log s + 10))
    rotations  3 x round(127.5 q + 127.5) of the unit quaternion's x, y, z (w >= 0 implied)

Version 2 of the layout, which every SPZ reader reads (version 3 changes only the rotation's
packing, and pghm's Gaussians are isotropic: the identity rotation, stored exactly as 128, 128,
128). Degree 0: the view-dependent colour is baked for one view, as in the .ply export. SPZ's
frame is right-up-back, which is pghm's world frame seen from the front (x right, y up, the body
facing +z), so coordinates are written as they are.

What the layout loses (docs/export.md): a position moves by at most 2^-13 m per axis, a colour
channel by SH_C0 / (2 COLOR_SCALE 255) = 0.0037, an opacity by 1/510, and a scale by a factor of
at most e^(1/32) = 1.032, the largest error of the four.
"""

from __future__ import annotations

import gzip
import struct
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from pghm.errors import PghmError
from pghm.io.atomic import atomic_write_bytes
from pghm.io.ply import SH_C0

MAGIC = 0x5053474E
"""``NGSP`` read as a little-endian uint32."""
VERSION = 2
HEADER = struct.Struct("<IIIBBBB")
"""magic, version, count, SH degree, fractional bits, flags, reserved."""
FRACTIONAL_BITS = 12
"""Fractional bits of the fixed-point positions: a 1/4096 m (0.24 mm) grid."""
COLOR_SCALE = 0.15
"""The layout's scale of f_dc into a byte (below 1/(2 SH_C0), so colours a little outside [0, 1] fit)."""
LOG_SCALE_OFFSET, LOG_SCALE_STEPS = 10.0, 16.0
"""A scale byte is round(LOG_SCALE_STEPS (log s + LOG_SCALE_OFFSET))."""
MAX_COORDINATE = (2**23 - 1) / 2**FRACTIONAL_BITS
"""The largest |coordinate| in metres 24 bits hold (2048 m)."""
MIN_SCALE, MAX_SCALE = float(np.exp(-LOG_SCALE_OFFSET)), float(np.exp(255 / LOG_SCALE_STEPS - LOG_SCALE_OFFSET))
"""The scales a byte holds: 45 micrometres to 380 m."""
IDENTITY_ROTATION = 128
"""Each of x, y, z of the identity quaternion as stored: round(127.5)."""


def _rounded(values: np.ndarray) -> np.ndarray:
    """Round half away from zero, as the reference coder's ``std::round`` (numpy's rounds half to even)."""
    return np.trunc(values + np.copysign(0.5, values))


def _bytes(values: np.ndarray) -> np.ndarray:
    return np.clip(_rounded(values), 0, 255).astype(np.uint8)


def spz_bytes(means: Tensor, scales: Tensor, colors: Tensor, opacities: Tensor) -> bytes:
    """The .spz file of N isotropic Gaussians: means (N, 3), scales (N,), colors (N, 3), opacities (N,).

    Colours and opacities outside what a byte holds are the layout's to clip (a colour beyond
    [-0.94, 1.94] does not occur in a render's [0, 1]); a position or scale outside the layout's
    range is refused: it would move the Gaussian, not round it.
    """
    n = means.shape[0]
    if means.shape != (n, 3) or scales.shape != (n,) or colors.shape != (n, 3) or opacities.shape != (n,):
        raise PghmError("spz export needs means (N, 3), scales (N,), colors (N, 3), opacities (N,)")
    tensors = (means, scales, colors, opacities)
    means64, scales64, colors64, alphas64 = (t.detach().cpu().double().numpy() for t in tensors)
    if n and (far := np.abs(means64).max()) > MAX_COORDINATE:
        raise PghmError(f"spz holds coordinates within +-{MAX_COORDINATE:.0f} m; a Gaussian lies {far:.3g} m out")
    if n and not (MIN_SCALE <= scales64.min() and scales64.max() <= MAX_SCALE):
        raise PghmError(
            f"spz holds scales of {MIN_SCALE:.2g} to {MAX_SCALE:.3g} m; "
            f"these span {scales64.min():.3g} to {scales64.max():.3g}"
        )
    fixed = _rounded(means64 * 2**FRACTIONAL_BITS).astype("<i4").reshape(-1, 1).view(np.uint8)[:, :3]
    f_dc = (colors64 - 0.5) / SH_C0
    parts = (
        HEADER.pack(MAGIC, VERSION, n, 0, FRACTIONAL_BITS, 0, 0),
        fixed,
        _bytes(255 * alphas64),
        _bytes(255 * (COLOR_SCALE * f_dc + 0.5)),
        _bytes(LOG_SCALE_STEPS * (np.log(scales64) + LOG_SCALE_OFFSET))[:, None].repeat(3, 1),
        np.full((n, 3), IDENTITY_ROTATION, np.uint8),
    )
    payload = b"".join(part if isinstance(part, bytes) else np.ascontiguousarray(part).tobytes() for part in parts)
    return gzip.compress(payload, compresslevel=9, mtime=0)


def write_spz(path: str | Path, means: Tensor, scales: Tensor, colors: Tensor, opacities: Tensor) -> None:
    """Write N Gaussians as a .spz, atomically."""
    atomic_write_bytes(path, spz_bytes(means, scales, colors, opacities))


def read_spz(path: str | Path) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Read a degree-0, version-2 .spz of isotropic Gaussians (as :func:`write_spz` writes):
    means (N, 3), scales (N,), colors (N, 3), opacities (N,); a scale is the geometric mean of the three."""
    try:
        data = gzip.decompress(Path(path).read_bytes())
    except (OSError, EOFError) as error:
        raise PghmError(f"{path}: not a gzip stream ({error})") from None
    if len(data) < HEADER.size:
        raise PghmError(f"{path}: too short for an SPZ header")
    magic, version, n, degree, bits, _, _ = HEADER.unpack_from(data)
    if magic != MAGIC or version != VERSION or degree != 0:
        raise PghmError(
            f"{path}: not a degree-0 version-{VERSION} SPZ (magic {magic:#x}, version {version}, degree {degree})"
        )
    if len(data) != HEADER.size + 19 * n:
        raise PghmError(f"{path}: {len(data)} bytes for {n} Gaussians")
    body = np.frombuffer(data, np.uint8, offset=HEADER.size)
    positions, alphas, colours, scales = np.split(body[: 16 * n], [9 * n, 10 * n, 13 * n])
    padded = np.zeros((3 * n, 4), np.uint8)
    padded[:, :3] = positions.reshape(-1, 3)
    padded[:, 3] = np.where(padded[:, 2] & 0x80, 0xFF, 0)  # sign extension of the 24-bit integers
    means = padded.view("<i4").reshape(n, 3) / 2**bits
    f_dc = (colours.reshape(n, 3) / 255 - 0.5) / COLOR_SCALE
    log_scales = scales.reshape(n, 3) / LOG_SCALE_STEPS - LOG_SCALE_OFFSET

    def tensor(values: np.ndarray) -> Tensor:
        return torch.from_numpy(np.ascontiguousarray(values, dtype=np.float32))

    return tensor(means), tensor(np.exp(log_scales.mean(1))), tensor(f_dc * SH_C0 + 0.5), tensor(alphas / 255)
