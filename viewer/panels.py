"""The viewer's UI: imgui panels and mouse gestures, each turned into a call of a Viewer action.

Nothing here changes state directly or touches GL: every widget calls a
:class:`~viewer.viewer.Viewer` method (through ``try_action``, so that a bad motion path
or file shows its one-line error in the panel instead of raising). UI drawing is separate
from scene drawing: these methods only build imgui draw lists, which
:meth:`viewer.window.Window.end_ui` renders after the scene.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from imgui_bundle import imgui

from viewer.camera import FOV_RANGE, SNAP_VIEWS
from viewer.identity import COMPONENT_RANGE, GAIN_RANGE
from viewer.scene import ANGLE_LIMIT, AXES, POSE_JOINTS, SPEED_RANGE, clip_choices, clip_index
from viewer.settings import PANEL_WIDTH, RENDER_SCALES, SCALE_RANGE, SHIPPED_MOTIONS

MOTION_SUFFIXES = (".npz", ".bvh")
"""Files the motion picker lists."""
MAX_LISTED_FILES = 200
"""The motion picker lists at most this many files of a folder."""
ERROR_COLOUR = (1.0, 0.35, 0.3, 1.0)
NOTE_COLOUR = (0.5, 0.9, 0.5, 1.0)
PENDING_COLOUR = (1.0, 0.8, 0.3, 1.0)
HUD_MARGIN = 8.0
"""Pixels between the HUD and the window's top-right corner."""
WHEEL_STEP = 1.0
"""Zoom steps per wheel notch."""


@dataclass
class PanelState:
    """Text the user is typing, kept between frames (not viewer state: nothing happens until a button).

    Created by the :class:`~viewer.viewer.Viewer` (``panel_state``)."""

    avatar_path: str = ""
    motion_path: str = ""
    browse_dir: str = field(default_factory=lambda: str(SHIPPED_MOTIONS if SHIPPED_MOTIONS.is_dir() else Path.cwd()))
    screenshot_path: str = "screenshot.png"
    screenshot_ui: bool = True
    record_path: str = "recording.mp4"
    record_source: int = 0  # index into ("window", "motion")
    record_fps: float = 30.0


