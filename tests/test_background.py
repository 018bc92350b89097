"""Backgrounds: compositing equals the splatter's own, the silhouette term, eval's halo and IoU."""

from __future__ import annotations

import math

import pytest
import torch

from pghm.errors import PghmError
from pghm.splat import Camera, render
from pghm.train.background import composite_render, composite_target, draw_backgrounds, parse_colour
from pghm.train.evaluate import HALO_LEVEL, halo_pixels, silhouette_iou
from pghm.train.losses import silhouette


def scene(count: int = 40, seed: int = 0):
    """Random semi-transparent Gaussians in front of a 40 x 30 camera (some pixels uncovered)."""
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(count, 3, generator=g, dtype=torch.float64) * 0.25 + torch.tensor([0.0, 0.0, 3.0])
    scales = 0.06 + 0.08 * torch.rand(count, generator=g, dtype=torch.float64)
    colors = torch.rand(count, 3, generator=g, dtype=torch.float64)
    opacities = 0.1 + 0.8 * torch.rand(count, generator=g, dtype=torch.float64)
    camera = Camera.look_at(
        eye=(0.0, 0.0, 0.0), target=(0.0, 0.0, 3.0), up=(0.0, -1.0, 0.0), fov_y_degrees=40.0, width=40, height=30
    )
    return (means, scales, colors, opacities), camera


@pytest.mark.parametrize("backend", ["torch", "native"])
def test_two_backgrounds_differ_by_the_transmittance_times_their_difference(backend):
    gaussians, camera = scene()
    b1, b2 = (0.9, 0.2, 0.4), (0.1, 0.7, 0.3)
    one = render(*gaussians, camera, background=b1, backend=backend)
    two = render(*gaussians, camera, background=b2, backend=backend)
    # Covered and uncovered pixels both occur.
    assert 0.1 < float((one.alpha < 0.5).float().mean()) < 0.9
    difference = torch.tensor(b1, dtype=torch.float64) - torch.tensor(b2, dtype=torch.float64)
    expected = (1 - one.alpha)[..., None] * difference
    torch.testing.assert_close(one.rgb - two.rgb, expected, atol=1e-12, rtol=0)
    torch.testing.assert_close(one.alpha, two.alpha, atol=0, rtol=0)
    # One render on black serves any background, an image of them included (as training does).
    black = render(*gaussians, camera, background=(0.0, 0.0, 0.0), backend=backend)
    colour = torch.tensor(b1, dtype=torch.float64).view(3, 1, 1)
    moved = composite_render(black.rgb.permute(2, 0, 1)[None], black.alpha[None, None], colour)
    torch.testing.assert_close(moved[0].permute(1, 2, 0), one.rgb, atol=1e-12, rtol=0)


def test_a_render_composited_on_per_pixel_backgrounds_matches_each_pixels_own_colour():
    gaussians, camera = scene(seed=1)
    backgrounds = draw_backgrounds("gradient", 1, camera.height, camera.width, (0, 0, 0)).double()
    black = render(*gaussians, camera, background=(0.0, 0.0, 0.0))
    moved = composite_render(black.rgb.permute(2, 0, 1)[None], black.alpha[None, None], backgrounds)[0]
    for row, col in ((0, 0), (29, 39), (15, 20), (3, 33)):
        colour = backgrounds[0, :, row, col].tolist()
        single = render(*gaussians, camera, background=colour).rgb[row, col]
        torch.testing.assert_close(moved[:, row, col], single, atol=1e-12, rtol=0)


def test_drawn_backgrounds_are_deterministic_in_range_and_of_their_kind():
    assert draw_backgrounds("white", 2, 8, 6, (0, 5, 0)) is None
    colour = draw_backgrounds("colour", 3, 8, 6, (0, 5, 0))
    torch.testing.assert_close(colour, draw_backgrounds("colour", 3, 8, 6, (0, 5, 0)), atol=0, rtol=0)
    assert not torch.equal(colour, draw_backgrounds("colour", 3, 8, 6, (0, 6, 0)))
    assert colour.shape == (3, 3, 8, 6) and bool((colour == colour[:, :, :1, :1]).all())
    gradient = draw_backgrounds("gradient", 4, 8, 6, (1, 2, 3))
    assert gradient.shape == (4, 3, 8, 6) and 0 <= float(gradient.min()) and float(gradient.max()) <= 1
    # A ramp between two colours: every image spans the segment between its two end colours.
    corners = gradient[:, :, [0, 0, -1, -1], [0, -1, 0, -1]]
    assert bool((corners.amax(2) - corners.amin(2) > 0).all())
    with pytest.raises(PghmError, match="background kind"):
        draw_backgrounds("plaid", 1, 2, 2, (0,))


def test_composite_target_keeps_the_subject_and_replaces_the_rest():
    image = torch.rand(1, 3, 4, 5)
    mask = torch.zeros(1, 1, 4, 5)
    mask[..., 1:3, 2:4] = 1
    out = composite_target(image, mask, torch.tensor([0.2, 0.3, 0.4]).view(3, 1, 1))
    torch.testing.assert_close(out[..., 1:3, 2:4], image[..., 1:3, 2:4], atol=0, rtol=0)
    assert bool((out[0, :, 0, 0] == torch.tensor([0.2, 0.3, 0.4])).all())


