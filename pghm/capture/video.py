"""Streaming frame readers: a video file (through imageio-ffmpeg's ffmpeg) or a folder of images.

Both read one frame at a time, already cropped and scaled to the size asked for, so memory
holds one small frame whatever the input's length or resolution: ffmpeg decodes a 4K video
in C and hands Python frames after its ``crop`` and ``scale`` filters; JPEG images are
decoded at a reduced size (``Image.draft``) before the crop.

Orientation: ffmpeg applies a video's rotation (the display matrix phones write for
portrait videos) before the filters, and images are turned by their EXIF orientation, so
frames come out upright, and every size and pixel coordinate here is of the upright frame.

Colour: frames are SDR BT.709. An HDR video (HLG or PQ, as phones record: an iPhone's HEVC is
HLG) is mapped to it in ffmpeg's ``zscale`` with HDR's reference white at SDR's white
(:data:`REFERENCE_WHITE_NITS`). Read as SDR instead, an HDR frame is dim and desaturated (the
real video re-encoded in HLG: 14 grey levels a pixel from the original; in PQ: 26), and the avatar
learns those colours (``benchmarks/bench_capture_real.py``'s ``HDR`` variants, docs/capture.md).

Frame numbers are source frame numbers: with ``every`` N, the frames read are 0, N, 2N, ...
of the video (or of the folder's images sorted by name).
"""

from __future__ import annotations

import functools
import os
import re
import stat
import subprocess
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, ImageOps

from pghm.capture.crop import Region
from pghm.errors import PghmError, listed
from pghm.io.read_errors import IMAGE_READ_ERRORS

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".webp", ".tif", ".tiff")
SHOWN_FILES = 5
"""Unreadable files an error names before "and N more"."""
SHOWN_NAME = 40
"""Characters of a file name shown in a message (longer names are cut in the middle)."""
"""Files of an image folder that are read as frames (case-insensitive)."""

PROBE_SECONDS = 60.0
"""How long probing a video (decoding its first frame) may take before it counts as unreadable."""

TRUNCATION_SIGNS = ("partial file", "Invalid data found when processing input")
"""ffmpeg log lines (at level ``error``) that mean the file ended or broke mid-stream; a
clean decode of an intact file logs nothing at that level."""

HDR_TRANSFERS = {"arib-std-b67": "HLG", "smpte2084": "PQ"}
"""ffmpeg's names of the HDR transfer functions -> the names users know."""

REFERENCE_WHITE_NITS = 203
"""HDR's reference (diffuse) white in cd/m^2 (ITU-R BT.2408): HLG's 75 % signal, PQ's 58 %. It
becomes SDR's white; brighter highlights clip."""

_OUTPUT_SIZE = re.compile(r", (\d+)x(\d+)[ ,]")
_FPS = re.compile(r" (\d+(?:\.\d+)?) fps")
_DURATION = re.compile(r"Duration: (\d+):(\d\d):(\d\d(?:\.\d+)?)")
_SAMPLE_ASPECT = re.compile(r"\bSAR (\d+):(\d+)\b")
_PIXEL_FORMAT = re.compile(r" Video: [^,]*, ([a-z0-9_]+)")
_DEEP_FORMAT = re.compile(r"\d(le|be)$")
"""ffmpeg's pixel formats of more than 8 bits a sample end in their bits and byte order
(yuv420p10le, p010le, yuv422p12le)."""

INTERLACED_ORDERS = ("top first", "bottom first", "top coded first", "bottom coded first")
"""ffmpeg's field orders of an interlaced stream (camcorders' 1080i and DV): each frame holds two
fields a field period apart, which a moving limb shows as combing."""

DEINTERLACE_FILTER = "bwdif=mode=send_frame:deint=interlaced"
"""One progressive frame per interlaced frame (so frame numbers stay the source's), from its first
field and its neighbours' (Bob Weaver); frames not flagged interlaced pass untouched."""

TO_SDR_FILTER = f"zscale=p=bt709:t=bt709:npl={REFERENCE_WHITE_NITS}"
"""Maps an RGB (:data:`WORKING_FORMAT`) HDR frame (HLG or PQ, BT.2020) to SDR BT.709, reference white
to white: zscale linearises the input (HLG with its system gamma for a 1000 cd/m^2 display),
converts the primaries, and encodes BT.709 with ``npl`` = :data:`REFERENCE_WHITE_NITS` as SDR's 1.0."""

WORKING_FORMAT = "gbrp16le"
"""What a deep video's frames are converted to before cropping: ffmpeg's exact crop at an odd
offset of a subsampled deep format (10-bit HEVC and VP9, ProRes 422, 12-bit) scrambles its
colours (94 grey levels off on the real video in 10-bit HEVC; 1.6-2.0 through RGB, against 1.2 for
the 8-bit original), and zscale needs even sizes in subsampled formats. 16-bit RGB loses nothing."""


