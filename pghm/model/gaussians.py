"""Posed isotropic Gaussians, the model's output and the renderer's input."""

from __future__ import annotations

from dataclasses import dataclass

from torch import Tensor


@dataclass(frozen=True)
class Gaussians:
    """A batch of B sets of N isotropic Gaussians.

    Attributes:
        means: (B, N, 3) world positions.
        scales: (B, N) isotropic standard deviations, metres.
        colors: (B, N, 3) RGB in [0, 1].
        opacities: (B, N) in (0, 1]; all ones for PGHM (the paper fixes opacity to 1).
    """

    means: Tensor
    scales: Tensor
    colors: Tensor
    opacities: Tensor

    @property
    def batch_size(self) -> int:
        return self.means.shape[0]

    @property
    def num_gaussians(self) -> int:
        return self.means.shape[1]

    def __getitem__(self, index: int) -> Gaussians:
        """The ``index``-th set, keeping a batch dimension of one."""
        pick = slice(index, index + 1)
        return Gaussians(self.means[pick], self.scales[pick], self.colors[pick], self.opacities[pick])

    def detach(self) -> Gaussians:
        return Gaussians(self.means.detach(), self.scales.detach(), self.colors.detach(), self.opacities.detach())
