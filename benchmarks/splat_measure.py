"""Measurements of the splatter: speed against a naive baseline, scaling, and runtime against error.

Shared by ``benchmarks/bench_splat.py`` and ``pghm bench splat``. The scene is
the default body: N points on the surface of the rest-pose Anny body (1.65 m, standing at
the origin, y up, facing +z), isotropic scales 5-13 mm, seen from 3 m in front.

Times are medians over repeats after a warm-up. Settings of a sweep are timed round-robin
(one call of each per round), so a burst of load on a shared machine hits all alike.
"""

from __future__ import annotations

import json
import math
import os
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import torch
from torch import Tensor

from pghm.io.atomic import atomic_write_bytes, save_figure
from pghm.splat import Camera, SplatSettings, render
from pghm.splat._projection import project, to_camera
from pghm.splat.spec import ALPHA_MAX, ALPHA_MIN, NEAR_PLANE

SCALE_RANGE = (0.005, 0.013)
"""Isotropic standard deviations of the body scene, metres."""

CAMERA_DISTANCE = 3.0
"""Metres from the camera to the body's centre."""

FIELD_OF_VIEW = 35.0
"""Vertical field of view in degrees: the 1.65 m body fills about 90 % of the image height."""

BASELINE_TILE = 64
"""Tile side of the naive baseline, pixels."""

BASELINE_SIGMAS = 3.0
"""The baseline gathers Gaussians whose 3-sigma square meets a tile, as most hand-written splatters do."""


@dataclass(frozen=True)
class BodyScene:
    """N Gaussians on the body surface and a camera in front of it.

    Attributes:
        means: (N, 3) float32 surface points.
        scales: (N,) float32 standard deviations in SCALE_RANGE.
        colors: (N, 3) float32, the surface normal mapped to RGB.
        opacities: (N,) float32 in [0.5, 1].
        camera: 3 m in front of the body, looking at its centre.
    """

    means: Tensor
    scales: Tensor
    colors: Tensor
    opacities: Tensor
    camera: Camera

    def inputs(self, requires_grad: bool = False) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        values = (self.means, self.scales, self.colors, self.opacities)
        return tuple(value.detach().clone().requires_grad_(requires_grad) for value in values)


def body_scene(num_gaussians: int = 10_000, resolution: int = 256, seed: int = 0) -> BodyScene:
    """``num_gaussians`` points of the default body's texel surface, at a ``resolution``^2 camera."""
    from pghm.body import load_body
    from pghm.uv.atlas import build_atlas
    from pghm.uv.maps import texel_surface

    body = load_body()
    rest = body.rest()
    for atlas_resolution in (128, 256, 512):
        surface = texel_surface(body, build_atlas(body, atlas_resolution), rest)
        if surface.positions.shape[0] >= num_gaussians:
            break
    else:
        raise ValueError(f"the body atlas has fewer than {num_gaussians} texels")
    generator = torch.Generator().manual_seed(seed)
    chosen = torch.randperm(surface.positions.shape[0], generator=generator)[:num_gaussians]
    low, high = SCALE_RANGE
    centre = 0.5 * (surface.positions.amin(0) + surface.positions.amax(0))
    eye = centre + torch.tensor([0.0, 0.0, CAMERA_DISTANCE])
    return BodyScene(
        means=surface.positions[chosen].float().contiguous(),
        scales=low + (high - low) * torch.rand(num_gaussians, generator=generator),
        colors=(0.5 + 0.5 * surface.normals[chosen]).clamp(0, 1).float().contiguous(),
        opacities=0.5 + 0.5 * torch.rand(num_gaussians, generator=generator),
        camera=Camera.look_at(eye, centre, (0.0, 1.0, 0.0), FIELD_OF_VIEW, resolution, resolution),
    )


