""".spz export: Niantic's layout byte for byte, its rounding within the layout's steps, and a
reader pghm did not write (spz-js, in Node) decoding the same Gaussians."""

from __future__ import annotations

import gzip
import json
import math
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch
from test_export_cli import avatar_file  # noqa: F401 - the fixture, shared
from test_ply import random_gaussians

from pghm.cli.main import main
from pghm.errors import PghmError
from pghm.io.avatar import avatar_geometry, load_avatar
from pghm.io.ply import SH_C0
from pghm.io.spz import read_spz, spz_bytes, write_spz
from pghm.model.evaluator import CachedEvaluator
from pghm.motion.procedural import procedural_motion

SPZ_JS = Path(__file__).parent / "js" / "spz-js" / "spz-loader.js"
POSITION_STEP = 2.0**-12
"""A coordinate's grid (12 fractional bits): rounding moves it by at most half of this."""
COLOUR_STEP = SH_C0 / (0.15 * 255)
"""A colour channel's step: one byte of 0.15 f_dc, f_dc = (rgb - 0.5) / SH_C0."""
LOG_SCALE_STEP = 1 / 16


def test_the_bytes_are_the_layout_worked_by_hand():
    """Two Gaussians whose every byte follows from the spec's formulas by hand."""
    means = torch.tensor([[1.0, -0.5, 0.25], [0.0, 2.0**-12, -3.0]])
    scales = torch.tensor([math.exp(-5.0), 1.0])  # (log s + 10) 16 = 80 and 160
    colors = torch.tensor([[0.5, 0.5, 0.5], [0.5 + SH_C0, 0.5 - SH_C0, 1.0]])
    opacities = torch.tensor([0.5, 1.0])
    data = gzip.decompress(spz_bytes(means, scales, colors, opacities))
    header = bytes.fromhex("4e475350" "02000000" "02000000" "00" "0c" "00" "00")  # NGSP, v2, 2, SH 0, 12 bits
    positions = bytes.fromhex("001000" "00f8ff" "000400" "000000" "010000" "00d0ff")  # 4096, -2048, 1024, 0, 1, -12288
    alphas = bytes([128, 255])  # 127.5 rounds half away from zero
    # 255 (0.15 f_dc + 0.5): f_dc 0 -> 127.5 -> 128; +-1 -> 165.75, 89.25; (0.5 / SH_C0) -> 195.3
    colours = bytes([128, 128, 128, 166, 89, 195])
    scale_bytes = bytes([80, 80, 80, 160, 160, 160])
    rotations = bytes([128] * 6)  # the identity quaternion's x, y, z: 127.5 -> 128
    assert data == header + positions + alphas + colours + scale_bytes + rotations


def test_reading_back_moves_each_value_less_than_half_a_step(tmp_path):
    means, scales, colors, _ = random_gaussians(2000, seed=4)
    opacities = torch.rand(2000, generator=torch.Generator().manual_seed(5))
    path = tmp_path / "g.spz"
    write_spz(path, means, scales, colors, opacities)
    got = read_spz(path)
    # Half a step, and float32's rounding of the decoded value on top (a relative 2^-24).
    assert (got[0] - means).abs().max() <= POSITION_STEP / 2 * (1 + 1e-6) + 1e-7
    assert (got[1] / scales).log().abs().max() <= LOG_SCALE_STEP / 2 + 1e-6
    assert (got[2] - colors).abs().max() <= COLOUR_STEP / 2 + 1e-6
    assert (got[3] - opacities).abs().max() <= 1 / 510 + 1e-7


def test_what_the_layout_cannot_hold_is_refused():
    ok = random_gaussians(3)
    far = ok[0].clone()
    far[1, 2] = 3000.0
    with pytest.raises(PghmError, match="within"):
        spz_bytes(far, *ok[1:])
    tiny = ok[1].clone()
    tiny[0] = 1e-6
    with pytest.raises(PghmError, match="scales"):
        spz_bytes(ok[0], tiny, *ok[2:])
    with pytest.raises(PghmError, match="needs means"):
        spz_bytes(ok[0][:2], *ok[1:])


