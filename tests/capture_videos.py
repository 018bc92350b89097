"""Videos for the capture tests: written with imageio-ffmpeg, and the real phone video's frames;
and the fake detection the front end's ordering tests hand around.

The real video (``shared/data/video/outdoor_dribble_40f.mp4``, never copied into the
repository) is looked for in a ``shared/`` folder beside the repository or beside one of
its parents (a git worktree sits one level deeper than the main checkout).

A test whose input this machine lacks (the real video, the ``capture`` extra) is skipped with
the reason, except under CI (``$CI`` set), where ``shared/`` sits beside the clone and
``scripts/setup.sh`` installs the extra: there it fails, since a skip would read as a pass.
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path
from typing import NoReturn

import numpy as np
import pytest

from pghm.capture.frontend import Detection

ROOT = Path(__file__).resolve().parent.parent
REAL_VIDEO_PATH = Path("shared") / "data" / "video" / "outdoor_dribble_40f.mp4"
REAL_VIDEO = next((parent / REAL_VIDEO_PATH for parent in ROOT.parents if (parent / REAL_VIDEO_PATH).is_file()), None)

CAPTURE_EXTRA_MISSING = "the capture extra (pip install 'pghm[capture]') is not installed"


def unavailable(reason: str) -> NoReturn:
    """Skip the test for ``reason``, or fail it under CI (see the module doc)."""
    if os.environ.get("CI"):
        pytest.fail(f"{reason}, which CI guarantees")
    pytest.skip(reason)


def require_mediapipe() -> None:
    """Return when mediapipe imports; else :func:`unavailable`."""
    try:
        import mediapipe  # noqa: F401
    except ImportError:
        unavailable(CAPTURE_EXTRA_MISSING)


def require_real_video() -> Path:
    """The real video's path; :func:`unavailable` when it is not beside the repository."""
    if REAL_VIDEO is None:
        unavailable(f"the real video {REAL_VIDEO_PATH} is not beside the repository")
    return REAL_VIDEO


LOSSLESS_QUALITY = 10
"""imageio-ffmpeg's best H.264 quality: flat test patterns come back within a few grey levels."""


def ffmpeg() -> str:
    import imageio_ffmpeg

    return imageio_ffmpeg.get_ffmpeg_exe()


def write_video(path: Path, frames: np.ndarray, fps: float = 10.0) -> Path:
    """Write (T, H, W, 3) uint8 frames (even H and W) as an H.264 MP4."""
    import imageio_ffmpeg

    height, width = frames.shape[1:3]
    writer = imageio_ffmpeg.write_frames(
        str(path), (width, height), fps=fps, codec="libx264", quality=LOSSLESS_QUALITY,
        macro_block_size=1, pix_fmt_out="yuv420p", ffmpeg_log_level="error",
    )  # fmt: skip
    writer.send(None)
    for frame in frames:
        writer.send(np.ascontiguousarray(frame))
    writer.close()
    return path


def with_rotation(source: Path, path: Path, degrees: int) -> Path:
    """Copy ``source`` into ``path`` with a display matrix rotating it ``degrees`` anticlockwise
    (what a phone writes for a portrait video), without re-encoding."""
    command = [ffmpeg(), "-v", "error", "-y", "-display_rotation:v:0", str(degrees), "-i", str(source)]
    subprocess.run([*command, "-c", "copy", str(path)], check=True)
    return path


