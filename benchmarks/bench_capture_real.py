"""``pghm capture`` on the real phone video changed the ways a user's own video differs from it.

A user's own video is not the one the command was tuned on: static or hand-held camera,
indoors or outdoors, one person or several. There is no truth for the
real video, but there is one for what a filter does to it. Each variant is the real video
through an ffmpeg filter whose effect on a pixel is known,

    x' = o + s * m(x),    m(x) = (W - x, y) when mirrored, else x    (continuous pixel coordinates)

and on the frame order (reversed or not; ``--every`` keeps the source frame numbers), so
its capture, mapped back through that map, can be held against the original video's capture:

- kept: the frames the capture kept, of those it read; cut: those whose person runs out of the frame
  (meta.json's ``cut_frames``);
- mask IoU: the variant's mask against the original's mapped into the variant's frame;
- 2D: the canonical joints each capture's camera projects, the variant's mapped back, apart by
  this % of the person's height (the original mask's extent), mean over the shared frames;
- PA: PA-MPJPE (mm) between the two captures' 3D joints in camera coordinates, the mirrored
  variant's mirrored back (x -> -x, left and right swapped);
- colour: the person's mean colour in the subject's images (inside its mask), the two captures'
  apart by this many grey levels (0-255; the largest channel, mean over the shared frames): what
  the avatar's colours are learned from;
- seconds and peak memory of the capture (a child process, as bench_capture.py's e).

The reference is the original's capture, not the truth: the figures say how far the capture
moves when the video changes in ways that leave the person as they were (its accuracy against
a truth is bench_capture.py's, where the 2D error is 1.1-1.6 % of the height).

    python benchmarks/bench_capture_real.py [VIDEO] [--only NAME ...] [--keep DIR]

Prints the table; writes benchmarks/results/bench_capture_real.json and
docs/capture_real_variants.png (each variant's middle shared frame: its captured joints in
magenta, the original's mapped into it in green). VIDEO defaults to the real phone video
beside the repository (``shared/data/video/outdoor_dribble_40f.mp4``).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from bench_capture import Crop, canonical_parents, draw_skeleton, person_height_px, read_video, run_capture
from common import DOCS, ROOT, load_average, print_table, write_json
from PIL import Image

from pghm.capture.crop import to_region
from pghm.capture.video import REFERENCE_WHITE_NITS
from pghm.subject import Subject, check, image_name, read_mask, read_rgb

REAL_VIDEO = Path("shared") / "data" / "video" / "outdoor_dribble_40f.mp4"
"""The real phone video, in a ``shared/`` folder beside the repository (or beside a parent of it)."""
CRF = 18
"""x264's quality of every re-encoded variant but the compressed one: visually lossless."""
PAD_COLOUR = "0x556677"
"""The wall a scaled-down video is padded with (a muted blue-grey)."""
HEVC_10BIT = (
    "-c:v", "libx265", "-crf", str(CRF), "-pix_fmt", "yuv420p10le", "-tag:v", "hvc1", "-x265-params", "log-level=error",
)  # fmt: skip
"""How many phones store video: HEVC, 10 bits a sample."""
HDR_ENCODE = (*HEVC_10BIT, "-color_primaries", "bt2020", "-colorspace", "bt2020nc", "-color_range", "tv")
"""How an iPhone stores HDR: 10-bit HEVC in BT.2020; the transfer's tag is the variant's."""
TILE_SIZE = 320
"""Pixels of a panel's height (and of the square its whole frame is fitted in)."""
TILE_GAP = 8
FIGURE_COLUMNS = 5
JOINTS_COLOUR, ORIGINAL_COLOUR = (255, 60, 200), (40, 220, 90)


@dataclass(frozen=True)
class Variant:
    """The real video through ``filter`` (an ffmpeg filter graph; None: the video itself).

    ``scale``, ``offset`` and ``mirrored``: the pixel map of the module docstring; ``reversed``:
    the frames in reverse order; ``crf``: x264's quality; ``encode``: ffmpeg's output options instead
    of x264's at ``crf``; ``options``: extra ``pghm capture`` options.
    """

    name: str
    about: str
    filter: str | None = None
    scale: float = 1.0
    offset: tuple[float, float] = (0.0, 0.0)
    mirrored: bool = False
    reversed: bool = False
    crf: int = CRF
    encode: tuple[str, ...] | None = None
    options: tuple[str, ...] = ()

    def to_variant(self, xy: np.ndarray, width: int) -> np.ndarray:
        """(..., 2) original-video pixel positions -> the variant's (``width``: the original's)."""
        xy = np.array(xy, dtype=np.float64)
        if self.mirrored:
            xy[..., 0] = width - xy[..., 0]
        return self.scale * xy + np.asarray(self.offset)

    def to_original(self, xy: np.ndarray, width: int) -> np.ndarray:
        """(..., 2) the variant's pixel positions -> the original video's (the inverse of :meth:`to_variant`)."""
        xy = (np.array(xy, dtype=np.float64) - np.asarray(self.offset)) / self.scale
        if self.mirrored:
            xy[..., 0] = width - xy[..., 0]
        return xy


