"""What a held-out frame's pose error costs in PSNR: the floor under bench_capture's d.

bench_capture's d renders an avatar fitted on a captured subject at the poses the capture
stored for the held-out frames, and asks for PSNR within 1.5 dB of the same fit made with the
true poses. Two things cost PSNR there: the avatar (fitted on estimated poses) and the
held-out poses' own error. This bench measures the second alone, on d's references (avatars
fitted with the true poses and cameras, so their appearance is the best a fit of those frames
gives):

1. Sweep. Each held-out frame's true pose gets the synthetic generator's estimator noise
   (:func:`pghm.synth.poses.add_pose_noise`: every canonical joint's rotation composed
   with a random rotation of N(0, sigma_r^2) axis-angle components, the root translation
   N(0, sigma_t^2) per axis), sigma_r / sigma_t in the capture's own ratio (9.5 degrees, 5 cm)
   at several fractions of it, a few draws each. Per level: the PSNR drop against the same
   avatar at the true poses (same images), and the perturbed canonical joints' error against
   the true ones: 2D (% of the person's height in the image, as bench_capture's c), PA-MPJPE
   and root-relative MPJPE (b).
2. Captured. Each captured subject's held-out frames as stored, with the captured fit's pose
   track (``pghm eval --fit-poses``) and refined against their images (``--refine-poses``),
   placed on the same axes: their joints' error against the reference's true ones (same
   images, same crop), and d's gap.

The curve says how small a held-out frame's pose error must be for d's 1.5 dB, whatever made
the pose: where it crosses 1.5 dB, against c's 2 % and the 36-55 mm PA-MPJPE that published
monocular regressors report on 3DPW.

    python benchmarks/bench_pose_error.py --keep DIR/s0 DIR/s1 DIR/s2 [--levels 0.05 0.1 ...] [--draws 3]

DIR/sN: bench_capture's ``--fit ... --keep`` folders (their ``{background}_{seed}_true_poses.pt``
and ``_captured.pt`` avatars and the subjects beside them). Prints the tables; writes
benchmarks/results/bench_pose_error.json and docs/pose_error.png.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from bench_capture import person_height_px
from common import DOCS, load_average, print_table, setup_threads, write_json

from pghm.body import BodyModel, load_body
from pghm.capture.metrics import camera_joints, error_2d_percent, mapped_joints, mpjpe, pa_mpjpe, project
from pghm.capture.pipeline import POSE_NOISE
from pghm.io.avatar import Avatar, load_avatar
from pghm.synth.poses import add_pose_noise
from pghm.train import pose_refine
from pghm.train.data import PoseCorrections, TrainingData
from pghm.train.frames import on_background, render_images
from pghm.train.fit import POSE_LR, FitConfig
from pghm.train.losses import psnr
from pghm.train.pose_track import track_corrections

CAPTURE_NOISE = (math.radians(POSE_NOISE["rotation_std_deg"]), POSE_NOISE["translation_std_m"])
"""The pose error ``pghm capture`` states for its subjects (meta.json pose_noise): radians, metres."""
LEVELS = (0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0)
"""Fractions of :data:`CAPTURE_NOISE` swept."""
DRAWS = 3
REFINE_STEPS = 30
"""bench_capture's d refines each held-out pose this many steps."""
GAP_TARGET_DB = 1.5
REPROJ_TARGET_PCT = 2.0
PUBLISHED_PA_MPJPE_MM = (36.0, 55.0)
"""PA-MPJPE of published monocular regressors on 3DPW."""
WHITE = (1.0, 1.0, 1.0)
ERRORS = ("reproj_pct", "pa_mpjpe_mm", "mpjpe_mm")
"""The joint errors reported: 2D % of the person's height, PA-MPJPE and MPJPE in mm."""


@dataclass(frozen=True)
class Case:
    """One of d's videos: its captured avatar and subject, and its true-pose reference."""

    name: str
    captured_avatar: Path
    captured_subject: Path
    reference_avatar: Path
    reference_subject: Path