def write_encoded(
    path: Path, frames: np.ndarray, codec: str, pixel_format: str, interlaced: bool = False, options: tuple = ()
) -> Path:
    """Write (T, H, W, 3) uint8 frames with ffmpeg's encoder ``codec`` in ``pixel_format`` (e.g. 10-bit
    HEVC, ProRes 422), at its default quality; ``interlaced``: as x264's top-field-first interlaced
    frames (even rows the first field); ``options``: more output options (filters, colour tags)."""
    height, width = frames.shape[1:3]
    command = [ffmpeg(), "-v", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{width}x{height}"]
    command += ["-r", "10", "-i", "-", *options, "-c:v", codec, "-pix_fmt", pixel_format]
    command += ["-x265-params", "log-level=error"] if codec == "libx265" else []
    command += ["-flags", "+ildct+ilme", "-x264-params", "tff=1", "-crf", "10"] if interlaced else []
    subprocess.run([*command, str(path)], input=np.ascontiguousarray(frames).tobytes(), check=True)
    return path


HDR_TAGS = {"HLG": "arib-std-b67", "PQ": "smpte2084"}
"""The names users know of the HDR transfer functions -> ffmpeg's."""


def hdr_tags(transfer: str) -> list[str]:
    """ffmpeg's colour tags of a BT.2020 video with the HDR ``transfer`` (a key of :data:`HDR_TAGS`)."""
    return ["-color_primaries", "bt2020", "-color_trc", HDR_TAGS[transfer], "-colorspace", "bt2020nc"]


def write_hlg_video(path: Path, frames: np.ndarray) -> Path:
    """Write (T, H, W, 3) uint8 SDR BT.709 frames as an iPhone stores video: 10-bit HEVC in BT.2020 with
    the HLG transfer (SDR's white at HDR's reference white, ITU-R BT.2408)."""
    from pghm.capture.video import REFERENCE_WHITE_NITS

    to_hlg = "zscale=tin=bt709:min=bt709:pin=bt709:rin=full:t=arib-std-b67:m=bt2020nc:p=bt2020:r=tv"
    options = ("-vf", f"{to_hlg}:npl={REFERENCE_WHITE_NITS},format=yuv420p10le", *hdr_tags("HLG"))
    return write_encoded(path, frames, "libx265", "yuv420p10le", options=options)


def with_sample_aspect(source: Path, path: Path, aspect: tuple[int, int]) -> Path:
    """Copy the H.264 ``source`` into ``path`` stating pixels ``aspect`` = (width, height) wide, without
    re-encoding (what anamorphic footage states)."""
    sar = f"h264_metadata=sample_aspect_ratio={aspect[0]}/{aspect[1]}"
    command = [ffmpeg(), "-v", "error", "-y", "-i", str(source), "-c", "copy", "-bsf:v", sar, str(path)]
    subprocess.run(command, check=True)
    return path


def write_flat_hdr_video(path: Path, signals: list[float], transfer: str, size: int = 64) -> Path:
    """A 10-bit BT.2020 HEVC video (as an iPhone records) of flat grey frames, frame k at the HDR
    ``transfer``'s signal ``signals[k]`` in [0, 1] (limited range: Y' = 64 + 876 signal), lossless."""
    luma, chroma = size * size, (size // 2) ** 2
    planes = [np.concatenate([np.full(luma, round(64 + 876 * v)), np.full(2 * chroma, 512)]) for v in signals]
    tags = [*hdr_tags(transfer), "-color_range", "tv"]
    command = [ffmpeg(), "-v", "error", "-y", "-f", "rawvideo", "-pix_fmt", "yuv420p10le", "-s", f"{size}x{size}"]
    command += ["-r", "10", *tags, "-i", "-", "-c:v", "libx265", "-x265-params", "log-level=error:lossless=1"]
    command += ["-pix_fmt", "yuv420p10le", *tags, str(path)]
    subprocess.run(command, input=np.concatenate(planes).astype("<u2").tobytes(), check=True)
    return path


def truncated_video(folder: Path) -> Path:
    """``folder/cut.mp4``: a 20-frame video with its index moved to the front (so it still opens, as a
    phone video copied incompletely does) and its last third cut off."""
    source = write_video(folder / "noise.mp4", np.random.default_rng(0).integers(0, 256, (20, 48, 64, 3), np.uint8))
    whole = folder / "whole.mp4"
    command = [ffmpeg(), "-v", "error", "-i", str(source), "-c", "copy", "-movflags", "+faststart", str(whole)]
    subprocess.run(command, check=True)
    cut = folder / "cut.mp4"
    cut.write_bytes(whole.read_bytes()[: whole.stat().st_size * 2 // 3])
    return cut


def real_frames(count: int, longest: int = 256) -> np.ndarray:
    """(count, H, W, 3) uint8: the real video's first frames, longest side ``longest`` (skip if the video is absent)."""
    video = require_real_video()
    from pghm.capture.crop import Region
    from pghm.capture.video import open_source, scaled_size

    source = open_source(video)
    full = Region.full(source.width, source.height)
    size = scaled_size(full, longest)
    size = (size[0] - size[0] % 2, size[1] - size[1] % 2)  # H.264 needs even sizes
    return np.stack([image for _, image in source.frames(full, size, max_frames=count)])


def detection_at(box: np.ndarray) -> Detection:
    """A front-end detection that is only its (4,) box: for tests of which answer the front end takes."""
    return Detection(np.zeros((33, 2), np.float32), np.zeros(33, np.float32), np.zeros((33, 3), np.float32), None, box)
