"""``pghm motion``: import BVH clips, make procedural clips, inspect and preview motion files.

    pghm motion import FILE.bvh --out motion.npz [--body anny|smplx --body-model-path F] [--fps F]
    pghm motion make NAME --out motion.npz [--frames N --fps F]
    pghm motion info FILE
    pghm motion preview CLIP [CLIP ...] --out sheet.png [--frames-per-clip N]

A CLIP of ``preview`` is a motion file (.npz), a BVH file (retargeted on the fly, its own
skeleton drawn over the body in red) or the name of a procedural motion.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from pghm.body import BODY_NAMES, BodyModel, RestBody, load_body
from pghm.cli.options import Integer, Real
from pghm.errors import MotionFileError
from pghm.io.atomic import save_figure
from pghm.io.outputs import FIGURE_SUFFIXES, check_output
from pghm.motion.bvh import load_bvh
from pghm.motion.motion import MAX_FPS, MIN_FPS, Motion
from pghm.motion.procedural import MAX_PROCEDURAL_FRAMES, PROCEDURAL_MOTIONS, procedural_motion
from pghm.motion.retarget import RIG_MAPS, UNIT_SCALES, clip_facing, detect_rig, import_bvh, leg_length, retarget_bvh

PREVIEW_VERTEX_STRIDE = 4
"""Plot every 4th vertex: enough points to read a pose, few enough to draw quickly."""
PREVIEW_HALF_WIDTH_M = 1.0
"""Each panel shows this far either side of the body's root."""
MAX_PREVIEW_FRAMES = 32
"""Most poses per clip in a preview sheet (two panels each)."""
MIN_DPI, MAX_DPI = 10, 600
"""Preview resolutions accepted (dots per inch of a 2.8 x 2.2 inch panel pair)."""
FPS = Real(MIN_FPS, MAX_FPS)


def _add_body_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--body", choices=BODY_NAMES, default="anny", help="body model to retarget onto")
    parser.add_argument("--body-model-path", help="the SMPL-X model file (with --body smplx)")


def _body(args: argparse.Namespace) -> BodyModel:
    return load_body(args.body, args.body_model_path)


def cmd_motion_import(args: argparse.Namespace) -> int:
    check_output(args.out, inputs=[args.file, args.body_model_path])
    motion = import_bvh(
        args.file,
        _body(args),
        rig=args.rig,
        units=args.units,
        scale_to_body=not args.no_scale,
        fps=args.fps,
    )
    motion.save(args.out)
    print(f"{args.out}: {_summary(motion)}")
    return 0


def cmd_motion_make(args: argparse.Namespace) -> int:
    check_output(args.out, inputs=[args.body_model_path])
    motion = procedural_motion(args.name, _body(args), frames=args.frames, fps=args.fps)
    motion.save(args.out)
    print(f"{args.out}: {_summary(motion)}")
    return 0


def _summary(motion: Motion) -> str:
    return (
        f"{motion.num_frames} frames at {motion.fps:g} fps ({motion.duration:.2f} s), "
        f"body {motion.body} ({len(motion.bone_names)} bones), source {motion.source}"
    )


def cmd_motion_info(args: argparse.Namespace) -> int:
    path = Path(args.file)
    if path.suffix.lower() == ".bvh":
        clip = load_bvh(path)
        duration = (clip.num_frames - 1) * clip.frame_time
        try:
            rig, joints = detect_rig(clip.names)
            rig_text = f"rig {rig} ({len(joints)} joints mapped)"
        except MotionFileError as error:
            rig_text = f"no known rig: {error}"
        print(
            f"{path}: BVH, {clip.num_frames} frames at {clip.fps:g} fps ({duration:.2f} s), "
            f"{clip.num_joints} joints, {rig_text}"
        )
    else:
        print(f"{path}: {_summary(Motion.load(path))}")
    return 0


def _clip(source: str, body: BodyModel) -> tuple[Motion, np.ndarray | None, list[int]]:
    """The motion to preview and, for a BVH file, the clip's own (F, J', 3) skeleton moved
    onto the body (scaled by leg length, turned to the project's axes, root on the body's
    root) with its parent indices, to draw over the body."""
    if source in PROCEDURAL_MOTIONS:
        return procedural_motion(source, body), None, []
    if not source.lower().endswith(".bvh"):
        motion = Motion.load(source)
        motion.check_skeleton(body.name, body.bone_names)
        return motion, None, []
    clip = load_bvh(source)
    motion = retarget_bvh(clip, body)
    joints = detect_rig(clip.names)[1]
    rest_joints = body.rest().joints.double().numpy()
    scale = leg_length(rest_joints, body.joint_map) / leg_length(clip.rest_positions(), joints)
    positions = clip.joint_positions()
    skeleton = scale * (positions - positions[:, :1]) @ clip_facing(clip.rest_positions(), joints).T
    skeleton += rest_joints[body.joint_map["pelvis"]] + motion.translation[:, None]
    return motion, skeleton, clip.parents