def scaled_size(region: Region, longest: int) -> tuple[int, int]:
    """(H, W) of ``region`` scaled so its longest side is ``longest`` pixels, never enlarged.

    s = min(1, longest / max(w, h)); each side rounds to the nearest pixel (at least 1), so
    the two axes' scales differ by under half a pixel: :func:`pghm.capture.crop.crop_intrinsics`
    uses each axis' exact ratio.
    """
    scale = min(1.0, longest / max(region.width, region.height))
    return max(1, round(region.height * scale)), max(1, round(region.width * scale))


def _ffmpeg() -> str:
    import imageio_ffmpeg

    return imageio_ffmpeg.get_ffmpeg_exe()


@functools.cache
def has_filter(name: str) -> bool:
    """Whether imageio-ffmpeg's ffmpeg has the video filter ``name`` (its builds differ by platform)."""
    listing = subprocess.run([_ffmpeg(), "-hide_banner", "-filters"], capture_output=True, text=True, errors="replace")
    return any(line.split()[1:2] == [name] for line in listing.stdout.splitlines())


def _last_line(text: str) -> str:
    lines = [line.strip() for line in text.strip().splitlines() if line.strip()]
    return lines[-1] if lines else "no output"


@dataclass(frozen=True)
class VideoFile:
    """A video file. ``width`` x ``height`` is its upright frame size at full resolution, in square
    pixels: a video whose pixels are not square (a sample aspect ratio, as camcorders' DV and
    anamorphic footage state) is read stretched to its display width.

    Attributes:
        path: the file.
        width: W, upright.
        height: H, upright.
        frame_estimate: frames in the video from its duration and frame rate (for progress
            bars only; containers do not always say), or None.
        fps: its frame rate as the container states it, or None.
        transfer: its HDR transfer function (a value of :data:`HDR_TRANSFERS`), or None for SDR.
        sample_aspect: a stored pixel's width over its height (1 for square pixels).
        deep: whether its samples have more than 8 bits (read through :data:`WORKING_FORMAT`).
        interlaced: whether its frames are interlaced (read through :data:`DEINTERLACE_FILTER`).
    """

    path: Path
    width: int
    height: int
    frame_estimate: int | None
    fps: float | None = None
    transfer: str | None = None
    sample_aspect: float = 1.0
    deep: bool = False
    interlaced: bool = False

    @classmethod
    def open(cls, path: Path) -> VideoFile:
        """Probe ``path`` by decoding its first frame; :class:`PghmError` if it is not a readable video.

        The frames are the first video stream that is not an attached picture (``0:V:0``): a song's
        cover art is not a one-frame video.
        """
        command = [_ffmpeg(), "-hide_banner", "-nostdin", "-i", str(path), "-map", "0:V:0"]
        command += ["-frames:v", "1", "-f", "null", "-"]
        try:
            result = subprocess.run(command, capture_output=True, text=True, errors="replace", timeout=PROBE_SECONDS)
        except subprocess.TimeoutExpired:
            raise PghmError(f"{path.name}: not a readable video (ffmpeg took over {PROBE_SECONDS:.0f} s)") from None
        log = result.stderr
        if "matches no streams" in log:
            raise PghmError(f"{path.name}: has no video stream")
        if result.returncode != 0:
            message = _last_line(log).replace(str(path), path.name)
            raise PghmError(f"{path.name}: not a readable video (ffmpeg: {message})")
        # The output stream's size is after ffmpeg's automatic rotation: the upright frame.
        output = log.split("Output #0", 1)[-1]
        sizes = [_OUTPUT_SIZE.search(line) for line in output.splitlines() if " Video: " in line]
        if not sizes or sizes[0] is None:
            raise PghmError(f"{path.name}: not a readable video (ffmpeg reported no frame size)")
        width, height = int(sizes[0].group(1)), int(sizes[0].group(2))
        stated_aspect = _SAMPLE_ASPECT.search(output)
        aspect = 1.0
        if stated_aspect and int(stated_aspect.group(1)) > 0 and int(stated_aspect.group(2)) > 0:
            aspect = int(stated_aspect.group(1)) / int(stated_aspect.group(2))
            width = max(1, round(width * aspect))
        inputs = log.split("Output #0", 1)[0].splitlines()
        stream = next((line for line in inputs if " Video: " in line and "(attached pic)" not in line), "")
        transfer = next((name for key, name in HDR_TRANSFERS.items() if key in stream), None)
        interlaced = any(order in stream for order in INTERLACED_ORDERS)
        pixel_format = _PIXEL_FORMAT.search(stream)
        deep = bool(pixel_format and _DEEP_FORMAT.search(pixel_format.group(1)))
        stated, duration = _FPS.search(log), _DURATION.search(log)
        fps = float(stated.group(1)) if stated else None
        estimate = None
        if fps and duration:
            hours, minutes, seconds = duration.groups()
            estimate = round((int(hours) * 3600 + int(minutes) * 60 + float(seconds)) * fps)
        return cls(path, width, height, estimate, fps, transfer, aspect, deep, interlaced)

    @property
    def tone_mapped(self) -> bool:
        """Whether frames are mapped from HDR to SDR (an HDR video, and an ffmpeg with ``zscale``)."""
        return self.transfer is not None and has_filter("zscale")

    @property
    def name(self) -> str:
        return self.path.name

    def frames(
        self, region: Region, out_size: tuple[int, int], every: int = 1, max_frames: int | None = None
    ) -> Iterator[tuple[int, np.ndarray]]:
        """Yield (source frame number, (H, W, 3) uint8 RGB) for frames 0, every, 2 every, ...

        Each frame is the upright frame's ``region`` scaled to ``out_size`` = (H, W) by ffmpeg: an
        interlaced video deinterlaced (before the stride, which would take away the neighbouring
        frames it uses), a deep video converted to :data:`WORKING_FORMAT`, non-square pixels
        stretched to square, ``crop`` with exact odd offsets, ``scale`` with area averaging, then an
        HDR video's :data:`TO_SDR_FILTER` on the small frame.
        ``-fps_mode passthrough`` keeps one output frame per decoded frame, so the k-th frame
        read is source frame k * every even in variable-frame-rate videos.
        """
        height, width = out_size
        filters = [DEINTERLACE_FILTER] if self.interlaced else []
        if every > 1:
            filters.append(f"select='not(mod(n\\,{every}))'")
        if self.deep or self.tone_mapped:
            filters.append(f"format={WORKING_FORMAT}")
        if self.sample_aspect != 1.0:
            filters.append(f"scale={self.width}:{self.height},setsar=1")
        if (region.x, region.y, region.width, region.height) != (0, 0, self.width, self.height):
            filters.append(f"crop={region.width}:{region.height}:{region.x}:{region.y}:exact=1")
        if (height, width) != (region.height, region.width):
            filters.append(f"scale={width}:{height}:flags=area")
        if self.tone_mapped:
            filters.append(TO_SDR_FILTER)
        command = [_ffmpeg(), "-hide_banner", "-nostdin", "-loglevel", "error", "-i", str(self.path)]
        command += ["-map", "0:V:0", "-vf", ",".join(filters) or "null", "-fps_mode", "passthrough"]
        if max_frames is not None:
            command += ["-frames:v", str(max_frames)]
        command += ["-f", "rawvideo", "-pix_fmt", "rgb24", "-"]
        frame_bytes = height * width * 3
        with tempfile.TemporaryFile() as log:
            process = subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=log)
            count = 0
            try:
                while True:
                    data = process.stdout.read(frame_bytes)
                    if len(data) < frame_bytes:
                        break
                    yield count * every, np.frombuffer(data, np.uint8).reshape(height, width, 3)
                    count += 1
                process.stdout.close()
                returncode = process.wait()
            finally:
                if process.poll() is None:  # the consumer stopped early, or an error or Ctrl-C
                    process.kill()
                    process.wait()
            log.seek(0)
            text = log.read().decode("utf-8", "replace")
        broken = [line for line in text.splitlines() if any(sign in line for sign in TRUNCATION_SIGNS)]
        if returncode != 0 or len(data) not in (0, frame_bytes) or broken:
            detail = (broken or [_last_line(text)])[0].split("] ")[-1].replace(str(self.path), self.name)
            raise PghmError(
                f"{self.name}: truncated or corrupt video (decoding stopped after source frame "
                f"{max(count - 1, 0) * every}: {detail})"
            )


