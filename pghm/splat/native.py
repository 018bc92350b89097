"""The native splatter: the C++ kernel ``_rasterize.cpp``, built on first use, and its autograd Function.

Readable twin: :mod:`pghm.splat._torch_impl`. The kernel is compiled once per source,
compiler flags, torch installation and CPU into ``cache_dir() / "ext"`` (``$PGHM_CACHE_DIR``);
``python -m pghm.splat.native`` builds it ahead of time (``scripts/setup.sh`` does), so the
first render is not slow.
"""

from __future__ import annotations

import contextlib
import fcntl
import functools
import hashlib
import os
import platform
import sys
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

import torch
from torch import Tensor

from pghm.errors import PghmError
from pghm.splat._projection import Footprints
from pghm.splat._settings import SplatSettings
from pghm.splat.spec import ALPHA_MAX
from pghm.uv.atlas import cache_dir

SOURCE = Path(__file__).with_name("_rasterize.cpp")

TILE_SIZE = 32
"""Tile side in pixels: the unit of binning and of parallel work (docs/splat.md: 16, 32, 64 measured)."""

CXX_FLAGS = ("-O3", "-fno-trapping-math", "-fopenmp", "-march=native", "-mprefer-vector-width=256")
"""-fno-trapping-math lets the per-block loops vectorise (no result changes: pghm never reads FP
exception flags); a block of 8 floats is one 256-bit vector; -fopenmp makes at::parallel_for
use torch's OpenMP pool (the extension reuses torch's libgomp) and honours ``omp simd``."""

RECORD_BYTES = 1 << 30
"""The most a differentiated render keeps of its forward pass for its backward pass (the blocks of
its tiles, docs/splat.md "Backward per tile"); the tiles past it are composited again by the
backward pass. A fit's renders keep 25-50 MB each."""

GRAD_COLUMNS = {"means2d": slice(0, 2), "conics": slice(2, 5), "opacities": 5, "colors": slice(6, 9), "depths": 9}
"""Columns of the kernel's (B, N, 10) per-Gaussian gradient (enum GradColumn in the .cpp)."""


def _cpu_signature() -> str:
    """The CPU's feature flags: -march=native code must not be reused on a different CPU."""
    try:
        with open("/proc/cpuinfo") as cpuinfo:
            return next((line for line in cpuinfo if line.startswith("flags")), platform.processor())
    except OSError:
        return platform.processor()


def build_directory() -> Path:
    """Where the kernel is compiled: one directory per source, flags, torch installation and CPU.

    The installation's path and the source's are part of the key: torch's build file names its
    include directories and the source file, so two environments (or two checkouts) sharing one
    directory would each rebuild the kernel whenever the other had run last."""
    digest = hashlib.sha256()
    torch_dir = str(Path(torch.__file__).resolve().parent)
    for part in (" ".join(CXX_FLAGS), torch.__version__, torch_dir, str(SOURCE.resolve()), _cpu_signature()):
        digest.update(part.encode())
    digest.update(SOURCE.read_bytes())
    return cache_dir() / "ext" / f"splat-{digest.hexdigest()[:16]}"


BUILD_LOCK = "pghm.lock"
"""The file whose OS lock (``flock``) a process holds while it builds or loads the kernel."""
TORCH_BATON = "lock"
"""torch's own build lock: a plain file that a builder creates and deletes (``FileBaton``)."""


@contextlib.contextmanager
def build_lock(directory: Path) -> Iterator[None]:
    """Hold ``directory``'s build lock, and clear a baton that a dead builder left there.

    torch waits, forever, while its baton file exists, and a builder killed mid-compile (a
    SIGTERM, the OOM killer) never deletes it: every later run would hang without a word. An
    ``flock`` is released by the kernel when its holder dies, and every pghm builder holds it
    across torch's build, so a baton found while holding it belongs to no living builder."""
    # Created empty and opened read-only: nothing is ever written to it, only locked.
    handle = os.open(directory / BUILD_LOCK, os.O_RDONLY | os.O_CREAT, 0o644)
    try:
        fcntl.flock(handle, fcntl.LOCK_EX)
        with contextlib.suppress(FileNotFoundError):
            os.remove(directory / TORCH_BATON)
        yield
    finally:
        os.close(handle)  # releases the lock