def baseline_render(
    means: Tensor, scales: Tensor, colors: Tensor, opacities: Tensor, camera: Camera, background: Sequence[float]
) -> Tensor:
    """(H, W, 3) rgb the way a CPU user would write a splatter in plain PyTorch.

    Per 64 x 64 tile: gather the Gaussians whose 3-sigma square meets the tile, sort them
    by depth, build the dense (pixels x Gaussians) alpha matrix, transmittance by cumprod,
    colour by a matrix product; autograd does the backward. Same projection and alpha
    rule as the spec, so it draws nearly the same image (it misses the footprint beyond
    3 sigma where a tile was not gathered).
    """
    width, height = camera.width, camera.height
    means_cam = to_camera(means[None], camera.world_to_camera[None])
    projection = project(means_cam, scales[None], camera.intrinsics(), width, height)
    means2d, conics = projection.means2d[0].to(means.dtype), projection.conics[0].to(means.dtype)
    depths = projection.depths[0]
    s_xx, s_xy, s_yy = projection.covariances[0].unbind(-1)
    middle = (s_xx + s_yy) / 2
    lambda_max = middle + torch.sqrt((middle.square() - s_xx * s_yy + s_xy.square()).clamp(min=0))
    radius = BASELINE_SIGMAS * torch.sqrt(lambda_max)
    u, v = projection.means2d[0].detach().unbind(-1)
    background_color = torch.tensor(background, dtype=means.dtype)
    in_front = depths.detach() > NEAR_PLANE
    rows = []
    for y0 in range(0, height, BASELINE_TILE):
        row = []
        for x0 in range(0, width, BASELINE_TILE):
            y1, x1 = min(y0 + BASELINE_TILE, height), min(x0 + BASELINE_TILE, width)
            near = in_front & (u + radius >= x0) & (u - radius <= x1) & (v + radius >= y0) & (v - radius <= y1)
            index = near.nonzero().squeeze(1)
            index = index[torch.argsort(depths.detach()[index], stable=True)]
            ys, xs = torch.meshgrid(torch.arange(y0, y1) + 0.5, torch.arange(x0, x1) + 0.5, indexing="ij")
            dx = xs.reshape(-1, 1) - means2d[index, 0]  # (P, G)
            dy = ys.reshape(-1, 1) - means2d[index, 1]
            a, b, c = conics[index].unbind(-1)
            q = a * dx * dx + 2 * b * dx * dy + c * dy * dy
            alpha = (opacities[index] * torch.exp(-0.5 * q)).clamp(max=ALPHA_MAX)
            alpha = alpha * (alpha >= ALPHA_MIN)
            ones = torch.ones(len(alpha), 1, dtype=alpha.dtype)
            transmittance = torch.cumprod(torch.cat([ones, 1 - alpha], dim=1), dim=1)
            rgb = (alpha * transmittance[:, :-1]) @ colors[index] + transmittance[:, -1:] * background_color
            row.append(rgb.reshape(y1 - y0, x1 - x0, 3))
        rows.append(torch.cat(row, dim=1))
    return torch.cat(rows, dim=0)


Renderer = Callable[[Tensor, Tensor, Tensor, Tensor], Tensor]


def renderers(scene: BodyScene) -> dict[str, Renderer]:
    """name -> function of (means, scales, colors, opacities) returning rgb, for the speed table."""
    background = (1.0, 1.0, 1.0)
    return {
        "native": lambda *g: render(*g, scene.camera, background, backend="native").rgb,
        "torch twin": lambda *g: render(*g, scene.camera, background, backend="torch").rgb,
        "baseline": lambda *g: baseline_render(*g, scene.camera, background),
    }


def _cotangent(shape: torch.Size) -> Tensor:
    return torch.randn(shape, generator=torch.Generator().manual_seed(0))


def timed_calls(scene: BodyScene, rgb_of: Renderer) -> dict[str, Callable[[], None]]:
    """The two timed operations: a forward, and a forward plus backward of a fixed random cotangent."""
    plain = scene.inputs()
    trainable = scene.inputs(requires_grad=True)
    cotangent = _cotangent((scene.camera.height, scene.camera.width, 3))

    def forward() -> None:
        with torch.no_grad():
            rgb_of(*plain)

    def forward_backward() -> None:
        torch.autograd.grad(rgb_of(*trainable), trainable, cotangent)

    return {"forward": forward, "forward_backward": forward_backward}


def median_times(calls: dict[str, Callable[[], None]], repeats: int, warmup: int = 1) -> dict[str, float]:
    """Median milliseconds of each call, timed round-robin after ``warmup`` rounds."""
    samples: dict[str, list[float]] = {name: [] for name in calls}
    for round_index in range(warmup + repeats):
        for name, call in calls.items():
            start = time.perf_counter()
            call()
            if round_index >= warmup:
                samples[name].append((time.perf_counter() - start) * 1e3)
    return {name: statistics.median(values) for name, values in samples.items()}


def speed_table(
    cases: Sequence[tuple[int, int]], repeats: int, baseline_repeats: int, include_baseline: bool = True
) -> list[dict]:
    """Forward and forward+backward medians of each renderer, for (N, resolution) cases."""
    rows = []
    for num_gaussians, resolution in cases:
        scene = body_scene(num_gaussians, resolution)
        for name, rgb_of in renderers(scene).items():
            if name == "baseline" and not include_baseline:
                continue
            calls = timed_calls(scene, rgb_of)
            times = median_times(calls, baseline_repeats if name != "native" else repeats)
            rows.append(
                {
                    "renderer": name,
                    "gaussians": num_gaussians,
                    "resolution": resolution,
                    "forward_ms": times["forward"],
                    "forward_backward_ms": times["forward_backward"],
                }
            )
    return rows