VARIANTS = (
    Variant("original", "the phone video as it is (portrait, hand-held, outdoors)"),
    Variant("mirrored", "flipped left to right", "hflip", mirrored=True),
    Variant(
        "wide",
        "a wide static shot: the person at half size in a landscape frame",
        f"scale=540:960,pad=1920:1080:690:60:color={PAD_COLOUR}",
        scale=0.5,
        offset=(690, 60),
    ),
    Variant(
        "far",
        "far from the camera: a quarter size, off centre in a landscape frame",
        f"scale=270:480,pad=1920:1080:1400:500:color={PAD_COLOUR}",
        scale=0.25,
        offset=(1400, 500),
    ),
    Variant(
        "two people",
        "beside a smaller mirrored copy of themselves (the tracked one must stay the large one)",
        "[0:v]scale=540:960,split[a][b];[b]hflip,scale=378:672,pad=540:960:81:200:color=gray[c];[a][c]hstack",
        scale=0.5,
    ),
    Variant("cut off", "filmed too close: the frame ends at the knees", "crop=1080:1250:0:0"),
    Variant("dark", "underexposed and noisy (dusk, indoors)", "eq=brightness=-0.25:contrast=0.7,noise=alls=12:allf=t"),
    Variant("compressed", "heavily compressed (x264 CRF 40, a messaging app's)", "null", crf=40),
    Variant("reversed", "played backwards (the tracker starts from the last frame)", "reverse", reversed=True),
    Variant("every 2", "every second frame (--every 2)", options=("--every", "2")),
    Variant(
        "anamorphic",
        "stored half as wide, pixels stated twice as wide as tall (a camcorder's)",
        "scale=540:1920,setsar=2",
    ),
    Variant("10-bit", "10-bit HEVC (SDR, as many Android phones record)", "null", encode=HEVC_10BIT),
    *(
        Variant(
            f"HDR {name}",
            f"an HDR video ({name}, HEVC 10-bit BT.2020, as {phones}), SDR's white at HDR's reference white",
            f"zscale=tin=bt709:min=bt709:pin=bt709:rin=tv:t={tag}:m=bt2020nc:p=bt2020:r=tv:npl={REFERENCE_WHITE_NITS},"
            "format=yuv420p10le",
            encode=(*HDR_ENCODE, "-color_trc", tag),
        )
        for name, tag, phones in (("HLG", "arib-std-b67", "iPhones record"), ("PQ", "smpte2084", "HDR10 phones do"))
    ),
)


def make_variant(video: Path, variant: Variant, out: Path) -> Path:
    """The variant's video file (the video itself when it has no filter)."""
    if variant.filter is None:
        return video
    import imageio_ffmpeg

    command = [imageio_ffmpeg.get_ffmpeg_exe(), "-y", "-loglevel", "error", "-i", str(video)]
    encode = variant.encode or ("-c:v", "libx264", "-crf", str(variant.crf), "-pix_fmt", "yuv420p")
    subprocess.run([*command, "-filter_complex", variant.filter, *encode, str(out)], check=True)
    return out