def _distinct_frames(body: BodyModel, rest: RestBody, motion: Motion, count: int) -> np.ndarray:
    """``count`` frames showing poses as different as possible, in time order.

    Farthest-point sampling on the posed joints relative to the root: start from the pose
    farthest from rest, then repeatedly take the frame whose nearest chosen pose is
    farthest (mean joint distance), so a clip's extremes and not its pauses are shown.
    """
    transforms = body.bone_transforms(motion.pose(), rest.joints)
    joints = (transforms[..., :3, :3] @ rest.joints[:, :, None])[..., 0] + transforms[..., :3, 3]
    joints = (joints - joints[:, :1]).numpy()
    rest_joints = (rest.joints - rest.joints[:1]).numpy()
    nearest = np.linalg.norm(joints - rest_joints, axis=-1).mean(-1)
    chosen: list[int] = []
    for _ in range(min(count, motion.num_frames)):
        chosen.append(int(np.argmax(nearest)))
        nearest = np.minimum(nearest, np.linalg.norm(joints - joints[chosen[-1]], axis=-1).mean(-1))
    return np.sort(np.array(chosen))


def cmd_motion_preview(args: argparse.Namespace) -> int:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    check_output(args.out, inputs=[*args.clips, args.body_model_path], suffixes=FIGURE_SUFFIXES)
    body = _body(args)
    rest = body.rest()
    floor = float(rest.vertices[:, 1].min())
    top = float(rest.vertices[:, 1].max())
    count = args.frames_per_clip
    figure, axes = plt.subplots(
        len(args.clips), 2 * count, figsize=(1.4 * 2 * count, 2.2 * len(args.clips)), squeeze=False
    )
    for row, source in enumerate(args.clips):
        motion, skeleton, parents = _clip(source, body)
        frames = _distinct_frames(body, rest, motion, count)
        vertices = body.posed_vertices(motion.pose(frames), rest).numpy()[:, ::PREVIEW_VERTEX_STRIDE]
        for column, (frame, points) in enumerate(zip(frames, vertices, strict=True)):
            root = motion.translation[frame]
            # Side view looks along -x (forward +z to the right), front view along -z.
            for view, (axis, title) in enumerate(((2, "side"), (0, "front"))):
                ax = axes[row, 2 * column + view]
                depth = points[:, 0 if axis == 2 else 2]
                ax.scatter(points[:, axis], points[:, 1], s=0.3, c=depth, cmap="viridis", linewidths=0)
                if skeleton is not None:
                    for child, parent in enumerate(parents):
                        if parent >= 0:
                            bone = skeleton[frame, [parent, child]]
                            ax.plot(bone[:, axis], bone[:, 1], color="red", linewidth=0.6)
                ax.axhline(floor, color="k", linewidth=0.5)
                ax.set_xlim(root[axis] - PREVIEW_HALF_WIDTH_M, root[axis] + PREVIEW_HALF_WIDTH_M)
                ax.set_ylim(floor - 0.1, top + 0.3)
                ax.set_aspect("equal")
                ax.set_xticks([])
                ax.set_yticks([])
                ax.set_title(f"{Path(source).stem} {frame / motion.fps:.1f}s {title}", fontsize=6)
    figure.tight_layout()
    save_figure(figure, args.out, dpi=args.dpi)
    plt.close(figure)
    print(f"{args.out}: {len(args.clips)} clips x {count} frames")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("motion", help="import, make, inspect and preview motion clips")
    commands = parser.add_subparsers(dest="motion_command", metavar="ACTION")
    commands.required = True

    importer = commands.add_parser("import", help="retarget a BVH file onto a body, save as .npz")
    importer.add_argument("file", help="the .bvh file")
    importer.add_argument("--out", required=True, help="the motion file to write (.npz)")
    _add_body_options(importer)
    importer.add_argument("--fps", type=FPS, help="resample to this frame rate (default: the clip's)")
    importer.add_argument("--units", choices=("auto", *UNIT_SCALES), default="auto", help="the clip's length unit")
    importer.add_argument("--rig", choices=tuple(RIG_MAPS), help="the clip's rig (default: detected from joint names)")
    importer.add_argument(
        "--no-scale",
        action="store_true",
        help="keep the clip's root trajectory size instead of fitting it to the body's legs",
    )
    importer.set_defaults(func=cmd_motion_import)

    maker = commands.add_parser("make", help="generate a procedural motion, save as .npz")
    maker.add_argument("name", choices=tuple(PROCEDURAL_MOTIONS), help="which motion")
    maker.add_argument("--out", required=True, help="the motion file to write (.npz)")
    maker.add_argument(
        "--frames",
        type=Integer(1, MAX_PROCEDURAL_FRAMES),
        help="number of frames (default: the motion's own)",
    )
    maker.add_argument("--fps", type=FPS, default=30.0, help="frames per second")
    _add_body_options(maker)
    maker.set_defaults(func=cmd_motion_make)

    info = commands.add_parser("info", help="frames, fps, duration and body of a motion (.npz) or BVH file")
    info.add_argument("file")
    info.set_defaults(func=cmd_motion_info)

    preview = commands.add_parser(
        "preview", help="a contact sheet of each clip's most distinct poses (side and front) as an image"
    )
    preview.add_argument("clips", nargs="+", help="motion files, BVH files or procedural motion names")
    preview.add_argument("--out", required=True, help="the image to write (.png)")
    preview.add_argument("--frames-per-clip", type=Integer(1, MAX_PREVIEW_FRAMES), default=5)
    preview.add_argument("--dpi", type=Integer(MIN_DPI, MAX_DPI), default=80)
    _add_body_options(preview)
    preview.set_defaults(func=cmd_motion_preview)