@pytest.mark.skipif(shutil.which("node") is None, reason="the second reader runs in Node.js, not installed here")
def test_another_reader_decodes_the_same_gaussians(tmp_path):
    """spz-js (a port of Niantic's reference code, tests/js/spz-js) reads what pghm wrote."""
    means, scales, colors, _ = random_gaussians(500, seed=6)
    opacities = torch.rand(500, generator=torch.Generator().manual_seed(7)) * 0.98 + 0.01
    path = tmp_path / "g.spz"
    write_spz(path, means, scales, colors, opacities)
    script = (
        f"import {{ readFileSync }} from 'fs'; import {{ loadSpz }} from '{SPZ_JS.as_uri()}';"
        "const g = await loadSpz(readFileSync(process.argv[1]));"
        "const out = {n: g.numPoints, degree: g.shDegree, positions: g.positions, scales: g.scales,"
        " rotations: g.rotations, alphas: g.alphas, colors: g.colors};"
        "for (const k in out) if (ArrayBuffer.isView(out[k])) out[k] = Array.from(out[k]);"
        "console.log(JSON.stringify(out));"
    )
    result = subprocess.run(
        ["node", "--input-type=module", "-e", script, str(path)], capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0, result.stderr
    decoded = json.loads(result.stdout)
    assert decoded["n"] == 500 and decoded["degree"] == 0
    ours = read_spz(path)
    positions = torch.tensor(decoded["positions"]).reshape(500, 3)
    assert (positions - means).abs().max() <= POSITION_STEP / 2 + 1e-6
    log_scales = torch.tensor(decoded["scales"], dtype=torch.float64).reshape(500, 3)
    assert (log_scales - scales.double().log()[:, None]).abs().max() <= LOG_SCALE_STEP / 2 + 1e-6
    rgb = torch.tensor(decoded["colors"]).reshape(500, 3) * SH_C0 + 0.5
    assert (rgb - colors).abs().max() <= COLOUR_STEP / 2 + 1e-5
    alphas = torch.sigmoid(torch.tensor(decoded["alphas"], dtype=torch.float64))  # spz-js returns logits
    assert (alphas - opacities.double()).abs().max() <= 1 / 510 + 1e-6
    rotations = np.array(decoded["rotations"]).reshape(500, 4)  # x, y, z, w: the identity within a byte
    assert np.abs(rotations[:, :3]).max() < 1 / 127 and rotations[:, 3].min() > 0.9999
    # Both readers decode the same bytes to the same values, to float32's rounding.
    torch.testing.assert_close(positions, ours[0], rtol=0, atol=1e-6)
    torch.testing.assert_close(rgb, ours[2], rtol=0, atol=1e-5)


def test_export_writes_the_models_gaussians_as_spz(avatar_file, tmp_path, body):
    out = tmp_path / "posed.spz"
    args = ["export", str(avatar_file), "--pose", "walk", "--frame", "7", "--out", str(out), "--view", "0.5,0.2,3"]
    assert main(args) == 0
    avatar = load_avatar(avatar_file)
    motion = procedural_motion("walk", body, shape=avatar.shape)
    evaluator = CachedEvaluator(avatar.model, avatar_geometry(avatar))
    want = evaluator.evaluate(avatar.identity_map(), motion.pose(7), torch.tensor([0.5, 0.2, 3.0])).dynamic
    means, scales, colors, opacities = read_spz(out)
    assert means.shape == want.means[0].shape
    assert (means - want.means[0]).abs().max() <= POSITION_STEP / 2 + 1e-6
    assert (scales / want.scales[0]).log().abs().max() <= LOG_SCALE_STEP / 2 + 1e-6
    assert (colors - want.colors[0]).abs().max() <= COLOUR_STEP / 2 + 1e-5
    assert (opacities - want.opacities[0]).abs().max() <= 1 / 510 + 1e-6


def test_export_refuses_a_format_it_does_not_write(avatar_file, tmp_path, capsys):
    assert main(["export", str(avatar_file), "--out", str(tmp_path / "posed.obj")]) == 2
    error = capsys.readouterr().err.strip()
    assert len(error.splitlines()) == 1 and ".ply, .spz" in error
    assert not list(tmp_path.iterdir())
