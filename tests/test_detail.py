"""The detail layer: the paper's model untouched without it, an exact upsampling, a zero layer that
renders the same surface in the same colours, the avatar file, and every consumer using it."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from conftest import SMALL_MODEL as SMALL

from pghm.body import BodyPose
from pghm.cli.main import main
from pghm.errors import AvatarFileError
from pghm.io.avatar import Avatar, avatar_geometry, avatar_payload, load_avatar, save_avatar
from pghm.io.ply import read_ply
from pghm.model.detail import DETAIL_CHANNELS, DETAIL_FACTOR, upsample
from pghm.model.evaluator import CachedEvaluator
from pghm.motion.procedural import procedural_motion
from pghm.render import AvatarDriver
from pghm.splat import Camera, render
from pghm.uv.maps import gather_from_map
from viewer.demo import development_avatar

CENTRE = torch.tensor([0.4, 0.3, 3.0])
BILINEAR = {0.0625, 0.1875, 0.5625}
"""The weights of a 2L texel's four L neighbours, (1/4 or 3/4) x (1/4 or 3/4), where all four are usable."""


def with_detail(avatar: Avatar, maps: torch.Tensor | None = None) -> Avatar:
    """``avatar`` with a detail layer, zero or holding ``maps`` (1, 5, 2L, 2L)."""
    model = avatar.model.with_detail().eval()
    if maps is not None:
        model.detail.maps.data = maps
    return Avatar(model=model, kind="avatar", body_name=avatar.body_name, shape=avatar.shape, latent=avatar.latent)


def random_maps(config, seed: int = 0) -> torch.Tensor:
    size = DETAIL_FACTOR * config.uv_resolution
    return torch.randn(1, DETAIL_CHANNELS, size, size, generator=torch.Generator().manual_seed(seed))


@pytest.fixture(scope="module")
def avatar():
    return development_avatar(SMALL, seed=5)


@pytest.fixture(scope="module")
def pose(body):
    generator = torch.Generator().manual_seed(1)
    return BodyPose(torch.randn(1, body.num_bones, 3, generator=generator) * 0.2, torch.zeros(1, 3))


def paper_gaussians(model, geometry, identity, pose, centre):
    """The dynamic Gaussians written from the paper's formulas (pghm.model.pghm's docstring) on the
    decoder maps, apart from :meth:`PGHM.assemble`."""
    features = model.identity_features(identity)
    skinned = model.skin(geometry, pose)
    branch = model.pose_branch(features, skinned)
    view = model.view_branch(features, skinned, branch, geometry, centre[None])
    static, dynamic, colour = (gather_from_map(m, geometry.atlas) for m in (features.static, branch.maps, view))
    config = model.config
    offset = config.max_static_offset * torch.tanh(static[..., 0:3]) + config.max_pose_offset * torch.tanh(
        dynamic[..., 0:3]
    )
    means = skinned.surface_points + offset + (skinned.rotation_delta @ offset[..., None])[..., 0]
    base = (config.base_scale_factor * geometry.texel_length).clamp(config.min_scale, config.max_scale)
    log_scale = math.log(config.scale_factor_range) * torch.tanh(static[..., 3] + dynamic[..., 3])
    scales = (base * torch.exp(log_scale)).clamp(config.min_scale, config.max_scale)
    return means, scales, torch.sigmoid(static[..., 4:7] + colour)


def test_without_a_layer_every_consumer_gets_the_papers_gaussians_bit_for_bit(avatar, pose):
    geometry = avatar_geometry(avatar)
    assert geometry.detail is None and avatar.model.detail is None
    with torch.no_grad():
        means, scales, colours = paper_gaussians(avatar.model, geometry, avatar.latent, pose, CENTRE)
    arrays = AvatarDriver(avatar).evaluate(avatar.latent, pose, CENTRE)  # what the viewer and render use
    evaluated = CachedEvaluator(avatar.model, geometry).evaluate(avatar.latent, pose, CENTRE).dynamic  # eval, export
    for got in (evaluated, avatar.model(avatar.latent, geometry, pose, CENTRE[None]).dynamic):
        assert torch.equal(got.means, means) and torch.equal(got.scales, scales) and torch.equal(got.colors, colours)
    assert np.array_equal(arrays.means, means[0].numpy()) and np.array_equal(arrays.colors, colours[0].numpy())