@functools.cache
def _build() -> ModuleType | Exception:
    """The compiled module, or the exception that stopped the build (remembered, not retried)."""
    from torch.utils.cpp_extension import load

    directory = build_directory()
    try:
        directory.mkdir(parents=True, exist_ok=True)
        with build_lock(directory):
            return load(
                name=f"pghm_{directory.name.replace('-', '_')}",
                sources=[str(SOURCE)],
                build_directory=str(directory),
                extra_cflags=list(CXX_FLAGS),
                extra_ldflags=["-fopenmp"],
            )
    except Exception as error:  # any build failure (no compiler, ninja, headers) means "use the torch path"
        return error


def is_available() -> bool:
    """True when the kernel is (or can be) built; compiles it on first call."""
    return not isinstance(_build(), Exception)


def load_extension() -> ModuleType:
    """The compiled kernel; raises :class:`PghmError` saying why when it cannot be built."""
    module = _build()
    if isinstance(module, Exception):
        first_line = str(module).strip().splitlines()[0] if str(module).strip() else type(module).__name__
        raise PghmError(f"the native splat kernel could not be built in {build_directory()}: {first_line}")
    return module


class _Rasterize(torch.autograd.Function):
    """Spec steps 5-6 by the native kernel; inputs as :func:`pghm.splat._torch_impl.rasterize`."""

    @staticmethod
    def forward(
        ctx,
        means2d: Tensor,
        conics: Tensor,
        colors: Tensor,
        opacities: Tensor,
        depths: Tensor,
        background: Tensor,
        footprints: Footprints,
        width: int,
        height: int,
        settings: SplatSettings,
    ) -> tuple[Tensor, Tensor, Tensor]:
        geometry = (width, height, TILE_SIZE, settings.alpha_cutoff, ALPHA_MAX, settings.transmittance_stop)
        gaussians = (means2d, conics, colors, opacities, depths, background, footprints.bbox, footprints.radius2)
        # A pass that will be differentiated keeps its blocks, so that the backward pass need not
        # composite the tiles again to find them.
        record_bytes = RECORD_BYTES if any(ctx.needs_input_grad[:5]) else 0
        rgb, alpha, depth, tile_offsets, tile_ids, recording = load_extension().forward(
            list(gaussians), footprints.order, footprints.counts, *geometry, record_bytes
        )
        ctx.save_for_backward(*gaussians, tile_offsets, tile_ids)
        ctx.geometry = geometry
        ctx.recording = recording
        return rgb, alpha, depth

    @staticmethod
    def backward(ctx, v_rgb: Tensor, v_alpha: Tensor, v_depth: Tensor):
        *gaussians, tile_offsets, tile_ids = ctx.saved_tensors
        cotangents = (v_rgb.contiguous(), v_alpha.contiguous(), v_depth.contiguous())
        grads = load_extension().backward(gaussians, tile_offsets, tile_ids, *cotangents, *ctx.geometry, ctx.recording)
        dtype = gaussians[2].dtype
        v_means2d = grads[..., GRAD_COLUMNS["means2d"]]
        v_conics = grads[..., GRAD_COLUMNS["conics"]]
        v_colors = grads[..., GRAD_COLUMNS["colors"]].to(dtype)
        v_opacities = grads[..., GRAD_COLUMNS["opacities"]].to(dtype)
        v_depths = grads[..., GRAD_COLUMNS["depths"]].to(dtype)
        return (
            v_means2d,
            v_conics,
            v_colors,
            v_opacities,
            v_depths,
            None,  # background
            None,  # footprints
            None,  # width
            None,  # height
            None,  # settings
        )


def rasterize(
    means2d: Tensor,
    conics: Tensor,
    colors: Tensor,
    opacities: Tensor,
    depths: Tensor,
    background: Tensor,
    footprints: Footprints,
    width: int,
    height: int,
    settings: SplatSettings,
) -> tuple[Tensor, Tensor, Tensor]:
    """The native counterpart of :func:`pghm.splat._torch_impl.rasterize` (same arguments and results)."""
    return _Rasterize.apply(
        means2d.contiguous(),
        conics.contiguous(),
        colors.contiguous(),
        opacities.contiguous(),
        depths.contiguous(),
        background.contiguous(),
        footprints,
        width,
        height,
        settings,
    )


def main() -> int:
    """Build the kernel now (``python -m pghm.splat.native``) and say where it is."""
    module = _build()
    if isinstance(module, Exception):
        print(f"pghm.splat.native: build failed, renders will use the torch path: {module}", file=sys.stderr)
        return 1
    print(f"pghm.splat.native: kernel ready in {build_directory()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
