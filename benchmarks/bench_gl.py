"""GL sprite renderer: depth sort (CPU vs GPU), orbit frame time, upload cost.

Scene: Gaussians on the canonical body surface (UV texel points, 1.65 m tall, y up,
facing +z), scales 5-13 mm, opacities 0.6-1. Cameras orbit the body at 2.5 m, 1280 x 720,
the body filling ~85% of the height. Also the accuracy against the CPU
splatter on that scene. Prints tables and writes benchmarks/results/bench_gl.json.

    .venv/bin/python benchmarks/bench_gl.py [--frames 60] [--repeats 30] [--views 8]
    .venv/bin/python benchmarks/bench_gl.py --png docs/gl_body.png   # the preview in docs/gl.md
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import moderngl
import numpy as np
import torch

from pghm.body import load_body
from pghm.gl import SpriteRenderer, driver_info, headless_context
from pghm.gl.resources import TEXTURE_WIDTH, float_texture, texture_rows
from pghm.gl.sort import BitonicSorter, depth_order, view_depths
from pghm.splat import Camera, render
from pghm.uv.atlas import build_atlas
from pghm.uv.maps import texel_surface

RESULTS = Path(__file__).parent / "results" / "bench_gl.json"
WIDTH, HEIGHT = 1280, 720
ORBIT_RADIUS = 2.5
SORT_SIZES = (10_000, 30_000, 100_000)
SEED = 0


def orbit_camera(angle: float, render_scale: float = 1.0) -> Camera:
    """Camera on a circle of ORBIT_RADIUS around the y axis, looking at the origin (OpenCV axes).

    ``render_scale`` < 1 gives the same view at a fraction of WIDTH x HEIGHT.
    """
    eye = ORBIT_RADIUS * np.array([np.sin(angle), 0.0, np.cos(angle)])
    z = -eye / np.linalg.norm(eye)
    x = np.cross(z, [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    w2c = np.eye(4)
    w2c[:3, :3] = np.stack([x, np.cross(z, x), z])
    w2c[:3, 3] = -w2c[:3, :3] @ eye
    width, height = round(WIDTH * render_scale), round(HEIGHT * render_scale)
    focal = 0.85 * height * ORBIT_RADIUS / 1.65
    return Camera(focal, focal, width / 2, height / 2, width, height, torch.tensor(w2c, dtype=torch.float32))


def body_scene(count: int) -> tuple[np.ndarray, ...]:
    """(means, scales, colors, opacities) of ``count`` Gaussians on the body surface."""
    body = load_body()
    atlas = build_atlas(body, 128 if count <= 11_000 else 512)
    surface = texel_surface(body, atlas, body.rest())
    rng = np.random.default_rng(SEED)
    pick = rng.choice(surface.positions.shape[0], count, replace=False)
    means = surface.positions.numpy()[pick]
    colors = 0.5 + 0.5 * surface.normals.numpy()[pick]  # normals as colours: shows the shape
    scales = rng.uniform(0.005, 0.013, count)
    opacities = rng.uniform(0.6, 1.0, count)
    return tuple(a.astype(np.float32) for a in (means, scales, colors, opacities))


def summary(samples: list[float]) -> dict[str, float]:
    """Minimum, median and 90th percentile of millisecond samples (the minimum is the least
    disturbed by other processes on a shared 2-core machine)."""
    return {
        "min_ms": float(np.min(samples)),
        "median_ms": float(np.median(samples)),
        "p90_ms": float(np.percentile(samples, 90)),
    }


def timed(fn, repeats: int) -> dict[str, float]:
    """:func:`summary` of ``fn()``'s wall time after one warm-up call."""
    fn()
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        samples.append((time.perf_counter() - start) * 1e3)
    return summary(samples)


