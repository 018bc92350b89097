"""Viewer frame times (scrubbing a motion, orbiting), the speed options, and GL-vs-CPU accuracy.

Sections (all by default):

* scrub: the viewer's per-frame path while scrubbing a motion — model (cached evaluator)
  + skinning + sort + upload + draw into an RGBA8 framebuffer the size of the default
  window's scene viewport — for the default ModelConfig (11,156 Gaussians) on 2 threads,
  for each display mode (I_d with view-dependent colour, I_d without it, I_s).
* orbit: camera-only frames (sort + draw) of the 10k-Gaussian body scene of bench_gl.py at
  1280 x 720: the exact path (double and float projection, quads; octagons measured in
  docs/viewer.md) and the optional approximations (internal resolution, back-face culling),
  each with its error against the exact image.
* accuracy: GL against the CPU splatter on avatar renders (3 poses x 8 views, 1280 x 720)
  with the float and the double projection: pixels over 2e-3, over 1e-4, max, mean.
* window (only with a DISPLAY): the real Viewer.frame() in a glfw window, synchronous
  (the model waited for in each frame): idle (cached scene), orbit, scrub.
* interactive (only with a DISPLAY): the viewer before (synchronous) and after (model
  worker, frame cache, dynamic resolution) at a 1280 x 720 scene: playback, scrubbing
  (first pass and cached), orbit, a slider drag (UI frame and latency); the keys
  playback_p95_ms, scrub_first_pass_median_ms, orbit_moving_p95_ms, slider_ui_max_ms.
  With it, headless: each approximation of a moving frame (a depth order some degrees
  behind, the float projection, the least internal resolution) against the exact image;
  the keys orbit_stale_order_max_error / _mean_error (the order at the refresh angle) and
  orbit_cull_max_error / _mean_error (back-face culling made at the refresh angle's lag).

* resolution (only with ``--avatars``): the scrub path of the shipped avatar and of other avatars
  (fits at another ``--uv-resolution``) in one run, frame by frame in turn, with each one's ratio
  to the shipped one; written to benchmarks/results/bench_viewer_resolution.json.

    xvfb-run -a -s "-screen 0 1920x1080x24" .venv/bin/python benchmarks/bench_viewer.py \
        [--frames 40] [--sections interactive scrub orbit accuracy window] [--avatars A.pt ...]

``--sections`` with no names runs none of them (``--avatars`` alone: the resolution comparison).

Prints tables and writes benchmarks/results/bench_viewer.json (with the driver and the load
average: the machine is shared, so medians and minima are both reported).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
import torch
from bench_gl import body_scene, summary
from bench_gl import orbit_camera as body_orbit_camera
from common import load_average, print_table, setup_threads, write_json

from pghm.gl import SpriteRenderer, driver_info, headless_context
from pghm.io.avatar import load_avatar
from pghm.motion.open_motion import open_motion
from pghm.render import AvatarDriver, frame_points, orbit_camera
from pghm.splat import render
from viewer.demo import development_avatar
from viewer.dynamic_resolution import ResolutionSettings
from viewer.pipeline import COLOUR_REFRESH_DEGREES, ORDER_REFRESH_DEGREES
from viewer.settings import BACKFACE_DEGREES, SYNTHETIC_AVATAR

ROOT = Path(__file__).resolve().parent.parent
SCENE_VIEWPORT = (920, 800)
"""The default window (1280 x 800) minus the 360-pixel control panel."""
ORBIT_SIZE = (1280, 720)
ACCURACY_POSES = (("rest", 0), ("walk", 20), ("squat", 60))
ACCURACY_VIEWS = 8
FLIP = 2e-3
"""The GL-vs-CPU max-error bar; pixels above it are cut-off flips."""


def the_avatar():
    """assets/avatar.pt when shipped, else the development avatar at the default config."""
    if SYNTHETIC_AVATAR.is_file():
        return load_avatar(SYNTHETIC_AVATAR), str(SYNTHETIC_AVATAR.relative_to(ROOT))
    return development_avatar(), "development avatar (viewer.demo, default ModelConfig)"


# ------------------------------------------------------------------------------ scrub


DISPLAY_MODES = (
    ("I_d + view-dependent (default)", "dynamic", True, 1.0, "auto"),
    ("I_d + view-dependent, quads only (before points)", "dynamic", True, 1.0, "quads"),
    ("I_d, no view-dependent", "dynamic", False, 1.0, "auto"),
    ("I_s (static)", "static", False, 1.0, "auto"),
    ("I_d + view-dep., approx: 50% resolution", "dynamic", True, 0.5, "auto"),
)
"""(label, Gaussians drawn, view-dependent colour, internal resolution scale, sprite primitive)."""


def bench_scrub(ctx, avatars: list, frames: int, modes: tuple = DISPLAY_MODES) -> list[dict]:
    """Consecutive walk frames, as the viewer runs them when the timeline is dragged.

    The display modes take turns frame by frame (one driver and renderer each), so that
    load from other processes falls on all of them alike. ``avatars``: one per mode (the same
    avatar in every mode, or several avatars in one mode to compare them under the same load).
    """
    drivers = [AvatarDriver(avatar) for avatar in avatars]
    renderers = [SpriteRenderer(ctx, primitive=mode[4]) for mode in modes]
    body, shape = drivers[0].body, drivers[0].geometry.shape
    motion = open_motion("walk", body, shape)
    identities = [driver.avatar.identity_map() for driver in drivers]
    width, height = SCENE_VIEWPORT
    framing = frame_points(drivers[0].geometry.surface.positions.numpy(), 40.0, width / height)
    rest_root = drivers[0].root_position(drivers[0].rest_pose())
    screen = ctx.simple_framebuffer((width, height), components=4)
    names = ("model", "skinning", "sort", "upload", "draw", "total")
    stages = [{name: [] for name in names} for _ in modes]
    try:
        for k in range(frames + 2):
            for (_label, gaussians, view_dependent, scale, _primitive), driver, identity, renderer, record in zip(
                modes, drivers, identities, renderers, stages
            ):
                start = time.perf_counter()
                pose = motion.pose(k % motion.num_frames)
                shift = driver.root_position(pose) - rest_root  # the viewer's camera follows the root
                target = np.asarray(framing.target) + np.array([shift[0], 0.0, shift[2]])
                camera = orbit_camera(target, 20.0, 5.0, framing.distance, 40.0, width, height)
                arrays = driver.evaluate(identity, pose, camera.centre, gaussians, view_dependent)
                upload = time.perf_counter()
                renderer.set_gaussians(arrays.means, arrays.scales, arrays.colors, arrays.opacities)
                set_ms = (time.perf_counter() - upload) * 1e3
                size = (round(width * scale), round(height * scale))
                internal = orbit_camera(target, 20.0, 5.0, framing.distance, 40.0, *size)
                timings = renderer.draw(internal, (0.16, 0.17, 0.19), target=screen)
                total = (time.perf_counter() - start) * 1e3
                if k < 2:  # warm-up: shader JIT, first allocations
                    continue
                record["model"].append(driver.times.model_ms)
                record["skinning"].append(driver.times.skinning_ms)
                record["sort"].append(timings.sort_ms)
                record["upload"].append(set_ms + timings.upload_ms)
                record["draw"].append(timings.draw_ms)
                record["total"].append(total)
    finally:
        for renderer in renderers:
            renderer.release()
        screen.release()
    rows = []
    for (label, *_), driver, record in zip(modes, drivers, stages):
        row = {"display": label, "gaussians": driver.geometry.num_gaussians}
        row.update({f"{name}_ms": float(np.median(values)) for name, values in record.items()})
        row["total_min_ms"] = float(np.min(record["total"]))
        rows.append(row)
    rows[-1]["load"] = load_average()
    return rows


def bench_resolutions(ctx, shipped, shipped_name: str, paths: list[str], frames: int) -> list[dict]:
    """The default display's scrub frame of the shipped avatar and of each avatar in ``paths``
    (taking turns frame by frame), with each one's time as a ratio to the shipped one's."""
    avatars = [shipped] + [load_avatar(path) for path in paths]
    names = [shipped_name] + [Path(path).name for path in paths]
    rows = bench_scrub(ctx, avatars, frames, modes=DISPLAY_MODES[:1] * len(avatars))
    base = rows[0]["total_ms"]
    for row, name, avatar in zip(rows, names, avatars):
        row["display"] = name
        row["L"] = avatar.model.config.uv_resolution
        row["ratio"] = row["total_ms"] / base
    return rows


# ------------------------------------------------------------------------------ orbit


def _float_target(ctx, size):
    return ctx.framebuffer(color_attachments=[ctx.texture(size, 4, dtype="f4")])


def _read(fbo) -> np.ndarray:
    width, height = fbo.size
    return np.frombuffer(fbo.read(components=4, dtype="f4"), np.float32).reshape(height, width, 4)[..., :3]


def bench_orbit(ctx, frames: int) -> list[dict]:
    """Camera-only frames of the body scene; each option's time and its error against the exact image."""
    means, scales, colors, opacities = body_scene(10_000)
    normals = 2.0 * colors - 1.0  # body_scene colours each Gaussian by its normal: c = 0.5 + 0.5 n
    angles = np.linspace(0, 2 * np.pi, frames, endpoint=False)
    screen = ctx.simple_framebuffer(ORBIT_SIZE, components=4)
    exact_target, option_target = _float_target(ctx, ORBIT_SIZE), _float_target(ctx, ORBIT_SIZE)
    exact = SpriteRenderer(ctx)
    exact.set_gaussians(means, scales, colors, opacities)
    options = (
        ("exact, double projection (default)", "double", 1.0, False, "auto"),
        ("exact, double projection, quads only (before points)", "double", 1.0, False, "quads"),
        ("exact, float projection (GL 3.3)", "float", 1.0, False, "auto"),
        ("approx: internal resolution 75%", "double", 0.75, False, "auto"),
        ("approx: internal resolution 50%", "double", 0.5, False, "auto"),
        ("approx: cull back-facing", "double", 1.0, True, "auto"),
        ("approx: cull back-facing + 50%", "double", 0.5, True, "auto"),
    )
    renderers = [SpriteRenderer(ctx, precision=option[1], primitive=option[4]) for option in options]
    records = [{"times": [], "max": [], "mean": [], "drawn": []} for _ in options]
    try:
        # The options take turns view by view, so that load from other processes falls on all alike.
        for k, angle in enumerate(np.concatenate([angles[:2], angles])):
            for (_label, _precision, scale, cull, _primitive), renderer, record in zip(options, renderers, records):
                camera = body_orbit_camera(angle, scale)
                if k == 0:
                    renderer.set_gaussians(means, scales, colors, opacities, normals)
                cull_degrees = BACKFACE_DEGREES if cull else None
                start = time.perf_counter()
                timings = renderer.draw(camera, (1.0, 1.0, 1.0), target=screen, cull_degrees=cull_degrees)
                if k < 2:  # warm-up
                    continue
                record["times"].append((time.perf_counter() - start) * 1e3)
                if cull:
                    record["drawn"].append(timings.drawn)
                renderer.draw(
                    camera,
                    (1.0, 1.0, 1.0),
                    target=option_target,
                    viewport=(0, 0, *ORBIT_SIZE),
                    cull_degrees=cull_degrees,
                )
                exact.draw(body_orbit_camera(angle), (1.0, 1.0, 1.0), target=exact_target)
                error = np.abs(_read(option_target) - _read(exact_target))
                record["max"].append(float(error.max()))
                record["mean"].append(float(error.mean()))
        rows = []
        for (label, *_), record in zip(options, records):
            stats = summary(record["times"])
            rows.append(
                {
                    "option": label,
                    "gaussians_drawn": int(np.mean(record["drawn"])) if record["drawn"] else len(means),
                    "median_ms": stats["median_ms"],
                    "min_ms": stats["min_ms"],
                    "p90_ms": stats["p90_ms"],
                    "max_error": max(record["max"]),
                    "mean_error": float(np.mean(record["mean"])),
                }
            )
        rows[-1]["load"] = load_average()
    finally:
        for renderer in (exact, *renderers):
            renderer.release()
        for fbo in (screen, exact_target, option_target):
            for attachment in fbo.color_attachments:
                attachment.release()
            fbo.release()
    return rows


