"""pghm export: the posed Gaussians of an avatar as a .ply that reads back and re-renders the same."""

from __future__ import annotations

import pytest
import torch
from conftest import SMALL_MODEL

from pghm.cli.main import main
from pghm.io.avatar import avatar_geometry, load_avatar, save_avatar
from pghm.io.ply import read_ply
from pghm.model.evaluator import CachedEvaluator
from pghm.motion.procedural import procedural_motion
from pghm.splat import Camera, render
from viewer.demo import development_avatar


@pytest.fixture(scope="module")
def avatar_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("export") / "avatar.pt"
    save_avatar(path, development_avatar(SMALL_MODEL, seed=3))
    return path


def test_export_matches_the_model_and_rerenders(avatar_file, tmp_path, body):
    out = tmp_path / "posed.ply"
    assert (
        main(["export", str(avatar_file), "--pose", "walk", "--frame", "7", "--out", str(out), "--view", "0.5,0.2,3"])
        == 0
    )
    avatar = load_avatar(avatar_file)
    motion = procedural_motion("walk", body, shape=avatar.shape)
    evaluator = CachedEvaluator(avatar.model, avatar_geometry(avatar))
    want = evaluator.evaluate(avatar.identity_map(), motion.pose(7), torch.tensor([0.5, 0.2, 3.0])).dynamic
    means, scales, colors, opacities = read_ply(out)
    assert torch.equal(means, want.means[0])
    torch.testing.assert_close(scales, want.scales[0], rtol=1e-6, atol=0)
    torch.testing.assert_close(colors, want.colors[0], rtol=0, atol=1e-6)
    assert torch.equal(opacities, want.opacities[0])
    camera = Camera.look_at(eye=(0.5, 0.2, 3.0), target=(0.0, 0.0, 0.0), width=96, height=128)
    direct = render(want.means[0], want.scales[0], want.colors[0], want.opacities[0], camera)
    again = render(means, scales, colors, opacities, camera)
    # float32 log/exp and the SH affine map round each value once: far below 1/255.
    assert (direct.rgb - again.rgb).abs().max() < 1e-5


def test_export_errors_are_one_line(avatar_file, tmp_path, capsys):
    assert (
        main(["export", str(avatar_file), "--pose", "walk", "--frame", "100000", "--out", str(tmp_path / "a.ply")]) == 2
    )
    assert main(["export", str(avatar_file), "--pose", "no-such-motion", "--out", str(tmp_path / "b.ply")]) == 2
    assert main(["export", str(avatar_file), "--view", "1,2", "--out", str(tmp_path / "c.ply")]) == 2
    errors = capsys.readouterr().err.strip().splitlines()
    assert len(errors) == 3 and all(line.startswith("pghm: error:") for line in errors)
    assert not list(tmp_path.glob("*.ply"))
