"""The web page of a baked avatar: one self-contained HTML file that plays it in any WebGL2 browser.

The file is ``page.html`` with ``player.js`` inlined and one JSON block of data: the sprite,
composite and skinning shaders as GLSL ES 3.00 sources made from ``shaders/`` with the splatting
spec's constants (:func:`web_shaders`: the page draws by pghm's rule, from the sources the viewer
runs), and the baked motion (:mod:`pghm.web.bake`) as base64 little-endian typed arrays with their
shapes. Nothing is fetched: the page opens from a double click with no network.
"""

from __future__ import annotations

import base64
import json
from importlib import resources

import numpy as np

import shaders
from pghm.render.framing import BODY_FILL, DEFAULT_FOV_Y
from pghm.web.bake import BAKE_ASPECT, WEIGHT_STEPS, BakedMotion, Components

PAGE_SHADERS = {
    "points": ("gaussian_sprite.vert", "gaussian_sprite.frag", {"PGHM_POINTS": 1}),
    "quads": ("gaussian_sprite.vert", "gaussian_sprite.frag", {"PGHM_TRIANGLES": 1}),
    "composite": ("fullscreen.vert", "composite.frag", {}),
    "skinning": ("web_skinning.vert", "web_skinning.frag", {}),
}
"""Program name -> (vertex, fragment) shader of ``shaders/``, and the variant's defines. Sprites are
GL points where every square fits the browser's largest point, else two triangles each of a plain
draw (software WebGL runs an instanced draw one instance at a time)."""
SPEC_CONSTANTS = ("NEAR_PLANE", "COV_DILATION", "ALPHA_MIN", "FRUSTUM_CLAMP")
"""The splatting spec's constants the player's sprite extents use (as the shader does)."""
DATA_MARKER = "/*PGHM_DATA*/"
PLAYER_MARKER = "/*PGHM_PLAYER*/"
TITLE_MARKER = "PGHM_TITLE"
FORMAT = 1
"""The data block's layout version, which the player checks."""


def web_shaders() -> dict[str, dict[str, str]]:
    """Program name -> {"vertex", "fragment"}: GLSL ES 3.00 sources with the spec's constants."""
    from pghm.gl.resources import SPEC_DEFINES

    return {
        name: {
            "vertex": shaders.source(vertex, {**SPEC_DEFINES, **variant}, "es"),
            "fragment": shaders.source(fragment, {**SPEC_DEFINES, **variant}, "es"),
        }
        for name, (vertex, fragment, variant) in PAGE_SHADERS.items()
    }


def encode(array: np.ndarray) -> dict:
    """A typed array for the page: dtype (numpy's little-endian code), shape, base64 bytes."""
    array = np.ascontiguousarray(array)
    little = array.astype(array.dtype.newbyteorder("<"), copy=False)
    return {
        "dtype": little.dtype.str.lstrip("<|"),
        "shape": list(array.shape),
        "data": base64.b64encode(little.tobytes()).decode("ascii"),
    }


def _group(components: Components) -> dict:
    return {
        "mean": encode(components.mean),
        "basis": encode(components.basis),
        "coefficients": encode(components.coefficients),
        "error": components.error,
    }


def page_data(baked: BakedMotion, title: str) -> dict:
    """The page's JSON block (module docstring)."""
    from pghm.gl.resources import SPEC_DEFINES, TEXTURE_WIDTH

    rig = baked.rig

    return {
        "format": FORMAT,
        "title": title,
        "gaussians": baked.num_gaussians,
        "frames": baked.num_frames,
        "fps": rig.fps,
        "camera": {"fov_y": DEFAULT_FOV_Y, "body_fill": BODY_FILL, "bake_aspect": BAKE_ASPECT},
        "texture_width": TEXTURE_WIDTH,
        "weight_steps": WEIGHT_STEPS,
        "shaders": web_shaders(),
        "spec": {name: SPEC_DEFINES[name] for name in SPEC_CONSTANTS},
        "skin": {"index": encode(rig.skin.index), "weights": encode(rig.skin.weights)},
        "transforms": encode(rig.transforms),
        "points": _group(baked.points),
        "log_scales": _group(baked.log_scales),
        "colors": _group(baked.colors),
        "roots": encode(rig.roots),
        "rest_root": rig.rest_root.tolist(),
        "rest_box": rig.rest_box.tolist(),
    }


def page_html(baked: BakedMotion, title: str) -> str:
    """The whole page: ``page.html`` with the player and the data inlined."""
    folder = resources.files(__package__)
    template = folder.joinpath("page.html").read_text(encoding="utf-8")
    player = folder.joinpath("player.js").read_text(encoding="utf-8")
    # "</" inside a script element would end it; JSON allows the escaped solidus.
    data = json.dumps(page_data(baked, title), separators=(",", ":")).replace("</", "<\\/")
    escaped_title = title.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
    return (
        template.replace(TITLE_MARKER, escaped_title)
        .replace(PLAYER_MARKER, player.replace("</script", "<\\/script"))
        .replace(DATA_MARKER, data)
    )