# ----------------------------------------------------------------------- stale order

STALE_DEGREES = (2.5, 5.0, ORDER_REFRESH_DEGREES, 20.0)
"""How far the order's view lags the drawn view (degrees of yaw) in the stale-order error."""
STALE_VIEWS = 8
MOVING = ResolutionSettings()
"""The viewer's moving-frame settings (projection, culling margin)."""
MOVING_SCALE = MOVING.min_scale
"""The dynamic resolution's least internal scale, for comparison."""


def stale_label(lag: float) -> str:
    return f"order {lag:g} degrees behind"


STALE_LABEL = stale_label(ORDER_REFRESH_DEGREES)
"""The row of the viewer's refresh angle: the largest lag a moving frame's order has."""
CULL_LABEL = (
    f"cull {MOVING.moving_cull_degrees:g} degrees, made {ORDER_REFRESH_DEGREES:g} degrees behind "
    "(against the unculled image in that order)"
)
"""The culling's own error at the largest lag (orbit_cull_max_error / _mean_error)."""
COLOUR_LAGS = (COLOUR_REFRESH_DEGREES, 45.0, 90.0)
"""How far the view-dependent colour's view lags the drawn view: the viewer's refresh angle
(the largest lag while orbiting) and larger ones, for the trade a larger angle would make."""


