"""Synthetic subjects: people painted and dressed procedurally, rendered as lit, textured
triangle meshes (not Gaussians) from capture rings or a monocular camera.

The generator writes the project's subject format (:mod:`pghm.subject`), the same one
real captures are converted into; docs/data.md describes both.

    config = load_config("prior")            # or a SynthConfig(...)
    generate(config, seed=0, out="data/prior", workers=2)

Pieces, for tests and experiments: :func:`sample_identity` (an :class:`Identity`),
:func:`build_clothed_body` / :func:`pose_clothed_body` (textures, cloth and folds on the
body model), :class:`MeshRenderer` (the ModernGL renderer, OpenCV camera convention).
"""

from pghm.synth.avatar import ClothedBody, build_clothed_body, pose_clothed_body
from pghm.synth.config import PRESETS, SynthConfig, load_config
from pghm.synth.generate import GENERATOR_VERSION, GenerationReport, generate, plan_subject
from pghm.synth.identity import Identity, sample_identity
from pghm.synth.render import Lighting, MeshRenderer, RenderedView, project_points
from pghm.synth.sheet import contact_sheet

__all__ = [
    "GENERATOR_VERSION",
    "PRESETS",
    "ClothedBody",
    "GenerationReport",
    "Identity",
    "Lighting",
    "MeshRenderer",
    "RenderedView",
    "SynthConfig",
    "build_clothed_body",
    "contact_sheet",
    "generate",
    "load_config",
    "plan_subject",
    "pose_clothed_body",
    "project_points",
    "sample_identity",
]
