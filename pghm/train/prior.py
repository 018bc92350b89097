"""``pghm train-prior``: learn the identity bank, Feature Decoder and U-Net over many identities.

Jointly optimises (paper, "Training objectives") the per-identity latents, the Feature
Decoder, the multi-head U-Net and per-frame pose corrections (the stored poses are noisy
estimates) with the loss on both renders I_s and I_d.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import torch

from pghm.io.avatar import Avatar, recorded_path, save_avatar
from pghm.model import PGHM, ModelConfig
from pghm.train import distributed
from pghm.train.background import SILHOUETTE_WEIGHT, TRAINING_BACKGROUND
from pghm.train.data import TrainingData
from pghm.train.loop import (
    AvatarObjective,
    LoopConfig,
    LoopState,
    check_learning_rate,
    check_step_memory,
    check_trained,
    load_checkpoint,
    restore,
    run_stage,
)
from pghm.train.losses import LossWeights
from pghm.train.optim import LazyAdam
from pghm.train.run_setup import GeometryCache, check_output_room, checkpoint_path, config_record, lpips_for

log = logging.getLogger(__name__)


@dataclass
class PriorConfig:
    """Prior training; defaults sized for a 2-core CPU."""

    model: ModelConfig = field(default_factory=ModelConfig)
    loop: LoopConfig = field(
        default_factory=lambda: LoopConfig(
            steps=9000,
            images_per_shard=4,
            loss=LossWeights(silhouette=SILHOUETTE_WEIGHT),
            background=TRAINING_BACKGROUND,
        )
    )
    network_lr: float = 1e-3
    """Adam learning rate of the Feature Decoder and the U-Net."""
    latent_lr: float = 1e-2
    """Adam learning rate of the bank latents."""
    pose_lr: float = 1e-2
    """Adam learning rate of the per-frame pose corrections (radians, metres). Lazy rows: a
    frame's correction moves only when the frame is in the batch, by about this much per visit."""
    refine_poses: bool = True
    """Learn per-frame pose corrections."""
    lpips: bool = True
    """Use the LPIPS term when its weights are on this machine."""
    body_model_path: str | None = None
    """The user's model file for bodies that are not embedded (SMPL-X)."""
    max_identities: int | None = None
    """Train on the first this-many subjects only (the identity-count ablation); None: all."""


def initial_model(model: ModelConfig, num_identities: int, seed: int) -> PGHM:
    """The prior's network and identity bank before its first step (what step 0 of
    :func:`train_prior` starts from for ``PriorConfig(model=model, loop=LoopConfig(seed=seed))``).
    Drawn on the CPU whatever the device, so a seed gives the same start everywhere."""
    torch.manual_seed(seed)
    return PGHM(model, num_identities=num_identities)


def train_prior(
    data_dir: str | Path,
    out: str | Path,
    config: PriorConfig | None = None,
    resume: bool = False,
    device: torch.device | str = "cpu",
) -> Avatar:
    """Train a prior on the subjects in ``data_dir`` and save it to ``out`` (default config: PriorConfig()).

    Computes on ``device``; under torchrun with CUDA, each process on its own GPU
    (:func:`pghm.train.distributed.process_device`). The file is written from the CPU.
    """
    config = config or PriorConfig()
    for name in ("network_lr", "latent_lr", "pose_lr"):
        check_learning_rate(name, getattr(config, name))
    device = distributed.process_device(torch.device(device))
    distributed.init(device)
    out = Path(out)
    ckpt = checkpoint_path(out, resume)
    data = TrainingData(data_dir, max_identities=config.max_identities)
    check_step_memory(data, config.loop, "train-prior")
    geometries = GeometryCache(data, config.model, config.body_model_path, device)
    model = initial_model(config.model, data.num_identities, config.loop.seed).to(device)
    corrections = data.pose_corrections(geometries.body).to(device) if config.refine_poses else None
    check_output_room(out, model, *([corrections] if corrections is not None else []))
    lpips, lpips_line = lpips_for(config.lpips, device)
    objective = AvatarObjective(model, None, corrections, config.loop.loss, lpips)
    bank = [model.identity_bank]
    network = [p for name, p in model.named_parameters() if name != "identity_bank"]
    # A step sees one identity's latent and one frame's correction: those tables are lazy.
    groups = [
        {"params": network, "lr": config.network_lr},
        {"params": bank, "lr": config.latent_lr, "lazy": True},
    ]
    if corrections is not None:
        groups.append({"params": list(corrections.parameters()), "lr": config.pose_lr, "lazy": True})
    optimizer = LazyAdam(groups)
    trainable = [p for group in groups for p in group["params"]]

    state = LoopState()
    if resume:
        state = restore(load_checkpoint(ckpt), objective, optimizer)
        log.info("resuming from %s at step %d", ckpt, state.step)
    state = run_stage(
        objective=objective,
        trainable=trainable,
        optimizer=optimizer,
        data=data,
        geometry_of=geometries,
        config=config.loop,
        checkpoint=ckpt,
        state=state,
        extra={"kind": "prior"},
        description="prior",
    )
    shapes = torch.stack([data.shape(i) for i in range(data.num_identities)])
    avatar = Avatar(
        model=model.eval(),
        kind="prior",
        body_name=data.body_name,
        shape=shapes[0],
        shapes=shapes,
        metadata={
            "command": "train-prior",
            "data": recorded_path(data_dir),
            "identities": data.num_identities,
            "training_images": int(sum(len(i) for i in data.images)),
            "steps": state.step,
            "seconds": round(state.seconds, 1),
            "threads": torch.get_num_threads(),  # per process; the last bits of every float depend on it
            "skipped_steps": state.skipped_steps,
            "skipped_images": [list(b) for b in state.bad_images],
            "lpips": lpips_line,
            "final": state.history[-1] if state.history else {},
            "config": config_record(config),
            "processes": distributed.world_size(),
        },
    )
    check_trained([state], out)
    if distributed.rank() == 0:
        save_avatar(out, avatar)
        ckpt.unlink(missing_ok=True)  # the prior holds the result; a stale checkpoint would only mislead --resume
    return avatar
