"""GLSL sources of the GL renderer (:mod:`pghm.gl`), shipped as package data.

Each shader is one ``<name>.glsl`` file beginning with ``#version 330 core``. Constants
shared with the CPU splatter (``NEAR_PLANE``, ``ALPHA_MIN``, ...) are not written in the
files: :func:`source` inserts them as ``#define`` lines, so Python stays their only source.
"""

from __future__ import annotations

from importlib import resources


def source(name: str, defines: dict[str, int | float] | None = None) -> str:
    """The text of ``shaders/<name>.glsl`` with ``#define NAME value`` lines after ``#version``.

    Floats are written with ``repr`` (round-trip exact, e.g. ``0.00392156862745098``), so
    the shader rounds each constant to float32 exactly as a float32 tensor op would.
    """
    text = resources.files(__package__).joinpath(f"{name}.glsl").read_text(encoding="utf-8")
    if not defines:
        return text
    version, _, body = text.partition("\n")
    if not version.startswith("#version"):
        raise ValueError(f"shader {name!r} must begin with a #version line")
    lines = [f"#define {key} {_glsl_literal(value)}" for key, value in defines.items()]
    # '#line 2' keeps the compiler's line numbers equal to the file's.
    return "\n".join([version, *lines, "#line 2", body])


def _glsl_literal(value: int | float) -> str:
    """A GLSL literal: ints stay ints, floats always carry a '.' or an exponent."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise TypeError(f"shader constants must be int or float, got {value!r}")
    return str(value) if isinstance(value, int) else repr(float(value))
