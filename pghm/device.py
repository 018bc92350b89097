"""Which device a run computes on: the one resolver every command uses.

``--device auto`` (the default) is CUDA when torch sees a CUDA device, else the CPU;
``--device cuda`` without one is a :class:`PghmError`. The library itself never picks a
device: its functions compute on the device of their inputs (a model moved with
``.to(device)``, tensors made there), and files are written from and read onto the CPU,
so an avatar trained on a GPU opens anywhere.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import TypeVar

import torch
from torch import Tensor

from pghm.errors import PghmError

T = TypeVar("T")

DEVICE_CHOICES: tuple[str, ...] = ("auto", "cpu", "cuda")
"""Values of ``--device``."""
CPU = torch.device("cpu")
"""The device functions default to where a caller names none."""


def resolve_device(name: str) -> torch.device:
    """The device ``name`` ("auto", "cpu", "cuda" or "cuda:K") stands for on this machine.

    Raises PghmError for a CUDA device this machine lacks, or an unknown name.
    """
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        device = torch.device(name)
    except (RuntimeError, TypeError):
        raise PghmError(f"--device must be one of {', '.join(DEVICE_CHOICES)}, got {name!r}") from None
    if device.type == "cpu":
        return device
    if device.type != "cuda":
        raise PghmError(f"--device must be one of {', '.join(DEVICE_CHOICES)}, got {name!r}")
    if not torch.cuda.is_available():
        build = "a CPU-only build of torch" if torch.version.cuda is None else "no CUDA device visible"
        raise PghmError(f"--device {name}: CUDA is not available here ({build}); use --device cpu")
    if device.index is not None and device.index >= torch.cuda.device_count():
        raise PghmError(f"--device {name}: this machine has {torch.cuda.device_count()} CUDA device(s)")
    return device


PRECISION_CHOICES: tuple[str, ...] = ("auto", "float32", "bfloat16")
"""Values of ``--precision``."""


BFLOAT16_PROBES: tuple[str, ...] = ("_is_amx_tile_supported", "_is_avx512_bf16_supported")
"""torch's probes of the CPU features that multiply bfloat16 natively: AMX tiles (Intel Sapphire
Rapids and later) and AVX512-BF16's dot products (AMD Zen 4 and later, Intel Cooper Lake)."""


def bfloat16_features() -> dict[str, bool]:
    """Each of :data:`BFLOAT16_PROBES` by its feature's name ("amx_tile", "avx512_bf16"): whether this
    CPU has it (False where this torch has no such probe)."""
    return {
        name.removeprefix("_is_").removesuffix("_supported"): bool(getattr(torch.cpu, name, lambda: False)())
        for name in BFLOAT16_PROBES
    }


def has_bfloat16_arithmetic() -> bool:
    """Whether this CPU multiplies bfloat16 natively, so that oneDNN's bfloat16 convolutions beat its
    float32 ones; without such units bfloat16 is converted to float32 and back, and is slower."""
    return any(bfloat16_features().values())


def resolve_precision(name: str, device: torch.device) -> torch.dtype:
    """The dtype the networks compute in for ``--precision name`` on ``device``.

    "auto" is bfloat16 on a CPU that multiplies it natively (:func:`has_bfloat16_arithmetic`), where
    a fit's stage-2 network runs 1.3-1.5 times faster at the same held-out figures (docs/training.md,
    "bfloat16 where the CPU multiplies it natively"), and float32 elsewhere: on other CPUs bfloat16
    is emulated and slower, and on CUDA it is not yet measured.
    """
    if name == "auto":
        return torch.bfloat16 if device.type == "cpu" and has_bfloat16_arithmetic() else torch.float32
    if name not in PRECISION_CHOICES:
        raise PghmError(f"--precision must be one of {', '.join(PRECISION_CHOICES)}, got {name!r}")
    return getattr(torch, name)


def move(value: T, device: torch.device) -> T:
    """``value`` with every tensor in it on ``device``: a tensor, or a (nested) dataclass holding tensors.

    A value already there is returned as it is (the same object), so moving to the device a run
    already computes on costs nothing and changes nothing.
    """
    if isinstance(value, Tensor):
        return value.to(device)
    if not dataclasses.is_dataclass(value) or isinstance(value, type):
        return value
    fields = [field.name for field in dataclasses.fields(value) if field.init]
    moved = {name: move(getattr(value, name), device) for name in fields}
    if all(moved[name] is getattr(value, name) for name in fields):
        return value
    return dataclasses.replace(value, **moved)


@functools.lru_cache(maxsize=256)
def constant(values: tuple[float, ...] | tuple[int, ...], dtype: torch.dtype, device: torch.device) -> Tensor:
    """The tensor of ``values`` on ``device``, made there once per (values, dtype, device) and shared:
    a constant a step uses each time (a background colour, an index table) without a copy from
    the host each time, which on a CUDA device waits for the device. Read it, never write into it."""
    return torch.tensor(values, dtype=dtype, device=device)
