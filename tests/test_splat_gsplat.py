"""The gsplat mapping (pghm.splat.gsplat_backend) held to the CPU splatter without a GPU.

gsplat's CUDA kernels need a GPU, and its pure-PyTorch rasteriser (``_rasterize_to_pixels``)
does too: it gathers its pairs with the CUDA ``rasterize_to_indices_in_range`` and composites
with nerfacc. Its torch projection (``_fully_fused_projection``) and tile binning
(``_isect_tiles``, ``_isect_offset_encode``) do run on the CPU. So the arguments
:func:`rasterization_arguments` makes are fed, in float64, through gsplat's own projection
and binning, and each tile's list is composited here by the rule of gsplat's forward kernel
(``RasterizeToPixels3DGSFwd.cu``: alpha = min(0.999, o exp(-sigma)), pairs below 1/255
skipped, a pixel done before the pair that would leave T <= 1e-4). With the spec's rule
(clamp 0.99, no stop) that must be pghm's float64 image to rounding (gsplat orders a tile by
float32 depth; these scenes hold no Gaussians closer in depth than float32 resolves): any
mistake in the camera, scales, background, depth or batch mapping shows. With gsplat's rule the image
differs only where the docs say, by at most what they say.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace

import pytest
import torch
from cutoff import BAND, MAX_ERROR
from test_splat import SCENE_SIZES, Scene, random_scene

from pghm.errors import PghmError
from pghm.splat import Camera, render
from pghm.splat import gsplat_backend as backend
from pghm.splat.spec import ALPHA_MAX, ALPHA_MIN

gsplat_torch = pytest.importorskip("gsplat.cuda._torch_impl")

TILE = 16
"""gsplat's default tile side (pixels)."""
MAPPING_TOLERANCE = 1e-9
"""Both paths in float64 with the same formulas in another order: rounding is ~1e-15 per operation."""
SCENES = list(enumerate(SCENE_SIZES))[:14]
"""The oracle scenes of tests/test_splat.py up to 128 Gaussians (a few seconds in all)."""


def centred(scene: Scene) -> Scene:
    """The scene in float64 with its principal point at the image centre, where gsplat's frustum
    clamp is the spec's (gsplat_backend's docstring), and its rotation made orthonormal in float64:
    gsplat rotates the covariance, R s^2 I R^T, which equals s^2 I only for an orthonormal R, and
    the float32 pose's R is orthonormal only to 1e-7."""
    camera = scene.camera
    pose = camera.world_to_camera.double().clone()
    left, _, right = torch.linalg.svd(pose[:3, :3])
    pose[:3, :3] = left @ right
    centred_camera = Camera(camera.fx, camera.fy, camera.width / 2, camera.height / 2, camera.width, camera.height, pose)
    values = (scene.means, scene.scales, scene.colors, scene.opacities)
    return Scene(*(value.double() for value in values), centred_camera, scene.background)


@dataclass(frozen=True)
class Binned:
    """A scene as gsplat's torch reference projects and bins it (one image): per Gaussian n, its
    screen mean (N, 2), conic (N, 3), depth (N,), opacity (N,) and colour + depth channels (N, 4);
    per tile, its Gaussians front to back (``flat[offsets[t]:offsets[t + 1]]``)."""

    means2d: torch.Tensor
    conics: torch.Tensor
    opacities: torch.Tensor
    values: torch.Tensor
    background: torch.Tensor
    offsets: list[int]
    flat: torch.Tensor
    width: int
    height: int


def project_and_bin(scene: Scene) -> Binned:
    """The mapping's arguments in float64 through gsplat's ``_fully_fused_projection`` and tile binning."""
    arguments = backend.rasterization_arguments(
        scene.means[None], scene.scales[None], scene.colors[None], scene.opacities[None], scene.camera,
        torch.tensor(scene.background, dtype=torch.float64), dtype=torch.float64,
    )  # fmt: skip
    width, height = arguments["width"], arguments["height"]
    covariances, _ = gsplat_torch._quat_scale_to_covar_preci(
        arguments["quats"], arguments["scales"], compute_preci=False
    )
    radii, means2d, depths, conics, _ = gsplat_torch._fully_fused_projection(
        arguments["means"], covariances, arguments["viewmats"], arguments["Ks"], width, height,
        eps2d=arguments["eps2d"], near_plane=arguments["near_plane"],
    )  # fmt: skip
    tiles_x, tiles_y = math.ceil(width / TILE), math.ceil(height / TILE)
    _, ids, flat = gsplat_torch._isect_tiles(means2d, radii, depths, TILE, tiles_x, tiles_y)
    offsets = gsplat_torch._isect_offset_encode(ids, 1, tiles_x, tiles_y).flatten().tolist() + [len(flat)]
    return Binned(
        means2d=means2d[0, 0],
        conics=conics[0, 0],
        opacities=arguments["opacities"][0],
        values=torch.cat([arguments["colors"][0], depths[0, 0, :, None]], dim=-1),  # gsplat's "RGB+D" channels
        background=torch.cat([arguments["backgrounds"][0, 0], torch.zeros(1, dtype=torch.float64)]),
        offsets=offsets,
        flat=flat.long(),
        width=width,
        height=height,
    )


