"""Export posed Gaussians as a standard 3DGS ``.ply`` (readable by other 3DGS viewers).

Binary little-endian vertex records with the layout of the original 3DGS code:

    x y z  nx ny nz  f_dc_0..2  f_rest_0..44  opacity  scale_0..2  rot_0..3

with f_dc = (rgb - 0.5) / SH_C0 (the degree-0 spherical-harmonic coefficient), f_rest zero
(view-dependent colour is baked into f_dc for one stated view), opacity as a logit, the
isotropic scale as log(s) on all three axes, and rot = (1, 0, 0, 0) (w first). Normals are
zero, as 3DGS writes them.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from pghm.errors import PghmError
from pghm.io.atomic import atomic_write_bytes

SH_C0 = 0.28209479177387814
"""Y_0^0 = 1 / (2 sqrt(pi)): rgb = SH_C0 f_dc + 0.5."""
NUM_REST = 45
"""Higher-order SH coefficients of a degree-3 3DGS file (15 per channel), all zero here."""
OPACITY_LOGIT_MAX = 20.0
"""Logit written for opacity 1; sigmoid(20) rounds to exactly 1.0 in float32."""

PROPERTIES = (
    ["x", "y", "z", "nx", "ny", "nz"]
    + [f"f_dc_{i}" for i in range(3)]
    + [f"f_rest_{i}" for i in range(NUM_REST)]
    + ["opacity"]
    + [f"scale_{i}" for i in range(3)]
    + [f"rot_{i}" for i in range(4)]
)


def _logit(p: Tensor) -> Tensor:
    p = p.double()
    logit = torch.log(p) - torch.log1p(-p)
    return torch.where(p >= 1.0, torch.full_like(p, OPACITY_LOGIT_MAX), logit.clamp(max=OPACITY_LOGIT_MAX))


def ply_bytes(means: Tensor, scales: Tensor, colors: Tensor, opacities: Tensor) -> bytes:
    """The .ply file of N Gaussians: means (N, 3), scales (N,), colors (N, 3), opacities (N,)."""
    n = means.shape[0]
    if means.shape != (n, 3) or scales.shape != (n,) or colors.shape != (n, 3) or opacities.shape != (n,):
        raise PghmError("ply export needs means (N, 3), scales (N,), colors (N, 3), opacities (N,)")
    records = np.zeros((n, len(PROPERTIES)), dtype=np.float32)
    records[:, 0:3] = means.detach().cpu().numpy()
    records[:, 6:9] = ((colors.detach().double() - 0.5) / SH_C0).cpu().numpy()
    opacity_column = 9 + NUM_REST
    records[:, opacity_column] = _logit(opacities.detach()).cpu().numpy()
    records[:, opacity_column + 1 : opacity_column + 4] = torch.log(scales.detach().double()).cpu().numpy()[:, None]
    records[:, opacity_column + 4] = 1.0
    header = "\n".join(
        ["ply", "format binary_little_endian 1.0", f"element vertex {n}"]
        + [f"property float {name}" for name in PROPERTIES]
        + ["end_header", ""]
    )
    buffer = io.BytesIO()
    buffer.write(header.encode("ascii"))
    buffer.write(records.astype("<f4").tobytes())
    return buffer.getvalue()


def write_ply(path: str | Path, means: Tensor, scales: Tensor, colors: Tensor, opacities: Tensor) -> None:
    """Write N Gaussians as a 3DGS .ply, atomically."""
    atomic_write_bytes(path, ply_bytes(means, scales, colors, opacities))


def read_ply(path: str | Path) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Read a 3DGS .ply written by :func:`write_ply`: means (N,3), scales (N,), colors (N,3), opacities (N,).

    The isotropic scale is exp(scale_0) when the three log-scales agree (as written here),
    otherwise the geometric mean of the three; colours come from f_dc only.
    """
    data = Path(path).read_bytes()
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply\n") or end < 0:
        raise PghmError(f"{path}: not a .ply file")
    lines = data[:end].decode("ascii", errors="replace").splitlines()
    if "format binary_little_endian 1.0" not in lines:
        raise PghmError(f"{path}: only binary little-endian .ply files are supported")
    count = next(int(line.split()[2]) for line in lines if line.startswith("element vertex"))
    names = [line.split()[2] for line in lines if line.startswith("property float")]
    body = data[end + len(b"end_header\n") :]
    if len(body) != count * len(names) * 4:
        raise PghmError(f"{path}: truncated .ply ({len(body)} bytes for {count} vertices)")
    table = np.frombuffer(body, dtype="<f4").reshape(count, len(names))
    column = {name: i for i, name in enumerate(names)}

    def cols(*keys: str) -> Tensor:
        return torch.from_numpy(table[:, [column[k] for k in keys]].astype(np.float32))

    means = cols("x", "y", "z")
    colors = cols("f_dc_0", "f_dc_1", "f_dc_2") * SH_C0 + 0.5
    opacities = torch.sigmoid(cols("opacity")[:, 0])
    log_scales = cols("scale_0", "scale_1", "scale_2")
    isotropic = (log_scales == log_scales[:, :1]).all(-1)
    scales = torch.exp(torch.where(isotropic, log_scales[:, 0], log_scales.mean(-1)))
    return means, scales, colors, opacities
