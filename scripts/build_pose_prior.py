"""Rebuild pghm/capture/pose_prior.npz from motion-capture clips (BVH, any rig pghm.motion.retarget reads).

    python scripts/build_pose_prior.py assets/motion/*.bvh

Each clip is retargeted onto Anny, the fitted joints' rotations taken in the body fit's
parametrisation (elbows and knees about their hinge axes), and the Gaussian of
:mod:`pghm.capture.pose_prior` estimated from them and their mirror images.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from pghm.body import BodyModel, load_body
from pghm.capture.bodyfit import FITTED_JOINTS, hinge_axes
from pghm.capture.pose_prior import POSE_PRIOR_FILE, build_pose_prior, project_hinges, save_pose_prior
from pghm.motion.retarget import import_bvh


def clip_rotations(path: Path, body: BodyModel) -> np.ndarray:
    """(F, J, 3) rotations of FITTED_JOINTS in the clip at ``path``, hinges projected."""
    rotations = np.asarray(import_bvh(path, body).rotations, dtype=np.float64)
    bones = [body.joint_map[name] for name in FITTED_JOINTS]
    axes = {name: axis.double().numpy() for name, axis in hinge_axes(body).items()}
    return project_hinges(rotations[:, bones], FITTED_JOINTS, axes)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("clips", nargs="+", type=Path)
    parser.add_argument("--out", type=Path, default=POSE_PRIOR_FILE)
    args = parser.parse_args()
    body = load_body("anny")
    clips = {path.name: clip_rotations(path, body) for path in args.clips}
    prior = build_pose_prior(clips, FITTED_JOINTS)
    save_pose_prior(prior, args.out)
    clips_read = ", ".join(f"{name} ({frames} frames)" for name, frames in zip(prior.sources, prior.frames))
    print(f"{args.out.name}: {len(prior.joints)} joints from {clips_read}")


if __name__ == "__main__":
    main()
