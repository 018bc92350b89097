"""pghm: the Parametric Gaussian Human Model.

Data flows one way: body model -> UV maps -> network -> Gaussians -> renderer.

The public surface:
    load_body, BodyPose           the parametric body (pghm.body)
    build_atlas, texel_surface    the UV atlas and its canonical surface points (pghm.uv)
    load_avatar, save_avatar      avatar and prior files (pghm.io.avatar; imported on first use,
                                  so that ``import pghm`` does not build the network's modules)
"""

from pghm.body import BodyPose, load_body
from pghm.errors import PghmError
from pghm.uv.atlas import build_atlas
from pghm.uv.maps import texel_surface

__version__ = "0.1.0"

_AVATAR_FILE = ("Avatar", "load_avatar", "save_avatar")

__all__ = ["BodyPose", "PghmError", "build_atlas", "load_body", "texel_surface", *_AVATAR_FILE]


def __getattr__(name: str):
    if name in _AVATAR_FILE:
        from pghm.io import avatar

        return getattr(avatar, name)
    raise AttributeError(f"module 'pghm' has no attribute {name!r}")
