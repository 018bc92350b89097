"""The PGHM network: shapes, bounds, gradients, and the cached evaluator against a full recompute."""

from __future__ import annotations

import math

import pytest
import torch
from conftest import SMALL_MODEL as SMALL

from pghm.body import BodyPose
from pghm.errors import PghmError
from pghm.model import PGHM, ModelConfig, subject_geometry
from pghm.model.evaluator import CachedEvaluator
from pghm.model.pghm import REG_POSITION_UNIT
from pghm.uv.atlas import build_atlas


@pytest.fixture(scope="module")
def geometry(body):
    return subject_geometry(body, build_atlas(body, SMALL.uv_resolution))


def randomize_heads(model: PGHM, scale: float = 0.05) -> None:
    """Give the zero-initialised heads random weights, so every branch affects the output."""
    gen = torch.Generator().manual_seed(0)
    for module in model.modules():
        if isinstance(module, torch.nn.Conv2d) and module.kernel_size == (1, 1):
            module.weight.data = torch.randn(module.weight.shape, generator=gen) * scale
            module.bias.data = torch.randn(module.bias.shape, generator=gen) * scale


def random_pose(body, batch: int = 1, seed: int = 0) -> BodyPose:
    gen = torch.Generator().manual_seed(seed)
    return BodyPose(
        torch.randn(batch, body.num_bones, 3, generator=gen) * 0.3, torch.randn(batch, 3, generator=gen) * 0.1
    )


def test_untrained_model_puts_gaussians_on_the_surface(body, geometry):
    model = PGHM(SMALL, num_identities=2)
    pose = random_pose(body, batch=2)
    out = model(model.decode_identity(0), geometry, pose, torch.tensor([[0.0, 0.0, 3.0], [3.0, 0.0, 0.0]]))
    surface = model.skin(geometry, pose).surface_points
    n = geometry.num_gaussians
    for gaussians in (out.static, out.dynamic):
        assert gaussians.means.shape == (2, n, 3) and gaussians.scales.shape == (2, n)
        assert gaussians.colors.shape == (2, n, 3) and gaussians.opacities.shape == (2, n)
        torch.testing.assert_close(gaussians.means, surface)
        torch.testing.assert_close(gaussians.colors, torch.full_like(gaussians.colors, 0.5))
        assert torch.equal(gaussians.opacities, torch.ones(2, n))
    base = (SMALL.base_scale_factor * geometry.texel_length).clamp(SMALL.min_scale, SMALL.max_scale)
    torch.testing.assert_close(out.static.scales, base.expand(2, -1))
    assert out.regularizer == 0


def test_outputs_stay_bounded_for_wild_inputs(body, geometry):
    model = PGHM(SMALL, num_identities=1)
    randomize_heads(model, scale=50.0)  # saturate every activation
    identity = model.decode_identity(0) * 100
    out = model(identity, geometry, random_pose(body), torch.tensor([[0.0, 0.0, 3.0]]))
    for g in (out.static, out.dynamic):
        assert torch.isfinite(g.means).all() and torch.isfinite(g.scales).all()
        assert (g.scales >= SMALL.min_scale).all() and (g.scales <= SMALL.max_scale).all()
        assert (g.colors >= 0).all() and (g.colors <= 1).all()
    surface = model.skin(geometry, random_pose(body)).surface_points
    max_offset = SMALL.max_static_offset + SMALL.max_pose_offset
    assert (out.dynamic.means - surface).norm(dim=-1).max() <= max_offset * math.sqrt(3) + 1e-5


def test_gradients_reach_every_component(body, geometry):
    model = PGHM(SMALL, num_identities=2)
    randomize_heads(model)
    out = model(model.decode_identity(1), geometry, random_pose(body), torch.tensor([[0.5, 0.2, 3.0]]))
    loss = sum(g.means.square().mean() + g.scales.mean() + g.colors.mean() for g in (out.static, out.dynamic))
    (loss + out.regularizer).backward()
    for name, parameter in model.named_parameters():
        assert parameter.grad is not None and torch.isfinite(parameter.grad).all(), name
        assert parameter.grad.abs().sum() > 0, name
    assert model.identity_bank.grad[0].abs().sum() == 0  # only identity 1 was used