def composite(binned: Binned, alpha_max: float, stop: float, band: float = 0.0) -> dict[str, torch.Tensor]:
    """rgb (H, W, 3), alpha, depth (H, W) by gsplat's forward rule with its clamp and stop replaced by
    ``alpha_max`` and ``stop`` (0: never); per pixel also the transmittance before the pair it stopped
    at (0 where none), whether a pair's alpha exceeded the spec's ALPHA_MAX, and whether a pair lies
    within relative ``band`` of the 1/255 cut-off or of the stop (a float32 kernel may decide it
    either way)."""
    width, height = binned.width, binned.height
    tiles_x = math.ceil(width / TILE)
    out = torch.zeros(height, width, 4, dtype=torch.float64)
    left = torch.ones(height, width, dtype=torch.float64)
    at_stop = torch.zeros(height, width, dtype=torch.float64)
    clamped = torch.zeros(height, width, dtype=torch.bool)
    near = torch.zeros(height, width, dtype=torch.bool)
    for tile in range(len(binned.offsets) - 1):
        gaussians = binned.flat[binned.offsets[tile] : binned.offsets[tile + 1]]  # front to back
        rows = torch.arange(tile // tiles_x * TILE, min((tile // tiles_x + 1) * TILE, height))
        cols = torch.arange(tile % tiles_x * TILE, min((tile % tiles_x + 1) * TILE, width))
        py, px = torch.meshgrid(rows + 0.5, cols + 0.5, indexing="ij")
        dx = binned.means2d[gaussians, 0] - px.reshape(-1, 1)  # (P, L); gsplat's delta = mean - pixel
        dy = binned.means2d[gaussians, 1] - py.reshape(-1, 1)
        a, b, c = binned.conics[gaussians].unbind(-1)
        sigma = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy
        raw = binned.opacities[gaussians] * torch.exp(-sigma)
        alpha = torch.where((sigma >= 0) & (raw >= ALPHA_MIN), raw.clamp(max=alpha_max), torch.zeros_like(raw))
        # The pixel is done at the first pair that would leave T <= stop; that pair and all behind it drop.
        after = torch.cumprod(1 - alpha, dim=1)
        done = torch.cummax(((after <= stop) & (alpha > 0)).to(torch.uint8), dim=1).values.bool()
        first_done = done & ~torch.cat([torch.zeros_like(done[:, :1]), done[:, :-1]], dim=1)
        before = torch.cat([torch.ones_like(after[:, :1]), after[:, :-1]], dim=1)
        alpha = torch.where(done, torch.zeros_like(alpha), alpha)
        kept = torch.cumprod(1 - alpha, dim=1)
        weight = alpha * torch.cat([torch.ones_like(kept[:, :1]), kept[:, :-1]], dim=1)
        final = torch.prod(1 - alpha, dim=1, keepdim=True)
        block = weight @ binned.values[gaussians] + final * binned.background
        shape = (len(rows), len(cols))
        out[rows[:, None], cols] = block.reshape(*shape, 4)
        left[rows[:, None], cols] = final.reshape(shape)
        at_stop[rows[:, None], cols] = (before * first_done).sum(dim=1).reshape(shape)
        clamped[rows[:, None], cols] = ((raw > ALPHA_MAX) & (alpha > 0)).any(dim=1).reshape(shape)
        at_cut = (sigma >= 0) & ((raw - ALPHA_MIN).abs() <= band * ALPHA_MIN)
        at_end = (after - stop).abs() <= band * stop
        near[rows[:, None], cols] = (at_cut | at_end).any(dim=1).reshape(shape)
    return {
        "rgb": out[..., :3], "alpha": 1 - left, "depth": out[..., 3],
        "at_stop": at_stop, "clamped": clamped, "near": near,
    }  # fmt: skip


@functools.cache
def binned_oracle(seed: int, count: int) -> tuple[Scene, Binned]:
    scene = centred(random_scene(seed, count))
    return scene, project_and_bin(scene)


@functools.cache
def oracle(seed: int, count: int, opaque: bool) -> tuple[Scene, Binned, dict[str, torch.Tensor]]:
    """Oracle scene ``seed`` (centred; every opacity 1 when ``opaque``, as pghm's avatars), gsplat's
    binning of it, and the CPU splatter's float64 image. The torch reference's tiles do not depend
    on the opacities (it always bins 3.33 sigma), so the opaque scene shares them."""
    scene, binned = binned_oracle(seed, count)
    if opaque:
        scene = replace(scene, opacities=torch.ones_like(scene.opacities))
        binned = replace(binned, opacities=torch.ones_like(binned.opacities))
    out = scene.render("torch")
    return scene, binned, {"rgb": out.rgb, "alpha": out.alpha, "depth": out.depth}


@pytest.mark.parametrize("opaque", [False, True])
def test_mapping_through_gsplat_projection_is_the_spec(opaque):
    """gsplat's projection and tiles, fed by the mapping, composited by the spec's rule = the CPU splatter."""
    for seed, count in SCENES:
        _, binned, want = oracle(seed, count, opaque)
        got = composite(binned, ALPHA_MAX, 0.0)
        for name in ("rgb", "alpha", "depth"):
            error = float((got[name] - want[name]).abs().max())
            assert error <= MAPPING_TOLERANCE * max(1.0, float(want[name].abs().max())), (seed, name, error)


@pytest.mark.parametrize("opaque", [False, True])
def test_gsplat_rule_differs_only_where_documented(opaque):
    """gsplat's own rule: a pixel differs from the spec only if it stopped early or had a pair above
    ALPHA_MAX; a pixel that only stopped differs by T_k (C_behind - background), where T_k is the
    transmittance before the pair it stopped at, so by at most T_k times the largest colour step,
    and T_k <= GSPLAT_STOP / (1 - GSPLAT_ALPHA_MAX)."""
    seen = {"stopped": 0, "clamped": 0}
    for seed, count in SCENES:
        scene, binned, want = oracle(seed, count, opaque)
        got = composite(binned, backend.GSPLAT_ALPHA_MAX, backend.GSPLAT_STOP)
        error = (got["rgb"] - want["rgb"]).abs().amax(dim=-1)
        stopped, clamped = got["at_stop"] > 0, got["clamped"]
        assert bool((error[~stopped & ~clamped] <= MAPPING_TOLERANCE).all()), seed
        values = torch.cat([scene.colors.flatten(), torch.tensor(scene.background, dtype=torch.float64)])
        step = float(values.max() - values.min())
        only_stopped = stopped & ~clamped
        assert bool((error[only_stopped] <= got["at_stop"][only_stopped] * step + MAPPING_TOLERANCE).all()), seed
        assert float(got["at_stop"].max()) <= backend.GSPLAT_STOP / (1 - backend.GSPLAT_ALPHA_MAX)
        seen["stopped"] += int(stopped.sum())
        seen["clamped"] += int(clamped.sum())
    assert seen["stopped"] > 0 and (seen["clamped"] > 0) == opaque, seen  # the scenes exercise what they should


@pytest.mark.skipif(not torch.cuda.is_available(), reason="gsplat's kernels need a CUDA device")
@pytest.mark.parametrize("opaque", [False, True])
def test_gsplat_kernels_are_the_transcribed_rule(opaque):
    """gsplat's CUDA kernels (float32), through pghm.splat.render, against its forward rule composited
    here in float64. Every pixel is within the float32 budget of tests/cutoff.py (MAX_ERROR, derived
    there for a float32 projection and blend), except pixels with a pair within the float band of the
    cut-off or the stop, where the kernel may decide the other way."""
    pytest.importorskip("gsplat")
    near_pixels = total = 0
    for seed, count in SCENES:
        scene, binned, _ = oracle(seed, count, opaque)
        want = composite(binned, backend.GSPLAT_ALPHA_MAX, backend.GSPLAT_STOP, band=BAND["float"])
        values = [value.float().cuda() for value in (scene.means, scene.scales, scene.colors, scene.opacities)]
        got = render(*values, scene.camera, background=scene.background).rgb.double().cpu()
        error = (got - want["rgb"]).abs().amax(dim=-1)
        assert float(error[~want["near"]].max()) <= MAX_ERROR, (seed, float(error[~want["near"]].max()))
        near_pixels += int(want["near"].sum())
        total += error.numel()
    assert near_pixels < total / 4, near_pixels  # the band leaves most pixels to the strict bound


def tiny_batch() -> tuple[torch.Tensor, ...]:
    """Two Gaussian sets (B = 2, N = 2) and two cameras with hand-picked values."""
    means = torch.tensor([[[0.0, 0.0, 2.0], [0.1, -0.2, 3.0]], [[0.3, 0.1, 2.5], [0.0, 0.0, 4.0]]], dtype=torch.float64)
    scales = torch.tensor([[0.05, 0.1], [0.2, 0.01]], dtype=torch.float64)
    colors = torch.tensor([[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], [[0.0, 0.0, 1.0], [0.5, 0.5, 0.5]]])
    opacities = torch.tensor([[0.9, 0.5], [1.0, 0.25]], dtype=torch.float64)
    return means, scales, colors.double(), opacities


def test_arguments_by_hand():
    """Every argument against values written out here (no gsplat needed for the mapping itself)."""
    means, scales, colors, opacities = tiny_batch()
    poses = torch.eye(4).repeat(2, 1, 1)
    poses[1, :3, 3] = torch.tensor([0.1, 0.2, 0.3])
    camera = Camera(torch.tensor([50.0, 60.0]), torch.tensor([55.0, 65.0]), 16.0, 12.0, 32, 24, poses)
    arguments = backend.rasterization_arguments(means, scales, colors, opacities, camera, torch.tensor([0.2, 0.4, 0.6]))
    expected_k = torch.tensor([[[50.0, 0, 16], [0, 55, 12], [0, 0, 1]], [[60, 0, 16], [0, 65, 12], [0, 0, 1]]])
    expected = {
        "means": means.float(),
        "quats": torch.tensor([1.0, 0, 0, 0]).expand(2, 2, 4),
        "scales": torch.tensor([[[0.05] * 3, [0.1] * 3], [[0.2] * 3, [0.01] * 3]]),
        "opacities": opacities.float(),
        "colors": colors.float(),
        "viewmats": poses[:, None],
        "Ks": expected_k[:, None],
        "backgrounds": torch.tensor([[[0.2, 0.4, 0.6]], [[0.2, 0.4, 0.6]]]),
    }
    for name, value in expected.items():
        assert arguments[name].dtype == torch.float32, name
        torch.testing.assert_close(arguments[name], value, rtol=0, atol=0, msg=name)
    settings = {name: arguments[name] for name in ("width", "height", "near_plane", "eps2d", "render_mode")}
    assert settings == {"width": 32, "height": 24, "near_plane": 0.01, "eps2d": 0.3, "render_mode": "RGB+D"}
    assert (arguments["rasterize_mode"], arguments["packed"], arguments["sh_degree"]) == ("classic", False, None)


def test_outputs_unpacked_from_gsplat_layout(monkeypatch):
    """gsplat returns (B, C=1, H, W, 4) with depth in channel 3 and alphas (B, 1, H, W, 1)."""
    gsplat = pytest.importorskip("gsplat")
    means, scales, colors, opacities = tiny_batch()
    camera = Camera(50.0, 55.0, 16.0, 12.0, 32, 24, torch.eye(4))
    images = torch.arange(2 * 24 * 32 * 4, dtype=torch.float32).reshape(2, 1, 24, 32, 4)
    alphas = -torch.arange(2 * 24 * 32, dtype=torch.float32).reshape(2, 1, 24, 32, 1)
    monkeypatch.setattr(gsplat, "rasterization", lambda **kwargs: (images, alphas, {}))
    rgb, alpha, depth = backend.render_gsplat(means, scales, colors, opacities, camera, torch.ones(3))
    assert rgb.dtype == alpha.dtype == depth.dtype == torch.float64
    assert torch.equal(rgb, images[:, 0, ..., :3].double()) and torch.equal(depth, images[:, 0, ..., 3].double())
    assert torch.equal(alpha, alphas[:, 0, ..., 0].double())


def test_missing_gsplat_says_how_to_install(monkeypatch):
    import importlib

    real = importlib.import_module

    def without_gsplat(name, *args):
        if name == "gsplat":
            raise ImportError("No module named 'gsplat'")
        return real(name, *args)

    monkeypatch.setattr(importlib, "import_module", without_gsplat)
    with pytest.raises(PghmError, match=r"pip install 'pghm\[gpu\]'"):
        backend.load_gsplat()


def test_cpu_tensors_refuse_the_gsplat_backend():
    means, scales, colors, opacities = (value[0] for value in tiny_batch())
    camera = Camera(50.0, 55.0, 16.0, 12.0, 32, 24, torch.eye(4))
    with pytest.raises(PghmError, match="CUDA tensors"):
        render(means, scales, colors, opacities, camera, backend="gsplat")