def scaling_table(gaussian_counts: Sequence[int], resolutions: Sequence[int], repeats: int) -> list[dict]:
    """Native forward and forward+backward medians against N (at 256^2) and against resolution (at 10k)."""
    rows = []
    cases = [(n, 256) for n in gaussian_counts] + [(10_000, r) for r in resolutions if r != 256]
    for num_gaussians, resolution in cases:
        scene = body_scene(num_gaussians, resolution)
        times = median_times(timed_calls(scene, renderers(scene)["native"]), repeats)
        rows.append(
            {
                "gaussians": num_gaussians,
                "resolution": resolution,
                "forward_ms": times["forward"],
                "forward_backward_ms": times["forward_backward"],
            }
        )
    return rows


SWEEP: dict[str, SplatSettings] = {
    "exact": SplatSettings(),
    "cutoff 2/255": SplatSettings(alpha_cutoff=2 / 255),
    "cutoff 4/255": SplatSettings(alpha_cutoff=4 / 255),
    "cutoff 8/255": SplatSettings(alpha_cutoff=8 / 255),
    "cutoff 16/255": SplatSettings(alpha_cutoff=16 / 255),
    "stop T<1e-4": SplatSettings(transmittance_stop=1e-4),
    "stop T<1e-3": SplatSettings(transmittance_stop=1e-3),
    "stop T<1e-2": SplatSettings(transmittance_stop=1e-2),
    "3 sigma": SplatSettings(footprint_sigmas=3.0),
    "2.5 sigma": SplatSettings(footprint_sigmas=2.5),
    "2 sigma": SplatSettings(footprint_sigmas=2.0),
    "float16 depth": SplatSettings(half_precision_depth=True),
    "3DGS (3 sigma, T<1e-4)": SplatSettings(footprint_sigmas=3.0, transmittance_stop=1e-4),
    "cutoff 4/255 + T<1e-3": SplatSettings(alpha_cutoff=4 / 255, transmittance_stop=1e-3),
}
"""The approximations ``pghm bench splat`` measures, by name."""


def psnr(error_mse: float) -> float:
    """Peak signal-to-noise ratio in dB of images in [0, 1] (inf when identical)."""
    return math.inf if error_mse == 0 else -10.0 * math.log10(error_mse)


def sweep(scene: BodyScene, settings: dict[str, SplatSettings], repeats: int) -> list[dict]:
    """Each setting's median forward and forward+backward time and its image error against the exact render."""
    exact = render(*scene.inputs(), scene.camera, backend="native").rgb
    calls, errors = {}, {}
    for name, setting in settings.items():

        def rgb_of(*gaussians, setting=setting):
            return render(*gaussians, scene.camera, backend="native", settings=setting).rgb

        rgb = rgb_of(*scene.inputs())
        difference = (rgb - exact).double()
        errors[name] = {"max_abs": float(difference.abs().max()), "psnr": psnr(float(difference.square().mean()))}
        for operation, call in timed_calls(scene, rgb_of).items():
            calls[(name, operation)] = call
    times = median_times(calls, repeats)
    return [
        {
            "setting": name,
            **errors[name],
            "forward_ms": times[(name, "forward")],
            "forward_backward_ms": times[(name, "forward_backward")],
            "settings": asdict(setting),
        }
        for name, setting in settings.items()
    ]


def pareto_front(rows: list[dict], time_key: str = "forward_backward_ms", error_key: str = "max_abs") -> list[str]:
    """Settings no other setting beats on both time and error (ties count as not beaten)."""
    front = []
    for row in rows:
        dominated = any(
            other[time_key] <= row[time_key]
            and other[error_key] <= row[error_key]
            and (other[time_key] < row[time_key] or other[error_key] < row[error_key])
            for other in rows
        )
        if not dominated:
            front.append(row["setting"])
    return front


def format_table(rows: list[dict], columns: Sequence[str]) -> str:
    """A plain-text table of ``rows``: floats to 3 significant digits."""

    def cell(value: object) -> str:
        if isinstance(value, float):
            return "inf" if math.isinf(value) else f"{value:.3g}"
        return str(value)

    cells = [[cell(row.get(column, "")) for column in columns] for row in rows]
    widths = [max(len(column), *(len(line[i]) for line in cells)) for i, column in enumerate(columns)]
    lines = ["  ".join(column.ljust(width) for column, width in zip(columns, widths))]
    lines.append("  ".join("-" * width for width in widths))
    lines += ["  ".join(value.ljust(width) for value, width in zip(line, widths)) for line in cells]
    return "\n".join(lines)


