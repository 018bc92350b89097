"""3DGS .ply export: the standard layout, and a round trip that re-renders identically."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pghm.errors import PghmError
from pghm.io.ply import NUM_REST, PROPERTIES, SH_C0, read_ply, write_ply
from pghm.splat import Camera, render


def random_gaussians(n: int = 300, seed: int = 0):
    gen = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=gen) * 0.3
    scales = torch.rand(n, generator=gen) * 0.02 + 0.003
    colors = torch.rand(n, 3, generator=gen)
    opacities = torch.ones(n)
    return means, scales, colors, opacities


def test_header_is_the_3dgs_layout(tmp_path):
    path = tmp_path / "g.ply"
    write_ply(path, *random_gaussians(5))
    header = path.read_bytes().split(b"end_header\n")[0].decode().splitlines()
    assert header[:3] == ["ply", "format binary_little_endian 1.0", "element vertex 5"]
    names = [line.split()[2] for line in header if line.startswith("property")]
    expected = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    expected += [f"f_rest_{i}" for i in range(45)] + ["opacity", "scale_0", "scale_1", "scale_2"]
    expected += ["rot_0", "rot_1", "rot_2", "rot_3"]
    assert names == expected == PROPERTIES and NUM_REST == 45
    assert all(line.startswith("property float ") for line in header if line.startswith("property"))


def test_values_follow_the_3dgs_conventions(tmp_path):
    path = tmp_path / "g.ply"
    means, scales, colors, opacities = random_gaussians(7)
    opacities = torch.tensor([1.0, 0.5, 0.25, 0.9, 0.1, 1.0, 0.75])
    write_ply(path, means, scales, colors, opacities)
    body = path.read_bytes().split(b"end_header\n")[1]
    table = np.frombuffer(body, dtype="<f4").reshape(7, len(PROPERTIES))
    col = {name: i for i, name in enumerate(PROPERTIES)}
    np.testing.assert_allclose(table[:, col["f_dc_0"]], (colors[:, 0].numpy() - 0.5) / SH_C0, rtol=1e-6)
    np.testing.assert_allclose(table[:, col["scale_1"]], np.log(scales.numpy()), rtol=1e-6)
    logit = np.log(0.5 / 0.5)
    assert table[1, col["opacity"]] == pytest.approx(logit, abs=1e-6)
    assert table[2, col["opacity"]] == pytest.approx(np.log(0.25 / 0.75), abs=1e-6)
    np.testing.assert_array_equal(table[:, col["rot_0"]], 1.0)
    assert not table[:, [col[f"f_rest_{i}"] for i in range(45)]].any()


def test_round_trip_rerenders_identically(tmp_path):
    path = tmp_path / "g.ply"
    gaussians = random_gaussians()
    write_ply(path, *gaussians)
    loaded = read_ply(path)
    assert torch.equal(loaded[0], gaussians[0]) and torch.equal(loaded[3], gaussians[3])
    camera = Camera.look_at(eye=(0.3, 0.2, 2.0), target=(0.0, 0.0, 0.0), width=96, height=96)
    before = render(*gaussians, camera)
    after = render(*loaded, camera)
    # log/exp and the SH affine map each round a float32 once: a few ulps, far below 1/255.
    assert (before.rgb - after.rgb).abs().max() < 1e-5
    assert (before.alpha - after.alpha).abs().max() < 1e-5


def test_truncated_file_is_rejected(tmp_path):
    path = tmp_path / "g.ply"
    write_ply(path, *random_gaussians(10))
    path.write_bytes(path.read_bytes()[:-8])
    with pytest.raises(PghmError, match="truncated"):
        read_ply(path)