def test_upsampling_is_bilinear_within_a_chart_and_exact_on_linear_fields(avatar):
    geometry = avatar_geometry(with_detail(avatar))
    coarse, detail = geometry.atlas, geometry.detail
    weights, source = detail.weights, detail.source
    assert detail.atlas.resolution == DETAIL_FACTOR * coarse.resolution
    torch.testing.assert_close(weights.sum(1), torch.ones(len(weights)), rtol=0, atol=1e-6)
    used = weights > 0
    assert (coarse.chart[source][used] == detail.atlas.chart[:, None].expand_as(source)[used]).all()
    interior = (used.sum(1) == 4) & torch.tensor([set(w.tolist()) <= BILINEAR for w in weights])
    assert interior.float().mean() > 0.8  # most 2L texels see four usable neighbours
    # A field linear in the map's (row, column): bilinear interpolation reproduces it exactly at a
    # 2L texel centre, which lies at (k + 1/2) / 2 - 1/2 in L texel units.
    linear = torch.tensor([[0.25, -1.5], [2.0, 0.5], [-0.75, 1.25]], dtype=torch.float64)  # (C, 2)
    at_coarse = coarse.texel_rc.double() @ linear.T  # (N, C)
    fine_centres = (detail.atlas.texel_rc.double() + 0.5) / DETAIL_FACTOR - 0.5
    got = upsample(at_coarse[None], detail)[0]
    torch.testing.assert_close(got[interior], (fine_centres @ linear.T)[interior], rtol=0, atol=1e-9)
    # ... and matches the image operation on a whole map wherever its four neighbours are valid texels.
    maps = torch.randn(1, 3, coarse.resolution, coarse.resolution, dtype=torch.float64)
    image = gather_from_map(F.interpolate(maps, scale_factor=DETAIL_FACTOR, mode="bilinear"), detail.atlas)[0]
    torch.testing.assert_close(upsample(gather_from_map(maps, coarse), detail)[0][interior], image[interior])


def test_a_zero_layer_renders_the_same_surface_in_the_same_colours(avatar, pose):
    """A uniform colour (every head zero but the colour bias) makes colour exact in both renders:
    on black, rgb = c alpha at every pixel, whatever the Gaussians' number and size. The silhouettes
    {alpha > 1/2} are those of one surface, each padded by its Gaussians' reach: each lies within
    the L Gaussians' largest reach (plus a pixel of rasterisation) of the other."""
    plain = development_avatar(SMALL, seed=5)
    with torch.no_grad():
        for name in ("static_decoder", "pose_decoder", "view_decoder"):
            getattr(plain.model, name).head.weight.zero_()
            if name != "static_decoder":
                getattr(plain.model, name).head.bias.zero_()
    colour = torch.sigmoid(plain.model.static_decoder.head.bias[4:7])
    camera = Camera.look_at(eye=(0.0, 0.2, 3.0), target=(0.0, -0.1, 0.0), width=96, height=128)
    alphas = []
    for model_avatar in (plain, with_detail(plain)):
        geometry = avatar_geometry(model_avatar)
        with torch.no_grad():
            g = model_avatar.model(model_avatar.latent, geometry, pose, camera.centre[None].float()).dynamic
            drawn = render(g.means[0], g.scales[0], g.colors[0], g.opacities[0], camera, background=torch.zeros(3))
        torch.testing.assert_close(drawn.rgb, drawn.alpha[..., None] * colour, rtol=0, atol=1e-6)
        alphas.append(drawn.alpha > 0.5)
        if model_avatar is plain:
            depth = (camera.world_to_camera[:3, :3].float() @ g.means[0].T + camera.world_to_camera[:3, 3:].float())[2]
            # The farthest an L Gaussian reaches with alpha above 1/2: sqrt(2 ln 2) sigma, in pixels.
            reach = math.sqrt(2 * math.log(2)) * float((g.scales[0] * camera.K[1, 1] / depth).max())
    band = math.ceil(reach) + 1

    def grown(mask: torch.Tensor) -> torch.Tensor:
        return F.max_pool2d(mask.float()[None, None], 2 * band + 1, 1, band)[0, 0] > 0

    assert alphas[0].sum() > 500
    assert not (alphas[1] & ~grown(alphas[0])).any() and not (alphas[0] & ~grown(alphas[1])).any()