def test_single_head_variant(body, geometry):
    config = ModelConfig(**{**SMALL.to_dict(), "head": "single"})
    model = PGHM(config, num_identities=1)
    randomize_heads(model)
    identity = model.decode_identity(0)
    camera = torch.tensor([[0.0, 0.0, 3.0]])
    a = model(identity, geometry, random_pose(body, seed=1), camera)
    b = model(identity, geometry, random_pose(body, seed=2), camera)
    assert not hasattr(model, "static_decoder") and hasattr(model, "single_decoder")
    # One decoder predicts everything, so even the "static" colours depend on the pose.
    assert (a.static.colors - b.static.colors).abs().max() > 1e-4


@pytest.mark.parametrize("head", ["multi", "single"])
def test_cached_evaluation_equals_full_recompute(body, geometry, head):
    config = ModelConfig(**{**SMALL.to_dict(), "head": head})
    model = PGHM(config, num_identities=2).eval()
    randomize_heads(model)
    evaluator = CachedEvaluator(model, geometry)
    identity_a, identity_b = model.decode_identity(0).detach(), model.decode_identity(1).detach()
    pose_a, pose_b = random_pose(body, seed=3), random_pose(body, seed=4)
    cam_a, cam_b = torch.tensor([0.0, 0.3, 3.0]), torch.tensor([2.0, 0.1, 2.0])
    steps = [
        ("first", identity_a, pose_a, cam_a),
        ("nothing", identity_a, pose_a, cam_a),
        ("camera", identity_a, pose_a, cam_b),
        ("pose", identity_a, pose_b, cam_b),
        ("identity", identity_b, pose_b, cam_b),
        (
            "same values, new tensors",
            identity_b.clone(),
            BodyPose(pose_b.rotations.clone(), pose_b.translation.clone()),
            cam_b.clone(),
        ),
    ]
    ran = {}
    for label, identity, pose, camera in steps:
        model.run_counts.clear()
        cached = evaluator.evaluate(identity, pose, camera)
        ran[label] = dict(model.run_counts)
        with torch.no_grad():
            full = model(identity, geometry, pose, camera[None])
        for got, want in ((cached.static, full.static), (cached.dynamic, full.dynamic)):
            for field in ("means", "scales", "colors"):
                assert (getattr(got, field) - getattr(want, field)).abs().max() <= 1e-6, (label, field)

    assert ran["nothing"] == {} and ran["same values, new tensors"] == {}
    if head == "multi":
        assert ran["first"] == {
            k: 1
            for k in ("unet_encoder", "static_decoder", "pose_encoder", "pose_decoder", "view_encoder", "view_decoder")
        }
        assert ran["camera"] == {"view_encoder": 1, "view_decoder": 1}
        assert ran["pose"] == {"pose_encoder": 1, "pose_decoder": 1, "view_encoder": 1, "view_decoder": 1}
        assert ran["identity"] == ran["first"]
    else:
        assert ran["camera"] == {"view_encoder": 1, "single_decoder": 1}
        assert ran["pose"] == {"pose_encoder": 1, "view_encoder": 1, "single_decoder": 1}


def test_evaluator_skips_branches_the_display_does_not_need(body, geometry):
    model = PGHM(SMALL, num_identities=1).eval()
    randomize_heads(model)
    evaluator = CachedEvaluator(model, geometry)
    identity, pose = model.decode_identity(0).detach(), random_pose(body)
    out = evaluator.evaluate(identity, pose, torch.tensor([0.0, 0.0, 3.0]), dynamic=False)
    assert "pose_decoder" not in model.run_counts and "view_decoder" not in model.run_counts
    torch.testing.assert_close(out.dynamic.means, out.static.means)
    model.run_counts.clear()
    evaluator.evaluate(identity, pose, torch.tensor([1.0, 0.0, 3.0]), dynamic=False)
    assert model.run_counts == {}  # the camera only matters to D_view, which is off
    out = evaluator.evaluate(identity, pose, torch.tensor([1.0, 0.0, 3.0]), view_dependent=False)
    assert model.run_counts == {"pose_encoder": 1, "pose_decoder": 1}
    torch.testing.assert_close(out.dynamic.colors, out.static.colors)