def machine() -> dict:
    """What the numbers were measured on, and how busy the machine was (other jobs slow medians)."""
    info = {
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
        "cpus": os.cpu_count(),
        "load_average_1min": os.getloadavg()[0],
    }
    pressure = Path("/proc/pressure/cpu")
    if pressure.exists():
        info["cpu_pressure"] = pressure.read_text().splitlines()[0]
    return info


def write_json(path: Path, payload: dict) -> None:
    atomic_write_bytes(path, json.dumps({"machine": machine(), **payload}, indent=2, default=str).encode())


def plot_pareto(rows: list[dict], front: Sequence[str], path: Path) -> None:
    """Forward+backward time against max abs error, the Pareto frontier joined."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axis = plt.subplots(figsize=(7.5, 5))
    floor = 1e-7  # the exact setting has zero error; draw it on the log axis's floor
    for index, row in enumerate(sorted(rows, key=lambda r: (r["max_abs"], r["forward_backward_ms"]))):
        on_front = row["setting"] in front
        error = max(row["max_abs"], floor)
        axis.scatter(row["forward_backward_ms"], error, color="C3" if on_front else "C0", zorder=3)
        # Alternate labels above and below: settings with equal error sit side by side.
        axis.annotate(
            row["setting"],
            (row["forward_backward_ms"], error),
            fontsize=7,
            xytext=(4, 4 if index % 2 == 0 else -10),
            textcoords="offset points",
        )
    frontier = sorted((r for r in rows if r["setting"] in front), key=lambda r: r["forward_backward_ms"])
    axis.plot(
        [r["forward_backward_ms"] for r in frontier], [max(r["max_abs"], floor) for r in frontier], color="C3", lw=1
    )
    axis.set_yscale("log")
    axis.set_xlabel("forward + backward, median ms (2 threads)")
    axis.set_ylabel(f"max abs rgb error vs exact (exact drawn at {floor:g})")
    axis.set_title("pghm.splat approximations: runtime against error (red: Pareto frontier)")
    axis.grid(True, which="both", alpha=0.3)
    figure.tight_layout()
    save_figure(figure, path, dpi=110)
    plt.close(figure)


def plot_scaling(rows: list[dict], path: Path) -> None:
    """Log-log time against N (at 256^2) and against pixel count (at 10k Gaussians)."""
    import matplotlib
    import matplotlib.ticker

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(1, 2, figsize=(10, 4))
    by_count = sorted((r for r in rows if r["resolution"] == 256), key=lambda r: r["gaussians"])
    by_size = sorted((r for r in rows if r["gaussians"] == 10_000), key=lambda r: r["resolution"])
    for axis, series, key, tick, label in (
        (
            axes[0],
            by_count,
            lambda r: r["gaussians"],
            lambda r: f"{r['gaussians'] / 1000:g}k",
            "Gaussians N (256 x 256)",
        ),
        (
            axes[1],
            by_size,
            lambda r: r["resolution"] ** 2,
            lambda r: f"{r['resolution']}^2",
            "pixels H W (10,000 Gaussians)",
        ),
    ):
        xs = [key(r) for r in series]
        for column, name in (("forward_ms", "forward"), ("forward_backward_ms", "forward + backward")):
            axis.plot(xs, [r[column] for r in series], marker="o", label=name)
        reference = [series[0]["forward_backward_ms"] * x / xs[0] for x in xs]
        axis.plot(xs, reference, color="grey", ls="--", lw=1, label="linear")
        axis.set_xscale("log")
        axis.set_yscale("log")
        axis.set_xticks(xs, [tick(r) for r in series])
        axis.xaxis.set_minor_locator(matplotlib.ticker.NullLocator())
        axis.set_xlabel(label)
        axis.set_ylabel("median ms (2 threads)")
        axis.grid(True, which="both", alpha=0.3)
        axis.legend()
    figure.suptitle("pghm.splat native: time against scene size")
    figure.tight_layout()
    save_figure(figure, path, dpi=110)
    plt.close(figure)


def run_sweep(
    num_gaussians: int = 10_000,
    resolution: int = 256,
    repeats: int = 15,
    output: Path | None = None,
    plot: Path | None = None,
) -> tuple[list[dict], list[str]]:
    """The approximation sweep on the body scene: rows, Pareto front; JSON and PNG when paths are given."""
    scene = body_scene(num_gaussians, resolution)
    rows = sweep(scene, SWEEP, repeats)
    front = pareto_front(rows)
    if output is not None:
        write_json(
            output,
            {
                "gaussians": num_gaussians,
                "resolution": resolution,
                "repeats": repeats,
                "rows": rows,
                "pareto_front": front,
            },
        )
    if plot is not None:
        plot_pareto(rows, front, plot)
    return rows, front