@dataclass(frozen=True)
class ImageFolder:
    """A folder of images, the frames in file-name order; every image must have the same upright size.

    Attributes:
        path: the folder.
        files: the image files, sorted by name.
        width: W of the upright images.
        height: H of the upright images.
    """

    path: Path
    files: tuple[Path, ...]
    width: int
    height: int

    @classmethod
    def open(cls, path: Path) -> ImageFolder:
        """The folder's images, in name order. Every file named like an image must be one: a dangling
        link, a link loop, a folder, an unreadable or corrupt file among them refuses the folder, all
        of them named in one line, before anything is written (docs/capture.md)."""
        files = tuple(sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES))
        if not files:
            raise PghmError(f"{path.name}: a folder with no images ({', '.join(IMAGE_SUFFIXES)})")
        bad = [file.name for file in files if _unreadable(file)]
        if bad:
            names = listed((_short_name(name) for name in bad), SHOWN_FILES)
            raise PghmError(
                f"{path.name}: {len(bad)} of its {len(files)} image file(s) cannot be read ({names}): "
                "a broken link, a folder, no permission or not an image; remove or replace them"
            )
        width, height = _upright_size(files[0])
        return cls(path, files, width, height)

    @property
    def name(self) -> str:
        return self.path.name

    @property
    def frame_estimate(self) -> int:
        return len(self.files)

    @property
    def fps(self) -> None:
        """Images have no frame rate."""
        return None

    @property
    def transfer(self) -> None:
        """Images are read as SDR."""
        return None

    @property
    def tone_mapped(self) -> bool:
        return False

    def frames(
        self, region: Region, out_size: tuple[int, int], every: int = 1, max_frames: int | None = None
    ) -> Iterator[tuple[int, np.ndarray]]:
        """Yield (image number in name order, (H, W, 3) uint8 RGB), as :meth:`VideoFile.frames`."""
        numbers = range(0, len(self.files), every)
        for count, number in enumerate(numbers):
            if max_frames is not None and count >= max_frames:
                return
            yield number, _read_region(self.files[number], (self.width, self.height), region, out_size)


