"""The web page: the bake against the model, the page's skinning shader against the bake, the page
against the CPU splatter in a real browser, and the export command's refusals."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest
import torch
from test_export_cli import avatar_file  # noqa: F401 - the fixture, shared

from benchmarks.browser import chromium, drive
from pghm.cli.main import main
from pghm.errors import EXIT_USER_ERROR
from pghm.io.avatar import load_avatar
from pghm.motion.open_motion import open_motion
from pghm.render.driver import AvatarDriver
from pghm.render.framing import DEFAULT_FOV_Y, floor_shift, frame_points, orbit_camera
from pghm.web import export_web
from pghm.web.bake import (
    BAKE_ASPECT,
    SKIN_BONES,
    WEIGHT_STEPS,
    BakeConfig,
    bake_motion,
    components_of,
    front_centre,
    skin_of,
)


def test_skin_keeps_each_gaussians_largest_weights_summing_to_the_steps():
    generator = torch.Generator().manual_seed(0)
    weights = torch.rand(200, 12, generator=generator) ** 4
    weights[0] = 0
    weights[0, 5] = 1.0  # one bone alone
    weights /= weights.sum(1, keepdim=True)
    skin = skin_of(weights)
    assert skin.weights.dtype == np.uint8 and (skin.weights.astype(int).sum(1) == WEIGHT_STEPS).all()
    bones = skin.bones[skin.index]  # (N, SKIN_BONES) body bone indices
    for row in range(200):
        kept = skin.weights[row] > 0
        largest = torch.topk(weights[row], SKIN_BONES).indices.numpy()
        assert set(bones[row][kept]) <= set(largest)
        want = weights[row, largest] / weights[row, largest].sum()
        got = np.zeros(12)
        np.add.at(got, bones[row], skin.weights[row] / WEIGHT_STEPS)
        # Largest remainders: each weight within one step of its exact share.
        assert np.abs(got[largest] - want.numpy()).max() <= 1 / WEIGHT_STEPS
    assert bones[0][skin.weights[0] > 0].tolist() == [5] and skin.weights[0].max() == WEIGHT_STEPS


def test_components_rebuild_every_frame_within_the_tolerance_from_what_is_stored():
    rng = np.random.default_rng(1)
    frames, n = 40, 300
    directions = rng.normal(size=(2, n, 3))
    coefficients = rng.normal(size=(frames, 2)) * [0.01, 0.002]
    base = rng.normal(size=(n, 3))
    motion = base + np.einsum("fk,knc->fnc", coefficients, directions) + rng.normal(size=(frames, n, 3)) * 1e-6
    tolerance = 1e-4
    kept = components_of(motion.astype(np.float32), tolerance, max_components=16)
    assert kept.rank <= 3 and kept.basis.dtype == np.int8
    worst = max(math.sqrt(((kept.frame(f) - motion[f]) ** 2).sum() / n) for f in range(frames))
    assert worst <= tolerance * 1.01 and worst == pytest.approx(kept.error, rel=1e-2, abs=1e-6)
    still = components_of(np.repeat(base[None].astype(np.float32), 5, axis=0), tolerance, 16)
    assert still.rank == 0 and np.array_equal(still.frame(3), base.astype(np.float32))


@pytest.fixture(scope="module")
def baked(avatar_file, body):  # noqa: F811 - the shared fixture
    driver = AvatarDriver(load_avatar(avatar_file))
    motion = open_motion("walk", driver.body, driver.geometry.shape.cpu())
    return driver, motion, bake_motion(driver, motion)


def test_the_bake_skins_to_the_models_gaussians(baked):
    """Blended rotations have operator norm at most 1, so a canonical point within the tolerance
    puts the posed mean within it too (plus float32 rounding)."""
    driver, motion, bake = baked
    config = BakeConfig()
    framing = frame_points(driver.geometry.surface.positions.cpu().numpy(), DEFAULT_FOV_Y, BAKE_ASPECT)
    rest_root = driver.root_position(driver.rest_pose())
    for frame in (0, 17, motion.num_frames - 1):
        pose = motion.pose(frame)
        target = np.asarray(framing.target) + floor_shift(driver.root_position(pose), rest_root)
        want = driver.evaluate(driver.avatar.identity_map(), pose, front_centre(target, framing.distance))
        rms = lambda error: math.sqrt((np.asarray(error, np.float64) ** 2).sum() / bake.num_gaussians)  # noqa: E731
        assert rms(bake.means(frame) - want.means) <= config.position_tolerance + 1e-6
        assert rms(bake.log_scales.frame(frame)[:, 0] - np.log(want.scales)) <= config.log_scale_tolerance + 1e-6
        assert rms(bake.colors.frame(frame) - want.colors) <= config.color_tolerance + 1e-6


@pytest.mark.gl
def test_the_pages_skinning_shader_gives_the_bakes_means(baked):
    """shaders/web_skinning.vert.glsl by transform feedback (here on the desktop GL the viewer
    uses; the page runs the same source as GLSL ES) against the bake's float64 skinning."""
    import moderngl

    import shaders
    from pghm.gl.context import headless_context
    from pghm.gl.resources import SPEC_DEFINES, TEXTURE_WIDTH

    _, _, bake = baked
    ctx = headless_context()
    try:
        program = ctx.program(
            vertex_shader=shaders.source("web_skinning.vert", SPEC_DEFINES),
            fragment_shader=shaders.source("web_skinning.frag", SPEC_DEFINES),
            varyings=["mean_scale", "color_opacity"],
        )
        frame = 20
        n = bake.num_gaussians
        attributes = [
            (bake.points.frame(frame), "3f", "canonical"),
            (bake.log_scales.frame(frame), "1f", "log_scale"),
            (bake.colors.frame(frame), "3f", "color"),
            (bake.rig.skin.index, "4u2", "bone_index"),
            (bake.rig.skin.weights, "4f1", "bone_weight"),  # f1: normalised unsigned bytes
        ]
        content = [(ctx.buffer(np.ascontiguousarray(a).tobytes()), f, name) for a, f, name in attributes]
        rows = -(-3 * bake.rig.transforms.shape[1] // TEXTURE_WIDTH)
        bones = np.zeros((rows * TEXTURE_WIDTH, 4), np.float32)
        bones[: 3 * bake.rig.transforms.shape[1]] = bake.rig.transforms[frame].reshape(-1, 4)
        texture = ctx.texture((TEXTURE_WIDTH, rows), 4, bones.tobytes(), dtype="f4")
        texture.filter = (moderngl.NEAREST, moderngl.NEAREST)
        texture.use(0)
        program["bones"] = 0
        out = ctx.buffer(reserve=n * 8 * 4)
        ctx.simple_framebuffer((1, 1)).use()  # a surfaceless context draws nothing without a framebuffer
        ctx.vertex_array(program, content).transform(out, moderngl.POINTS, vertices=n)
        result = np.frombuffer(out.read(), np.float32).reshape(n, 8)
    finally:
        ctx.release()
    np.testing.assert_allclose(result[:, :3], bake.means(frame), rtol=0, atol=1e-5)  # float32 of metres
    np.testing.assert_allclose(result[:, 3], np.exp(bake.log_scales.frame(frame)[:, 0]), rtol=1e-5)
    np.testing.assert_allclose(result[:, 4:7], np.clip(bake.colors.frame(frame), 0, 1), rtol=0, atol=1e-6)
    assert (result[:, 7] == 1).all()


def test_the_page_is_one_file_that_fetches_nothing(avatar_file, baked, tmp_path):  # noqa: F811
    out = tmp_path / "a.html"
    assert main(["export", str(avatar_file), "--web", str(out)]) == 0
    text = out.read_text(encoding="utf-8")
    assert not re.search(r"https?://|<script[^>]+src=|<link|import\(|fetch\(", text)
    data = json.loads(re.search(r'<script type="application/json" id="pghm-data">(.*?)</script>', text, re.S).group(1))
    assert all(s[k].startswith("#version 300 es\n") for s in data["shaders"].values() for k in ("vertex", "fragment"))
    assert (data["frames"], data["gaussians"]) == (baked[1].num_frames, baked[2].num_gaussians)
    assert str(tmp_path) not in text


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    error = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2) / 255.0**2
    return math.inf if error == 0 else 10 * math.log10(1 / error)


