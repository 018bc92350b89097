"""Re-derive the MediaPipe landmark -> Anny correspondence of :mod:`pghm.capture.landmarks`.

Renders synthetic people (several identities, all motion kinds, a ring of views, white
background) with the project's generator, runs MediaPipe Pose (``model_complexity=1``,
static images) on every image, and for each body landmark finds the fixed convex
combination of a few rest vertices (skinned with the body) whose projection best explains
the detections over all images (softmax weights over the nearest vertices to the anchor
joint and to the best single vertex, Huber loss on pixels, then the largest weights kept
and refitted). Prints per landmark the median pixel residual of the anchor joint (what a
fit would use without the correspondence), of the best single vertex and of the fitted
point, and the constants to paste into ``pghm/capture/landmarks.py``.

    python benchmarks/derive_landmarks.py --work /tmp/landmarks [--identities 12]
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np
import torch
from common import print_table, setup_threads, write_json

from pghm.body import BodyPose, load_body
from pghm.capture.landmarks import LANDMARK_ANCHORS, LANDMARK_NAMES, landmark_points
from pghm.subject import Subject, image_name
from pghm.synth.config import SynthConfig
from pghm.synth.generate import generate

VISIBLE = 0.5
"""MediaPipe visibility above which a detection is used."""

CANDIDATES = 48
"""Nearest rest vertices (to the anchor joint, and to the best single vertex) offered to the fit."""

KEPT = 8
"""Vertices kept in each landmark's combination."""

HUBER_PX = 4.0
"""Pixels where the fit's loss turns from quadratic to linear (MediaPipe's outliers)."""

STEPS = 600


def detect(images: list[Path]) -> tuple[np.ndarray, np.ndarray]:
    """(N, 33, 2) pixel landmarks and (N, 33) visibility (zero where no person was found)."""
    import mediapipe as mp
    from PIL import Image

    points = np.zeros((len(images), len(LANDMARK_NAMES), 2), np.float32)
    visibility = np.zeros((len(images), len(LANDMARK_NAMES)), np.float32)
    with mp.solutions.pose.Pose(static_image_mode=True, model_complexity=1) as pose:
        for n, path in enumerate(images):
            rgb = np.asarray(Image.open(path).convert("RGB"))
            result = pose.process(rgb)
            if result.pose_landmarks is None:
                continue
            for k, mark in enumerate(result.pose_landmarks.landmark):
                points[n, k] = (mark.x * rgb.shape[1], mark.y * rgb.shape[0])
                visibility[n, k] = mark.visibility
    return points, visibility


def collect(root: Path) -> dict[str, torch.Tensor]:
    """Every image's detections, posed vertices and joints, camera, and person height."""
    body = load_body("anny")
    out: dict[str, list] = {k: [] for k in ("points", "visibility", "vertices", "joints", "K", "E", "height")}
    for folder in sorted(p for p in root.iterdir() if p.is_dir()):
        a = Subject.open(folder).arrays
        cache = root / f"detections_{folder.name}.npz"
        if not cache.exists():
            images = [folder / "images" / image_name(i) for i in range(len(a))]
            np.savez(cache, *detect(images))
        points, visibility = np.load(cache).values()
        rest = body.rest(torch.as_tensor(a.shape, dtype=torch.float32))
        pose = BodyPose(torch.as_tensor(a.rotations_true), torch.as_tensor(a.translation_true))
        transforms = body.bone_transforms(pose, rest.joints)
        vertices = body.posed_vertices(pose, rest)
        joints = (transforms[..., :3, :3] @ rest.joints[None, :, :, None])[..., 0] + transforms[..., :3, 3]
        height = float(rest.vertices[:, 1].max() - rest.vertices[:, 1].min())
        for key, value in (
            ("points", points),
            ("visibility", visibility),
            ("vertices", vertices.numpy()),
            ("joints", joints.numpy()),
            ("K", a.K),
            ("E", a.world_to_camera),
            ("height", np.full(len(a), height * a.K[:, 0, 0] / a.world_to_camera[:, 2, 3])),
        ):
            out[key].append(np.asarray(value, np.float32))
    return {k: torch.from_numpy(np.concatenate(v)) for k, v in out.items()}


def project(points: torch.Tensor, K: torch.Tensor, E: torch.Tensor) -> torch.Tensor:  # noqa: N803
    """(N, P, 2) pixels of world points (N, P, 3) through (N, 3, 3) K and (N, 4, 4) world_to_camera."""
    cam = points @ E[:, :3, :3].transpose(-1, -2) + E[:, None, :3, 3]
    return cam[..., :2] / cam[..., 2:] * K[:, None, [0, 1], [0, 1]] + K[:, None, :2, 2]


