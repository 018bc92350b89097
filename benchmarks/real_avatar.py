"""The shipped real person's avatar and its pictures, made by ``pghm capture`` + ``pghm fit`` with the defaults.

``make`` (one command; re-run it after a change of the capture's or the fit's defaults)::

    xvfb-run -a -s "-screen 0 1600x1000x24" .venv/bin/python benchmarks/real_avatar.py make [--work DIR]

1. ``pghm capture VIDEO --out WORK/subject`` (defaults; the shared real video unless ``--video``);
2. ``pghm fit WORK/subject --prior assets/prior.pt`` (defaults), copied to ``assets/real_avatar.pt``;
3. ``pghm eval`` of it on the held-out frames with its pose track (``--fit-poses``);
4. ``docs/real_avatar.png``: the video frame it learned from, then the avatar at that frame's camera
   and learned pose, turned about the body, and in a frame of a motion-capture walk it never saw;
5. ``docs/real_avatar_viewer.png`` when a display is there (Xvfb): ``pghm-view``'s default window;
6. ``benchmarks/results/real_avatar.json``: each stage's wall and CPU seconds and peak GB.

``compare`` (a before / after picture of two avatars of the same subject, e.g. two fits' defaults)::

    .venv/bin/python benchmarks/real_avatar.py compare BEFORE.pt AFTER.pt --subject WORK/subject --out cmp.png

One row per avatar, the same columns as ``make``'s strip: the subject's image, then each avatar in
the same frame and the same pose (the stored one; ``--fit-poses``: each avatar's own pose track).
The children run in the repository root, so the avatar records ``assets/prior.pt`` and its subject
by name only (no path of this machine).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from bench_real import PGHM, run
from common import DOCS, ROOT, write_json

VIDEO = ROOT.parent / "shared" / "data" / "video" / "outdoor_dribble_40f.mp4"
"""The shared real video (assets/SOURCE.md says where it comes from); it is not shipped."""
PRIOR = Path("assets/prior.pt")
SHIPPED = Path("assets/real_avatar.pt")
"""Relative to the repository root, where the children run."""
WALK = ROOT / "assets" / "motion" / "mixamo_walk_69f.bvh"
WALK_FRAME = 20
"""The motion-capture walk's frame shown (mid-stride)."""
FRAME = 27
"""The subject image (a training frame) of the strips: facing the camera, the ball low."""
TURNS = (-45.0, 180.0)
"""Degrees about the vertical the views after the video's own are turned from it: a three-quarter
view, and the back, which the video hardly showed (the prior's guess)."""
WALK_YAW = 30.0
"""Degrees from the body's front of the walk frame's view."""
WHITE = (1.0, 1.0, 1.0)
GAP = 6
"""Pixels between the pictures of a strip."""
LABEL_HEIGHT = 28
"""Pixels of the label band above each row of a comparison."""
LABEL_FONT = 18
"""Pixel size of the labels' font (Pillow's own, no font file needed)."""
SCREENSHOT_FRAME = 20
"""Frame of the walk at which the viewer's screenshot is taken."""