class ViewerPanels:
    """The viewer's UI, mixed into :class:`~viewer.viewer.Viewer`: every widget and gesture calls
    one of the viewer's actions (``self`` is the Viewer)."""

    def draw_panels(self) -> None:
        """The control panel (left) and the HUD (top right of the scene)."""
        state = self.panel_state
        io = imgui.get_io()
        height = io.display_size.y
        imgui.set_next_window_pos(imgui.ImVec2(0, 0))
        imgui.set_next_window_size(imgui.ImVec2(PANEL_WIDTH, height))
        flags = imgui.WindowFlags_.no_move | imgui.WindowFlags_.no_resize | imgui.WindowFlags_.no_collapse
        imgui.begin("pghm-view", None, flags)
        self._file_section(state)
        self._camera_section()
        self._pose_section()
        self._motion_section(state)
        self._identity_section()
        self._display_section()
        self._output_section(state)
        imgui.end()
        self._hud()
        self._keys()

    def handle_mouse(self) -> None:
        """Gestures on the scene: left drag orbits, right drag pans, the wheel zooms."""
        io = imgui.get_io()
        if io.want_capture_mouse:
            return
        position = io.mouse_pos
        if position.x < PANEL_WIDTH:
            return
        delta = io.mouse_delta
        if imgui.is_mouse_dragging(imgui.MouseButton_.left) and io.mouse_clicked_pos[0].x >= PANEL_WIDTH:
            self.orbit(delta.x, delta.y)
        elif imgui.is_mouse_dragging(imgui.MouseButton_.right) and io.mouse_clicked_pos[1].x >= PANEL_WIDTH:
            scale = io.display_framebuffer_scale
            self.pan(delta.x * scale.x, delta.y * scale.y)
        if io.mouse_wheel:
            self.zoom(io.mouse_wheel * WHEEL_STEP)

    def _keys(self) -> None:
        """Space plays or pauses, R resets the camera (when no text field has the keyboard)."""
        if imgui.get_io().want_capture_keyboard:
            return
        if imgui.is_key_pressed(imgui.Key.space):
            self.set_playing(not self.scene.pose_state.playing)
        if imgui.is_key_pressed(imgui.Key.r):
            self.reset_camera()

    def _file_section(self, state: PanelState) -> None:
        scene = self.scene
        kind = scene.avatar.kind
        imgui.text(f"{self.avatar_path.name}: {kind}, {scene.driver.geometry.num_gaussians} Gaussians")
        imgui.push_text_wrap_pos(PANEL_WIDTH - 10)
        imgui.text_disabled(self.driver)
        imgui.pop_text_wrap_pos()
        _, state.avatar_path = imgui.input_text("##avatar", state.avatar_path)
        imgui.same_line()
        if imgui.button("Open avatar"):
            self.try_action(self.open_avatar, state.avatar_path)
        if self.error:
            imgui.push_text_wrap_pos(PANEL_WIDTH - 10)
            imgui.text_colored(imgui.ImVec4(*ERROR_COLOUR), self.error)
            imgui.pop_text_wrap_pos()
        if self.message:
            imgui.push_text_wrap_pos(PANEL_WIDTH - 10)
            imgui.text_colored(imgui.ImVec4(*NOTE_COLOUR), self.message)
            imgui.pop_text_wrap_pos()

    def _camera_section(self) -> None:
        if not imgui.collapsing_header("Camera", imgui.TreeNodeFlags_.default_open):
            return
        imgui.text_disabled("left drag: orbit, right drag: pan, wheel: zoom")
        if imgui.button("Reset"):
            self.reset_camera()
        for view in SNAP_VIEWS:
            imgui.same_line()
            if imgui.button(view.capitalize()):
                self.snap_camera(view)
        changed, fov = imgui.slider_float("field of view", self.camera.fov_y, *FOV_RANGE, "%.0f deg")
        if changed:
            self.try_action(self.set_fov, fov)
        changed, follow = imgui.checkbox("follow the body", self.display.follow)
        if changed:
            self.set_follow(follow)

    def _pose_section(self) -> None:
        if not imgui.collapsing_header("Pose"):
            return
        if imgui.button("Reset pose"):
            self.reset_pose()
        imgui.text_disabled("degrees, rest-aligned axes, on top of the motion")
        sliders = self.scene.pose_state.sliders
        for row, joint in enumerate(POSE_JOINTS):
            label = "root orientation" if joint == "pelvis" else joint.replace("_", " ")
            if imgui.tree_node(label):
                for axis, name in enumerate(AXES):
                    value = float(sliders[row, axis])
                    changed, value = imgui.slider_float(f"{name}##{joint}", value, -ANGLE_LIMIT, ANGLE_LIMIT, "%.0f")
                    if changed:
                        self.try_action(self.set_pose_slider, joint, axis, value)
                imgui.tree_pop()

    def _motion_section(self, state: PanelState) -> None:
        if not imgui.collapsing_header("Motion", imgui.TreeNodeFlags_.default_open):
            return
        scene = self.scene
        pose_state = scene.pose_state
        choices = clip_choices()
        changed, picked = imgui.combo("clip", clip_index(choices, scene.motion_name), [label for label, _ in choices])
        if changed:
            self.try_action(self.open_motion, choices[picked][1])
        _, state.motion_path = imgui.input_text("##motion", state.motion_path)
        imgui.same_line()
        if imgui.button("Open motion"):
            self.try_action(self.open_motion, state.motion_path)
        if imgui.tree_node("Browse .npz / .bvh"):
            self._motion_browser(state)
            imgui.tree_pop()
        motion = pose_state.motion
        imgui.text(f"{Path(scene.motion_name).name}: {motion.num_frames} frames at {motion.fps:g} fps")
        last = pose_state.motion.num_frames - 1
        changed, frame = imgui.slider_int("frame", pose_state.frame, 0, max(last, 0))
        if changed:
            self.scrub_to(frame)
        if imgui.button("Pause" if pose_state.playing else "Play"):
            self.set_playing(not pose_state.playing)
        imgui.same_line()
        changed, loop = imgui.checkbox("loop", pose_state.loop)
        if changed:
            self.set_loop(loop)
        changed, speed = imgui.slider_float("speed", pose_state.speed, *SPEED_RANGE, "%.2fx")
        if changed:
            self.try_action(self.set_speed, speed)

    def _motion_browser(self, state: PanelState) -> None:
        """A folder's motion files and subfolders; a click opens a file or enters a folder."""
        _, state.browse_dir = imgui.input_text("folder", state.browse_dir)
        folder = Path(state.browse_dir).expanduser()
        if not folder.is_dir():
            imgui.text_disabled("not a folder")
            return
        try:
            entries = sorted(folder.iterdir(), key=lambda p: (not p.is_dir(), p.name.lower()))
        except OSError as error:
            imgui.text_disabled(str(error))
            return
        if imgui.selectable("..", False)[0]:
            state.browse_dir = str(folder.parent)
        shown = 0
        for entry in entries:
            if shown >= MAX_LISTED_FILES:
                break
            if entry.name.startswith("."):
                continue
            if entry.is_dir():
                if imgui.selectable(f"{entry.name}/", False)[0]:
                    state.browse_dir = str(entry)
                shown += 1
            elif entry.suffix.lower() in MOTION_SUFFIXES:
                if imgui.selectable(entry.name, False)[0]:
                    state.motion_path = str(entry)
                    self.try_action(self.open_motion, str(entry))
                shown += 1

    def _identity_section(self) -> None:
        if not imgui.collapsing_header("Identity"):
            return
        identity = self.scene.identity
        if identity.is_prior:
            last = identity.num_identities - 1
            changed, index = imgui.slider_int("identity", identity.index_a, 0, last)
            if changed:
                self.try_action(self.pick_identity, index)
            changed, other = imgui.slider_int("blend with", identity.index_b, 0, last)
            if changed:
                self.try_action(self.set_blend, other, identity.blend)
            changed, weight = imgui.slider_float("blend", identity.blend, 0.0, 1.0)
            if changed:
                self.try_action(self.set_blend, identity.index_b, weight)
            for k in range(identity.num_components):
                changed, value = imgui.slider_float(
                    f"PC {k + 1}", float(identity.coefficients[k]), -COMPONENT_RANGE, COMPONENT_RANGE, "%.2f sd"
                )
                if changed:
                    self.try_action(self.set_component, k, value)
        else:
            imgui.text_disabled("a personalised avatar: no bank to pick or blend")
        if imgui.tree_node("Region gain on the latent"):
            for index, name in enumerate(identity.regions.names):
                gain = float(identity.gains[index])
                changed, gain = imgui.slider_float(name.replace("_", " "), gain, *GAIN_RANGE, "%.2f")
                if changed:
                    self.try_action(self.set_region_gain, index, gain)
            imgui.tree_pop()
        if imgui.button("Reset identity"):
            self.reset_identity()

    def _display_section(self) -> None:
        if not imgui.collapsing_header("Display", imgui.TreeNodeFlags_.default_open):
            return
        display = self.display
        if imgui.radio_button("dynamic (I_d)", display.gaussians == "dynamic"):
            self.set_gaussian_set("dynamic")
        imgui.same_line()
        if imgui.radio_button("static (I_s)", display.gaussians == "static"):
            self.set_gaussian_set("static")
        imgui.begin_disabled(display.gaussians == "static")
        changed, enabled = imgui.checkbox("view-dependent colour", display.view_dependent)
        imgui.end_disabled()
        if changed:
            self.set_view_dependent(enabled)
        changed, factor = imgui.slider_float("point size", display.scale_multiplier, *SCALE_RANGE, "%.2fx")
        if changed:
            self.try_action(self.set_scale_multiplier, factor)
        changed, colour = imgui.color_edit3("background", list(display.background))
        if changed:
            self.try_action(self.set_background, tuple(colour))
        changed_centres, centres = imgui.checkbox("Gaussian centres", display.show_centres)
        imgui.same_line()
        changed_mesh, mesh = imgui.checkbox("body mesh", display.show_mesh)
        if changed_centres or changed_mesh:
            self.set_overlays(centres, mesh)
        if imgui.tree_node("Approximations (off = exact)"):
            labels = [f"{int(scale * 100)}%" for scale in RENDER_SCALES]
            current = RENDER_SCALES.index(display.render_scale) if display.render_scale in RENDER_SCALES else 0
            changed, picked = imgui.combo("internal resolution", current, labels)
            if changed:
                self.set_render_scale(RENDER_SCALES[picked])
            changed, cull = imgui.checkbox("cull back-facing Gaussians", display.cull_backfacing)
            if changed:
                self.set_backface_culling(cull)
            imgui.tree_pop()

    def _output_section(self, state: PanelState) -> None:
        if not imgui.collapsing_header("Output"):
            return
        _, state.screenshot_path = imgui.input_text("##shot", state.screenshot_path)
        imgui.same_line()
        if imgui.button("Screenshot"):
            self.try_action(self.screenshot, state.screenshot_path, state.screenshot_ui)
        _, state.screenshot_ui = imgui.checkbox("with the UI", state.screenshot_ui)
        _, state.record_path = imgui.input_text("file or folder", state.record_path)
        _, state.record_source = imgui.combo("record", state.record_source, ["the window", "the motion at fixed fps"])
        _, state.record_fps = imgui.slider_float("fps", state.record_fps, 5.0, 60.0, "%.0f")
        recording = self.recording
        if recording is None:
            if imgui.button("Start recording"):
                source = ("window", "motion")[state.record_source]
                self.try_action(self.start_recording, state.record_path, source, state.record_fps)
        else:
            if imgui.button("Stop recording"):
                self.stop_recording()
            imgui.same_line()
            total = f"/{recording.total}" if recording.total else ""
            imgui.text(f"{recording.sink.frames}{total} frames")

    def _hud(self) -> None:
        """FPS, Gaussian count and the stage times, over the scene's top-right corner (no input).

        Each stage shows its last run: model and skinning of the evaluation whose Gaussians are
        drawn (0 for a frame from the cache; on the model worker, not in the frame time); sort,
        upload and draw of the last frame that redrew the sprites (a frame whose scene did not
        change copies the cached image). fps and frame are this frame's; the internal
        resolution is reduced while the view moves; the cache line is the motion frame cache's
        fill; "update pending" means the model worker has not yet delivered what is asked.
        """
        hud = self.hud
        io = imgui.get_io()
        imgui.set_next_window_pos(imgui.ImVec2(io.display_size.x - HUD_MARGIN, HUD_MARGIN), 0, imgui.ImVec2(1.0, 0.0))
        imgui.set_next_window_bg_alpha(0.6)
        flags = (
            imgui.WindowFlags_.no_decoration
            | imgui.WindowFlags_.always_auto_resize
            | imgui.WindowFlags_.no_inputs
            | imgui.WindowFlags_.no_saved_settings
            | imgui.WindowFlags_.no_focus_on_appearing
            | imgui.WindowFlags_.no_nav
        )
        imgui.begin("HUD", None, flags)
        imgui.text(f"{hud.fps:5.1f} fps   frame {hud.frame_ms:6.1f} ms")
        width, height = hud.internal_size
        quality = "moving" if hud.moving else "exact" if not hud.pending else "settling"
        imgui.text(f"internal {width} x {height} ({quality})")
        drawn = f" ({hud.drawn} drawn)" if hud.drawn != hud.gaussians else ""
        imgui.text(f"{hud.gaussians} Gaussians{drawn}")
        imgui.text(f"cache {hud.cache_frames} frames, {hud.cache_mb:.1f} / {hud.cache_budget_mb:.0f} MB")
        work = ("update pending" if hud.pending else "up to date") + (", prefetching" if hud.prefetching else "")
        if hud.pending:
            imgui.text_colored(imgui.ImVec4(*PENDING_COLOUR), work)
        else:
            imgui.text(work)
        imgui.text(f"model     {hud.model_ms:6.1f} ms")
        imgui.text(f"skinning  {hud.skinning_ms:6.1f} ms")
        imgui.text(f"sort      {hud.sort_ms:6.1f} ms")
        imgui.text(f"upload    {hud.upload_ms:6.1f} ms")
        imgui.text(f"draw      {hud.draw_ms:6.1f} ms")
        imgui.end()