def bench_moving_error(ctx, avatar) -> list[dict]:
    """The error of each approximation of a moving frame against the exact image.

    Compositing in the depth order of a view ``lag`` degrees behind the drawn one (what a
    moving camera trades when it keeps its last order, viewer.pipeline), the float
    projection, the reduced internal resolution, back-face culling (for the drawn view; made
    with an order ``ORDER_REFRESH_DEGREES`` behind, against the unculled image in that order:
    the culling's own error), a whole moving frame at the largest lag with and without
    culling, and view-dependent colour made for a view ``COLOUR_LAGS`` behind (what an orbit
    shows between two colour refreshes, against the colour of the drawn view): the shipped
    avatar (walk frame 20) at 1280 x 720 from 8 views; RGB error per pixel, the pixels over
    1/255 (one 8-bit level) per image, the Gaussians drawn.
    """
    driver = AvatarDriver(avatar)
    pose = open_motion("walk", driver.body, driver.geometry.shape).pose(20)
    identity = avatar.identity_map()
    arrays = driver.evaluate(identity, pose, np.array([0.0, 0.0, 3.0]))
    width, height = ORBIT_SIZE
    framing = frame_points(arrays.means, 40.0, width / height)
    exact_target, approx_target = _float_target(ctx, ORBIT_SIZE), _float_target(ctx, ORBIT_SIZE)
    renderer = SpriteRenderer(ctx)
    renderer.set_gaussians(arrays.means, arrays.scales, arrays.colors, arrays.opacities, arrays.normals)

    def camera(yaw: float, scale: float = 1.0):
        size = (round(width * scale), round(height * scale))
        return orbit_camera(framing.target, yaw, 10.0, framing.distance, 40.0, *size)

    approximations = [(stale_label(lag), {"order_lag": lag}) for lag in sorted(set(STALE_DEGREES))]
    cull, lag = MOVING.moving_cull_degrees, ORDER_REFRESH_DEGREES
    moving_frame = {"order_lag": lag, "precision": MOVING.moving_precision, "scale": MOVING_SCALE}
    approximations += [
        ("float projection", {"precision": MOVING.moving_precision}),
        (f"internal resolution {MOVING_SCALE:.0%}", {"scale": MOVING_SCALE}),
        (f"cull {cull:g} degrees (the drawn view's)", {"cull_degrees": cull}),
        (CULL_LABEL, {"order_lag": lag, "cull_degrees": cull, "reference_lag": lag}),
        (f"moving frame ({lag:g} behind, float, {MOVING_SCALE:.0%}), no culling", moving_frame),
        (f"moving frame ({lag:g} behind, float, {MOVING_SCALE:.0%}), culled", {**moving_frame, "cull_degrees": cull}),
    ]
    # Last: these replace the Gaussians (colours) per view.
    approximations += [(f"colour made {lag:g} degrees behind", {"colour_lag": lag}) for lag in COLOUR_LAGS]

    def seen_from(yaw: float) -> tuple:
        """The Gaussians with view-dependent colour made for the view at ``yaw``."""
        seen = driver.evaluate(identity, pose, camera(yaw).centre.numpy())
        return seen.means, seen.scales, seen.colors, seen.opacities, seen.normals

    rows = []
    try:
        for label, option in approximations:
            errors, drawn = [], []
            for k in range(STALE_VIEWS):
                yaw = 360.0 * k / STALE_VIEWS + 10.0
                reference_lag, colour_lag = option.get("reference_lag"), option.get("colour_lag")
                if colour_lag is not None:
                    renderer.set_gaussians(*seen_from(yaw))
                renderer.draw(
                    camera(yaw),
                    (1.0, 1.0, 1.0),
                    target=exact_target,
                    flip_y=False,
                    order_camera=camera(yaw - reference_lag) if reference_lag else None,
                )
                if colour_lag is not None:
                    renderer.set_gaussians(*seen_from(yaw - colour_lag))
                order_lag, scale = option.get("order_lag"), option.get("scale", 1.0)
                timings = renderer.draw(
                    camera(yaw, scale),
                    (1.0, 1.0, 1.0),
                    target=approx_target,
                    viewport=(0, 0, width, height),
                    flip_y=False,
                    precision=option.get("precision"),
                    order_camera=camera(yaw - order_lag, scale) if order_lag else None,
                    cull_degrees=option.get("cull_degrees"),
                )
                errors.append(np.abs(_read(approx_target) - _read(exact_target)).max(axis=-1))
                drawn.append(timings.drawn)
            errors = np.stack(errors)
            rows.append(
                {
                    "approximation": label,
                    "max_error": float(errors.max()),
                    "mean_error": float(errors.mean()),
                    "pixels_over_1/255_per_image": float((errors > 1.0 / 255.0).sum() / len(errors)),
                    "gaussians_drawn": float(np.mean(drawn)),
                }
            )
    finally:
        renderer.release()
        for fbo in (exact_target, approx_target):
            for attachment in fbo.color_attachments:
                attachment.release()
            fbo.release()
    return rows


