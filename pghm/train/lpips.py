"""LPIPS (Zhang et al. 2018, "The Unreasonable Effectiveness of Deep Features as a Perceptual
Metric"), AlexNet variant, with weights loaded only from local files.

    LPIPS(x, y) = sum_l mean_hw w_l . (n(f_l(x)) - n(f_l(y)))^2

f_l are AlexNet's five ReLU outputs (torchvision's ``features`` layout), n normalises each
pixel's feature vector to unit length, and w_l are the learned linear weights of LPIPS
v0.1. Inputs in [0, 1] are mapped to [-1, 1] and shifted/scaled as LPIPS does.

Nothing is downloaded. Two files are looked for in the torch hub cache
(``$TORCH_HOME/hub/checkpoints``, by default ``~/.cache/torch/hub/checkpoints``):

    alexnet-owt-7be5be79.pth      torchvision's ImageNet AlexNet (the backbone)
    lpips_alex_v0.1.pth           the LPIPS linear weights; also found inside an installed
                                  ``lpips`` package (lpips/weights/v0.1/alex.pth)

When either is missing, :func:`load_lpips` returns None and callers drop the term.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import torch
from torch import Tensor, nn

BACKBONE_FILE = "alexnet-owt-7be5be79.pth"
LINEAR_FILE = "lpips_alex_v0.1.pth"
ALEX_CHANNELS = (64, 192, 384, 256, 256)
SLICE_ENDS = (2, 5, 8, 10, 12)
"""``features[a:b]`` slices whose outputs are relu1..relu5."""
SHIFT = (-0.030, -0.088, -0.188)
SCALE = (0.458, 0.448, 0.450)
NORM_EPS = 1e-10


def alexnet_features() -> nn.Sequential:
    """torchvision's ``alexnet().features``, layer for layer (so its state dict keys match)."""
    return nn.Sequential(
        nn.Conv2d(3, 64, 11, stride=4, padding=2),
        nn.ReLU(inplace=True),
        nn.MaxPool2d(3, stride=2),
        nn.Conv2d(64, 192, 5, padding=2),
        nn.ReLU(inplace=True),
        nn.MaxPool2d(3, stride=2),
        nn.Conv2d(192, 384, 3, padding=1),
        nn.ReLU(inplace=True),
        nn.Conv2d(384, 256, 3, padding=1),
        nn.ReLU(inplace=True),
        nn.Conv2d(256, 256, 3, padding=1),
        nn.ReLU(inplace=True),
        nn.MaxPool2d(3, stride=2),
    )


class LPIPS(nn.Module):
    """The AlexNet LPIPS distance; frozen."""

    def __init__(self) -> None:
        super().__init__()
        self.features = alexnet_features()
        self.lins = nn.ModuleList(nn.Conv2d(c, 1, 1, bias=False) for c in ALEX_CHANNELS)
        self.register_buffer("shift", torch.tensor(SHIFT).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor(SCALE).view(1, 3, 1, 1))
        self.requires_grad_(False)
        self.eval()

    def load_weights(self, backbone: dict, linear: dict) -> None:
        """Load torchvision AlexNet weights (``features.*`` keys) and LPIPS linear weights
        (``lin{k}.model.1.weight`` keys, as the lpips package stores them)."""
        self.features.load_state_dict(
            {k.removeprefix("features."): v for k, v in backbone.items() if k.startswith("features.")}
        )
        for k, lin in enumerate(self.lins):
            lin.weight.data.copy_(linear[f"lin{k}.model.1.weight"])

    def _levels(self, image: Tensor) -> list[Tensor]:
        x = (image * 2 - 1 - self.shift) / self.scale
        outputs, start = [], 0
        for end in SLICE_ENDS:
            x = self.features[start:end](x)
            outputs.append(x)
            start = end
        return outputs

    def forward(self, x: Tensor, y: Tensor) -> Tensor:
        """(B,) distances between images (B, 3, H, W) in [0, 1]."""
        total = x.new_zeros(x.shape[0])
        for lin, fx, fy in zip(self.lins, self._levels(x), self._levels(y)):
            nx = fx / (fx.square().sum(1, keepdim=True).sqrt() + NORM_EPS)
            ny = fy / (fy.square().sum(1, keepdim=True).sqrt() + NORM_EPS)
            total = total + lin((nx - ny).square()).mean(dim=(1, 2, 3))
        return total


def hub_checkpoints() -> Path:
    return Path(torch.hub.get_dir()) / "checkpoints"


def _linear_weights_path() -> Path | None:
    local = hub_checkpoints() / LINEAR_FILE
    if local.is_file():
        return local
    spec = importlib.util.find_spec("lpips")
    if spec is not None and spec.submodule_search_locations:
        packaged = Path(next(iter(spec.submodule_search_locations))) / "weights" / "v0.1" / "alex.pth"
        if packaged.is_file():
            return packaged
    return None


def load_lpips() -> LPIPS | None:
    """LPIPS with its weights from local files, or None when they are not on this machine."""
    backbone = hub_checkpoints() / BACKBONE_FILE
    linear = _linear_weights_path()
    if not backbone.is_file() or linear is None:
        return None
    model = LPIPS()
    model.load_weights(
        torch.load(backbone, map_location="cpu", weights_only=True),
        torch.load(linear, map_location="cpu", weights_only=True),
    )
    return model


def lpips_status(directories: bool = True) -> str:
    """One line saying where the LPIPS weights were found, or which file is missing; without
    ``directories`` it names the files only (for metadata, which records no path of this machine)."""

    def shown(path: Path) -> str | Path:
        return path if directories else path.name

    backbone = hub_checkpoints() / BACKBONE_FILE
    if not backbone.is_file():
        return f"LPIPS off: backbone weights {shown(backbone)} not found (nothing is downloaded)"
    linear = _linear_weights_path()
    if linear is None:
        return f"LPIPS off: linear weights {shown(hub_checkpoints() / LINEAR_FILE)} not found"
    return f"LPIPS on: {shown(backbone)} and {shown(linear)}"
