"""Where rendered frames go: MP4, one PNG, or a PNG sequence, none ever left half-written.

:func:`open_sink` picks the writer from the output path (:func:`output_kind`); an MP4
without an encoder (imageio-ffmpeg) falls back to a PNG sequence. Every writer goes
through :mod:`pghm.io.atomic`: a file appears complete or not at all.
"""

from __future__ import annotations

import contextlib
import io
import os
from collections.abc import Callable
from pathlib import Path
from typing import Literal, Protocol

import numpy as np

from pghm.errors import PghmError
from pghm.io.atomic import PendingFile, atomic_write_bytes, free_space_note
from pghm.io.outputs import StagedFolder, check_output

PNG_PATTERN = "frame_{:05d}.png"
"""File names of a PNG sequence."""
MP4_QUALITY = 8
"""imageio-ffmpeg quality (0-10, 10 best): H.264 at near-visually-lossless rates."""


class FrameSink(Protocol):
    """Where rendered frames go: ``write`` (H, W, 3) uint8 images, then ``close`` (finish the
    file) or, after an error or an interrupt, ``abort`` (never leave a half-written file)."""

    path: Path
    frames: int

    def write(self, image: np.ndarray) -> None: ...

    def close(self) -> None: ...

    def abort(self) -> None: ...


def to_uint8(rgb: np.ndarray) -> np.ndarray:
    """(H, W, 3) float in [0, 1] -> uint8, rounded to nearest."""
    return np.clip(rgb * 255.0 + 0.5, 0, 255).astype(np.uint8)


def encoder_available() -> bool:
    """Whether imageio-ffmpeg and its ffmpeg binary are present (MP4 output)."""
    try:
        import imageio_ffmpeg

        return Path(imageio_ffmpeg.get_ffmpeg_exe()).exists()
    except (ImportError, RuntimeError):
        return False


class Mp4Sink:
    """H.264 MP4 through imageio-ffmpeg; the size is fixed by the first frame (even W and H).

    ffmpeg writes a temporary file beside ``path``; :meth:`close` finishes it and renames it
    into place, :meth:`abort` deletes it, so ``path`` is never a half-written video.
    """

    def __init__(self, path: Path, fps: float) -> None:
        self.path, self.fps, self.frames = path, fps, 0
        self._writer = None
        self._pending: PendingFile | None = None

    @staticmethod
    def check_size(width: int, height: int) -> None:
        """Raise :class:`PghmError` unless H.264 in yuv420p can hold W x H frames (even sides)."""
        if width % 2 or height % 2:
            raise PghmError(f"an MP4 (H.264, yuv420p) needs an even width and height, got {width} x {height}")

    def write(self, image: np.ndarray) -> None:
        import imageio_ffmpeg

        height, width = image.shape[:2]
        if self._writer is None:
            self.check_size(width, height)
            self._size = (width, height)
            self._pending = PendingFile(self.path, suffix=".mp4")
            self._writer = imageio_ffmpeg.write_frames(
                str(self._pending.path),
                self._size,
                fps=self.fps,
                codec="libx264",
                quality=MP4_QUALITY,
                macro_block_size=1,
                pix_fmt_out="yuv420p",
                ffmpeg_log_level="quiet",  # its failures are this sink's one line (encoder_failure)
            )
            self._writer.send(None)  # start the generator
        if (width, height) != self._size:
            raise PghmError(f"frame size changed from {self._size} to {(width, height)} while recording")
        try:
            self._writer.send(np.ascontiguousarray(image, dtype=np.uint8))
        except (OSError, RuntimeError):  # ffmpeg died: its pipe broke
            raise self.encoder_failure() from None
        self.frames += 1

    def encoder_failure(self) -> PghmError:
        """The one line for an encoder that stopped or wrote nothing (a full disk, most often)."""
        return PghmError(f"{self.path}: the video encoder failed{free_space_note(self.path)}")

    def close(self) -> None:
        """Finish the video and move it to ``path``."""
        if self._writer is not None:
            writer, pending, self._writer, self._pending = self._writer, self._pending, None, None
            try:
                writer.close()
                written = os.path.getsize(pending.path)
            except (OSError, RuntimeError):
                pending.discard()
                raise self.encoder_failure() from None
            except BaseException:
                pending.discard()
                raise
            if written == 0:  # ffmpeg failed and exited without a word to imageio-ffmpeg
                pending.discard()
                raise self.encoder_failure()
            pending.commit()

    def abort(self) -> None:
        """Stop without touching ``path``: the unfinished video is deleted."""
        if self._writer is not None:
            writer, pending, self._writer, self._pending = self._writer, self._pending, None, None
            with contextlib.suppress(Exception):
                writer.close()
            pending.discard()


