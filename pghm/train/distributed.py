"""Multi-process training with torch.distributed, started by ``torchrun``.

``torchrun --nproc_per_node N -m pghm.cli.main train-prior ...`` sets RANK, WORLD_SIZE,
LOCAL_RANK and the rendezvous variables. On the CPU the processes join with gloo; on CUDA
each process takes the GPU of its LOCAL_RANK (:func:`process_device`) and they join with
NCCL (:func:`backend_for`). Without torchrun everything runs in one process and these
functions are no-ops. The training objective is wrapped whole in DistributedDataParallel,
which averages every gradient across processes after backward. The batch plan, checkpoints
(written by rank 0, read onto the CPU) and ``--resume`` do not depend on the device.
"""

from __future__ import annotations

import contextlib
import os

import torch
import torch.distributed as dist
from torch import nn

from pghm.device import CPU
from pghm.errors import PghmError


def requested() -> bool:
    """Whether this process was started by torchrun with more than one process."""
    return int(os.environ.get("WORLD_SIZE", "1")) > 1


def backend_for(device: torch.device) -> str:
    """The process-group backend for processes computing on ``device``: NCCL between GPUs, else gloo."""
    return "nccl" if device.type == "cuda" else "gloo"


def process_device(device: torch.device) -> torch.device:
    """This process's device: under torchrun with CUDA, the GPU of its LOCAL_RANK (one per process;
    PghmError when there are fewer GPUs than processes on this node); otherwise ``device`` itself."""
    if device.type != "cuda" or not requested():
        return device
    local = int(os.environ.get("LOCAL_RANK", "0"))
    count = torch.cuda.device_count()
    if local >= count:
        raise PghmError(f"process {local} of this node has no GPU of its own ({count} visible); use fewer processes")
    return torch.device("cuda", local)


def init(device: torch.device = CPU) -> None:
    """Join the process group when started by torchrun (idempotent), for processes on ``device``."""
    if requested() and not dist.is_initialized():
        if device.type == "cuda":
            torch.cuda.set_device(device)
        dist.init_process_group(backend=backend_for(device))


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
    device = next(module.parameters()).device
    ids = [device] if device.type == "cuda" else None
    return nn.parallel.DistributedDataParallel(module, device_ids=ids, find_unused_parameters=True)


def no_sync(module: nn.Module):
    """DDP's ``no_sync`` context (gradient accumulation without all-reduce), or a no-op."""
    return module.no_sync() if isinstance(module, nn.parallel.DistributedDataParallel) else contextlib.nullcontext()


def shutdown() -> None:
    if dist.is_initialized():
        dist.destroy_process_group()