def test_config_validation():
    from pghm.errors import PghmError

    with pytest.raises(PghmError, match="power of two"):
        ModelConfig(uv_resolution=100)
    with pytest.raises(PghmError, match="one entry fewer"):
        ModelConfig(decoder_channels=(8,))
    with pytest.raises(PghmError, match="too many"):
        ModelConfig(uv_resolution=32, encoder_channels=(4,) * 6, decoder_channels=(4,) * 5, condition_channels=(4,) * 6)
    assert ModelConfig.from_dict(SMALL.to_dict()) == SMALL


def test_shared_poses_equal_repeated_poses(body, geometry):
    """Views sharing a pose through pose_index give what repeating the pose per view gives."""
    model = PGHM(SMALL, num_identities=1)
    randomize_heads(model)
    poses = random_pose(body, batch=2, seed=5)
    index = torch.tensor([0, 1, 1, 0])
    centres = torch.tensor([[0.0, 0.0, 3.0], [3.0, 0.0, 0.0], [0.0, 1.0, -3.0], [-2.0, 0.5, 2.0]])
    identity = model.decode_identity(0)
    with torch.no_grad():
        shared = model(identity, geometry, poses, centres, pose_index=index)
        repeated = model(identity, geometry, BodyPose(poses.rotations[index], poses.translation[index]), centres)
    for a, b in ((shared.static, repeated.static), (shared.dynamic, repeated.dynamic)):
        for field in ("means", "scales", "colors"):
            torch.testing.assert_close(getattr(a, field), getattr(b, field), atol=1e-6, rtol=0)


def test_inference_layout_gives_the_training_layout_outputs(body, geometry):
    """Eval mode stores the conv weights channels-last (faster inference), train mode NCHW;
    the outputs agree to float32 rounding (the two layouts sum in different orders)."""
    model = PGHM(SMALL, num_identities=1)
    randomize_heads(model)
    pose, centre = random_pose(body, seed=7), torch.tensor([[0.4, 0.3, 2.5]])
    spatial = [m for m in model.modules() if isinstance(m, torch.nn.Conv2d) and m.kernel_size != (1, 1)]
    with torch.no_grad():
        trained = model.train()(model.decode_identity(0), geometry, pose, centre)
        assert all(c.weight.is_contiguous() for c in spatial)
        inferred = model.eval()(model.decode_identity(0), geometry, pose, centre)
        assert all(c.weight.is_contiguous(memory_format=torch.channels_last) for c in spatial)
        assert not any(c.weight.is_contiguous() for c in spatial)
    for a, b in ((trained.static, inferred.static), (trained.dynamic, inferred.dynamic)):
        for field in ("means", "scales", "colors"):
            torch.testing.assert_close(getattr(a, field), getattr(b, field), atol=1e-5, rtol=0)