@dataclass(frozen=True)
class Captured:
    """A captured subject in its source video's pixels.

    Attributes:
        frames: (n,) the source frame of each kept image.
        masks: source frame -> (H, W) bool mask in the source video's frame.
        uv: (n, C, 2) the canonical joints projected by the captured camera, in source pixels.
        joints: (n, C, 3) the canonical joints in camera coordinates (metres).
        colours: (n, 3) the person's mean RGB (0-255) in each kept image, inside its mask.
        source_size: (H, W) of the source video.
        crop: the capture's crop.
    """

    frames: np.ndarray
    masks: dict[int, np.ndarray]
    uv: np.ndarray
    joints: np.ndarray
    colours: np.ndarray
    source_size: tuple[int, int]
    crop: Crop

    @classmethod
    def of(cls, subject_dir: Path) -> Captured:
        from pghm.body import load_body
        from pghm.capture.metrics import camera_joints, project

        subject = Subject.open(subject_dir)
        a, crop = subject.arrays, Crop.of(subject)
        size = (int(subject.meta["crop"]["source_height"]), int(subject.meta["crop"]["source_width"]))
        frames = np.asarray(a.frame_index, dtype=np.int64)
        crop_masks = [read_mask(subject_dir / "masks" / image_name(i)) > 0.5 for i in range(len(frames))]
        masks = {int(f): crop.mask_to_source(mask, size) for f, mask in zip(frames, crop_masks)}
        colours = np.stack(
            [255 * read_rgb(subject_dir / "images" / image_name(i))[mask].mean(0) for i, mask in enumerate(crop_masks)]
        )
        joints = camera_joints(load_body("anny"), a.shape, a.rotations, a.translation, a.world_to_camera)
        return cls(frames, masks, crop.to_source(project(joints, a.K)), joints, colours, size, crop)


def swapped_sides(names: list[str]) -> np.ndarray:
    """(C,) the index of each joint's mirror image (left <-> right; itself on the midline)."""
    other = {"left": "right", "right": "left"}
    mirrored = ["_".join(other.get(part, part) for part in name.split("_")) for name in names]
    return np.array([names.index(name) for name in mirrored])


def warp_mask(mask: np.ndarray, variant: Variant, size: tuple[int, int]) -> np.ndarray:
    """(H', W') bool: the original's (H, W) mask seen in the variant's frame (nearest; outside it: empty)."""
    ys, xs = np.mgrid[0 : size[0], 0 : size[1]]
    centres = np.stack([xs + 0.5, ys + 0.5], -1)
    source = np.floor(variant.to_original(centres, mask.shape[1])).astype(np.int64)
    x, y = source[..., 0], source[..., 1]
    inside = (x >= 0) & (x < mask.shape[1]) & (y >= 0) & (y < mask.shape[0])
    out = np.zeros(size, dtype=bool)
    out[inside] = mask[y[inside], x[inside]]
    return out


