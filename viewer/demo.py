"""An untrained development avatar, for trying the viewer before a trained one exists.

The network's 1x1 output heads are zero-initialised, so an untrained model outputs the bare
body in grey. :func:`development_avatar` gives the heads random weights (small for
positions, scales and the pose/view terms, larger for colour, so that latent edits show) and
a skin-tone colour bias, and draws a random identity latent: a mannequin with mottled
colour that reacts to every edit the viewer offers. Tests and the benchmark build theirs
with it; ``assets/avatar.pt`` is the trained default.
"""

from __future__ import annotations

import math

import torch

from pghm.io.avatar import Avatar
from pghm.model import PGHM, ModelConfig
from pghm.model.pghm import STATIC_CHANNELS

SKIN_TONE = (0.80, 0.62, 0.52)
"""RGB the colour bias centres on."""
COLOUR_WEIGHT = 0.15
"""Std of the static head's colour weights: latent edits change colours visibly."""
GEOMETRY_WEIGHT = 0.02
"""Std of every other head weight: offsets and scales stay near the body surface."""
COLOUR_CHANNELS = slice(4, STATIC_CHANNELS)
"""D_static's colour-logit outputs (after position offset (3) and log-scale (1))."""


def development_avatar(
    config: ModelConfig | None = None, kind: str = "avatar", num_identities: int = 4, seed: int = 0
) -> Avatar:
    """A random avatar (or prior with ``num_identities`` bank latents) on the Anny body.

    Args:
        config: network sizes (default: :class:`ModelConfig`'s defaults, L = 128).
        kind: "avatar" (a personal latent) or "prior" (a bank of identities).
        seed: makes the weights and latents reproducible.
    """
    from pghm.body import load_body

    config = config or ModelConfig()
    generator = torch.Generator().manual_seed(seed)
    with torch.random.fork_rng():  # the network's default initialisation draws from the global RNG
        torch.manual_seed(seed)
        model = PGHM(config, num_identities=num_identities if kind == "prior" else 0)
    with torch.no_grad():
        if kind == "prior":
            model.identity_bank.normal_(generator=generator)
        for name in ("static_decoder", "pose_decoder", "view_decoder", "single_decoder"):
            if hasattr(model, name):
                head = getattr(model, name).head
                head.weight.normal_(0.0, GEOMETRY_WEIGHT, generator=generator)
                head.bias.normal_(0.0, GEOMETRY_WEIGHT, generator=generator)
        colour_head = model.static_decoder.head if model.multi_head else model.single_decoder.head
        colour_head.weight[COLOUR_CHANNELS].normal_(0.0, COLOUR_WEIGHT, generator=generator)
        colour_head.bias[COLOUR_CHANNELS] = torch.tensor([math.log(c / (1 - c)) for c in SKIN_TONE])
    model.eval()
    body = load_body("anny")
    shape = body.default_shape().clone()
    size = config.uv_resolution
    latent = torch.randn(1, config.latent_channels, size, size, generator=generator) if kind == "avatar" else None
    shapes = shape.expand(num_identities, -1).clone() if kind == "prior" else None
    return Avatar(
        model=model,
        kind=kind,
        body_name="anny",
        shape=shape,
        shapes=shapes,
        latent=latent,
        metadata={"data": "development avatar (untrained, random heads)", "seed": seed},
    )
