"""The avatar as a web page: size, fidelity against the CPU splatter, and speed in headless Chromium.

For the shipped real avatar in the 69-frame walk:

1. ``pghm export AVATAR --web docs/real_avatar.html``: seconds, bytes, the components each group kept;
2. the pose-dependent part three ways, stored numbers against the worst frame's RMS error: baked
   per frame (float16, nothing dropped), the principal components the page stores, and a
   per-Gaussian linear model of the pose (least squares on the rotations of its SKIN_BONES
   bones, fitted on the very frames it is scored on);
3. the page in headless Chromium (software WebGL, SwiftShader) at 960 x 540: shots at frames of
   the walk and camera yaws, PSNR against the CPU splatter given the colours the page baked (the
   page's renderer and bake) and against the CPU splatter with the view-dependent colour of that
   very camera (``pghm render --yaw``: what baking the colour for the front view costs); the first
   frame's time after the page opened; the median frame time over a full loop, each frame skinned,
   sorted and drawn;
4. a screenshot of the page as it opens (``docs/web_page.png``).

    python benchmarks/bench_web.py [--avatar assets/real_avatar.pt] [--motion walk]

Prints tables and writes benchmarks/results/bench_web.json.
"""

from __future__ import annotations

import argparse
import math
import subprocess
import time
from pathlib import Path

import numpy as np
from browser import CHROMIUM_FLAGS, chromium, drive
from common import DOCS, ROOT, load_average, print_table, setup_threads, write_json

from pghm.io.avatar import load_avatar
from pghm.motion.open_motion import open_motion
from pghm.render.driver import AvatarDriver
from pghm.render.frames import CPUFrames
from pghm.render.framing import DEFAULT_FOV_Y, floor_shift, frame_points, orbit_camera
from pghm.web import export_web
from pghm.web.bake import BAKE_ASPECT, SKIN_BONES, BakeConfig, compress, front_centre, sample_motion

WIDTH, HEIGHT = 960, 540
SHOTS = [
    *({"frame": f, "yaw": 0} for f in (0, 17, 34, 51)),
    *({"frame": 10, "yaw": y} for y in (45, 90, 180)),
    {"frame": 25, "yaw": 30, "pitch": 20},
]
FLOAT16_BYTES = 2
PAGE = DOCS / "real_avatar.html"
SCREENSHOT = DOCS / "web_page.png"


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    error = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2) / 255.0**2
    return math.inf if error == 0 else 10 * math.log10(1 / error)


def worst_rms(error: np.ndarray) -> float:
    """The worst frame's RMS over the Gaussians of (F, N, C) errors."""
    return float(np.sqrt(np.max(np.einsum("fnc,fnc->f", error, error)) / error.shape[1]))


def linear_pose_model(samples, values: np.ndarray) -> tuple[int, float]:
    """Numbers stored and worst-frame RMS error of x_f ~ A_i [vec(R_jk,f - I) for its bones, 1],
    least squares per Gaussian i over the frames."""
    frames, n, channels = values.shape
    rotations = samples.rig.transforms[:, :, :, :3] - np.eye(3, dtype=np.float32)  # (F, B, 3, 3)
    features = rotations[:, samples.rig.skin.index.astype(np.int64)].reshape(frames, n, -1)  # (F, N, 9 K)
    design = np.concatenate([features, np.ones((frames, n, 1), np.float32)], axis=2).transpose(1, 0, 2)
    targets = values.transpose(1, 0, 2)  # (N, F, C)
    solution = np.linalg.pinv(design.astype(np.float64)) @ targets  # (N, 9 K + 1, C)
    error = (design @ solution - targets).transpose(1, 0, 2)
    return solution.size, worst_rms(error)


def storage_rows(samples, baked) -> list[dict]:
    rows = []
    config = BakeConfig()
    groups = {
        "points": (samples.points, baked.points, config.position_tolerance),
        "log-scales": (samples.log_scales, baked.log_scales, config.log_scale_tolerance),
        "colours": (samples.colors, baked.colors, config.color_tolerance),
    }
    for name, (values, kept, tolerance) in groups.items():
        frames, n, channels = values.shape
        per_frame = values.astype(np.float16).astype(np.float32) - values
        linear_numbers, linear_error = linear_pose_model(samples, values)
        rows += [
            {"group": name, "way": "baked per frame, float16", "bytes": values.size * FLOAT16_BYTES,
             "worst_rms": worst_rms(per_frame), "tolerance": tolerance},
            {"group": name, "way": f"principal components ({kept.rank})",
             "bytes": kept.mean.nbytes + kept.basis.nbytes + kept.coefficients.nbytes,
             "worst_rms": kept.error, "tolerance": tolerance},
            {"group": name, "way": f"linear in its {SKIN_BONES} bones' rotations, float16",
             "bytes": linear_numbers * FLOAT16_BYTES, "worst_rms": linear_error, "tolerance": tolerance},
        ]  # fmt: skip
    return rows