def kabsch(source: torch.Tensor, target: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(R, t) minimising |R source + t - target| over (N, 3) point sets (least-squares rigid fit)."""
    mu_s, mu_t = source.mean(0), target.mean(0)
    u, _, vt = torch.linalg.svd((source - mu_s).T @ (target - mu_t))
    sign = torch.sign(torch.det(vt.T @ u.T))
    rotation = vt.T @ torch.diag(torch.tensor([1.0, 1.0, sign], dtype=source.dtype)) @ u.T
    return rotation, mu_t - rotation @ mu_s


def test_offset_gaussians_are_skinned_rigidly_with_the_root(body, geometry, rest):
    """A root-only pose moves every bone alike, so LBS of V_bar + offsets is one rigid motion.

    The motion is recovered from the mesh vertices alone (a Kabsch fit, exact for a rigid
    pose), then both Gaussian sets, non-zero static and pose offsets included, must be that
    motion applied to their rest-pose positions; the pose branch sees U_theta in the root
    frame, which a root motion leaves unchanged, so the offsets and scales do not change.
    """
    model = PGHM(SMALL, num_identities=1).eval()
    randomize_heads(model, scale=0.3)
    identity = model.decode_identity(0).detach()
    rotations = torch.zeros(1, body.num_bones, 3)
    rotations[0, 0] = torch.tensor([0.4, -1.1, 0.7])
    moved = BodyPose(rotations, torch.tensor([[0.3, -0.2, 0.5]]))
    camera = torch.tensor([[0.0, 0.0, 3.0]])
    with torch.no_grad():
        at_rest = model(identity, geometry, body.rest_pose(), camera)
        posed = model(identity, geometry, moved, camera)
    rotation, translation = kabsch(rest.vertices.double(), body.posed_vertices(moved, rest)[0].double())
    for before, after in ((at_rest.static, posed.static), (at_rest.dynamic, posed.dynamic)):
        offsets = (before.means[0] - geometry.surface.positions).norm(dim=-1)
        assert offsets.max() > 1e-3  # the offsets are really there
        expected = before.means[0].double() @ rotation.T + translation
        assert (after.means[0].double() - expected).abs().max() < 1e-5
        assert (after.scales - before.scales).abs().max() < 1e-6


def test_regulariser_is_the_l2_of_the_returned_offsets(body, geometry):
    """At rest the posed surface is V_bar, so offsets and log scales are read off the outputs."""
    model = PGHM(SMALL, num_identities=1).eval()
    randomize_heads(model, scale=0.3)
    with torch.no_grad():
        out = model(model.decode_identity(0), geometry, body.rest_pose(), torch.tensor([[0.0, 0.0, 3.0]]))
    base = (SMALL.base_scale_factor * geometry.texel_length).clamp(SMALL.min_scale, SMALL.max_scale)
    static_offset = out.static.means[0] - geometry.surface.positions
    pose_offset = out.dynamic.means[0] - out.static.means[0]
    unit = REG_POSITION_UNIT
    expected = (
        static_offset.square().sum(-1).mean() / unit**2
        + pose_offset.square().sum(-1).mean() / unit**2
        + torch.log(out.static.scales[0] / base).square().mean()
        + torch.log(out.dynamic.scales[0] / base).square().mean()
    )
    assert pose_offset.abs().max() > 1e-4 and out.regularizer > 0
    torch.testing.assert_close(out.regularizer, expected, rtol=1e-4, atol=0)


def test_a_model_at_another_resolution_keeps_its_networks_and_resamples_its_bank():
    model = PGHM(SMALL, num_identities=2)
    randomize_heads(model)
    size = SMALL.latent_resolution
    centres = (torch.arange(size) + 0.5) / size
    with torch.no_grad():  # identity 0: a ramp along the columns; identity 1: a constant
        model.identity_bank[0] = 2.0 * centres - 1.0
        model.identity_bank[1] = 0.3
    bank_before = model.identity_bank.detach().clone()

    finer = model.at_resolution(2 * SMALL.uv_resolution)

    assert finer.config.uv_resolution == 2 * SMALL.uv_resolution
    assert torch.equal(model.identity_bank, bank_before)  # the source model is untouched
    weights, finer_weights = model.state_dict(), finer.state_dict()
    for name, value in weights.items():
        if name != "identity_bank":
            assert torch.equal(finer_weights[name], value), name
    bank = finer.identity_bank.detach()
    assert bank.shape == (2, SMALL.latent_channels, 2 * size, 2 * size)
    # Bilinear resampling reproduces a linear function exactly away from the outer half texel.
    fine_centres = (torch.arange(2 * size) + 0.5) / (2 * size)
    inner = slice(1, -1)
    torch.testing.assert_close(bank[0, :, :, inner], (2.0 * fine_centres[inner] - 1.0).expand_as(bank[0, :, :, inner]))
    torch.testing.assert_close(bank[1], torch.full_like(bank[1], 0.3))
    # The same convolutions on a constant latent give the same identity map, far from the borders.
    with torch.no_grad():
        coarse_map, fine_map = model.decode_identity(1), finer.decode_identity(1)
    assert fine_map.shape[-1] == 2 * coarse_map.shape[-1]
    middle, fine_middle = coarse_map.shape[-1] // 2, fine_map.shape[-1] // 2
    torch.testing.assert_close(fine_map[..., fine_middle, fine_middle], coarse_map[..., middle, middle])


@pytest.mark.parametrize("batches", [(2, 1, 2), (1, 3, 1), (1, 1, 1), (2, 2, 2)])
def test_concat_conv_equals_the_convolution_of_the_broadcast_concatenation(batches):
    """The decoders' first convolutions split by input part (shared parts convolved once) against
    the plain convolution of the parts broadcast to the batch and concatenated: the same in float64."""
    from pghm.model.networks import concat_conv, conv3x3

    torch.manual_seed(0)
    widths = (5, 3, 4)
    conv = conv3x3(sum(widths), 6).double()
    torch.nn.init.normal_(conv.bias)
    parts = [torch.randn(b, w, 8, 8, dtype=torch.float64, requires_grad=True) for b, w in zip(batches, widths)]
    batch = max(batches)
    plain = conv(torch.cat([p.expand(batch, -1, -1, -1) for p in parts], 1))
    split = concat_conv(conv, parts)
    assert split.shape == plain.shape
    torch.testing.assert_close(split, plain, rtol=1e-12, atol=1e-12)
    weights = torch.randn_like(plain)
    grads_plain = torch.autograd.grad((plain * weights).sum(), [*parts, conv.weight, conv.bias])
    grads_split = torch.autograd.grad((split * weights).sum(), [*parts, conv.weight, conv.bias])
    for a, b in zip(grads_split, grads_plain):
        torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-12)


BFLOAT16_UNIT = 2.0**-8
"""bfloat16's spacing relative to a value (8 bits of mantissa): twice its rounding error."""


def head_outputs(model: PGHM, body, geometry) -> tuple[list[torch.Tensor], list[torch.Tensor]]:
    """Every decoder head's output (float32 maps) and the gradients of a loss over the Gaussians
    with respect to every weight, of one forward and backward pass at two views."""
    outputs = []
    heads = [m for m in model.modules() if isinstance(m, torch.nn.Conv2d) and m.kernel_size == (1, 1)]
    hooks = [head.register_forward_hook(lambda module, inputs, output: outputs.append(output)) for head in heads]
    model.zero_grad(set_to_none=True)
    centres = torch.tensor([[0.3, 0.1, 2.8], [2.0, 0.4, 1.5]])
    out = model(model.decode_identity(0), geometry, random_pose(body, 2, seed=3), centres)
    (out.dynamic.colors.square().mean() + out.dynamic.means.square().mean() + out.regularizer).backward()
    for hook in hooks:
        hook.remove()
    return [o.detach() for o in outputs], [p.grad for p in model.parameters()]


@pytest.mark.parametrize("training", [True, False])
def test_bfloat16_networks_stay_within_their_rounding_of_float32(body, geometry, training):
    """bfloat16 autocast rounds each convolution's inputs and weights to 8 bits of mantissa and sums
    in float32: a layer's output moves by at most about one bfloat16 unit relative to its size, in
    no preferred direction, so D layers in a row by about sqrt(D) units (independent roundings add
    in quadrature), D at most the model's convolution count; a gradient passes the layers twice. The
    heads run in float32, the weights and their gradients stay float32, and float32 afterwards gives
    float32's values again."""
    model = PGHM(SMALL, num_identities=1)
    randomize_heads(model, scale=0.5)
    model.train(training)
    reference, reference_grads = head_outputs(model, body, geometry)
    bound = math.sqrt(sum(isinstance(m, torch.nn.Conv2d) for m in model.modules())) * BFLOAT16_UNIT
    model.set_precision(torch.bfloat16).train(training)
    rounded, rounded_grads = head_outputs(model, body, geometry)
    for a, b in zip(reference, rounded):
        assert b.dtype == torch.float32
        error = float((a - b).norm() / a.norm())
        assert 0 < error <= bound  # rounded (bfloat16 ran), but within its bound
    for a, b in zip(reference_grads, rounded_grads):
        assert b.dtype == torch.float32
        assert float((a - b).norm()) <= 2 * bound * float(a.norm())
    assert all(p.dtype == torch.float32 for p in model.parameters())
    again, _ = head_outputs(model.set_precision(torch.float32).train(training), body, geometry)
    for a, b in zip(reference, again):
        torch.testing.assert_close(a, b, atol=1e-6, rtol=0)  # the layouts sum in other orders


def test_precision_carries_to_derived_models_and_refuses_other_dtypes():
    model = PGHM(SMALL, num_identities=1).set_precision(torch.bfloat16)
    assert model.at_resolution(2 * SMALL.uv_resolution).compute_dtype == torch.bfloat16
    assert model.with_detail().compute_dtype == torch.bfloat16
    spatial = [m for m in model.train().modules() if isinstance(m, torch.nn.Conv2d) and m.kernel_size != (1, 1)]
    assert all(c.weight.is_contiguous(memory_format=torch.channels_last) for c in spatial)  # bfloat16 trains NHWC
    with pytest.raises(PghmError, match="float32 or bfloat16"):
        model.set_precision(torch.float16)
