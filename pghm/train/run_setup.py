"""What both training commands (``pghm train-prior``, ``pghm fit``) set up besides the model:
each identity's geometry, the LPIPS network, the checkpoint's path and the config's record."""

from __future__ import annotations

import logging
from dataclasses import asdict
from pathlib import Path
from typing import Protocol

import torch

from pghm.body import load_body
from pghm.device import move
from pghm.errors import PghmError
from pghm.io.atomic import check_free_space
from pghm.io.avatar import recorded_path
from pghm.model import ModelConfig, subject_geometry
from pghm.model.geometry import SubjectGeometry, detail_atlas
from pghm.train.data import TrainingData
from pghm.train.lpips import load_lpips, lpips_status
from pghm.uv.atlas import build_atlas

log = logging.getLogger(__name__)


class TrainingConfig(Protocol):
    """A training command's config dataclass (``PriorConfig``, ``FitConfig``), as far as it is read here."""

    body_model_path: str | None


def checkpoint_path(out: Path, resume: bool = False) -> Path:
    """OUT.ckpt; with ``resume``, :class:`PghmError` unless it exists (asked before any data is read)."""
    ckpt = out.with_name(out.name + ".ckpt")
    if resume and not ckpt.is_file():
        raise PghmError(f"--resume: no checkpoint {ckpt} to continue from")
    return ckpt


class GeometryCache:
    """Each identity's :class:`SubjectGeometry` on ``device``, built on first use."""

    def __init__(
        self,
        data: TrainingData,
        config: ModelConfig,
        body_model_path: str | None,
        device: torch.device | str = "cpu",
    ) -> None:
        self.body = load_body(data.body_name, body_model_path)
        self.atlas = build_atlas(self.body, config.uv_resolution)
        self.detail_atlas = detail_atlas(self.body, config)
        self.data = data
        self.device = device
        self._cache: dict[int, SubjectGeometry] = {}

    def __call__(self, identity: int) -> SubjectGeometry:
        if identity not in self._cache:
            geometry = subject_geometry(self.body, self.atlas, self.data.shape(identity), self.detail_atlas)
            self._cache[identity] = move(geometry, self.device)
        return self._cache[identity]


def config_record(config: TrainingConfig) -> dict:
    """A training config as metadata: its fields, the user's body model file by name only."""
    record = asdict(config)
    if config.body_model_path is not None:
        record["body_model_path"] = recorded_path(config.body_model_path)
    return record


def lpips_for(enabled: bool, device: torch.device | str = "cpu"):
    """(the LPIPS network on ``device`` or None, a status line for the metadata, naming files without
    their directories)."""
    if not enabled:
        return None, "LPIPS off: disabled by configuration"
    network = load_lpips()
    if network is None:
        log.warning("%s; the LPIPS loss term is dropped", lpips_status())
        return None, lpips_status(directories=False)
    return network.to(device), lpips_status(directories=False)


OUTPUT_COPIES = 4
"""The model's bytes an output folder holds at most during a run, roughly: the result once and
its checkpoint (the weights and Adam's two moments of each, three times over)."""


def check_output_room(out: Path, *modules: torch.nn.Module) -> None:
    """Refuse a run before its first step when ``out``'s filesystem cannot hold its files
    (:func:`pghm.io.atomic.check_free_space`, OUTPUT_COPIES x the modules' tensors)."""
    tensors = [t for module in modules for t in module.state_dict().values()]
    check_free_space(out, OUTPUT_COPIES * sum(t.numel() * t.element_size() for t in tensors))