def _png_bytes(image: np.ndarray) -> bytes:
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="PNG")
    return buffer.getvalue()


class PngSequenceSink:
    """frame_00000.png, frame_00001.png, ... in a new (or empty) directory, built in a hidden
    sibling and moved into place by :meth:`close`: an interrupted render leaves no frames."""

    def __init__(self, directory: Path) -> None:
        self.path, self.frames = directory, 0
        self._staged = StagedFolder(directory)

    def write(self, image: np.ndarray) -> None:
        atomic_write_bytes(self._staged.path / PNG_PATTERN.format(self.frames), _png_bytes(image))
        self.frames += 1

    def close(self) -> None:
        """Move the finished sequence to ``path``."""
        self._staged.commit()

    def abort(self) -> None:
        """Remove the frames written so far."""
        self._staged.discard()


class PngFileSink:
    """One PNG file: exactly one frame, written atomically."""

    def __init__(self, path: Path) -> None:
        self.path, self.frames = path, 0

    def write(self, image: np.ndarray) -> None:
        if self.frames:
            raise PghmError(f"{self.path}: a .png holds one frame; give a directory for a sequence")
        atomic_write_bytes(self.path, _png_bytes(image))
        self.frames = 1

    def close(self) -> None:
        """Nothing buffered."""

    def abort(self) -> None:
        """Nothing buffered."""


def output_kind(path: str | Path) -> Literal["mp4", "png", "dir"]:
    """What ``path`` asks for: ``.mp4``, ``.png``, or a directory (anything else)."""
    suffix = Path(path).suffix.lower()
    if str(path).endswith(("/", "\\")) or Path(path).is_dir() or not suffix:
        return "dir"
    if suffix in (".mp4", ".png"):
        return suffix[1:]
    raise PghmError(f"{path}: output must be a .mp4, a .png or a directory, not {suffix}")


def check_frame_size(path: str | Path, width: int, height: int) -> None:
    """Raise :class:`PghmError` when the writer :func:`open_sink` picks for ``path`` cannot take
    W x H frames: asked before any rendering, so that a refused size costs nothing."""
    if output_kind(path) == "mp4" and encoder_available():
        Mp4Sink.check_size(width, height)


def open_sink(path: str | Path, fps: float, on_fallback: Callable[[str], None] | None = None) -> FrameSink:
    """The writer for ``path`` (see :func:`output_kind`).

    An ``.mp4`` without an encoder becomes a PNG sequence in ``<stem>_frames/`` beside it;
    ``on_fallback`` is told so in one line.
    """
    path = Path(path)
    kind = output_kind(path)
    if kind == "png":
        return PngFileSink(path)
    if kind == "dir":
        return PngSequenceSink(path)
    if encoder_available():
        return Mp4Sink(path, fps)
    directory = check_output(path.with_name(f"{path.stem}_frames"), folder=True)
    if on_fallback is not None:
        on_fallback(f"no MP4 encoder (imageio-ffmpeg) found: writing a PNG sequence to {directory}/ instead")
    return PngSequenceSink(directory)
