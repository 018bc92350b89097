"""pghm: the Parametric Gaussian Human Model.

Data flows one way: body model -> UV maps -> network -> Gaussians -> renderer.

The public surface:
    load_body, BodyPose           the parametric body (pghm.body)
    build_atlas, texel_surface    the UV atlas and its canonical surface points (pghm.uv)
"""

from pghm.body import BodyPose, load_body
from pghm.errors import PghmError
from pghm.uv.atlas import build_atlas
from pghm.uv.maps import texel_surface

__version__ = "0.1.0"

__all__ = ["BodyPose", "PghmError", "build_atlas", "load_body", "texel_surface"]