# --------------------------------------------------------------------------- accuracy


def bench_accuracy(ctx, avatar) -> list[dict]:
    """GL (float and double projection) against the CPU splatter on avatar renders."""
    driver = AvatarDriver(avatar)
    identity = avatar.identity_map()
    width, height = ORBIT_SIZE
    scenes = []
    for name, frame in ACCURACY_POSES:
        pose = open_motion(name, driver.body, driver.geometry.shape).pose(frame)
        arrays = driver.evaluate(identity, pose, np.array([0.0, 0.0, 3.0]))
        framing = frame_points(arrays.means, 40.0, width / height)
        cameras = [
            orbit_camera(framing.target, 45.0 * k + 10.0, 10.0, framing.distance, 40.0, width, height)
            for k in range(ACCURACY_VIEWS)
        ]
        tensors = [torch.from_numpy(a) for a in (arrays.means, arrays.scales, arrays.colors, arrays.opacities)]
        truths = [render(*tensors, camera).rgb.numpy() for camera in cameras]
        scenes.append((arrays, cameras, truths))
    rows = []
    for precision in ("double", "float"):
        renderer = SpriteRenderer(ctx, precision=precision)
        errors, times = [], []
        for arrays, cameras, truths in scenes:
            renderer.set_gaussians(arrays.means, arrays.scales, arrays.colors, arrays.opacities)
            for camera, truth in zip(cameras, truths):
                start = time.perf_counter()
                image = renderer.render(camera, (1.0, 1.0, 1.0)).rgb
                times.append((time.perf_counter() - start) * 1e3)
                errors.append(np.abs(image - truth).max(axis=-1))
        renderer.release()
        errors = np.stack(errors)
        rows.append(
            {
                "projection": precision,
                "images": len(errors),
                "pixels": int(errors.size),
                f"pixels_over_{FLIP:g}": int((errors > FLIP).sum()),
                "pixels_over_1e-4": int((errors > 1e-4).sum()),
                "max_error": float(errors.max()),
                "mean_error": float(errors.mean()),
                "render_median_ms": float(np.median(times)),
            }
        )
    return rows


