"""How far gsplat's rule is from the spec, measured on the CPU (no GPU needed).

The reference of tests/test_splat_gsplat.py (gsplat's torch projection and tile binning fed
by pghm's argument mapping, composited by gsplat's forward-kernel rule, in float64) against the
CPU splatter's float64 image: on the 24 oracle scenes of tests/test_splat.py (as they are, with
every opacity 1, and with their principal point off centre) and on the shipped avatar (rest
pose, front, 256 x 256). Each difference alone and all together; rgb over all pixels.

    python benchmarks/bench_gsplat_reference.py

Prints the table of docs/splat.md, "GPU (gsplat)", and writes
benchmarks/results/bench_gsplat_reference.json. About two minutes on 2 cores (the avatar's
binning is a Python loop over its 11k Gaussians).
"""

from __future__ import annotations

import dataclasses
import math
import sys

import numpy as np
import torch
from common import ROOT, print_table, setup_threads, write_json

sys.path.insert(0, str(ROOT / "tests"))
from test_splat import SCENE_SIZES, Scene, random_scene  # noqa: E402
from test_splat_gsplat import centred, composite, project_and_bin  # noqa: E402

from pghm.io.avatar import load_avatar  # noqa: E402
from pghm.render.driver import AvatarDriver  # noqa: E402
from pghm.render.framing import DEFAULT_FOV_Y, frame_points, orbit_camera  # noqa: E402
from pghm.splat import Camera  # noqa: E402
from pghm.splat import gsplat_backend as backend  # noqa: E402
from pghm.splat.spec import ALPHA_MAX  # noqa: E402

AVATAR = ROOT / "assets" / "avatar.pt"
AVATAR_SIDE = 256
RULES = {
    "gsplat's rule": (backend.GSPLAT_ALPHA_MAX, backend.GSPLAT_STOP),
    "the stop alone": (ALPHA_MAX, backend.GSPLAT_STOP),
    "the 0.999 clamp alone": (backend.GSPLAT_ALPHA_MAX, 0.0),
    "the spec's rule (float32 depth order, frustum clamp)": (ALPHA_MAX, 0.0),
}


def off_centre(scene: Scene) -> Scene:
    """``centred(scene)`` with the scene's own principal point back (3 px off centre at most)."""
    camera, original = centred(scene).camera, scene.camera
    moved = Camera(camera.fx, camera.fy, original.cx, original.cy, camera.width, camera.height, camera.world_to_camera)
    return dataclasses.replace(centred(scene), camera=moved)


def opaque(scene: Scene) -> Scene:
    scene = centred(scene)
    return dataclasses.replace(scene, opacities=torch.ones_like(scene.opacities))


def avatar_scene() -> Scene:
    """The shipped avatar's dynamic Gaussians in the rest pose, seen from the front."""
    avatar = load_avatar(AVATAR)
    driver = AvatarDriver(avatar)
    framing = frame_points(driver.geometry.surface.positions.numpy(), DEFAULT_FOV_Y, 1.0)
    target = np.asarray(framing.target, dtype=np.float64)
    camera = orbit_camera(target, 0.0, 0.0, framing.distance, DEFAULT_FOV_Y, AVATAR_SIDE, AVATAR_SIDE)
    arrays = driver.evaluate(avatar.identity_map(), driver.rest_pose(), camera.centre)
    values = (torch.from_numpy(a) for a in (arrays.means, arrays.scales, arrays.colors, arrays.opacities))
    return centred(Scene(*values, camera, (1.0, 1.0, 1.0)))


def errors(pairs: list[tuple[torch.Tensor, torch.Tensor]]) -> dict:
    difference = torch.cat([(got - want).abs().flatten() for got, want in pairs])
    mse = float(difference.square().mean())
    return {
        "psnr": round(-10 * math.log10(mse), 1) if mse > 0 else math.inf,
        "mean_abs": float(f"{float(difference.mean()):.2g}"),
        "max_abs": float(f"{float(difference.max()):.2g}"),
    }


def rows_for(name: str, scenes: list[Scene], rules: dict) -> list[dict]:
    binned = [project_and_bin(scene) for scene in scenes]
    exact = [scene.render("torch").rgb for scene in scenes]
    rows = []
    for rule, (alpha_max, stop) in rules.items():
        pairs = [(composite(b, alpha_max, stop)["rgb"], want) for b, want in zip(binned, exact)]
        rows.append({"scenes": name, "difference": rule, **errors(pairs)})
    return rows


def main() -> None:
    setup_threads()
    oracle = [random_scene(seed, count) for seed, count in enumerate(SCENE_SIZES)]
    spec_rule = {k: v for k, v in RULES.items() if k.startswith("the spec's")}
    rows = [
        *rows_for("oracle, principal point centred", [centred(s) for s in oracle], RULES),
        *rows_for("oracle, every opacity 1", [opaque(s) for s in oracle], RULES),
        *rows_for("oracle, principal point off centre", [off_centre(s) for s in oracle], spec_rule),
        *rows_for(f"shipped avatar, rest, front, {AVATAR_SIDE} px", [avatar_scene()], RULES),
    ]
    print_table(rows)
    write_json("bench_gsplat_reference", {"rows": rows})


if __name__ == "__main__":
    main()