def test_a_target_on_white_moves_through_its_matte_onto_any_background_exactly():
    """I = a c + (1 - a) on white becomes a c + (1 - a) B: the outline's pixels keep their
    colour's share a c and take the new background's share (1 - a) B, no white left."""
    g = torch.Generator().manual_seed(3)
    colour = torch.rand(2, 3, 6, 7, generator=g, dtype=torch.float64)
    matte = torch.rand(2, 1, 6, 7, generator=g, dtype=torch.float64)
    matte[..., 0, :] = 0.0  # uncovered
    matte[..., 1, :] = 1.0  # fully covered
    background = torch.rand(2, 3, 6, 7, generator=g, dtype=torch.float64)
    on_white = matte * colour + (1 - matte)
    expected = matte * colour + (1 - matte) * background
    torch.testing.assert_close(composite_target(on_white, matte, background), expected, atol=1e-12, rtol=0)


def test_silhouette_term_by_hand():
    alpha = torch.tensor([[[[1.0, 0.5], [0.2, 0.0]]], [[[0.0, 0.0], [0.0, 0.0]]]])
    mask = torch.tensor([[[[1.0, 1.0], [0.0, 0.0]]], [[[1.0, 0.0], [0.0, 0.0]]]])
    # |0| + |0.5| + |0.2| + |0| over 4 pixels; one missed pixel of 4.
    torch.testing.assert_close(silhouette(alpha, mask), torch.tensor([0.7 / 4, 0.25]))


def test_silhouette_term_of_one_gaussian_against_its_analytic_alpha():
    """A single Gaussian's alpha at a pixel is o exp(-d^2 / 2 sigma^2) (+ the 0.3 px^2 dilation);
    against an empty mask the term is the mean of those values over the pixels it reaches."""
    camera = Camera.from_matrices(
        torch.tensor([[100.0, 0.0, 8.0], [0.0, 100.0, 8.0], [0.0, 0.0, 1.0]]), torch.eye(4), width=16, height=16
    )
    scale, opacity, depth = 0.02, 0.6, 2.0
    out = render(
        torch.tensor([[0.0, 0.0, depth]]), torch.tensor([scale]), torch.ones(1, 3), torch.tensor([opacity]), camera
    )
    variance = (100.0 * scale / depth) ** 2 + 0.3  # pixels^2
    centres = torch.arange(16) + 0.5 - 8.0
    d2 = centres[:, None] ** 2 + centres[None, :] ** 2
    expected = opacity * torch.exp(-d2 / (2 * variance))
    expected = torch.where(expected >= 1 / 255, expected, torch.zeros(()))
    value = silhouette(out.alpha[None, None], torch.zeros(1, 1, 16, 16))
    torch.testing.assert_close(value, expected.mean().view(1), atol=1e-6, rtol=1e-5)


def test_iou_and_halo_of_a_constructed_render():
    mask = torch.zeros(10, 10)
    mask[2:6, 2:6] = 1  # 16 pixels
    alpha = torch.zeros(10, 10)
    alpha[2:6, 2:7] = 0.8  # covers the mask and 4 pixels more
    alpha[0, 0] = 0.5  # not above COVERED
    assert silhouette_iou(alpha, mask) == pytest.approx(16 / 20)
    assert silhouette_iou(torch.zeros(3, 3), torch.zeros(3, 3)) == 1.0
    rgb = torch.zeros(3, 10, 10)
    rgb[:, 2:6, 2:7] = 0.9  # the 4 extra pixels outside the mask glow
    rgb[:, 9, 9] = HALO_LEVEL  # not brighter than the level
    rgb[0, 8, 8] = 0.9  # mean 0.3: brighter
    assert halo_pixels(rgb, mask) == 4 + 1


def test_parse_colour():
    assert parse_colour("white") == (1.0, 1.0, 1.0) and parse_colour("Black") == (0.0, 0.0, 0.0)
    assert parse_colour("0.2,0.3,0.4") == (0.2, 0.3, 0.4)
    assert parse_colour("#334455") == pytest.approx((0x33 / 255, 0x44 / 255, 0x55 / 255))
    for bad in ("grey", "#12345", "0.2,0.3", "1.2,0,0", "nan,0,0", "#gg0000"):
        with pytest.raises(PghmError, match="background"):
            parse_colour(bad)


def test_eval_background_option_is_checked_by_the_cli(capsys):
    from pghm.cli.main import main

    assert main(["eval", "a.pt", "subject", "--background", "mauve"]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert "--background" in line and "mauve" in line


def test_nothing_is_lost_to_rounding_on_white():
    """White evaluation composites a render on black onto white: equal to rendering on white to float precision."""
    gaussians, camera = scene(seed=2)
    gaussians = tuple(t.float() for t in gaussians)
    white = render(*gaussians, camera, background=(1.0, 1.0, 1.0))
    black = render(*gaussians, camera, background=(0.0, 0.0, 0.0))
    moved = composite_render(black.rgb.permute(2, 0, 1), black.alpha[None], torch.ones(3, 1, 1))
    error = (moved.permute(1, 2, 0) - white.rgb).abs().max()
    assert float(error) < 1e-6 and math.isfinite(float(error))