def compare(original: Captured, captured: Captured, variant: Variant, frames_read: int) -> dict:
    """The module docstring's figures of one variant's capture against the original's."""
    from pghm.body import load_body
    from pghm.capture.metrics import error_2d_percent, mapped_joints, pa_mpjpe

    width = original.source_size[1]
    source_frame = (frames_read - 1 - captured.frames) if variant.reversed else captured.frames
    row_of = {int(f): k for k, f in enumerate(original.frames)}
    shared = [(k, row_of[int(f)]) for k, f in enumerate(source_frame) if int(f) in row_of]
    if not shared:
        return {"shared_frames": 0}
    mine, theirs = (np.array(column) for column in zip(*shared))
    order = swapped_sides(mapped_joints(load_body("anny"))[0]) if variant.mirrored else slice(None)
    uv = variant.to_original(captured.uv[mine], width)[:, order]
    joints = captured.joints[mine][:, order] * (np.array([-1.0, 1.0, 1.0]) if variant.mirrored else 1.0)
    masks = np.stack([original.masks[int(original.frames[t])] for t in theirs])
    ious = []
    for k, t in zip(mine, theirs):
        reference = warp_mask(original.masks[int(original.frames[t])], variant, captured.source_size)
        mask = captured.masks[int(captured.frames[k])]
        ious.append((mask & reference).sum() / max((mask | reference).sum(), 1))
    return {
        "shared_frames": len(shared),
        "mask_iou": round(float(np.mean(ious)), 4),
        "joints_2d_pct": round(error_2d_percent(uv, original.uv[theirs], person_height_px(masks)), 3),
        "pa_mpjpe_mm": round(1000 * pa_mpjpe(joints, original.joints[theirs]), 2),
        "colour_levels": round(float(np.abs(captured.colours[mine] - original.colours[theirs]).max(-1).mean()), 2),
        "middle": (int(mine[len(mine) // 2]), int(theirs[len(theirs) // 2])),
    }


def panel(
    video: Path, original: Captured, captured: Captured, variant: Variant, middle: tuple[int, int]
) -> Image.Image:
    """The variant's middle shared frame, whole (fitted in a square), beside the capture's crop of it with
    its joints and the original capture's mapped into it."""
    mine, theirs = middle
    frame = int(captured.frames[mine])
    whole = Image.fromarray(read_video(video, {frame})[frame])
    crop = captured.crop
    image = Image.fromarray(crop.image_to_subject(np.asarray(whole)))
    zoom = TILE_SIZE / image.height  # drawn after resizing, so the lines keep their width
    image = image.resize((round(image.width * zoom), TILE_SIZE), Image.Resampling.LANCZOS)
    parents = canonical_parents()
    reference = variant.to_variant(original.uv[theirs], original.source_size[1])
    draw_skeleton(image, zoom * to_region(reference, crop.region, crop.size), ORIGINAL_COLOUR, parents)
    draw_skeleton(image, zoom * to_region(captured.uv[mine], crop.region, crop.size), JOINTS_COLOUR, parents)
    whole.thumbnail((TILE_SIZE, TILE_SIZE), Image.Resampling.LANCZOS)
    out = Image.new("RGB", (TILE_SIZE + TILE_GAP + image.width, TILE_SIZE), "white")
    out.paste(whole, ((TILE_SIZE - whole.width) // 2, (TILE_SIZE - whole.height) // 2))
    out.paste(image, (TILE_SIZE + TILE_GAP, 0))
    return out


def plot_panels(panels: list[tuple[str, Image.Image]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pghm.io.atomic import save_figure

    rows = -(-len(panels) // FIGURE_COLUMNS)
    fig, axes = plt.subplots(rows, FIGURE_COLUMNS, figsize=(4.2 * FIGURE_COLUMNS, 2.6 * rows), squeeze=False)
    for ax in axes.flat:
        ax.axis("off")
    for ax, (name, image) in zip(axes.flat, panels):
        ax.imshow(np.asarray(image))
        ax.set_title(name, fontsize=9)
    fig.suptitle(
        "the real video's variants: a frame | the capture's crop of it, its joints (magenta) "
        "and the original capture's mapped in (green)",
        fontsize=9,
    )
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = next((p / REAL_VIDEO for p in ROOT.parents if (p / REAL_VIDEO).is_file()), None)
    parser.add_argument("video", nargs="?", type=Path, default=default)
    names = [v.name for v in VARIANTS]
    parser.add_argument("--only", nargs="+", choices=names, default=names, help="these variants (the original always)")
    parser.add_argument("--keep", type=Path, default=None, help="keep the videos, subjects and logs in this folder")
    parser.add_argument("--results", default="bench_capture_real")
    args = parser.parse_args()
    if args.video is None or not args.video.is_file():
        print("bench_capture_real: the real video was not found; give its path", file=sys.stderr)
        return 2
    variants = [v for v in VARIANTS if v.name == "original" or v.name in args.only]
    rows, pictures = [], []
    with tempfile.TemporaryDirectory() as scratch:
        work = args.keep or Path(scratch)
        work.mkdir(parents=True, exist_ok=True)
        original = None
        for variant in variants:
            slug = variant.name.replace(" ", "_")
            video = make_variant(args.video, variant, work / f"{slug}.mp4")
            subject = work / slug
            run = run_capture(video, subject, work / f"{slug}.log", variant.options)
            counts = Subject.open(subject).meta["counts"]
            captured = Captured.of(subject)
            original = original or captured
            figures = compare(original, captured, variant, counts["frames_read"])
            middle = figures.pop("middle", None)
            rows.append(
                {
                    "variant": variant.name,
                    "kept": f"{len(captured.frames)}/{counts['frames_read']}",
                    "cut": len(counts["cut_frames"]),
                    **figures,
                    "check_problems": len(check(subject)),
                    "seconds": round(run.seconds, 1),
                    "peak_gb": round(run.peak_gb, 2),
                    "about": variant.about,
                }
            )
            if middle is not None:
                pictures.append((variant.name, panel(video, original, captured, variant, middle)))
            print(f"{variant.name}: done ({run.seconds:.0f} s)", flush=True)
    columns = ["variant", "kept", "cut", "shared_frames", "mask_iou", "joints_2d_pct", "pa_mpjpe_mm", "colour_levels"]
    columns.append("check_problems")
    print_table(rows, [*columns, "seconds", "peak_gb"])
    figure = DOCS / "capture_real_variants.png"
    plot_panels(pictures, figure)
    write_json(args.results, {"video": args.video.name, "load_average": round(load_average(), 2), "rows": rows})
    print(f"wrote {figure.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
