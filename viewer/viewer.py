"""The viewer's state object: actions (plain methods), one :meth:`Viewer.frame`, set-up and teardown.

The UI (:mod:`viewer.panels`) and the tests call the same action methods
(``set_pose_slider``, ``scrub_to``, ``set_region_gain``, ``orbit``, ``screenshot``, ...);
an action only changes state, and the next :meth:`Viewer.frame` does the work that state
implies:

1. events and UI (imgui), mouse gestures on the scene viewport -> camera actions;
2. the motion clock (or the fixed step of a motion recording);
3. the model, through the scene's cached evaluator (only the branches whose inputs
   changed re-run; an unchanged state costs nothing);
4. the sprites (``pghm.gl.SpriteRenderer.draw``) into the window when the Gaussians, camera
   or display changed; otherwise the last draw's accumulation is composited again
   (``SpriteRenderer.present``: the sprites' box, not the sprite pass);
5. overlays, UI, screenshot / recording capture, buffer swap.

GL resources exist between :meth:`setup` and :meth:`teardown`; constructing a Viewer only
loads the avatar (so a bad file fails before any window opens).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

import numpy as np

from pghm.errors import PghmError
from pghm.io.avatar import load_avatar
from pghm.render import GaussianSet
from pghm.render.frame_cache import DEFAULT_BUDGET_MB, MEGABYTE, FrameCache
from viewer.camera import OrbitController
from viewer.dynamic_resolution import ResolutionController, ResolutionSettings
from viewer.panels import PanelState, ViewerPanels
from viewer.pipeline import FrameStatus, ScenePipeline, Shown
from viewer.recording import Recording, RecordSource, save_png, start_recording
from viewer.scene import AvatarScene
from viewer.settings import BACKFACE_DEGREES, PANEL_WIDTH, SCALE_RANGE, WINDOW_SIZE, DisplaySettings, HudStats

IDLE_WAIT = 0.05
"""Seconds the loop sleeps waiting for input when nothing animates (the machine is shared)."""
PENDING_WAIT = 0.01
"""Seconds the loop waits for input while the view settles or the model worker is busy."""
SETTLE_TIMEOUT = 120.0
"""Seconds :meth:`Viewer.settle` waits for the model worker before giving up."""
MAX_SETTLE_FRAMES = 8
"""Frames :meth:`Viewer.settle` draws at most (post, wait, draw; a state may need two rounds)."""
FPS_SMOOTHING = 0.9
"""Exponential smoothing of the HUD's frames per second."""


@dataclass
class _Requests:
    """Actions that need the next frame's pixels."""

    screenshot: tuple[Path, bool] | None = None
    recording: Recording | None = None


@dataclass
class _Cache:
    """Keys of what the GL side last received, to skip unchanged uploads and draws."""

    upload_key: tuple | None = None
    scene_key: tuple | None = None
    mesh_key: tuple | None = None
    mesh_topology_sent: bool = False
    set_gaussians_ms: float = 0.0
    """Time of the last ``set_gaussians`` not yet counted in the HUD's upload."""
    offset_key: tuple | None = None
    offset: np.ndarray | None = None