def test_round_trip_keeps_the_layer_and_its_gaussians(avatar, pose, tmp_path):
    detailed = with_detail(avatar, random_maps(SMALL))
    save_avatar(tmp_path / "a.pt", detailed)
    loaded = load_avatar(tmp_path / "a.pt")
    assert loaded.model.config.detail and torch.equal(loaded.model.detail.maps, detailed.model.detail.maps)
    geometry = avatar_geometry(loaded)
    assert geometry.num_gaussians == geometry.detail.atlas.num_texels > 3 * geometry.atlas.num_texels
    a = CachedEvaluator(loaded.model, geometry).evaluate(loaded.latent, pose, CENTRE).dynamic
    b = CachedEvaluator(detailed.model, avatar_geometry(detailed)).evaluate(detailed.latent, pose, CENTRE).dynamic
    assert torch.equal(a.means, b.means) and torch.equal(a.colors, b.colors) and torch.equal(a.scales, b.scales)
    assert (a.means - detailed.model.skin(geometry, pose).detail.surface_points).norm(dim=-1).max() <= (
        SMALL.max_static_offset + SMALL.max_pose_offset
    ) * math.sqrt(3) + SMALL.max_detail_offset + 1e-5  # the lift is bounded too


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        (lambda maps: maps.fill_(math.nan), "'weights.detail.maps' has non-finite values"),
        (lambda maps: maps[:, :3], "'weights.detail.maps' has shape (1, 3, 128, 128), expected (1, 5, 128, 128)"),
    ],
)
def test_a_bad_layer_is_refused_in_one_line_naming_the_file(avatar, tmp_path, damage, message):
    payload = avatar_payload(with_detail(avatar, random_maps(SMALL)))
    payload["weights"]["detail.maps"] = damage(payload["weights"]["detail.maps"])
    path = tmp_path / "bad.pt"
    torch.save(payload, path)
    with pytest.raises(AvatarFileError) as error:
        load_avatar(path)
    assert str(error.value) == f"{path}: {message}"


def test_a_layer_in_a_version_1_file_or_a_prior_is_refused(avatar, tmp_path):
    payload = avatar_payload(with_detail(avatar))
    torch.save({**payload, "version": 1}, tmp_path / "old.pt")
    with pytest.raises(AvatarFileError, match="version 1 file cannot hold a detail layer"):
        load_avatar(tmp_path / "old.pt")
    prior = avatar_payload(development_avatar(SMALL, kind="prior", num_identities=2))
    prior["config"]["detail"] = True
    prior["weights"]["detail.maps"] = torch.zeros(1, 5, 128, 128)
    torch.save(prior, tmp_path / "prior.pt")
    with pytest.raises(AvatarFileError, match="prior file must not hold a detail layer"):
        load_avatar(tmp_path / "prior.pt")
    plain = avatar_payload(avatar)
    torch.save({**plain, "version": 1}, tmp_path / "plain.pt")
    assert load_avatar(tmp_path / "plain.pt").model.detail is None  # files from before the layer still read


def test_driver_export_and_eval_use_the_layer(avatar, pose, body, tmp_path, tiny_dataset):
    from pghm.train.data import TrainingData
    from pghm.train.frames import render_images

    maps = random_maps(SMALL)
    maps[:, 1:4] = 30.0  # colour logits far up: every Gaussian white, whatever the network says
    detailed = with_detail(avatar, maps)
    path = tmp_path / "detail.pt"
    save_avatar(path, detailed)
    geometry = avatar_geometry(detailed)
    count = geometry.detail.atlas.num_texels
    arrays = AvatarDriver(load_avatar(path)).evaluate(detailed.latent, pose, CENTRE)
    assert arrays.count == count and arrays.normals.shape == (count, 3)
    assert np.allclose(arrays.colors, 1.0, atol=1e-6)
    out = tmp_path / "posed.ply"
    assert main(["export", str(path), "--pose", "walk", "--frame", "3", "--out", str(out), "--view", "0.4,0.3,3"]) == 0
    motion = procedural_motion("walk", body, shape=detailed.shape)
    want = CachedEvaluator(detailed.model, geometry).evaluate(detailed.latent, motion.pose(3), CENTRE).dynamic
    means, _, colors, _ = read_ply(out)
    assert means.shape == (count, 3) and torch.equal(means, want.means[0])
    torch.testing.assert_close(colors, want.colors[0], rtol=0, atol=1e-6)
    data = TrainingData(tiny_dataset / "subject_000", split="train")
    for _, rgb_on_black, alpha in render_images(load_avatar(path), data, [int(data.images[0][0])]):
        assert alpha.max() > 0.9
        torch.testing.assert_close(rgb_on_black, alpha.expand_as(rgb_on_black), rtol=0, atol=1e-5)


