"""Body fit on real MediaPipe detections of a synthetic monocular video, against the truth.

Renders (or reuses) a ``pghm synth --config mono`` subject, runs MediaPipe Pose
(``model_complexity=1``, video mode) on its training frames, gives :func:`fit_body` the
detections with the true masks (the front end's segmentation is measured by
bench_capture), and compares the fitted canonical joints with the generator's exact poses
in each frame's camera coordinates, against the capture's targets b, c and e (docs/capture.md,
"How well it works"):

- root-relative MPJPE <= 80 mm and PA-MPJPE <= 50 mm;
- 2D error of the canonical joints <= 2 % of the person's height;
- the fit of 300 frames well under a minute on 2 cores (the whole capture <= 2 minutes).

    python benchmarks/bench_bodyfit.py --work /tmp/bodyfit [--seeds 3 4] [--repeat 3]

``--repeat`` tiles the frames (forwards, backwards, ...) to time longer videos.
"""

from __future__ import annotations

import argparse
import resource
import time
from pathlib import Path

import numpy as np
from common import load_average, print_table, write_json

from pghm.body import load_body
from pghm.capture.bodyfit import fit_body
from pghm.capture.config import BodyFitConfig
from pghm.capture.frontend import Observations
from pghm.capture.landmarks import NUM_LANDMARKS
from pghm.capture.metrics import camera_joints, error_2d_percent, mpjpe, pa_mpjpe, project
from pghm.subject import Subject, image_name, read_mask, read_rgb
from pghm.synth.config import PRESETS
from pghm.synth.generate import generate


def detect(folder: Path, indices: list[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """MediaPipe (video mode) on images ``indices``.

    Returns:
        (F, 33, 2) pixels, (F, 33) visibility, (F, 33, 3) world landmarks, (F, H, W) true masks.
    """
    import mediapipe as mp

    points = np.zeros((len(indices), NUM_LANDMARKS, 2), np.float32)
    visibility = np.zeros((len(indices), NUM_LANDMARKS), np.float32)
    world = np.zeros((len(indices), NUM_LANDMARKS, 3), np.float32)
    masks = []
    with mp.solutions.pose.Pose(model_complexity=1) as pose:
        for n, index in enumerate(indices):
            rgb = np.round(read_rgb(folder / "images" / image_name(index)) * 255).astype(np.uint8)
            masks.append(read_mask(folder / "masks" / image_name(index)) > 0.5)
            result = pose.process(rgb)
            if result.pose_landmarks is None:
                continue
            marks = zip(result.pose_landmarks.landmark, result.pose_world_landmarks.landmark)
            for k, (mark, metric) in enumerate(marks):
                points[n, k] = (mark.x * rgb.shape[1], mark.y * rgb.shape[0])
                visibility[n, k] = mark.visibility
                world[n, k] = (metric.x, metric.y, metric.z)
    return points, visibility, world, np.stack(masks)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True, help="folder for the rendered subjects (reused)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[3])
    parser.add_argument("--repeat", type=int, default=1, help="tile the frames this many times (timing)")
    args = parser.parse_args()
    body = load_body("anny")
    rows = []
    for seed in args.seeds:
        root = args.work / f"mono_{seed}"
        if not (root / "meta.json").exists():
            generate(PRESETS["mono"].validate(), seed, root, workers=1, progress=False)
        folder = root / "subject_000"
        a = Subject.open(folder).arrays
        train = [i for i in range(len(a)) if a.view_index[i] == 0 and i < PRESETS["mono"].frames]
        cache = args.work / f"detections_{seed}.npz"
        if not cache.exists():
            np.savez(cache, *detect(folder, train))
        points, visibility, world, masks = np.load(cache).values()
        forward = np.arange(len(train))
        order = np.concatenate([forward if r % 2 == 0 else forward[::-1] for r in range(args.repeat)])
        frames = np.asarray(train)[order]
        true = camera_joints(
            body, a.shape, a.rotations_true[frames], a.translation_true[frames], a.world_to_camera[frames]
        )
        height_px = np.array([np.ptp(np.nonzero(m.any(1))[0]) + 1 for m in masks[order]], np.float64)
        for known in (True, False):
            observations = Observations(
                np.arange(len(frames), dtype=np.int32),
                (int(a.height[0]), int(a.width[0])),
                a.K[0].astype(np.float32) if known else None,
                points[order],
                visibility[order],
                world[order],
                masks[order],
            )
            start, cpu_start = time.perf_counter(), time.process_time()
            fit = fit_body(observations, BodyFitConfig())
            seconds, cpu_seconds = time.perf_counter() - start, time.process_time() - cpu_start
            pred = camera_joints(body, fit.shape, fit.rotations, fit.translation, fit.world_to_camera)
            rows.append(
                {
                    "seed": seed,
                    "frames": len(frames),
                    "focal": "given" if known else f"fitted {fit.K[0, 0]:.0f} (true {a.K[0, 0, 0]:.0f})",
                    "mpjpe_mm": 1000 * mpjpe(pred, true),
                    "pa_mpjpe_mm": 1000 * pa_mpjpe(pred, true),
                    "error_2d_%height": error_2d_percent(project(pred, fit.K), project(true, a.K[frames]), height_px),
                    "landmark_px": fit.residuals["landmark_error_px"],
                    "seconds": seconds,
                    "cpu_seconds": cpu_seconds,  # the wall time on an idle core (the fit is single-threaded)
                }
            )
            print(rows[-1], flush=True)
    print_table(rows)
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"peak memory {peak_mb:.0f} MB (the whole process, MediaPipe included); load average {load_average():.1f}")
    write_json("bench_bodyfit", {"rows": rows, "peak_memory_mb": peak_mb, "load_average": load_average()})


if __name__ == "__main__":
    main()
