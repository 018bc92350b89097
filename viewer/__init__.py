"""``pghm-view``: the live viewer of pghm avatars (glfw window, ModernGL sprites, imgui panels).

Modules: :mod:`viewer.app` (entry point), :mod:`viewer.viewer` (state, actions, the frame),
:mod:`viewer.scene` (model side: pose, motion, identity -> Gaussian arrays),
:mod:`viewer.identity` (bank PCA, blend, region gains), :mod:`viewer.camera` (orbit camera),
:mod:`viewer.panels` (imgui UI), :mod:`viewer.settings` (display settings, HUD, layout),
:mod:`viewer.overlay` (overlays),
:mod:`viewer.window` (glfw + imgui backends), :mod:`viewer.recording`, :mod:`viewer.demo`
(an untrained development avatar). Importing the package does nothing else; docs/viewer.md
describes the controls.
"""