# ----------------------------------------------------------------------------- window


def bench_window(avatar_path: Path, frames: int) -> list[dict]:
    """The real viewer in a glfw window (needs DISPLAY): Viewer.frame() per situation."""
    from viewer.viewer import Viewer

    viewer = Viewer(avatar_path)
    viewer.setup()
    viewer.synchronous = True  # every frame runs what its label says (the interactive section has the rest)
    rows = []
    try:
        viewer.open_motion("walk")
        for _ in range(3):
            viewer.frame()

        def measure(label: str, action) -> None:
            rows.append({"situation": label, **summary(frame_times(viewer, frames, action)), "load": load_average()})

        measure("idle (scene unchanged, UI only)", lambda k: None)
        measure("orbit (view branch + sort + draw)", lambda k: viewer.orbit(3.0, 0.0))
        measure("scrub (model + skinning + sort + upload + draw)", lambda k: viewer.scrub_to(1 + k % 119))
        viewer.set_view_dependent(False)
        measure("orbit, view-dependent off (sort + draw)", lambda k: viewer.orbit(3.0, 0.0))
    finally:
        viewer.teardown()
    return rows


# ---------------------------------------------------------------------- interactive

INTERACTIVE_WINDOW = (1640, 720)
"""The window whose scene viewport (right of the 360-pixel panel) is 1280 x 720."""
WALK_CLIP = "assets/motion/mixamo_walk_69f.bvh"
SLIDER_DRAG = np.linspace(0.0, 90.0, 24)
"""Degrees of the left elbow on consecutive frames of a drag."""
LATENCY_FRAMES = 400
"""At most this many frames wait for the dragged pose to appear."""
PASS_KEYS = ("idle", "playback", "scrub_first_pass", "scrub_cached", "orbit_moving", "slider_ui")
"""idle: nothing changes (UI and the cached scene image only), the floor of every other frame."""
AFTER_KEYS = ("orbit_moving_unculled",)
"""After only: orbiting with the moving frames' back-face culling off, measured right after the
culled orbit (the culling's gain within one run)."""