def _validate(errors: list[float], without: float, steps: int):
    """A :class:`DetailValidation` fed ``errors`` (one per check, the first at step 0) for a stage of
    ``steps``: the steps it validated at before it said stop, its record and itself."""
    from pghm.train.detail import CHECK_EVERY, DetailValidation
    from pghm.train.loop import LoopState

    scripted = iter(errors)
    model = SimpleNamespace(detail=SimpleNamespace(maps=torch.zeros(1)))
    validation = DetailValidation(lambda _: next(scripted), without, 4)
    checked = []
    for step in range(0, steps + 1, CHECK_EVERY):
        model.detail.maps = torch.full((1,), float(step))  # which step's layer the best one is
        checked.append(step)
        if validation(model, LoopState(step=step), steps) or step == steps:
            break
    return checked, validation.record(), validation


def test_the_detail_stage_stops_when_the_layer_stops_paying_and_keeps_its_best():
    """Falling below the avatar's error, then up: stop at the rise, keep the layer of the lowest error."""
    checked, record, validation = _validate([120.0, 95.0, 90.0, 92.0, 80.0, 70.0], 100.0, 100)
    assert checked == [0, 20, 40, 60] and record["kept"] and record["best_step"] == 40
    assert record["error_with"] == 90.0 and float(validation.best[2]) == 40.0 and "stopped" in record


def test_the_detail_stage_stops_early_when_the_layer_cannot_pay_in_time():
    """Above the avatar's error and falling by 2 every 20 steps: 80 steps left cannot close a gap of
    15, so the stage stops at the second check and the layer is dropped."""
    checked, record, _ = _validate([119.0, 117.0, 115.0, 113.0], 100.0, 100)
    assert checked == [0, 20] and not record["kept"] and "could not beat" in record["stopped"]


def test_a_layer_that_keeps_paying_trains_all_its_steps():
    """Falling at every check: no stop, and the last layer is the best."""
    errors = [101.0, 99.0, 97.0, 95.0, 93.0, 91.0]
    checked, record, _ = _validate(errors, 100.0, 100)
    assert checked == [0, 20, 40, 60, 80, 100] and record["kept"] and record["best_step"] == 100
    assert "stopped" not in record


def test_the_detail_stage_stops_when_a_check_buys_less_than_its_least_gain():
    """Falling by 0.5 % from step 20 to 40 (under MIN_GAIN's 1 %): stop there and keep step 40's layer,
    whatever the steps after would have bought."""
    from pghm.train.detail import MIN_GAIN

    checked, record, _ = _validate([120.0, 95.0, 95.0 * (1 - MIN_GAIN / 2), 80.0], 100.0, 100)
    assert checked == [0, 20, 40] and record["kept"] and record["best_step"] == 40
    assert "stopped falling by 1% a check" in record["stopped"]


def test_a_layer_still_losing_is_not_stopped_for_one_slow_check():
    """Above the avatar's error and falling by 0.4 % from step 40 to 60 (under MIN_GAIN) but, at that
    rate, below it within the 40 steps left: the stage goes on (the synthetic exercise video's path
    in bfloat16), and keeps the layer when it then gets below; a layer above that rises is dropped
    at once."""
    errors = [48763.4, 22820.5, 22375.0, 22278.6, 21900.0, 21500.0]
    checked, record, _ = _validate(errors, 22157.4, 100)
    assert checked == [0, 20, 40, 60, 80, 100] and record["kept"] and record["best_step"] == 100
    checked, record, _ = _validate([23903.0, 14934.6, 15003.2, 14000.0], 13537.3, 100)  # the real video's
    assert checked == [0, 20, 40] and not record["kept"] and "could not beat" in record["stopped"]
