"""A stand-in CUDA device for tests on a machine without one: it catches a CPU tensor mixed into a
GPU computation, which on a CUDA build is "Expected all tensors to be on the same device".

Inside :func:`standin_cuda`, a tensor moved to or made on ``cuda`` (``.to("cuda")``, ``.cuda()``,
``torch.zeros(..., device=x.device)``, a module's ``.to``) is a :class:`OnDevice`: a wrapper whose
values live in a CPU tensor, which reports ``device == cuda`` to Python (so the code under test
takes its CUDA branches: gsplat, the device's optimiser state) and is a meta tensor to torch's
C++ core (which has a device guard for meta, none for CUDA on a CPU-only build). Every aten op
that reaches a wrapper checks its tensor arguments as CUDA's kernels would: a CPU tensor beside
device tensors raises :class:`MixedDevices`, except where CUDA accepts one (a 0-dim CPU tensor in
a pointwise op, CPU indices in indexing, the source of a copy). ``.cpu()`` returns a plain tensor.
Gradients cross both ways, ``p.data = x`` swaps the values too, and ``torch.save`` writes the
values (as a CUDA tensor read back with ``map_location="cpu"`` gives them).

gsplat's CUDA kernels are stood in for by :func:`fake_gsplat_rasterization`, which demands every
tensor argument on the device, renders with pghm's CPU splatter and returns device tensors.

Inside :func:`counting_syncs`, every point where the host would wait for a CUDA device is recorded
(:data:`SYNC_OPS`): a value read to the host (``.item()``, ``bool()``, ``.cpu()``, ``.tolist()``),
an op whose output size depends on the values (``nonzero``, a boolean mask), and a copy from
pageable CPU memory to the device (torch waits for it to finish); the stand-in's gsplat is not
counted (the real one's kernels are launched, not waited for, apart from its own sizing).
"""

from __future__ import annotations

import contextlib
import sys
import types
from collections.abc import Iterator

import torch
from torch.overrides import TorchFunctionMode
from torch.utils._python_dispatch import TorchDispatchMode
from torch.utils._pytree import tree_map

CUDA = torch.device("cuda", 0)
"""What a tensor on the stand-in reports, as a CUDA tensor does (its index included)."""
_STANDIN_TYPES = ("cuda", "meta")
"""Device types naming the stand-in: ``cuda``, and ``meta``, which torch's C++ side reports for a wrapper."""
_FACTORY_KEYWORD = "device"
_SCALAR_VALUE_OPS = ("fill", "fill_", "masked_fill", "masked_fill_")
"""Ops that take a 0-dim CPU tensor as their number beside device tensors, as pointwise ops do."""


class MixedDevices(RuntimeError):
    """A CPU tensor reached an op computing on the (stand-in) CUDA device."""


SYNC_OPS = ("_local_scalar_dense", "nonzero", "masked_select", "_unique2", "unique_dim", "unique_consecutive")
"""aten ops on a device tensor that make the host wait for the device: a value read to the host, or
an output whose size depends on the values."""
_syncs: list[str] | None = None
"""What :func:`counting_syncs` has recorded, or None when it is not counting."""


def _record_sync(what: str) -> None:
    if _syncs is not None:
        _syncs.append(what)


@contextlib.contextmanager
def counting_syncs() -> Iterator[list[str]]:
    """Record in the yielded list, one entry per wait, where the block makes the host wait for the
    stand-in device (module docstring)."""
    global _syncs
    saved, _syncs = _syncs, []
    try:
        yield _syncs
    finally:
        _syncs = saved


@contextlib.contextmanager
def _not_counted() -> Iterator[None]:
    global _syncs
    saved, _syncs = _syncs, None
    try:
        yield
    finally:
        _syncs = saved


def _elem(value):
    return value.elem if isinstance(value, OnDevice) else value


def _is_standin(device) -> bool:
    return device is not None and torch.device(device).type in _STANDIN_TYPES


def _allowed_cpu_tensor(func, position: str, value: torch.Tensor) -> bool:
    """Whether CUDA's kernel of ``func`` accepts the CPU tensor ``value`` (argument ``position``)."""
    name = func.overloadpacket.__name__
    if name in ("copy_", "_to_copy", "_copy_from", "_local_scalar_dense"):
        return True  # copies cross devices by design
    if position == "self" and name.endswith("_"):
        return False  # an in-place op writes where its self is
    if value.dim() == 0 and (torch.Tag.pointwise in func.tags or name in _SCALAR_VALUE_OPS):
        return True  # TensorIterator, fill and masked_fill take a CPU scalar tensor as a number
    if name in ("index", "index_put", "index_put_", "_index_put_impl_") and position == "indices":
        return True  # indexing moves CPU indices to the device
    return False