def cases(folders: list[Path]) -> list[Case]:
    """Every video of bench_capture's ``--keep`` folders whose captured and reference fits exist."""
    found = []
    for folder in folders:
        for reference in sorted(folder.glob("*_true_poses.pt")):
            stem = reference.name.removesuffix("_true_poses.pt")  # {background}_{seed}
            subjects = sorted(p for p in folder.glob(f"{stem}_*f") if p.is_dir())
            captured = folder / f"{stem}_captured.pt"
            if subjects and captured.exists():
                subject = subjects[0]
                found.append(Case(stem, captured, subject, reference, Path(f"{subject}_true_poses")))
    return found


def frame_psnr(avatar: Avatar, data: TrainingData, corrections: PoseCorrections | None) -> np.ndarray:
    """(n,) PSNR on white of each held-out image, posed through ``corrections`` (None: as stored)."""
    indices = [int(i) for i in data.images[0]]
    values = []
    for sample, rgb, alpha in render_images(avatar, data, indices, corrections=corrections):
        target, image = on_background(sample, rgb, alpha, WHITE)
        values.append(float(psnr(image[None], target[None])))
    return np.array(values)


def frame_keys(data: TrainingData) -> torch.Tensor:
    """(n,) the held-out images' rows in ``data``'s pose corrections (:attr:`Sample.frame_key`)."""
    return torch.as_tensor(data.subjects[0].arrays.frame_index[data.images[0]] + data.frame_offsets[0])


def corrected_poses(data: TrainingData, corrections: PoseCorrections | None) -> tuple[np.ndarray, np.ndarray]:
    """(n, J, 3) rotations and (n, 3) translations of the held-out images as rendered."""
    arrays, indices = data.subjects[0].arrays, data.images[0]
    rotations = torch.as_tensor(arrays.rotations[indices], dtype=torch.float32)
    translation = torch.as_tensor(arrays.translation[indices], dtype=torch.float32)
    if corrections is not None:
        with torch.no_grad():
            rotations, translation = corrections(frame_keys(data), rotations, translation)
    return rotations.double().numpy(), translation.double().numpy()


@dataclass(frozen=True)
class Truth:
    """The reference subject's held-out frames: true joints in camera coordinates and pixels."""

    joints: np.ndarray  # (n, C, 3) metres
    uv: np.ndarray  # (n, C, 2) pixels
    height_px: np.ndarray  # (n,)


def joints_of(body: BodyModel, data: TrainingData, rotations: np.ndarray, translation: np.ndarray):
    """(n, C, 3) camera-frame canonical joints and (n, C, 2) pixels of held-out poses of ``data``."""
    arrays, indices = data.subjects[0].arrays, data.images[0]
    joints = camera_joints(body, arrays.shape, rotations, translation, arrays.world_to_camera[indices])
    return joints, project(joints, arrays.K[indices])


def truth_of(body: BodyModel, data: TrainingData) -> Truth:
    joints, uv = joints_of(body, data, *corrected_poses(data, None))
    masks = np.stack([data.subjects[0][int(i)].mask > 0.5 for i in data.images[0]])
    return Truth(joints, uv, person_height_px(masks))


@dataclass(frozen=True)
class Reference:
    """A case's true-pose avatar on its held-out frames: what both parts of the bench compare with."""

    avatar: Avatar
    data: TrainingData
    truth: Truth
    psnr: np.ndarray  # (n,) at the true poses


def reference_of(case: Case, body: BodyModel) -> Reference:
    avatar = load_avatar(case.reference_avatar)
    data = TrainingData(case.reference_subject, split="test")
    return Reference(avatar, data, truth_of(body, data), frame_psnr(avatar, data, None))


def errors(body: BodyModel, truth: Truth, joints: np.ndarray, uv: np.ndarray) -> dict:
    """Mean 2D % of height, PA-MPJPE and MPJPE (mm) of held-out joints against the truth."""
    root = mapped_joints(body)[0].index("pelvis")
    return {
        "reproj_pct": error_2d_percent(uv, truth.uv, truth.height_px),
        "pa_mpjpe_mm": 1000 * pa_mpjpe(joints, truth.joints),
        "mpjpe_mm": 1000 * mpjpe(joints, truth.joints, root),
    }