class Viewer(ViewerPanels):
    """The live viewer of one avatar or prior file.

    Args:
        avatar_path: the ``.pt`` file to open (errors raise :class:`~pghm.errors.AvatarFileError`).
        window_size: (W, H) screen pixels.
        body_model_path: the model file of bodies that are not embedded (SMPL-X).
        cache_mb: memory budget of the motion frame cache, megabytes.
        resolution: the dynamic resolution's budget and the settle delay.
    """

    def __init__(
        self,
        avatar_path: str | Path,
        window_size: tuple[int, int] = WINDOW_SIZE,
        body_model_path: str | None = None,
        cache_mb: float = DEFAULT_BUDGET_MB,
        resolution: ResolutionSettings | None = None,
    ) -> None:
        self.avatar_path = Path(avatar_path)
        self.window_size = window_size
        self.body_model_path = body_model_path
        self.scene = AvatarScene(load_avatar(self.avatar_path), body_model_path)
        self.camera = OrbitController(home=self.scene.framing(self._scene_aspect(window_size)))
        self.display = DisplaySettings()
        self.hud = HudStats()
        self.error: str | None = None
        """The last failed action's one-line message, shown in the UI."""
        self.message: str | None = None
        """The last completed output action (screenshot written, recording saved)."""
        self.last_screenshot: np.ndarray | None = None
        self.panel_state = PanelState(avatar_path=str(self.avatar_path))
        self.driver = ""
        """The GL renderer and version strings (known after set-up), shown in the panel."""
        self.window = None
        self.cache_mb = cache_mb
        self.resolution = ResolutionController(resolution)
        self.pipeline: ScenePipeline | None = None
        """The model worker, frame cache and prefetcher (between :meth:`setup` and :meth:`teardown`)."""
        self.status: FrameStatus | None = None
        """The last frame's choice of Gaussians (moving, pending)."""
        self._settled = False
        self.synchronous = False
        """Wait for the model in every frame and draw it exactly (the viewer before the worker;
        benchmarks compare against it); a fixed-rate motion recording does so too."""
        self._requests = _Requests()
        self._cache = _Cache()
        self._last_frame = time.perf_counter()

    # ------------------------------------------------------------------ set-up

    def setup(self) -> None:
        """Open the window and create the GL resources (raises DisplayError without a display)."""
        from pghm.gl import SpriteRenderer, driver_info
        from viewer.overlay import OverlayRenderer
        from viewer.window import Window

        self.window = Window(f"pghm-view - {self.avatar_path.name}", self.window_size)
        self.driver = str(driver_info(self.window.ctx))
        self.renderer = SpriteRenderer(self.window.ctx)
        self.overlay = OverlayRenderer(self.window.ctx)
        self._cache = _Cache()
        cache = FrameCache(int(self.cache_mb * MEGABYTE))
        self.pipeline = ScenePipeline(cache, self.resolution.settings)

    def teardown(self) -> None:
        """Finish a recording, stop the model worker, free every GL object and close the window."""
        self.stop_recording()
        if self.pipeline is not None:
            self.pipeline.close()
            self.pipeline = None
        if self.window is None:
            return
        self.overlay.release()
        self.renderer.release()
        self.window.close()
        self.window = None

    def run(self) -> None:
        """Set up, loop over frames until the window closes, tear down."""
        self.setup()
        try:
            while not self.window.should_close():
                wait = self.input_wait()
                if wait:
                    self.window.poll(wait)
                self.frame()
        finally:
            self.teardown()

    def input_wait(self) -> float:
        """Seconds the loop may sleep until input before the next frame (input wakes it at once).

        None (0) while playing or recording; a short wait while the view settles or the model
        worker is busy (the frame between two mouse events would only copy the same scene
        and take the cores from the worker); a longer one when everything is still.
        """
        if self.scene.pose_state.playing or self._requests.recording is not None:
            return 0.0
        if self.status is not None and (self.status.moving or self.status.pending):
            return PENDING_WAIT
        return IDLE_WAIT

    def settle(self, timeout: float = SETTLE_TIMEOUT) -> None:
        """Draw frames until the exact frame of the current state is shown (tests and scripts; blocks).

        The view counts as still at once (no settle delay), and the loop waits for the model
        worker between frames instead of sleeping.
        """
        self._settled = True
        try:
            for _ in range(MAX_SETTLE_FRAMES):
                self.frame()
                if not self.status.pending and not self.status.moving:
                    return
                if not self.pipeline.worker.wait_idle(timeout):
                    break
        finally:
            self._settled = False
        raise PghmError(f"the model worker did not deliver the frame within {timeout:g} s")

    # ------------------------------------------------------------- the frame

    def frame(self) -> None:
        """One frame: events and UI, clock, model, sprites, overlays, capture, swap."""
        now = time.perf_counter()
        elapsed, self._last_frame = now - self._last_frame, now
        window = self.window
        window.poll()
        window.begin_ui()
        self.draw_panels()
        self.handle_mouse()

        recording = self._requests.recording
        if recording is not None and recording.source == "motion":
            self.scene.pose_state.time = recording.motion_time()
        else:
            self.scene.pose_state.advance(elapsed)

        viewport = self.scene_viewport()
        snapshot = self._snapshot()
        state = self.scene.pose_state
        offset = self._camera_offset(snapshot, state.frame)
        self.camera.offset = offset
        camera = self.camera.camera(viewport[2], viewport[3])
        block = self.synchronous or (recording is not None and recording.source == "motion")
        self.status = self.pipeline.update(
            snapshot,
            state.frame,
            self.camera.view(),
            offset,
            now,
            playing=state.playing,
            loop=state.loop,
            settled=self._settled,
            block=block,
        )
        if self.status.shown.arrays is not None:
            self._update_gaussians(self.status.shown)
        self._draw_scene(camera, viewport, self.status)
        self._hud_work()
        if recording is not None and recording.source == "motion":
            self._write_frame(recording, window.read_pixels(viewport))
        screenshot = self._requests.screenshot
        if screenshot is not None and not screenshot[1]:
            self._save_screenshot(screenshot[0], window.read_pixels(viewport))
        window.end_ui()
        if screenshot is not None and screenshot[1]:
            self._save_screenshot(screenshot[0], window.read_pixels())
        if recording is not None and recording.source == "window" and self._requests.recording is recording:
            self._write_frame(recording, window.read_pixels())
        window.swap()

        frame_ms = (time.perf_counter() - now) * 1e3
        hud = self.hud
        hud.frame_ms = frame_ms
        rate = 1e3 / max(elapsed * 1e3, 1e-3)
        hud.fps = rate if hud.fps == 0 else FPS_SMOOTHING * hud.fps + (1 - FPS_SMOOTHING) * rate

    def scene_viewport(self) -> tuple[int, int, int, int]:
        """(x, y, W, H) of the scene in GL framebuffer pixels: right of the panel, full height."""
        width, height = self.window.framebuffer_size() if self.window else self.window_size
        panel = min(self._panel_pixels(), width - 1)
        return panel, 0, max(width - panel, 1), max(height, 1)

    def _panel_pixels(self) -> int:
        """The panel's width in framebuffer pixels (screen pixels times the HiDPI scale)."""
        if self.window is None:
            return PANEL_WIDTH
        from imgui_bundle import imgui

        return int(round(PANEL_WIDTH * imgui.get_io().display_framebuffer_scale.x))

    def _scene_aspect(self, window_size: tuple[int, int]) -> float:
        return max(window_size[0] - PANEL_WIDTH, 1) / max(window_size[1], 1)

    def current_camera(self):
        """The scene's :class:`~pghm.splat.Camera` for the current viewport, pose (when following) and orbit."""
        return self._scene_camera(self.scene_viewport())

    def _hud_work(self) -> None:
        """The HUD's cache fill and pending work."""
        hud, pipeline = self.hud, self.pipeline
        hud.cache_frames = len(pipeline.cache)
        hud.cache_mb = pipeline.cache.nbytes / MEGABYTE
        hud.cache_budget_mb = pipeline.cache.budget_bytes / MEGABYTE
        hud.pending = self.status.pending
        hud.prefetching = pipeline.worker.background_busy
        hud.moving = self.status.moving
        if pipeline.error:
            self.error = pipeline.error

    def _scene_camera(self, viewport: tuple[int, int, int, int]):
        self.camera.offset = self._camera_offset(self._snapshot(), self.scene.pose_state.frame)
        return self.camera.camera(viewport[2], viewport[3])

    def _camera_offset(self, snapshot, frame: int) -> np.ndarray:
        """:meth:`SceneSnapshot.camera_offset`, computed once per (state, frame): the body's
        forward kinematics would otherwise run on the UI thread in every frame."""
        key = (snapshot.key, frame)
        if key != self._cache.offset_key:
            self._cache.offset_key, self._cache.offset = key, snapshot.camera_offset(frame)
        return self._cache.offset

    def _snapshot(self):
        display = self.display
        return self.scene.snapshot(display.gaussians, display.view_dependent, display.follow)

    def _update_gaussians(self, shown: Shown) -> None:
        """Upload the chosen Gaussians when they or the point size changed (with their normals:
        back-face culling happens in the renderer, with the depth order)."""
        display = self.display
        arrays = shown.arrays
        hud = self.hud
        hud.gaussians = arrays.count
        key = (shown.source, display.scale_multiplier)
        if key != self._cache.upload_key:
            if shown.source != (self._cache.upload_key or (None,))[0]:  # new Gaussians: show what they cost
                hud.model_ms, hud.skinning_ms = shown.model_ms, shown.skinning_ms
            start = time.perf_counter()
            scales = arrays.scales * display.scale_multiplier
            self.renderer.set_gaussians(arrays.means, scales, arrays.colors, arrays.opacities, arrays.normals)
            self.overlay.set_points(arrays.means)
            self._cache.set_gaussians_ms = (time.perf_counter() - start) * 1e3
            self._cache.upload_key = key

    def _draw_scene(self, camera, viewport: tuple[int, int, int, int], status: FrameStatus) -> None:
        """Sprites into the window when something visible changed, else the last sprites again; overlays.

        An unchanged scene costs the composite of the sprites' box (``SpriteRenderer.present``),
        not the sprite pass; no scene image is kept besides the renderer's accumulation.
        While the view moves the sprites are drawn at the dynamic resolution's scale (stretched
        to the viewport); when still, at the display's internal resolution (100% unless the
        approximation is chosen): the exact image. Every draw's time steers the next moving scale.
        """
        display = self.display
        hud = self.hud
        scale = min(display.render_scale, self.resolution.scale) if status.moving else display.render_scale
        width, height = max(1, round(viewport[2] * scale)), max(1, round(viewport[3] * scale))
        hud.internal_size = (width, height)
        screen = self.window.ctx.screen
        screen.use()
        self.window.ctx.viewport = (0, 0, *self.window.framebuffer_size())
        screen.clear(*display.background, 1.0)
        if status.shown.arrays is not None:
            w2c = camera.world_to_camera.double().numpy().tobytes()
            # Moving: the float projection and the order view's depth order (viewer.pipeline);
            # still: the renderer's precision and the view's own order, the exact image.
            precision = self.resolution.settings.moving_precision if status.moving else None
            order_view = status.order_view if status.order_view != self.camera.view() else None
            cull = self._cull_degrees(status.moving)
            scene_key = (self._cache.upload_key, w2c, viewport[2:], display.background, (width, height))
            scene_key += (precision, order_view, cull)
            hud.scene_redrawn = scene_key != self._cache.scene_key
            if hud.scene_redrawn:
                internal = self.camera.camera(width, height) if (width, height) != viewport[2:] else camera
                order_camera = order_view.camera(self.camera.offset, width, height) if order_view else None
                timings = self.renderer.draw(
                    internal,
                    display.background,
                    target=screen,
                    viewport=viewport,
                    precision=precision,
                    order_camera=order_camera,
                    cleared=True,
                    cull_degrees=cull,
                )
                hud.sort_ms, hud.draw_ms, hud.drawn = timings.sort_ms, timings.draw_ms, timings.drawn
                hud.upload_ms = self._cache.set_gaussians_ms + timings.upload_ms
                self._cache.set_gaussians_ms = 0.0
                self._cache.scene_key = scene_key
                # Still frames too, lowering only: the first move starts at most where they say.
                self.resolution.update(scale, timings.draw_ms, moving=status.moving)
            else:
                self.renderer.present(display.background, target=screen, viewport=viewport, cleared=True)
        if display.show_mesh:
            self._update_mesh()
        self.overlay.draw(camera, viewport, centres=display.show_centres, mesh=display.show_mesh)

    def _cull_degrees(self, moving: bool) -> float | None:
        """Back-face culling's margin for this frame (None: every Gaussian): while moving the
        dynamic resolution's (``moving_cull_degrees``), when still the display option's."""
        if moving:
            return self.resolution.settings.moving_cull_degrees
        return BACKFACE_DEGREES if self.display.cull_backfacing else None

    def _update_mesh(self) -> None:
        pose = self.scene.current_pose()
        key = (pose.rotations.numpy().tobytes(), pose.translation.numpy().tobytes(), id(self.scene.driver))
        if key != self._cache.mesh_key:
            edges = None if self._cache.mesh_topology_sent else self.scene.mesh_edges()
            self.overlay.set_mesh(self.scene.posed_mesh(), edges)
            self._cache.mesh_key, self._cache.mesh_topology_sent = key, True

    # ------------------------------------------------------------------ actions: file

    def open_avatar(self, path: str | Path) -> None:
        """Replace the avatar; on a bad file the error is raised and the current avatar stays."""
        scene = AvatarScene(load_avatar(path), self.body_model_path)
        self.scene = scene
        self.avatar_path = Path(path)
        self.camera.home = scene.framing(self._scene_aspect(self._window_pixels()))
        self.camera.reset()
        self._cache = _Cache()
        if self.pipeline is not None:
            self.pipeline.cache.clear()  # the old avatar's frames are never asked for again

    def try_action(self, action, *args) -> bool:
        """Call ``action(*args)`` for the UI: a PghmError becomes :attr:`error` (one line) instead of an exception."""
        try:
            action(*args)
        except PghmError as error:
            self.error = str(error).splitlines()[0]
            return False
        self.error = None
        return True

    # ------------------------------------------------------------------ actions: pose, motion

    def set_pose_slider(self, joint: str, axis: int | str, degrees: float) -> None:
        """Rotate ``joint`` about rest-aligned ``axis`` (x, y, z or 0-2) by ``degrees`` (see viewer.scene.PoseState)."""
        self.scene.set_pose_slider(joint, axis, degrees)

    def reset_pose(self) -> None:
        self.scene.reset_pose()

    def open_motion(self, source: str) -> None:
        """A motion file (.npz, .bvh), a procedural name or a subject folder; the timeline restarts."""
        self.scene.open_motion(source)

    def scrub_to(self, frame: int) -> None:
        self.scene.scrub_to(frame)

    def set_playing(self, playing: bool) -> None:
        self.scene.pose_state.playing = bool(playing)

    def set_loop(self, loop: bool) -> None:
        self.scene.pose_state.loop = bool(loop)

    def set_speed(self, speed: float) -> None:
        self.scene.set_speed(speed)

    # --------------------------------------------------------------- actions: identity

    def pick_identity(self, index: int) -> None:
        self.scene.pick_identity(index)

    def set_blend(self, index_b: int, weight: float) -> None:
        self.scene.identity.set_blend(index_b, weight)

    def set_component(self, k: int, value: float) -> None:
        """PCA slider ``k`` of the bank latents, in standard deviations."""
        self.scene.identity.set_component(k, value)

    def set_region_gain(self, region: str | int, gain: float) -> None:
        """Multiply the identity latent on one body region (pghm.uv.regions) by ``gain``."""
        self.scene.identity.set_region_gain(region, gain)

    def reset_identity(self) -> None:
        self.scene.reset_identity()

    # ----------------------------------------------------------------- actions: camera

    def orbit(self, dx_pixels: float, dy_pixels: float) -> None:
        self.camera.orbit(dx_pixels, dy_pixels)

    def pan(self, dx_pixels: float, dy_pixels: float) -> None:
        self.camera.pan(dx_pixels, dy_pixels, self.scene_viewport()[3])

    def zoom(self, steps: float) -> None:
        self.camera.zoom(steps)

    def reset_camera(self) -> None:
        self.camera.reset()

    def snap_camera(self, view: str) -> None:
        """front, left, back, right or top."""
        self.camera.snap(view)

    def set_fov(self, degrees: float) -> None:
        self.camera.set_fov(degrees)

    # ---------------------------------------------------------------- actions: display

    def set_gaussian_set(self, which: GaussianSet) -> None:
        if which not in ("dynamic", "static"):
            raise PghmError(f"Gaussian set must be 'dynamic' or 'static', got {which!r}")
        self.display.gaussians = which

    def set_view_dependent(self, enabled: bool) -> None:
        self.display.view_dependent = bool(enabled)

    def set_scale_multiplier(self, factor: float) -> None:
        if not SCALE_RANGE[0] <= factor <= SCALE_RANGE[1]:
            raise PghmError(f"point-size modifier must be in [{SCALE_RANGE[0]}, {SCALE_RANGE[1]}], got {factor}")
        self.display.scale_multiplier = float(factor)

    def set_background(self, rgb: tuple[float, float, float]) -> None:
        if len(rgb) != 3 or not all(0.0 <= c <= 1.0 for c in rgb):
            raise PghmError(f"background must be three values in [0, 1], got {rgb}")
        self.display.background = tuple(float(c) for c in rgb)

    def set_overlays(self, centres: bool, mesh: bool) -> None:
        self.display.show_centres, self.display.show_mesh = bool(centres), bool(mesh)

    def set_render_scale(self, scale: float) -> None:
        """Approximation: internal resolution as a fraction of the viewport (1 = exact)."""
        if not 0.1 <= scale <= 1.0:
            raise PghmError(f"render scale must be in [0.1, 1], got {scale}")
        self.display.render_scale = float(scale)

    def set_backface_culling(self, enabled: bool) -> None:
        """Approximation: skip Gaussians facing away from the camera."""
        self.display.cull_backfacing = bool(enabled)

    def set_follow(self, enabled: bool) -> None:
        self.display.follow = bool(enabled)

    # ----------------------------------------------------------------- actions: output

    def screenshot(self, path: str | Path | None = None, include_ui: bool = True) -> Path:
        """Write a PNG of the next frame (the window, or the scene alone); returns its path.

        The pixels are also kept in :attr:`last_screenshot` ((H, W, 3) uint8).
        """
        path = Path(path) if path else Path(f"pghm_screenshot_{datetime.now():%Y%m%d_%H%M%S}.png")
        if path.suffix.lower() != ".png":
            raise PghmError(f"screenshots are PNG files, got {path}")
        self._requests.screenshot = (path, include_ui)
        return path

    def start_recording(self, path: str | Path, source: RecordSource = "window", fps: float = 30.0) -> None:
        """Record the window from now on, or the motion from the current frame to its end at ``fps``."""
        self.stop_recording()
        state = self.scene.pose_state
        frames = int(np.floor((state.motion.duration - state.time) * fps + 1e-9)) + 1
        self._requests.recording = start_recording(
            path, source, fps, motion_start=state.time, motion_frames=frames, log=self._note
        )
        if source == "motion":
            state.playing = False

    def stop_recording(self) -> Path | None:
        """Close the recording file (if any); returns its path."""
        recording, self._requests.recording = self._requests.recording, None
        if recording is None:
            return None
        recording.sink.close()
        self._note(f"recorded {recording.sink.frames} frames to {recording.sink.path}")
        return recording.sink.path

    @property
    def recording(self) -> Recording | None:
        return self._requests.recording

    def _write_frame(self, recording: Recording, image: np.ndarray) -> None:
        try:
            recording.sink.write(image)
        except PghmError as error:
            self.error = str(error)
            self.stop_recording()
            return
        if recording.done:
            self.stop_recording()

    def _save_screenshot(self, path: Path, image: np.ndarray) -> None:
        self._requests.screenshot = None
        self.last_screenshot = image
        save_png(path, image)
        self._note(f"saved {path}")

    def _note(self, text: str) -> None:
        self.message = text

    def _window_pixels(self) -> tuple[int, int]:
        return self.window.framebuffer_size() if self.window else self.window_size