def fit_combination(
    data: dict[str, torch.Tensor],
    landmark: int,
    candidates: torch.Tensor,
    valid: torch.Tensor,
    start: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Convex weights over ``candidates`` minimising the Huber pixel error of landmark ``landmark``.

    ``start``: initial weights (uniform when None).
    """
    posed = data["vertices"][valid][:, candidates]  # (N, C, 3)
    target = data["points"][valid, landmark]
    K, E = data["K"][valid], data["E"][valid]  # noqa: N806
    logits = (torch.zeros(len(candidates)) if start is None else start.clamp_min(1e-6).log()).requires_grad_(True)
    optimiser = torch.optim.Adam([logits], lr=0.05)
    for _ in range(STEPS):
        weights = torch.softmax(logits, 0)
        pixels = project((weights[None, :, None] * posed).sum(1, keepdim=True), K, E)[:, 0]
        loss = torch.nn.functional.huber_loss(pixels, target, delta=HUBER_PX)
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    return candidates, torch.softmax(logits, 0).detach()


def mirror_map(vertices: torch.Tensor) -> torch.Tensor:
    """(V,) index of each rest vertex's mirror image across x = 0 (Anny is symmetric to 0.5 mm)."""
    return torch.cdist(vertices * torch.tensor([-1.0, 1.0, 1.0]), vertices).argmin(1)


def partner(landmark: int) -> int | None:
    """The other side's landmark (left_hip <-> right_hip), None for the nose."""
    name = LANDMARK_NAMES[landmark]
    for a, b in (("left_", "right_"), ("right_", "left_")):
        if name.startswith(a):
            return LANDMARK_NAMES.index(b + name[len(a) :])
    return None


def landmark_residual(data: dict[str, torch.Tensor], landmark: int, vertices: list[int], weights: list[float]) -> float:
    """Median pixel residual of the combination (vertices, weights) for ``landmark``."""
    valid = data["visibility"][:, landmark] > VISIBLE
    point = (torch.tensor(weights)[None, :, None] * data["vertices"][valid][:, vertices]).sum(1, keepdim=True)
    return residual(project(point, data["K"][valid], data["E"][valid])[:, 0], data["points"][valid, landmark])


def symmetrise(data: dict[str, torch.Tensor], constants: dict, mirror: torch.Tensor) -> dict:
    """Each side's combination, or the other side's mirrored when that explains this side better.

    The fits are local (softmax over nearby vertices) and one side can settle in a worse
    optimum (the right hip: 8.3 px, the left hip mirrored: 5.7 px).
    """
    out = dict(constants)
    for landmark, (vertices, weights) in constants.items():
        other = partner(landmark)
        if other not in constants:
            continue
        mirrored = mirror[constants[other][0]].tolist()
        own = landmark_residual(data, landmark, vertices, weights)
        if landmark_residual(data, landmark, mirrored, constants[other][1]) < own:
            out[landmark] = (mirrored, constants[other][1])
    return out


def residual(pixels: torch.Tensor, target: torch.Tensor) -> float:
    return float((pixels - target).norm(dim=-1).median())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True, help="folder for the rendered images (reused)")
    parser.add_argument("--identities", type=int, default=12)
    parser.add_argument("--seed", type=int, default=7)
    args = parser.parse_args()
    setup_threads(1)  # small tensors: a second thread costs more in synchronisation than it gains
    config = SynthConfig(
        identities=args.identities, views=6, frames=8, test_frames=1, width=512, height=512, texture_size=256
    )
    if not (args.work / "meta.json").exists():
        generate(config.validate(), args.seed, args.work, workers=1, progress=False)
    data = collect(args.work)
    body = load_body("anny")
    rest = body.rest()
    rows, constants = [], {}
    for landmark, anchor in LANDMARK_ANCHORS.items():
        valid = data["visibility"][:, landmark] > VISIBLE
        target = data["points"][valid, landmark]
        K, E = data["K"][valid], data["E"][valid]  # noqa: N806
        joint = body.joint_map[anchor]
        joint_px = project(data["joints"][valid][:, joint : joint + 1], K, E)[:, 0]
        all_px = project(data["vertices"][valid], K, E)  # (N, V, 2)
        best = int((all_px - target[:, None]).norm(dim=-1).median(0).values.argmin())
        near_joint = (rest.vertices - rest.joints[joint]).norm(dim=-1).argsort()[:CANDIDATES]
        near_best = (rest.vertices - rest.vertices[best]).norm(dim=-1).argsort()[:CANDIDATES]
        candidates, weights = fit_combination(data, landmark, torch.unique(torch.cat([near_joint, near_best])), valid)
        top = weights.argsort(descending=True)[:KEPT]
        candidates, weights = fit_combination(data, landmark, candidates[top], valid, weights[top])
        fitted = project((weights[None, :, None] * data["vertices"][valid][:, candidates]).sum(1, keepdim=True), K, E)
        height = data["height"][valid]
        rows.append(
            {
                "landmark": LANDMARK_NAMES[landmark],
                "images": int(valid.sum()),
                "anchor": anchor,
                "joint_px": residual(joint_px, target),
                "vertex_px": residual(all_px[:, best], target),
                "fitted_px": residual(fitted[:, 0], target),
                "fitted_%height": float(100 * ((fitted[:, 0] - target).norm(dim=-1) / height).median()),
            }
        )
        print(rows[-1], flush=True)
        order = weights.argsort(descending=True)
        constants[landmark] = (candidates[order].tolist(), [round(float(w), 4) for w in weights[order]])
    constants = symmetrise(data, constants, mirror_map(rest.vertices))
    for row, (landmark, (vertices, weights)) in zip(rows, constants.items()):
        row["symmetric_px"] = landmark_residual(data, landmark, vertices, weights)
    print_table(rows)
    print("LANDMARK_VERTICES = {")
    for landmark, (vertices, weights) in constants.items():
        print(f"    {landmark}: ({tuple(vertices)}, {tuple(weights)}),  # {LANDMARK_NAMES[landmark]}")
    print("}")
    write_json(
        "derive_landmarks",
        {"config": dataclasses.asdict(config), "seed": args.seed, "rows": rows, "constants": constants},
    )
    shipped_px = project(landmark_points(data["vertices"]), data["K"], data["E"])  # the module's constants
    for column, landmark in enumerate(LANDMARK_ANCHORS):
        valid = data["visibility"][:, landmark] > VISIBLE
        shipped = residual(shipped_px[valid, column], data["points"][valid, landmark])
        print(f"{LANDMARK_NAMES[landmark]}: shipped constants {shipped:.2f} px")


if __name__ == "__main__":
    main()