def bench_sort(ctx: moderngl.Context, means: np.ndarray, repeats: int) -> dict[str, dict[str, float]]:
    """Each way of computing the front-to-back order of ``means`` from scratch."""
    w2c = orbit_camera(0.3).world_to_camera.numpy()
    depths = view_depths(means, w2c)
    depths_torch = torch.from_numpy(depths)
    texture = float_texture(ctx, texture_rows(len(means)), 4)
    staged = np.zeros((texture.height * TEXTURE_WIDTH, 4), np.float32)
    staged[: len(means), :3] = means
    texture.write(staged)
    sorter = BitonicSorter(ctx)

    def gpu() -> None:
        sorter.sort(texture, len(means), w2c)
        ctx.finish()

    try:
        return {
            "cpu_depth_order (default)": timed(lambda: depth_order(view_depths(means, w2c)), repeats),
            "numpy_argsort_stable": timed(lambda: np.argsort(view_depths(means, w2c), kind="stable"), repeats),
            "torch_sort_stable": timed(lambda: torch.sort(depths_torch, stable=True), repeats),
            "gpu_bitonic": timed(gpu, max(3, repeats // 10)),
        }
    finally:
        sorter.release()
        texture.release()


def bench_frames(
    ctx: moderngl.Context, renderer: SpriteRenderer, frames: int, render_scale: float = 1.0
) -> dict[str, dict[str, float]]:
    """Orbit frames (camera moves, Gaussians fixed) drawn into a WIDTH x HEIGHT RGBA8 framebuffer
    like a window's, accumulated at ``render_scale`` times its size."""
    screen = ctx.simple_framebuffer((WIDTH, HEIGHT), components=4)
    angles = np.linspace(0, 2 * np.pi, frames, endpoint=False)
    for angle in angles[:3]:  # warm-up: shader JIT and first upload
        renderer.draw(orbit_camera(angle, render_scale), target=screen)
    stages: dict[str, list[float]] = {"sort_ms": [], "upload_ms": [], "draw_ms": [], "total_ms": []}
    for angle in angles:
        start = time.perf_counter()
        timings = renderer.draw(orbit_camera(angle, render_scale), background=(1.0, 1.0, 1.0), target=screen)
        stages["total_ms"].append((time.perf_counter() - start) * 1e3)
        for name in ("sort_ms", "upload_ms", "draw_ms"):
            stages[name].append(getattr(timings, name))
    screen.release()
    return {name: summary(samples) for name, samples in stages.items()}


def bench_upload(ctx: moderngl.Context, renderer: SpriteRenderer, scene: tuple[np.ndarray, ...], repeats: int) -> dict:
    """set_gaussians (validation and packing) and the next frame's texture writes (and order)."""
    camera = orbit_camera(0.0)
    pack, upload = [], []
    for _ in range(repeats):
        start = time.perf_counter()
        renderer.set_gaussians(*scene)
        pack.append((time.perf_counter() - start) * 1e3)
        renderer.render(camera)
        upload.append(renderer.timings.upload_ms)
    return {"set_gaussians_ms": float(np.median(pack)), "texture_upload_ms": float(np.median(upload))}


def bench_accuracy(renderer: SpriteRenderer, scene: tuple[np.ndarray, ...], views: int) -> dict[str, dict]:
    """GL image vs pghm.splat.render on orbit views of the body: max / mean abs error of rgb and alpha."""
    tensors = [torch.from_numpy(a) for a in scene]
    renderer.set_gaussians(*scene)
    results = {}
    for render_scale in (0.5, 1.0):
        errors = []
        for angle in np.linspace(0, 2 * np.pi, views, endpoint=False):
            camera = orbit_camera(angle, render_scale)
            expected = render(*tensors, camera, background=(1.0, 1.0, 1.0))
            image = renderer.render(camera, background=(1.0, 1.0, 1.0))
            rgb = np.abs(image.rgb - expected.rgb.numpy())
            alpha = np.abs(image.alpha - expected.alpha.numpy())
            errors.append((rgb.max(), rgb.mean(), alpha.max(), alpha.mean(), int((rgb.max(-1) > 2e-3).sum())))
        e = np.array(errors)
        cam = orbit_camera(0.0, render_scale)
        results[f"{cam.width}x{cam.height}"] = {
            "views": views,
            "rgb_max": float(e[:, 0].max()),
            "rgb_mean": float(e[:, 1].mean()),
            "alpha_max": float(e[:, 2].max()),
            "alpha_mean": float(e[:, 3].mean()),
            "pixels_over_2e-3_per_view": float(e[:, 4].mean()),
        }
    return results


def save_preview(renderer: SpriteRenderer, scene: tuple[np.ndarray, ...], path: Path) -> None:
    """Front and three-quarter views of the body scene through GL, side by side, as an 8-bit PNG."""
    from PIL import Image

    renderer.set_gaussians(*scene)
    views = []
    for angle in (0.0, 0.8):
        image = renderer.render(orbit_camera(angle), background=(1.0, 1.0, 1.0)).rgb
        views.append(image[:, WIDTH // 4 : 3 * WIDTH // 4])  # the body fills the middle half
    pixels = np.clip(np.concatenate(views, axis=1), 0.0, 1.0)
    Image.fromarray((pixels * 255 + 0.5).astype(np.uint8)).save(path)
    print(f"wrote {path}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=60, help="orbit frames per measurement")
    parser.add_argument("--repeats", type=int, default=30, help="repetitions of each sort")
    parser.add_argument("--views", type=int, default=8, help="orbit views per accuracy measurement")
    parser.add_argument("--png", type=Path, help="only write a preview of the body scene to this PNG")
    args = parser.parse_args()
    torch.set_num_threads(2)

    ctx = headless_context()
    driver = driver_info(ctx)
    results: dict = {
        "driver": str(driver),
        "machine": platform.processor() or platform.machine(),
        "cpus": os.cpu_count(),
        "load_average_at_start": os.getloadavg()[0],
        "sort": {},
        "frames": {},
        "upload": {},
    }
    print(f"driver: {driver}; load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs")
    if args.png:
        with SpriteRenderer(ctx) as renderer:
            save_preview(renderer, body_scene(10_000), args.png)
        ctx.release()
        return

    scenes = {count: body_scene(count) for count in SORT_SIZES}
    print("\nsort, from scratch (ms, min / median / p90)")
    for count, scene in scenes.items():
        results["sort"][count] = bench_sort(ctx, scene[0], args.repeats)
        for name, t in results["sort"][count].items():
            print(f"  N={count:>7,}  {name:<28} {t['min_ms']:8.2f} / {t['median_ms']:8.2f} / {t['p90_ms']:8.2f}")

    print(f"\norbit frames into {WIDTH} x {HEIGHT} (ms, min / median / p90)")
    for count, render_scale in ((10_000, 1.0), (10_000, 0.5), (100_000, 1.0)):
        with SpriteRenderer(ctx) as renderer:
            renderer.set_gaussians(*scenes[count])
            label = f"{count} @ {render_scale:g}"
            results["frames"][label] = bench_frames(ctx, renderer, args.frames, render_scale)
            if render_scale == 1.0:
                results["upload"][count] = bench_upload(ctx, renderer, scenes[count], 5)
        for name, t in results["frames"][label].items():
            print(
                f"  N={count:>7,} render scale {render_scale:g}  {name:<10} "
                f"{t['min_ms']:8.2f} / {t['median_ms']:8.2f} / {t['p90_ms']:8.2f}"
            )

    print("\nupload when the Gaussians change (ms, median)")
    for count, t in results["upload"].items():
        print(
            f"  N={count:>7,}  set_gaussians {t['set_gaussians_ms']:6.2f}"
            f"   texture writes {t['texture_upload_ms']:6.2f}"
        )

    print("\naccuracy vs pghm.splat.render, body scene N=10,000, white background")
    with SpriteRenderer(ctx) as renderer:
        results["accuracy"] = bench_accuracy(renderer, scenes[10_000], args.views)
    for size, t in results["accuracy"].items():
        print(
            f"  {size:>9}  rgb max {t['rgb_max']:.1e} mean {t['rgb_mean']:.1e}   alpha max {t['alpha_max']:.1e}"
            f" mean {t['alpha_mean']:.1e}   pixels > 2e-3 per view {t['pixels_over_2e-3_per_view']:.2f}"
        )

    ctx.release()
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(results, indent=2))
    print(f"\nwrote {RESULTS}")


if __name__ == "__main__":
    main()