QUARTER_TURNS = (5, 6, 7, 8)
"""EXIF orientations that turn the image a quarter turn (width and height swap)."""


def _upright(image: Image.Image) -> tuple[int, int]:
    """(W, H) of an open image after its EXIF orientation."""
    width, height = image.size
    if image.getexif().get(ImageOps.ExifTags.Base.Orientation, 1) in QUARTER_TURNS:
        return height, width
    return width, height


def _short_name(name: str) -> str:
    """``name``, cut in the middle to :data:`SHOWN_NAME` characters."""
    if len(name) <= SHOWN_NAME:
        return name
    half = (SHOWN_NAME - 3) // 2
    return f"{name[:half]}...{name[-half:]}"


def _unreadable(file: Path) -> bool:
    """Whether ``file`` is not a readable image: its target missing or a loop, not a regular file, no
    permission, or a header no image reader parses (a truncated body is found when it is decoded)."""
    try:
        if not stat.S_ISREG(os.stat(file).st_mode):
            return True
        with Image.open(file):
            return False
    except IMAGE_READ_ERRORS:
        return True


def _upright_size(file: Path) -> tuple[int, int]:
    """(W, H) of an image after its EXIF orientation, from its header."""
    try:
        with Image.open(file) as image:
            return _upright(image)
    except IMAGE_READ_ERRORS as error:
        raise PghmError(f"{file.name}: not a readable image ({error})") from None


def _read_region(file: Path, size: tuple[int, int], region: Region, out_size: tuple[int, int]) -> np.ndarray:
    """The upright image's ``region`` resampled to ``out_size`` (H, W); a JPEG is decoded at the
    smallest power-of-two reduction (``Image.draft``) still at least as fine as the output."""
    height, width = out_size
    scale = max(width / region.width, height / region.height)
    try:
        with Image.open(file) as image:
            upright = _upright(image)
            if upright != size:
                raise PghmError(
                    f"{file.name}: {upright[0]}x{upright[1]} pixels, "
                    f"the folder's first image is {size[0]}x{size[1]}; every frame must have one size"
                )
            image.draft("RGB", (max(1, int(image.width * scale)), max(1, int(image.height * scale))))
            image = ImageOps.exif_transpose(image)
            if image.mode.startswith("I;16"):  # 16-bit grey: convert("RGB") would clip it to white
                image = Image.fromarray((np.asarray(image, dtype=np.uint16) >> 8).astype(np.uint8))
            image = image.convert("RGB")
    except PghmError:
        raise
    except IMAGE_READ_ERRORS as error:
        raise PghmError(f"{file.name}: not a readable image ({error})") from None
    # After draft the image is the upright frame shrunk by (fx, fy); the region shrinks with it.
    fx, fy = image.width / size[0], image.height / size[1]
    box = (region.x * fx, region.y * fy, (region.x + region.width) * fx, (region.y + region.height) * fy)
    return np.asarray(image.resize((width, height), Image.Resampling.LANCZOS, box=box))


def open_source(path: str | os.PathLike) -> VideoFile | ImageFolder:
    """The reader for ``path``: a folder of images, or any file ffmpeg decodes as video."""
    path = Path(path)
    if not path.exists():
        raise PghmError(f"{path}: no such file or folder")
    if path.is_dir():
        return ImageFolder.open(path)
    return VideoFile.open(path)