def cpu_seconds() -> float:
    """User + system seconds of every child this process has waited for."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def stage(command: list[str], log: Path) -> dict:
    """Run a pghm child in the repository root: wall and CPU seconds, peak GB, the load before it."""
    print(" ".join(["pghm", *command[3:]]), flush=True)
    before = cpu_seconds()
    row = run(command, log)
    row["cpu_seconds"] = round(cpu_seconds() - before, 1)
    print(f"  {row['seconds']} s wall, {row['cpu_seconds']} s CPU, {row['peak_gb']} GB")
    return row


def frame_camera(frame):
    """The :class:`~pghm.splat.Camera` of a subject :class:`~pghm.subject.reader.Frame`."""
    import torch

    from pghm.splat import Camera

    K, world_to_camera = torch.as_tensor(frame.K), torch.as_tensor(frame.world_to_camera)  # noqa: N806
    return Camera.from_matrices(K.float(), world_to_camera.float(), frame.width, frame.height)


def turned_camera(means: np.ndarray, yaw: float, width: int, height: int):
    """A camera ``yaw`` degrees about world y (0: the body's front, +z) framing the centres ``means`` (N, 3).

    :func:`~pghm.render.framing.frame_points` frames from +z: the points turned by -yaw about y
    are framed, and the framing's target turned back.
    """
    from pghm.render import frame_points, orbit_camera
    from pghm.render.framing import DEFAULT_FOV_Y

    c, s = math.cos(math.radians(yaw)), math.sin(math.radians(yaw))
    to_front = np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])  # R_y(-yaw)
    framing = frame_points(means @ to_front.T, DEFAULT_FOV_Y, width / height)
    target = to_front.T @ np.asarray(framing.target)
    return orbit_camera(target, yaw, 0.0, framing.distance, DEFAULT_FOV_Y, width, height)


def camera_yaw(camera, target: np.ndarray) -> float:
    """Degrees about world y of the camera's centre seen from ``target`` (3,) (0: on +z)."""
    offset = camera.centre.numpy() - target
    return math.degrees(math.atan2(offset[0], offset[2]))


def avatar_views(avatar_path: Path, subject_dir: Path, index: int, fit_poses: bool) -> list[np.ndarray]:
    """(H, W, 3) uint8 pictures of an avatar on white, H x W the subject image's size.

    The subject image ``index``'s frame seen by its camera in its stored pose (``fit_poses``: the
    avatar's pose track), the same pose turned by each of :data:`TURNS`, and frame
    :data:`WALK_FRAME` of the walk seen from :data:`WALK_YAW`.
    """
    from pghm.io.avatar import load_avatar
    from pghm.motion.open_motion import open_motion, subject_motion
    from pghm.render import AvatarDriver
    from pghm.render.frames import CPUFrames
    from pghm.render.sinks import to_uint8
    from pghm.subject import Subject

    avatar = load_avatar(avatar_path)
    driver = AvatarDriver(avatar)
    identity = avatar.identity_map()
    subject = Subject.open(subject_dir)
    frame = subject[index]
    video = subject_motion(subject_dir, avatar.pose_track if fit_poses else None)
    numbers = subject.arrays.frame_index if subject.arrays.frame_index is not None else np.arange(len(subject))
    pose = video.pose(int(np.searchsorted(np.unique(numbers), frame.frame_index)))
    walk = open_motion(str(WALK), driver.body, driver.geometry.shape.cpu()).pose(WALK_FRAME)
    renderer = CPUFrames()

    def draw(pose, camera) -> np.ndarray:
        arrays = driver.evaluate(identity, pose, camera.centre)
        return to_uint8(renderer.render(arrays, camera, WHITE))

    camera = frame_camera(frame)
    views = [draw(pose, camera)]
    means = driver.evaluate(identity, pose, camera.centre).means
    front = camera_yaw(camera, means.mean(axis=0))
    views += [draw(pose, turned_camera(means, front + turn, frame.width, frame.height)) for turn in TURNS]
    walk_means = driver.evaluate(identity, walk, camera.centre).means
    views.append(draw(walk, turned_camera(walk_means, WALK_YAW, frame.width, frame.height)))
    return views


def video_frame(video: Path, subject_dir: Path, index: int) -> np.ndarray:
    """(H, W, 3) uint8: the video's frame of subject image ``index`` as the capture read it (its crop,
    scaled to the image's size), before the mask took the background away."""
    from pghm.capture.crop import Region
    from pghm.capture.video import open_source
    from pghm.subject import Subject

    subject = Subject.open(subject_dir)
    frame = subject[index]
    crop = subject.meta["crop"]
    region = Region(crop["x"], crop["y"], crop["width"], crop["height"])
    for number, pixels in open_source(video).frames(region, (frame.height, frame.width)):
        if number == frame.frame_index:
            return pixels
    raise SystemExit(f"{video.name}: no frame {frame.frame_index}")


def check_training_image(subject_dir: Path, index: int) -> None:
    """Exit with one line unless subject image ``index`` is one the fit learns from (the strip says so)."""
    from pghm.subject import Subject

    train = Subject.open(subject_dir).split("train").indices
    if index not in train:
        raise SystemExit(f"--frame {index}: not a training image of {subject_dir} (those are {train[:3]} ...)")


def subject_image(subject_dir: Path, index: int) -> np.ndarray:
    """(H, W, 3) uint8: subject image ``index`` as the fit sees it (the person on white)."""
    from pghm.render.sinks import to_uint8
    from pghm.subject import Subject

    return to_uint8(Subject.open(subject_dir)[index].image)


def strip(images: list[np.ndarray]) -> Image.Image:
    """Pictures of one height side by side, :data:`GAP` white pixels apart."""
    height = images[0].shape[0]
    width = sum(image.shape[1] for image in images) + GAP * (len(images) - 1)
    out = Image.new("RGB", (width, height), "white")
    x = 0
    for image in images:
        out.paste(Image.fromarray(image), (x, 0))
        x += image.shape[1] + GAP
    return out


def labelled_rows(rows: list[Image.Image], labels: list[str]) -> Image.Image:
    """Strips of one width stacked, each under a band with its label."""
    width = rows[0].width
    height = sum(row.height + LABEL_HEIGHT for row in rows)
    out = Image.new("RGB", (width, height), "white")
    draw, font = ImageDraw.Draw(out), ImageFont.load_default(size=LABEL_FONT)
    y = 0
    for row, label in zip(rows, labels):
        draw.text((4, y + 4), label, fill="black", font=font)
        out.paste(row, (0, y + LABEL_HEIGHT))
        y += row.height + LABEL_HEIGHT
    return out


def viewer_screenshot(avatar: Path, path: Path) -> None:
    """``pghm-view``'s default window on ``avatar`` at frame :data:`SCREENSHOT_FRAME` of the walk."""
    sys.path.insert(0, str(ROOT / "scripts"))
    from viewer.settings import WINDOW_SIZE
    from viewer.viewer import Viewer
    from viewer_shots import settled_screenshot

    viewer = Viewer(avatar, window_size=WINDOW_SIZE)
    viewer.setup()
    try:
        settled_screenshot(viewer, WALK.relative_to(ROOT), SCREENSHOT_FRAME, path)
    finally:
        viewer.teardown()


def make(args: argparse.Namespace) -> int:
    work = args.work or Path(tempfile.mkdtemp(prefix="real_avatar_"))
    work.mkdir(parents=True, exist_ok=True)
    subject, fitted = work / "subject", work / "avatar.pt"
    record = {"video": args.video.name, "frame": args.frame}
    try:
        if not subject.is_dir():
            record["capture"] = stage([*PGHM, "capture", str(args.video), "--out", str(subject)], work / "capture.log")
        check_training_image(subject, args.frame)
        fit = [*PGHM, "fit", str(subject), "--prior", str(PRIOR), "--out", str(fitted)]
        record["fit"] = stage(fit, work / "fit.log")
        shutil.copyfile(fitted, ROOT / SHIPPED)
        record["avatar_mb"] = round((ROOT / SHIPPED).stat().st_size / 1e6, 1)
        print(f"wrote {SHIPPED} ({record['avatar_mb']} MB)")
        report, held_out = work / "eval.json", work / "eval.png"
        evaluation = [*PGHM, "eval", str(SHIPPED), str(subject), "--fit-poses", "--report", str(report)]
        evaluation += ["--strip", str(held_out)]  # beside the subject, not the shipped avatar
        record["eval"] = stage(evaluation, work / "eval.log")
        mean = json.loads(report.read_text())["mean"]
        record["eval"].update({key: round(float(mean[key]), 4) for key in ("psnr", "ssim", "iou")})
        print(f"  held-out frames, the fit's pose track: PSNR {mean['psnr']:.2f} dB, SSIM {mean['ssim']:.3f}")
        picture = DOCS / "real_avatar.png"
        views = avatar_views(ROOT / SHIPPED, subject, args.frame, fit_poses=True)
        strip([video_frame(args.video, subject, args.frame), *views]).save(picture, optimize=True)
        print(f"wrote {picture.relative_to(ROOT)}")
        if args.screenshot:
            screenshot = DOCS / "real_avatar_viewer.png"
            viewer_screenshot(SHIPPED, screenshot)
            print(f"wrote {screenshot.relative_to(ROOT)}")
        else:
            print("viewer screenshot: skipped (no display; run under xvfb-run)")
    finally:
        if args.work is None:
            shutil.rmtree(work, ignore_errors=True)
    write_json("real_avatar", record)
    return 0


def compare(args: argparse.Namespace) -> int:
    first = subject_image(args.subject, args.frame)
    rows, labels = [], []
    for name, avatar in (("before", args.before), ("after", args.after)):
        print(f"rendering {avatar}")
        rows.append(strip([first, *avatar_views(avatar, args.subject, args.frame, args.fit_poses)]))
        labels.append(f"{name}: {avatar.name}")
    labelled_rows(rows, labels).save(args.out, optimize=True)
    print(f"wrote {args.out}")
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    made = commands.add_parser("make", help="capture, fit and picture the shipped real avatar")
    made.add_argument("--video", type=Path, default=VIDEO, help="the video (default: the shared real one)")
    made.add_argument("--work", type=Path, help="keep the subject, avatar and logs here (and reuse the subject)")
    made.add_argument("--frame", type=int, default=FRAME, help="subject image of the strip (default %(default)s)")
    compared = commands.add_parser("compare", help="two avatars of one subject, one row each")
    compared.add_argument("before", type=Path)
    compared.add_argument("after", type=Path)
    compared.add_argument("--subject", type=Path, required=True, help="the subject folder both were fitted on")
    compared.add_argument("--frame", type=int, default=FRAME, help="subject image shown (default %(default)s)")
    compared.add_argument("--fit-poses", action="store_true", help="each avatar in its own pose track's pose")
    compared.add_argument("--out", type=Path, default=Path("before_after.png"))
    args = parser.parse_args()
    if args.command == "compare":
        return compare(args)
    args.video = args.video.resolve()
    args.work = args.work.resolve() if args.work else None
    args.screenshot = bool(os.environ.get("DISPLAY"))
    os.chdir(ROOT)
    return make(args)


if __name__ == "__main__":
    sys.exit(main())