def noise_corrections(
    data: TrainingData, body: BodyModel, level: float, rng: np.random.Generator
) -> tuple[PoseCorrections, np.ndarray, np.ndarray]:
    """Corrections that move each held-out frame from its true pose to an estimator's noisy one,
    and those noisy (n, J, 3) rotations and (n, 3) translations."""
    rotations, translation = corrected_poses(data, None)
    corrections = data.pose_corrections(body).requires_grad_(False)
    bones = corrections.bones.tolist()
    noisy_r, noisy_t = add_pose_noise(
        rotations, translation, bones, level * CAPTURE_NOISE[0], level * CAPTURE_NOISE[1], rng
    )
    keys = frame_keys(data)
    with torch.no_grad():
        corrections.rotations[keys] = torch.as_tensor(noisy_r[:, bones] - rotations[:, bones], dtype=torch.float32)
        corrections.translation[keys] = torch.as_tensor(noisy_t - translation, dtype=torch.float32)
    return corrections, noisy_r, noisy_t


def sweep(case: Case, reference: Reference, body: BodyModel, levels: list[float], draws: int) -> list[dict]:
    """Rows (level, draw) of the reference avatar at noisy held-out poses: PSNR drop and joint errors."""
    rows = []
    for level in levels:
        for draw in range(draws):
            rng = np.random.default_rng([draw, round(1000 * level)])
            corrections, rotations, translation = noise_corrections(reference.data, body, level, rng)
            noisy = frame_psnr(reference.avatar, reference.data, corrections)
            joints, uv = joints_of(body, reference.data, rotations, translation)
            rows.append(
                {
                    "case": case.name,
                    "level": level,
                    "sigma_deg": round(math.degrees(level * CAPTURE_NOISE[0]), 2),
                    "sigma_cm": round(100 * level * CAPTURE_NOISE[1], 2),
                    "draw": draw,
                    "psnr_drop_db": float((reference.psnr - noisy).mean()),
                    **errors(body, reference.truth, joints, uv),
                }
            )
    return rows


def captured(case: Case, reference: Reference, body: BodyModel) -> list[dict]:
    """The captured avatar's held-out poses (stored, its track, refined): joint errors and d's gap."""
    avatar = load_avatar(case.captured_avatar)
    data = TrainingData(case.captured_subject, split="test")
    if not np.array_equal(data.images[0], reference.data.images[0]):
        raise SystemExit(f"{case.name}: the captured and reference subjects hold different test images")
    loss = FitConfig().stage2.loss
    reference_refined = pose_refine.refine_poses(
        reference.avatar, reference.data, REFINE_STEPS, loss, POSE_LR, progress=False
    )
    refined_reference_psnr = frame_psnr(reference.avatar, reference.data, reference_refined)
    choices = {
        "stored": (None, reference.psnr),
        "track": (track_corrections(avatar.pose_track, data, body)[0], reference.psnr),
        "refined": (
            pose_refine.refine_poses(avatar, data, REFINE_STEPS, loss, POSE_LR, progress=False),
            refined_reference_psnr,
        ),
    }
    rows = []
    for poses, (corrections, against) in choices.items():
        joints, uv = joints_of(body, data, *corrected_poses(data, corrections))
        rows.append(
            {
                "case": case.name,
                "poses": poses,
                "gap_db": float((against - frame_psnr(avatar, data, corrections)).mean()),
                **errors(body, reference.truth, joints, uv),
            }
        )
    return rows


def level_means(rows: list[dict]) -> list[dict]:
    """Each level's means over cases and draws."""
    out = []
    for level in sorted({r["level"] for r in rows}):
        at = [r for r in rows if r["level"] == level]
        out.append(
            {
                "level": level,
                "sigma_deg": at[0]["sigma_deg"],
                "sigma_cm": at[0]["sigma_cm"],
                **{k: float(np.mean([r[k] for r in at])) for k in ("psnr_drop_db", *ERRORS)},
            }
        )
    return out


