"""The convolutional networks of PGHM: Feature Decoder, U-Net encoder E_u, the light pose
and view encoders E_p and E_v, and the decoder heads.

Maps are channels-first (B, C, L, L). The encoder E_u turns the identity map F into a
pyramid of features F_u = [f_0 (L), f_1 (L/2), ..., f_K (L/2^K)]; every level is wired to
every decoder (U-Net skips). E_p and E_v produce pyramids of the same resolutions, and a
decoder conditioned on them concatenates their level k with f_k on the way up:

    x_K = conv([f_K, c_K])
    x_k = conv([up(x_{k+1}), f_k, c_k])      k = K-1, ..., 0
    out = head(x_0)                          1x1 conv, zero-initialised

The heads start at zero, so an untrained model places every Gaussian on the body surface
with its base scale and mid-grey colour, and training starts from a sensible render.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn
from torch.nn import functional as F

Pyramid = list[Tensor]


def conv3x3(in_channels: int, out_channels: int, stride: int = 1) -> nn.Conv2d:
    """A 3x3 convolution with He (Kaiming) initialisation.

    PyTorch's default init shrinks the activation variance about threefold per layer; over
    the ~20 layers from the latent to a head that starves the latent of gradient, and the
    model learns several times slower (measured: loss ratio after 40 steps 0.64 vs 0.20).
    """
    conv = nn.Conv2d(in_channels, out_channels, 3, stride=stride, padding=1)
    nn.init.kaiming_normal_(conv.weight, nonlinearity="relu")
    nn.init.zeros_(conv.bias)
    return conv


class ConvBlock(nn.Sequential):
    """conv3x3 -> SiLU -> conv3x3 -> SiLU; the first conv may downsample by 2."""

    def __init__(self, in_channels: int, out_channels: int, stride: int = 1) -> None:
        super().__init__(
            conv3x3(in_channels, out_channels, stride),
            nn.SiLU(),
            conv3x3(out_channels, out_channels),
            nn.SiLU(),
        )

    def rest(self, x: Tensor) -> Tensor:
        """The block after its first convolution, on that convolution's output ``x``."""
        for layer in list(self)[1:]:
            x = layer(x)
        return x


class FeatureDecoder(nn.Module):
    """Expands a compact latent (B, C, L', L') to the identity map F (B, C, L, L), L = 2 L'."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.expand = conv3x3(channels, 4 * channels)
        self.refine = nn.Sequential(nn.SiLU(), conv3x3(channels, channels), nn.SiLU(), conv3x3(channels, channels))

    def forward(self, latent: Tensor) -> Tensor:
        upsampled = F.pixel_shuffle(self.expand(latent), 2)
        return upsampled + self.refine(upsampled)


class PyramidEncoder(nn.Module):
    """A pyramid of features at L, L/2, ..., L/2^K: one block per level, downsampling by 2.

    Serves as the U-Net encoder E_u (wide) and as the light E_p and E_v (narrow).
    """

    def __init__(self, in_channels: int, channels: tuple[int, ...], light: bool = False) -> None:
        super().__init__()
        blocks = []
        previous = in_channels
        for level, width in enumerate(channels):
            stride = 1 if level == 0 else 2
            if light:
                blocks.append(nn.Sequential(conv3x3(previous, width, stride), nn.SiLU()))
            else:
                blocks.append(ConvBlock(previous, width, stride))
            previous = width
        self.blocks = nn.ModuleList(blocks)

    def forward(self, x: Tensor) -> Pyramid:
        features = []
        for block in self.blocks:
            x = block(x)
            features.append(x)
        return features


class PyramidDecoder(nn.Module):
    """A decoder head: U-Net upsampling path over the E_u pyramid and an optional condition pyramid.

    Args:
        skip_channels: channels of the E_u pyramid, finest first.
        condition_channels: channels of the condition pyramid (zeros for D_static).
        up_channels: channels on the way up, from level K-1 to 0.
        out_channels: outputs per texel.
    """

    def __init__(
        self,
        skip_channels: tuple[int, ...],
        condition_channels: tuple[int, ...],
        up_channels: tuple[int, ...],
        out_channels: int,
    ) -> None:
        super().__init__()
        levels = len(skip_channels)
        bottom = skip_channels[-1] + condition_channels[-1]
        self.bottom = nn.Sequential(conv3x3(bottom, skip_channels[-1]), nn.SiLU())
        ups = []
        previous = skip_channels[-1]
        for k, width in zip(range(levels - 2, -1, -1), up_channels):
            ups.append(ConvBlock(previous + skip_channels[k] + condition_channels[k], width))
            previous = width
        self.ups = nn.ModuleList(ups)
        self.head = nn.Conv2d(previous, out_channels, 1)
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(self.head.bias)

    def forward(self, skips: Pyramid, condition: Pyramid | None = None) -> Tensor:
        """(B, out_channels, L, L) from the E_u pyramid (batch 1 or B) and a condition pyramid."""

        def level(k: int) -> list[Tensor]:
            return [skips[k]] if condition is None else [skips[k], condition[k]]

        x = self.bottom[1](concat_conv(self.bottom[0], level(len(skips) - 1)))
        for up, k in zip(self.ups, range(len(skips) - 2, -1, -1)):
            x = F.interpolate(x, scale_factor=2.0, mode="nearest")
            x = up.rest(concat_conv(up[0], [x, *level(k)]))
        if x.dtype != torch.bfloat16:
            return self.head(x)
        with torch.autocast(x.device.type, enabled=False):  # the head's outputs in full precision
            return self.head(x.float())


def concat_conv(conv: nn.Conv2d, parts: list[Tensor]) -> Tensor:
    """``conv`` of the channel concatenation of ``parts`` (each (1 or B, C_i, H, W)), broadcast to B.

    A convolution is linear in its input channels, so with W = [W_1 | ... | W_n] split as the parts'
    channels,

        conv([p_1, ..., p_n], W) = b + sum_i conv(p_i, W_i),

    and a part shared by the batch (the E_u skips, batch 1, beside a condition of batch B) is
    convolved once instead of B times: in a decoder at two images a step, 28 % of its FLOPs are the
    skips'. The parts of batch B are convolved together, those shared together. What it saves depends
    on the layout: a model's forward and backward at two images in the inference layout (channels-last,
    as the settling and test-time refinement run it) 108 -> 87 ms, in the training layout nothing
    (docs/lab/fit-speed.md).
    """
    batch = max(part.shape[0] for part in parts)
    shared = [part.shape[0] != batch for part in parts]
    if not any(shared):
        return conv(torch.cat(parts, 1))
    weights = conv.weight.split([part.shape[1] for part in parts], 1)

    def grouped(which: bool) -> Tensor:
        inputs = [part for part, s in zip(parts, shared) if s == which]
        weight = torch.cat([w for w, s in zip(weights, shared) if s == which], 1)
        return F.conv2d(torch.cat(inputs, 1), weight, None, conv.stride, conv.padding)

    return grouped(False) + grouped(True) + conv.bias[:, None, None]
