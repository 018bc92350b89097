"""GLSL sources of the GL renderer (:mod:`pghm.gl`), shipped as package data.

Each shader is one ``<name>.glsl`` file beginning with ``#version 330 core``. The splatting
spec's constants (``NEAR_PLANE``, ``ALPHA_MIN``, ..., defined in :mod:`pghm.splat.spec`) are not
written in the files: :func:`source` inserts them as ``#define`` lines, so Python stays their
only source.

Precision. The Gaussian sprite shaders (``gaussian_sprite.vert.glsl`` and
``gaussian_sprite.frag.glsl``) run in float32 or float64 from one source: the quantities whose
precision is chosen are declared with the macro types ``real``, ``real2``, ``real3``,
``real4`` and ``realmat4``, converted explicitly where they meet float. ``source(name,
precision=...)`` defines the types (:data:`PRECISIONS`): "float" as ``float``, ``vec2``, ...
under ``#version 330 core``, where the conversions are identities; "double" as ``double``,
``dvec2``, ... under ``#version 400 core`` (double arithmetic is core in OpenGL 4.0),
plus ``#define PGHM_FP64 1`` for code that must differ (``#ifdef PGHM_FP64``).

The web page (:mod:`pghm.web`) runs the same sources as WebGL2: precision "es" puts them under
``#version 300 es`` with float ``real`` types, ``#define PGHM_ES 1`` and highp defaults (GLSL ES
has no default float precision in fragment shaders); what GLSL 3.30 core and GLSL ES 3.00 share
is all these shaders use.
"""

from __future__ import annotations

from importlib import resources
from typing import Literal

Precision = Literal["float", "double", "es"]

PRECISIONS: dict[str, tuple[str, dict[str, str]]] = {
    "float": (
        "#version 330 core",
        {"real": "float", "real2": "vec2", "real3": "vec3", "real4": "vec4", "realmat4": "mat4"},
    ),
    "double": (
        "#version 400 core",
        {"PGHM_FP64": "1", "real": "double", "real2": "dvec2", "real3": "dvec3", "real4": "dvec4", "realmat4": "dmat4"},
    ),
    "es": (
        "#version 300 es",
        {"PGHM_ES": "1", "real": "float", "real2": "vec2", "real3": "vec3", "real4": "vec4", "realmat4": "mat4"},
    ),
}
"""Precision -> (the ``#version`` line, the ``#define`` lines of its macro types)."""
ES_DEFAULTS = ("precision highp float;", "precision highp int;", "precision highp sampler2D;")
"""The default precisions of a GLSL ES shader (after its ``#define`` lines)."""


def source(name: str, defines: dict[str, int | float] | None = None, precision: Precision | None = None) -> str:
    """The text of ``shaders/<name>.glsl`` with ``#define NAME value`` lines after ``#version``.

    Floats are written with ``repr`` (round-trip exact, e.g. ``0.00392156862745098``), so
    the shader rounds each constant to float32 exactly as a float32 tensor op would.
    ``precision`` ("float", "double" or "es", see the module docstring) replaces the ``#version``
    line and defines the ``real`` types first, for shaders written with them.
    """
    text = resources.files(__package__).joinpath(f"{name}.glsl").read_text(encoding="utf-8")
    if not defines and precision is None:
        return text
    version, _, body = text.partition("\n")
    if not version.startswith("#version"):
        raise ValueError(f"shader {name!r} must begin with a #version line")
    lines = []
    if precision is not None:
        if precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
        version, types = PRECISIONS[precision]
        lines += [f"#define {key} {value}" for key, value in types.items()]
    lines += [f"#define {key} {_glsl_literal(value)}" for key, value in (defines or {}).items()]
    if precision == "es":
        lines += ES_DEFAULTS
    # '#line 2' keeps the compiler's line numbers equal to the file's.
    return "\n".join([version, *lines, "#line 2", body])


def _glsl_literal(value: int | float) -> str:
    """A GLSL literal: ints stay ints, floats always carry a '.' or an exponent."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise TypeError(f"shader constants must be int or float, got {value!r}")
    return str(value) if isinstance(value, int) else repr(float(value))
