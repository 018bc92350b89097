"""pghm: the Parametric Gaussian Human Model.

Data flows one way: body model -> UV maps -> network -> Gaussians -> renderer.

The public surface:
    load_body, BodyPose           the parametric body (pghm.body)
    build_atlas, texel_surface    the UV atlas and its canonical surface points (pghm.uv)
    load_avatar, save_avatar      avatar and prior files (pghm.io.avatar)

They are imported on first use (PEP 562): ``import pghm`` stays free of torch, so the ``pghm``
command's error handler (pghm.cli.main) is in place before the heavy imports start, and a
Ctrl-C during them is one line, not a traceback.
"""

from __future__ import annotations

import importlib

from pghm.errors import PghmError

__version__ = "0.1.0"

_LAZY = {
    "BodyPose": "pghm.body",
    "load_body": "pghm.body",
    "build_atlas": "pghm.uv.atlas",
    "texel_surface": "pghm.uv.maps",
    "Avatar": "pghm.io.avatar",
    "load_avatar": "pghm.io.avatar",
    "save_avatar": "pghm.io.avatar",
}

__all__ = ["PghmError", *_LAZY]


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'pghm' has no attribute {name!r}")