def frame_times(viewer, frames: int, action) -> list[float]:
    """ms of ``viewer.frame()`` after ``action(k)``, k = 0 .. frames - 1."""
    times = []
    for k in range(frames):
        action(k)
        start = time.perf_counter()
        viewer.frame()
        times.append((time.perf_counter() - start) * 1e3)
    return times


def interactive_pass(viewer, frames: int, synchronous: bool) -> dict:
    """Play, scrub, orbit and drag a slider in the real viewer; frame times and the slider latency.

    ``synchronous``: every frame waits for the model and draws exactly (the viewer before the
    worker, the cache and dynamic resolution); else the viewer as shipped.
    """
    viewer.synchronous = synchronous
    viewer.pipeline.cache.clear()
    viewer.reset_camera()
    viewer.reset_pose()
    viewer.open_motion(str(ROOT / WALK_CLIP))
    num_frames = viewer.scene.pose_state.motion.num_frames
    out = {}
    out["scrub_first_pass"] = frame_times(viewer, min(frames, num_frames), lambda k: viewer.scrub_to(k))
    viewer.settle()
    viewer.pipeline.worker.wait_background_idle()  # the clip is cached after one pass
    out["idle"] = frame_times(viewer, frames, lambda k: None)
    out["cache_frames"] = len(viewer.pipeline.cache)
    out["cache_mb"] = viewer.pipeline.cache.nbytes / 2**20
    out["scrub_cached"] = frame_times(viewer, frames, lambda k: viewer.scrub_to((7 * k) % num_frames))
    viewer.settle()
    viewer.set_playing(True)
    out["playback"] = frame_times(viewer, frames, lambda k: None)
    viewer.set_playing(False)
    viewer.settle()
    out["orbit_moving"] = frame_times(viewer, frames, lambda k: viewer.orbit(6.0, 0.0))
    viewer.settle()
    if not synchronous:
        settings = viewer.resolution.settings
        cull, settings.moving_cull_degrees = settings.moving_cull_degrees, None
        out["orbit_moving_unculled"] = frame_times(viewer, frames, lambda k: viewer.orbit(6.0, 0.0))
        settings.moving_cull_degrees = cull
        viewer.settle()
    viewer.open_motion("rest")
    viewer.settle()
    drag = SLIDER_DRAG[: max(frames // 2, 2)]
    out["slider_ui"] = frame_times(viewer, len(drag), lambda k: viewer.set_pose_slider("left_elbow", "z", drag[k]))
    # Latency: from the last drag event until a frame shows that pose (the frame's end),
    # with the waits of Viewer.run's loop between frames (no more input arrives).
    dragged = time.perf_counter()
    viewer.set_pose_slider("left_elbow", "z", float(drag[-1]) + 5.0)
    for _ in range(LATENCY_FRAMES):
        viewer.frame()
        if viewer.status.shown.state == (viewer._snapshot().key, 0):
            break
        if not synchronous:
            viewer.window.poll(viewer.input_wait())
    out["slider_latency_ms"] = (time.perf_counter() - dragged) * 1e3
    viewer.reset_pose()
    viewer.settle()
    return out


def bench_interactive(avatar_path: Path, frames: int) -> dict:
    """The viewer before (synchronous) and after (worker, cache, dynamic resolution), alternating passes."""
    from viewer.viewer import Viewer

    viewer = Viewer(avatar_path, window_size=INTERACTIVE_WINDOW)
    viewer.setup()
    passes = {"before": [], "after": []}
    loads = [load_average()]
    try:
        viewer.settle()
        for synchronous in (True, False, True, False):  # A B A B: load from other jobs falls on both
            passes["before" if synchronous else "after"].append(interactive_pass(viewer, frames, synchronous))
            loads.append(load_average())
    finally:
        viewer.teardown()
    result = {"viewport": [1280, 720], "frames_per_measurement": frames, "loads": loads}
    for name, runs in passes.items():
        row = {}
        for key in PASS_KEYS + (AFTER_KEYS if name == "after" else ()):
            times = [t for run in runs for t in run[key]]
            row[f"{key}_median_ms"] = float(np.median(times))
            row[f"{key}_p95_ms"] = float(np.percentile(times, 95))
            row[f"{key}_max_ms"] = float(np.max(times))
        row["slider_latency_ms"] = float(max(run["slider_latency_ms"] for run in runs))
        row["cache_frames"] = runs[-1]["cache_frames"]
        row["cache_mb"] = runs[-1]["cache_mb"]
        result[name] = row
    return result


def print_interactive(result: dict) -> None:
    before, after = result["before"], result["after"]
    rows = []
    for key in PASS_KEYS:
        for stat in ("median", "p95", "max"):
            name = f"{key}_{stat}_ms"
            ratio = after[name] / before[name]
            rows.append({"measure": name, "before": before[name], "after": after[name], "ratio": ratio})
    name = "slider_latency_ms"
    rows.append({"measure": name, "before": before[name], "after": after[name], "ratio": after[name] / before[name]})
    print_table(rows)
    unculled = ", ".join(f"{stat} {after[f'orbit_moving_unculled_{stat}_ms']:.1f}" for stat in ("median", "p95", "max"))
    print(f"after, orbit with the moving frames' back-face culling off (ms): {unculled}")
    print(f"cache after one pass: {after['cache_frames']} frames, {after['cache_mb']:.1f} MB; loads {result['loads']}")


SECTIONS = ("interactive", "scrub", "orbit", "accuracy", "window")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=40, help="frames per measurement")
    parser.add_argument("--sections", nargs="*", default=list(SECTIONS), choices=SECTIONS)
    parser.add_argument(
        "--avatars", nargs="+", default=[], help="avatars to scrub beside the shipped one (the resolution section)"
    )
    args = parser.parse_args()
    setup_threads()
    torch.manual_seed(0)
    avatar, avatar_name = the_avatar()
    ctx = headless_context()
    driver = str(driver_info(ctx))
    print(f"driver: {driver}; avatar: {avatar_name}; load average {load_average():.2f}")
    results: dict = {"driver": driver, "avatar": avatar_name, "load_before": load_average()}
    if "scrub" in args.sections:
        width, height = SCENE_VIEWPORT
        print(f"\nScrubbing the walk, scene viewport {width} x {height}, ms (medians; total_min = least disturbed)")
        results["scrub"] = bench_scrub(ctx, [avatar] * len(DISPLAY_MODES), args.frames)
        print_table(results["scrub"])
    if args.avatars:
        width, height = SCENE_VIEWPORT
        print(f"\nScrubbing the walk with each avatar in turn, {width} x {height}, default display, ms")
        rows = bench_resolutions(ctx, avatar, avatar_name, args.avatars, args.frames)
        print_table(rows)
        write_json("bench_viewer_resolution", {"driver": driver, "rows": rows})
    if "orbit" in args.sections:
        width, height = ORBIT_SIZE
        print(f"\nOrbit-only frames, 10k-Gaussian body scene, {width} x {height}, ms; error vs the exact image")
        results["orbit"] = bench_orbit(ctx, args.frames)
        print_table(results["orbit"])
    if "accuracy" in args.sections:
        width, height = ORBIT_SIZE
        print(f"\nGL vs CPU splatter, {len(ACCURACY_POSES)} poses x {ACCURACY_VIEWS} views at {width} x {height}")
        results["accuracy"] = bench_accuracy(ctx, avatar)
        print_table(results["accuracy"])
    if "interactive" in args.sections:
        width, height = ORBIT_SIZE
        print(f"\nApproximations of a moving frame against the exact image, shipped avatar, {width} x {height}")
        results["moving_error"] = bench_moving_error(ctx, avatar)
        print_table(results["moving_error"])
        stale = next(row for row in results["moving_error"] if row["approximation"] == STALE_LABEL)
        results["orbit_stale_order_max_error"] = stale["max_error"]
        results["orbit_stale_order_mean_error"] = stale["mean_error"]
        culled = next(row for row in results["moving_error"] if row["approximation"] == CULL_LABEL)
        results["orbit_cull_max_error"] = culled["max_error"]
        results["orbit_cull_mean_error"] = culled["mean_error"]
    ctx.release()
    if "window" in args.sections:
        if os.environ.get("DISPLAY"):
            import tempfile

            from pghm.io.avatar import save_avatar

            with tempfile.TemporaryDirectory() as folder:
                path = SYNTHETIC_AVATAR if SYNTHETIC_AVATAR.is_file() else Path(folder) / "avatar.pt"
                if not SYNTHETIC_AVATAR.is_file():
                    save_avatar(path, avatar)
                print("\nThe viewer in a glfw window (default 1280 x 800), Viewer.frame() ms")
                results["window"] = bench_window(path, args.frames)
                print_table(results["window"])
        else:
            print("\nwindow: skipped (no DISPLAY; run under Xvfb for the in-window numbers)")
    if "interactive" in args.sections:
        if os.environ.get("DISPLAY") and SYNTHETIC_AVATAR.is_file():
            print("\nThe viewer, scene 1280 x 720: before (model on the UI thread, exact frames) and after, ms")
            interactive = bench_interactive(SYNTHETIC_AVATAR, args.frames)
            print_interactive(interactive)
            results["interactive"] = interactive
            after = interactive["after"]
            results["playback_p95_ms"] = after["playback_p95_ms"]
            results["scrub_first_pass_median_ms"] = after["scrub_first_pass_median_ms"]
            results["orbit_moving_p95_ms"] = after["orbit_moving_p95_ms"]
            results["slider_ui_max_ms"] = after["slider_ui_max_ms"]
        else:
            print("\ninteractive: skipped (needs DISPLAY, e.g. xvfb-run, and assets/avatar.pt)")
    if args.sections:
        results["load_after"] = load_average()
        write_json("bench_viewer", results)


if __name__ == "__main__":
    main()