def references(driver, motion, shot: dict, renderer: CPUFrames) -> tuple[np.ndarray, np.ndarray]:
    """The CPU splatter's image of ``shot`` with the page's baked colours, and with the colours of
    the shot's own camera, as uint8."""
    rest = driver.geometry.surface.positions.cpu().numpy()
    framing = frame_points(rest, DEFAULT_FOV_Y, WIDTH / HEIGHT)
    bake_framing = frame_points(rest, DEFAULT_FOV_Y, BAKE_ASPECT)
    pose = motion.pose(shot["frame"])
    follow = floor_shift(driver.root_position(pose), driver.root_position(driver.rest_pose()))
    camera = orbit_camera(
        np.asarray(framing.target) + follow, shot["yaw"], shot.get("pitch", 0.0), framing.distance,
        DEFAULT_FOV_Y, WIDTH, HEIGHT,
    )  # fmt: skip
    identity = driver.avatar.identity_map()
    images = []
    for centre in (front_centre(np.asarray(bake_framing.target) + follow, bake_framing.distance), camera.centre):
        arrays = driver.evaluate(identity, pose, np.asarray(centre, np.float64))
        rgb = renderer.render(arrays, camera, (1.0, 1.0, 1.0))
        images.append(np.round(np.clip(rgb, 0, 1) * 255).astype(np.uint8))
    return images[0], images[1]


def screenshot(page: Path, out: Path) -> None:
    """The page as it opens, UI included, taken by headless Chromium."""
    flags = [f for f in CHROMIUM_FLAGS if f != "--dump-dom"]
    command = [chromium(), *flags, f"--screenshot={out}", f"--window-size={WIDTH},{HEIGHT}", page.as_uri()]
    subprocess.run(command, check=True, capture_output=True, timeout=300, cwd=out.parent)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--avatar", type=Path, default=ROOT / "assets" / "real_avatar.pt")
    parser.add_argument("--motion", default="walk")
    args = parser.parse_args()
    setup_threads()
    if chromium() is None:
        raise SystemExit("chromium is not installed (scripts/setup.sh installs it)")
    load = load_average()
    start = time.perf_counter()
    page = export_web(str(args.avatar), args.motion, str(PAGE))
    export_seconds = time.perf_counter() - start
    driver = AvatarDriver(load_avatar(args.avatar))
    motion = open_motion(args.motion, driver.body, driver.geometry.shape.cpu())
    samples = sample_motion(driver, motion)
    baked = compress(samples)
    storage = storage_rows(samples, baked)
    result = drive(PAGE, {"width": WIDTH, "height": HEIGHT, "shots": SHOTS, "loop": True}, timeout=600)
    renderer = CPUFrames()
    shots = []
    for shot in result["shots"]:
        as_baked, as_viewed = references(driver, motion, shot, renderer)
        shots.append({
            "frame": shot["frame"], "yaw": shot["yaw"], "pitch": shot.get("pitch", 0),
            "psnr_baked_colours": round(psnr(shot["image"], as_baked), 2),
            "psnr_render": round(psnr(shot["image"], as_viewed), 2),
            "max_abs_baked": int(np.abs(shot["image"].astype(int) - as_baked).max()),
        })  # fmt: skip
    frame_ms = np.asarray(result["frameMs"])
    screenshot(PAGE, SCREENSHOT)
    summary = {
        "page_bytes": page.bytes,
        "gaussians": baked.num_gaussians,
        "frames": baked.num_frames,
        "export_s": round(export_seconds, 1),
        "ranks": {"points": baked.points.rank, "log_scales": baked.log_scales.rank, "colors": baked.colors.rank},
        "first_frame_ms": round(result["firstFrameMs"], 1),
        "median_frame_ms": round(float(np.median(frame_ms)), 2),
        "fps_from_median": round(1000 / float(np.median(frame_ms)), 1),
        "p90_frame_ms": round(float(np.percentile(frame_ms, 90)), 2),
        "accumulation": result["accumulation"],
        "size": f"{WIDTH}x{HEIGHT}",
        "load_before": round(load, 2),
        "chromium": subprocess.run([chromium(), "--version"], capture_output=True, text=True).stdout.strip(),
    }
    print_table([summary])
    print_table(storage)
    print_table(shots)
    write_json("bench_web", {"summary": summary, "storage": storage, "shots": shots})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