def _check(func, args, kwargs) -> None:
    """Raise MixedDevices when a CPU tensor that CUDA would refuse is among ``func``'s arguments."""
    schema = func._schema.arguments
    named = {argument.name: value for argument, value in zip(schema, args)} | kwargs
    for name, value in named.items():
        values = value if isinstance(value, (list, tuple)) else [value]
        for item in values:
            if isinstance(item, torch.Tensor) and not isinstance(item, OnDevice):
                if item.device.type == "meta":
                    raise TypeError(f"{func}: argument '{name}' is a meta tensor the stand-in does not know")
                if not _allowed_cpu_tensor(func, name, item):
                    raise MixedDevices(
                        f"{func}: argument '{name}' is a CPU tensor {tuple(item.shape)} {item.dtype} "
                        "among tensors on the device (CUDA: expected all tensors to be on the same device)"
                    )


class OnDevice(torch.Tensor):
    """A tensor on the stand-in device: its values in ``elem`` (a CPU tensor)."""

    elem: torch.Tensor

    @staticmethod
    def __new__(cls, elem: torch.Tensor) -> OnDevice:
        wrapper = torch.Tensor._make_wrapper_subclass(
            cls,
            elem.size(),
            strides=elem.stride(),
            storage_offset=elem.storage_offset(),
            dtype=elem.dtype,
            layout=elem.layout,
            device=torch.device("meta"),
            requires_grad=elem.requires_grad,
        )
        wrapper.elem = elem
        return wrapper

    def __repr__(self) -> str:
        return f"OnDevice({self.elem!r})"

    def __reduce_ex__(self, protocol):
        # Saved as a CUDA tensor is and read back with map_location="cpu" (pghm.io.torch_file): its values.
        return self.elem.__reduce_ex__(protocol)

    @classmethod
    def __torch_function__(cls, func, types, args=(), kwargs=None):
        if func == torch.Tensor.device.__get__:
            return CUDA
        if func == torch.Tensor.is_cuda.__get__:
            return True
        if func == torch.Tensor.is_meta.__get__:
            return False
        if func is torch.Tensor.get_device:
            return CUDA.index
        if func in (torch.Tensor.numpy, torch.Tensor.__array__):
            raise TypeError("can't convert cuda:0 device type tensor to numpy. Use Tensor.cpu() first.")
        if func is torch.Tensor.tolist:
            _record_sync("tolist")
            return args[0].elem.tolist()
        if func == torch.Tensor.data.__set__ and isinstance(args[1], OnDevice):
            args[0].elem = args[1].elem  # ``p.data = x`` swaps the wrapper's metadata, not its values
        with torch._C.DisableTorchFunctionSubclass():
            return func(*args, **(kwargs or {}))

    @classmethod
    def __torch_dispatch__(cls, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        _check(func, args, kwargs)
        name = func.overloadpacket.__name__
        if name in SYNC_OPS or (name == "index" and any(_is_mask(i) for i in args[1] if i is not None)):
            _record_sync(name)
        if func is torch.ops.aten._to_copy.default and kwargs.get("device") == torch.device("cpu"):
            _record_sync("to the host")
            return func(*tree_map(_elem, args), **tree_map(_elem, kwargs))
        if name == "copy_" and not isinstance(args[0], OnDevice):
            _record_sync("copy to the host")
        elif name == "copy_" and not isinstance(args[1], OnDevice):
            _record_sync("copy from the host")
        if _is_standin(kwargs.get(_FACTORY_KEYWORD)):
            kwargs = {**kwargs, _FACTORY_KEYWORD: torch.device("cpu")}
        out = func(*tree_map(_elem, args), **tree_map(_elem, kwargs))
        if func.overloadpacket.__name__.endswith("_") and args and isinstance(args[0], OnDevice):
            return args[0]  # in place: the wrapper is the result, as torch returns self
        return tree_map(lambda x: OnDevice(x) if type(x) is torch.Tensor else x, out)


def _is_mask(index) -> bool:
    return isinstance(index, torch.Tensor) and index.dtype == torch.bool


def _as_meta(device):
    """``device`` with CUDA replaced by meta, the stand-in's C++ device."""
    return torch.device("meta") if device is not None and torch.device(device).type == "cuda" else device


_FROM_DATA = (torch.tensor, torch.as_tensor, torch.Tensor.new_tensor)


class _CudaToMeta(TorchFunctionMode):
    """Renames ``cuda`` to meta before torch's bindings see it (they would initialise CUDA)."""

    def __torch_function__(self, func, types, args=(), kwargs=None):
        kwargs = dict(kwargs or {})
        if func is torch.Tensor.cuda:
            return args[0].to("meta")
        if func is torch.Tensor.to:
            device, dtype, non_blocking, memory_format = torch._C._nn._parse_to(*args[1:], **kwargs)
            options = {"dtype": dtype, "non_blocking": non_blocking, "memory_format": memory_format}
            moved = args[0] if device is None else func(args[0], _as_meta(device))
            return func(moved, **{k: v for k, v in options.items() if v is not None})
        if func is torch.Tensor.__setitem__ and isinstance(args[0], OnDevice) and isinstance(args[2], (int, float)):
            return func(args[0], args[1], torch.tensor(args[2]))
        if func in _FROM_DATA:
            # torch makes these on the device below the modes: made on the CPU, then moved.
            device = kwargs.pop(_FACTORY_KEYWORD, None)
            if func is torch.Tensor.new_tensor and device is None:
                device = args[0].device
            made = func(*args, **kwargs, **({_FACTORY_KEYWORD: "cpu"} if device is not None else {}))
            return made if device is None else made.to(_as_meta(device))
        if _FACTORY_KEYWORD in kwargs:
            kwargs[_FACTORY_KEYWORD] = _as_meta(kwargs[_FACTORY_KEYWORD])
            if _is_standin(kwargs[_FACTORY_KEYWORD]) and kwargs.get("generator") is not None:
                raise MixedDevices(f"{func.__name__}: a CPU generator for a tensor on the device")
        return func(*args, **kwargs)


class _MetaFactories(TorchDispatchMode):
    """Makes every tensor asked for on meta (a factory, a copy to the device, a number torch makes a
    tensor on a wrapper's device) an :class:`OnDevice` with CPU values."""

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        if not _is_standin(kwargs.get(_FACTORY_KEYWORD)):
            return func(*args, **kwargs)
        if func is torch.ops.aten._to_copy.default and isinstance(args[0], OnDevice):
            return func(*args, **kwargs)
        if func is torch.ops.aten._to_copy.default:
            _record_sync("copy from the host")  # pageable memory: torch waits for the copy
        out = func(*args, **{**kwargs, _FACTORY_KEYWORD: torch.device("cpu")})
        return tree_map(lambda x: OnDevice(x) if type(x) is torch.Tensor else x, out)


def fake_gsplat_rasterization(**arguments):
    """gsplat.rasterization's outputs (images (B, 1, H, W, 4) RGB+D, alphas (B, 1, H, W, 1), meta)
    by pghm's CPU splatter, for the arguments :mod:`pghm.splat.gsplat_backend` passes (one camera
    per image, one background for all); MixedDevices unless every tensor argument is on the
    device, as gsplat's kernels need."""
    for name, value in arguments.items():
        if isinstance(value, torch.Tensor) and not isinstance(value, OnDevice):
            raise MixedDevices(f"gsplat.rasterization: '{name}' is a CPU tensor")
    tensors = [arguments[name] for name in _DIFFERENTIABLE]
    images, alphas = _FakeSplat.apply({k: v for k, v in arguments.items() if k not in _DIFFERENTIABLE}, *tensors)
    return images, alphas, {}


_DIFFERENTIABLE = ("means", "scales", "colors", "opacities", "viewmats")
"""The arguments gradients flow to (the Gaussians and, for pose refinement, the cameras)."""


class _FakeSplat(torch.autograd.Function):
    """The CPU splatter between device tensors, its copies to and from the CPU in both passes
    uncounted: they stand in for kernels on the device, which read nothing to the host."""

    @staticmethod
    def forward(ctx, arguments: dict, *tensors: torch.Tensor):
        from pghm.splat import Camera, render

        with _not_counted(), torch.enable_grad():
            leaves = [t.detach().cpu().requires_grad_(t.requires_grad) for t in tensors]
            given = {**{k: v.cpu() if isinstance(v, torch.Tensor) else v for k, v in arguments.items()}}
            given.update(zip(_DIFFERENTIABLE, leaves))
            camera = Camera.from_matrices(
                given["Ks"][:, 0], given["viewmats"][:, 0], width=given["width"], height=given["height"]
            )
            drawn = render(
                given["means"],
                given["scales"][..., 0],
                given["colors"],
                given["opacities"],
                camera,
                background=given["backgrounds"][0, 0].detach(),
            )
            images = torch.cat([drawn.rgb, drawn.depth[..., None]], -1)[:, None]
            alphas = drawn.alpha[:, None, ..., None]
            ctx.graph = (leaves, (images, alphas))
            return images.detach().cuda(), alphas.detach().cuda()

    @staticmethod
    def backward(ctx, grad_images: torch.Tensor, grad_alphas: torch.Tensor):
        leaves, outputs = ctx.graph
        wanted = [leaf for leaf in leaves if leaf.requires_grad]
        with _not_counted():
            grads = iter(
                torch.autograd.grad(outputs, wanted, (grad_images.cpu(), grad_alphas.cpu()), allow_unused=True)
            )
            moved = [next(grads) if leaf.requires_grad else None for leaf in leaves]
            # The engine may run this on its own thread, outside the stand-in's modes: wrapped by hand.
            return (None, *(OnDevice(g) if g is not None else None for g in moved))


@contextlib.contextmanager
def standin_cuda() -> Iterator[None]:
    """Run the block with ``cuda`` standing for the checked stand-in device (module docstring)."""
    fake = types.ModuleType("gsplat")
    fake.rasterization = fake_gsplat_rasterization
    saved = sys.modules.get("gsplat")
    sys.modules["gsplat"] = fake
    try:
        with _MetaFactories(), _CudaToMeta():
            yield
    finally:
        if saved is None:
            sys.modules.pop("gsplat", None)
        else:
            sys.modules["gsplat"] = saved