def crossing(means: list[dict], key: str, drop_db: float = GAP_TARGET_DB) -> float | None:
    """The value of ``key`` where the mean PSNR drop reaches ``drop_db`` (linear between levels)."""
    drops = np.array([m["psnr_drop_db"] for m in means])
    values = np.array([m[key] for m in means])
    above = np.nonzero(drops >= drop_db)[0]
    if len(above) == 0 or above[0] == 0:
        return None
    i = above[0]
    w = (drop_db - drops[i - 1]) / (drops[i] - drops[i - 1])
    return float(values[i - 1] + w * (values[i] - values[i - 1]))


def plot(rows: list[dict], means: list[dict], points: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    markers = {"stored": "o", "track": "^", "refined": "s"}
    for ax, key, label in (
        (axes[0], "reproj_pct", "2D joint error (% of the person's height)"),
        (axes[1], "pa_mpjpe_mm", "PA-MPJPE (mm)"),
    ):
        for name in sorted({r["case"] for r in rows}):
            at = level_means([r for r in rows if r["case"] == name])
            ax.plot([m[key] for m in at], [m["psnr_drop_db"] for m in at], color="0.75", lw=0.8)
        drops = [m["psnr_drop_db"] for m in means]
        ax.plot([m[key] for m in means], drops, "k.-", lw=2, label="true poses + noise (mean)")
        for poses, marker in markers.items():
            for background, colour in (("plain", "tab:blue"), ("cluttered", "tab:orange")):
                at = [p for p in points if p["poses"] == poses and p["case"].startswith(background)]
                if at:
                    ax.scatter(
                        [p[key] for p in at],
                        [p["gap_db"] for p in at],
                        marker=marker,
                        color=colour,
                        label=f"captured, {poses}, {background}",
                        zorder=3,
                    )
        ax.axhline(GAP_TARGET_DB, color="tab:red", ls="--", lw=1)
        ax.set_xlabel(label)
        ax.set_ylabel("PSNR below the true poses (dB)")
        ax.grid(alpha=0.3)
    axes[0].axvline(REPROJ_TARGET_PCT, color="tab:green", ls=":", lw=1, label="c: 2 %")
    axes[1].axvspan(*PUBLISHED_PA_MPJPE_MM, color="tab:green", alpha=0.12, label="published, 3DPW")
    axes[0].legend(fontsize=7, loc="upper left")
    axes[1].legend(fontsize=7, loc="upper left", handles=axes[1].get_legend_handles_labels()[0][-1:])
    fig.suptitle("held-out frames: PSNR lost to pose error (d's target 1.5 dB, dashed)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    print(f"wrote {path.name}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--keep", nargs="+", type=Path, required=True, help="bench_capture --fit --keep folders")
    parser.add_argument("--levels", nargs="+", type=float, default=list(LEVELS))
    parser.add_argument("--draws", type=int, default=DRAWS)
    parser.add_argument("--no-captured", action="store_true", help="the sweep only")
    args = parser.parse_args()
    setup_threads()
    load_before = load_average()
    body = load_body("anny")
    found = cases(args.keep)
    if not found:
        raise SystemExit("no captured and reference avatars in the --keep folders")
    rows, points = [], []
    for case in found:
        reference = reference_of(case, body)
        rows += sweep(case, reference, body, args.levels, args.draws)
        points += [] if args.no_captured else captured(case, reference, body)
    means = level_means(rows)
    print_table(means)
    if points:
        print_table(points)
    crossings = {key: crossing(means, key) for key in ERRORS}
    print("the mean drop reaches 1.5 dB at", {k: None if v is None else round(v, 2) for k, v in crossings.items()})
    plot(rows, means, points, DOCS / "pose_error.png")
    write_json(
        "bench_pose_error",
        {
            "cases": [case.name for case in found],
            "capture_noise": {"rotation_deg": math.degrees(CAPTURE_NOISE[0]), "translation_m": CAPTURE_NOISE[1]},
            "means": means,
            "crossing_at_1_5_db": crossings,
            "sweep": rows,
            "captured": points,
            "load_before": load_before,
            "load_after": load_average(),
            "command": ["python", "benchmarks/bench_pose_error.py", "--keep", "DIR/..."],
        },
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