@pytest.mark.skipif(chromium() is None, reason="chromium is not installed (scripts/setup.sh installs it)")
def test_the_page_in_a_browser_draws_what_the_cpu_splatter_draws(baked, avatar_file, tmp_path):  # noqa: F811
    """Each shot of the page in headless Chromium (software WebGL) against the CPU splatter's
    render of the same frame and camera, with the colours the page baked: the page's own
    approximations (the bake's tolerances: at most 0.1 mm and 1/1024 of a channel) and the GL
    twin's rounding (max 2e-3, tests/test_gl_sprites.py) stay far above 40 dB."""
    from pghm.render.frames import CPUFrames

    driver, motion, bake = baked
    page = tmp_path / "walk.html"
    export_web(str(avatar_file), "walk", str(page))
    width, height = 320, 180
    shots = [{"frame": 0, "yaw": 0}, {"frame": 30, "yaw": 0}, {"frame": 50, "yaw": 60, "pitch": 15}]
    result = drive(page, {"width": width, "height": height, "shots": shots, "loop": False})
    framing = frame_points(driver.geometry.surface.positions.cpu().numpy(), DEFAULT_FOV_Y, width / height)
    bake_framing = frame_points(driver.geometry.surface.positions.cpu().numpy(), DEFAULT_FOV_Y, BAKE_ASPECT)
    rest_root = driver.root_position(driver.rest_pose())
    renderer = CPUFrames()
    for shot in result["shots"]:
        pose = motion.pose(shot["frame"])
        follow = floor_shift(driver.root_position(pose), rest_root)
        baked_centre = front_centre(np.asarray(bake_framing.target) + follow, bake_framing.distance)
        arrays = driver.evaluate(driver.avatar.identity_map(), pose, baked_centre)
        camera = orbit_camera(
            np.asarray(framing.target) + follow, shot["yaw"], shot.get("pitch", 0), framing.distance,
            DEFAULT_FOV_Y, width, height,
        )  # fmt: skip
        want = np.round(np.clip(renderer.render(arrays, camera, (1.0, 1.0, 1.0)), 0, 1) * 255).astype(np.uint8)
        assert shot["image"].shape == want.shape
        assert psnr(shot["image"], want) >= 40, shot


@pytest.mark.parametrize(
    "options, words",
    [
        (["--web", "a.ply"], "a web page's name ends in .html"),
        (["--out", "a.html", "--pose", "walk"], "--pose choose a posed frame"),
        (["--web", "a.html", "--out", "b.html"], "give --out or --web, not both"),
        (["--out", "a.ply", "--motion", "walk"], "--motion is a web page's"),
        (["--out", "a.txt"], ".html"),
        ([], "give --out"),
        (["--web", "a.html", "--motion", "nowhere.bvh"], "nowhere.bvh"),
    ],
)
def test_export_refuses_what_it_cannot_write_in_one_line(
    avatar_file, tmp_path, capsys, monkeypatch, options, words  # noqa: F811
):
    monkeypatch.chdir(tmp_path)
    assert main(["export", str(avatar_file), *options]) == EXIT_USER_ERROR
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(lines) == 1 and words in lines[0], lines
    assert list(tmp_path.iterdir()) == []
