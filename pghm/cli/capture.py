"""``pghm capture``: a video of a person becomes a subject folder (docs/capture.md).

    pghm capture INPUT --out SUBJECT [--every N] [--max-frames N] [--target-frames N] [--size PX]
                 [--fov DEG | --focal PX] [--height M] [--test-every N] [--no-mirror-pass] [--no-pose-prior]
                 [--polish PRIOR] [--quiet]

INPUT is a video file (mp4, mov, webm, avi, anything ffmpeg reads) or a folder of images.
Needs the ``capture`` extra (mediapipe): ``pip install 'pghm[capture]'``.
"""

from __future__ import annotations

import argparse

from pghm.capture.config import (
    DEFAULT_SIZE,
    DEFAULT_TARGET_FRAMES,
    DEFAULT_TEST_EVERY,
    FOV_RANGE_DEG,
    HEIGHT_RANGE_M,
    MAX_FOCAL_PX,
    MIN_SIZE,
    CaptureConfig,
)
from pghm.cli.options import MAX_IMAGE_SIDE, MAX_INDEX, Integer, Real
from pghm.io.outputs import check_output


def cmd_capture(args: argparse.Namespace) -> int:
    check_output(args.out, inputs=[args.input, args.polish], folder=True)  # before the heavy imports
    from pghm.capture.pipeline import capture

    config = CaptureConfig(
        every=args.every,
        max_frames=args.max_frames,
        target_frames=args.target_frames,
        height_m=args.height,
        size=args.size,
        fov_deg=args.fov,
        focal_px=args.focal,
        test_every=args.test_every,
        mirror_pass=not args.no_mirror_pass,
        pose_prior=not args.no_pose_prior,
        polish=args.polish,
        progress=not args.quiet,
    )
    out = capture(args.input, args.out, config)
    print(f"{out}: subject written; next: pghm data check {out}, then pghm fit {out} --prior assets/prior.pt")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "capture",
        help="make a subject folder from a video of a person: masks, landmarks, body fit, camera",
        description=(
            "Make a subject folder (docs/data.md) from a video file or a folder of images of one person: "
            "the person's mask, body landmarks, a fitted body and the camera, ready for pghm fit."
        ),
    )
    parser.add_argument("input", help="a video file (mp4, mov, webm, avi, ...) or a folder of images")
    parser.add_argument("--out", required=True, help="the new subject folder to write")
    parser.add_argument(
        "--every",
        type=Integer(1, MAX_INDEX),
        default=None,
        help="keep every N-th frame (default: all, or about --target-frames of a longer video)",
    )
    parser.add_argument(
        "--target-frames",
        type=Integer(0, MAX_INDEX),
        default=DEFAULT_TARGET_FRAMES,
        help=f"without --every or --max-frames, read a longer video one frame in floor(frames / N), "
        f"keeping N to 2N evenly (default {DEFAULT_TARGET_FRAMES}; 0: all)",
    )
    parser.add_argument(
        "--max-frames", type=Integer(1, MAX_INDEX), default=None, help="stop after this many kept frames"
    )
    parser.add_argument(
        "--size",
        type=Integer(MIN_SIZE, MAX_IMAGE_SIDE),
        default=DEFAULT_SIZE,
        help=f"longest side of the subject images (default {DEFAULT_SIZE})",
    )
    camera = parser.add_mutually_exclusive_group()
    camera.add_argument(
        "--fov",
        type=Real(*FOV_RANGE_DEG),
        default=None,
        help="field of view along the frame's longest side, degrees (default: the body fit estimates the focal)",
    )
    camera.add_argument(
        "--focal",
        type=Real(0.0, MAX_FOCAL_PX, open_low=True),
        default=None,
        help="focal length in pixels of the full-resolution frames",
    )
    parser.add_argument(
        "--height",
        type=Real(*HEIGHT_RANGE_M),
        default=None,
        metavar="M",
        help="the person's height in metres, when known: one video does not tell a person's size "
        "(default: the body model's average adult, 1.63 m)",
    )
    parser.add_argument(
        "--test-every",
        type=Integer(2, MAX_INDEX),
        default=DEFAULT_TEST_EVERY,
        help=f"every N-th kept frame goes to the test split (default {DEFAULT_TEST_EVERY})",
    )
    parser.add_argument(
        "--no-mirror-pass",
        action="store_true",
        help="skip the landmark model's second pass on the mirrored frames (a faster front end, less accurate joints)",
    )
    parser.add_argument(
        "--no-pose-prior",
        action="store_true",
        help="fit the body without the pose prior learned from motion capture (walking, sitting); "
        "for motions far from those, such as dancing",
    )
    parser.add_argument(
        "--polish",
        metavar="PRIOR",
        default=None,
        help="align the test frames' poses to their images through an avatar fitted from this prior on all "
        "frames (e.g. assets/prior.pt; about 7 minutes per 100 frames on 2 cores)",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    parser.set_defaults(func=cmd_capture)
