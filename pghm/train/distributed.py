"""Multi-process training with torch.distributed, started by ``torchrun``.

``torchrun --nproc_per_node N -m pghm.cli.main train-prior ...`` sets RANK, WORLD_SIZE and
the rendezvous variables; :func:`init` joins the group with gloo on CPU (nccl where GPUs
exist). Without torchrun everything runs in one process and these functions are no-ops.
The training objective is wrapped whole in DistributedDataParallel, which averages every
gradient across processes after backward.
"""

from __future__ import annotations

import contextlib
import os

import torch
import torch.distributed as dist
from torch import nn


def requested() -> bool:
    """Whether this process was started by torchrun with more than one process."""
    return int(os.environ.get("WORLD_SIZE", "1")) > 1


def init() -> None:
    """Join the process group when started by torchrun (idempotent)."""
    if requested() and not dist.is_initialized():
        backend = "nccl" if torch.cuda.is_available() else "gloo"
        dist.init_process_group(backend=backend)


def world_size() -> int:
    return dist.get_world_size() if dist.is_initialized() else 1


def rank() -> int:
    return dist.get_rank() if dist.is_initialized() else 0


def wrap(module: nn.Module) -> nn.Module:
    """DDP around ``module`` when several processes train, else ``module`` itself.

    ``find_unused_parameters``: a group may not touch every tensor (the bank rows of other
    identities get zero gradients, but pose corrections of other frames none at all).
    """
    if not dist.is_initialized():
        return module
    return nn.parallel.DistributedDataParallel(module, find_unused_parameters=True)


def no_sync(module: nn.Module):
    """DDP's ``no_sync`` context (gradient accumulation without all-reduce), or a no-op."""
    return module.no_sync() if isinstance(module, nn.parallel.DistributedDataParallel) else contextlib.nullcontext()


def shutdown() -> None:
    if dist.is_initialized():
        dist.destroy_process_group()
