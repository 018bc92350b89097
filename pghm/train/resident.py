"""What a training step needs on its device, put there once, so that a step reads nothing from the host.

On a CUDA device torch waits for every copy from pageable host memory to finish, so a step that
moved its images, cameras, indices and constants to the device each time would wait for the
device a few dozen times a step, each wait idling it while the host queues the next kernels.
:class:`Resident` keeps each sample, index and constant on the device after its first use: a
sample is moved (and its camera checked) once per fit, an index or a constant once per value.
On the CPU every method returns its argument's values as they are (nothing to move).
"""

from __future__ import annotations

import torch
from torch import Tensor

from pghm.device import move
from pghm.train.data import Sample
from pghm.train.person_crop import area_tensor


class Resident:
    """Samples, indices and constants on ``device``, each moved there on first use."""

    def __init__(self, device: torch.device) -> None:
        self.device = device
        self._samples: dict[tuple[int, ...], Sample] = {}
        self._indices: dict[int, Tensor] = {}
        self._areas: dict[tuple[int, ...], Tensor] = {}

    def sample(self, sample: Sample) -> Sample:
        """``sample`` with its tensors on the device (the same sample each later visit)."""
        if self.device.type == "cpu":
            return sample
        key = _key(sample)
        if key not in self._samples:
            self._samples[key] = move(sample, self.device)
        return self._samples[key]

    def indices(self, values: list[int]) -> Tensor:
        """(len(values),) long tensor of ``values`` on the device, stacked from cached 0-dim ones."""
        for value in values:
            if value not in self._indices:
                self._indices[value] = torch.tensor(value, dtype=torch.long, device=self.device)
        return torch.stack([self._indices[value] for value in values])

    def areas(self, samples: list[Sample]) -> Tensor | None:
        """(B, 2) the area shares of :func:`pghm.train.person_crop.area_tensor`, or None when no
        sample is a crop."""
        if not any(s.crop for s in samples):
            return None
        for s in samples:
            if _key(s) not in self._areas:
                self._areas[_key(s)] = area_tensor([s.crop]).to(self.device)[0]
        return torch.stack([self._areas[_key(s)] for s in samples])


def _key(sample: Sample) -> tuple[int, ...]:
    """A sample's identity, image and resolution: a coarse step's image (:mod:`pghm.train.coarse`) is
    another sample than the same image at full resolution."""
    return sample.identity, sample.image_index, sample.camera.width, sample.camera.height
