"""Screenshots and recordings of the viewer.

Two kinds of recording:

* ``window``: every displayed frame of the whole window (UI included) as it is drawn, at
  whatever rate the machine manages; the file is tagged with the nominal ``fps``.
* ``motion``: the open motion played at exactly ``fps``: frame k shows the motion at
  ``start + k / fps`` whatever the frame time, the scene viewport only (no UI), from the
  current frame to the end of the clip, then the recording stops by itself.

Files are written by :func:`pghm.render.sinks.open_sink` (MP4 through imageio-ffmpeg; a
PNG sequence in ``<name>_frames/`` when no encoder is installed, or when asked with a
directory path).
"""

from __future__ import annotations

import io
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from PIL import Image

from pghm.errors import PghmError
from pghm.io.atomic import atomic_write_bytes
from pghm.render import FrameSink, open_sink

RecordSource = Literal["window", "motion"]


@dataclass
class Recording:
    """A recording in progress.

    Attributes:
        sink: where frames go.
        source: "window" or "motion".
        fps: frames per second of the file (and, for "motion", of the sampling).
        start: motion time of frame 0, seconds ("motion" only).
        total: frames to write ("motion" only; None for "window": until stopped).
    """

    sink: FrameSink
    source: RecordSource
    fps: float
    start: float = 0.0
    total: int | None = None

    @property
    def done(self) -> bool:
        return self.total is not None and self.sink.frames >= self.total

    def motion_time(self) -> float:
        """Motion time of the next frame ("motion" recordings)."""
        return self.start + self.sink.frames / self.fps


def save_png(path: str | Path, image: np.ndarray) -> Path:
    """Write (H, W, 3) uint8 ``image`` as a PNG, atomically (parent folders created)."""
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise PghmError(f"screenshots are PNG files, got {path}")
    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="PNG")
    atomic_write_bytes(path, buffer.getvalue())
    return path


def start_recording(
    path: str | Path,
    source: RecordSource,
    fps: float,
    motion_start: float = 0.0,
    motion_frames: int = 0,
    log: Callable[[str], None] | None = None,
) -> Recording:
    """Open the sink for a recording of ``source`` (see the module docstring).

    ``motion_start`` (seconds) and ``motion_frames`` place a "motion" recording on the
    timeline; ``log`` hears about a fallback to PNG frames.
    """
    if source not in ("window", "motion"):
        raise PghmError(f"record source must be 'window' or 'motion', got {source!r}")
    if not fps > 0:
        raise PghmError(f"recording fps must be positive, got {fps}")
    sink = open_sink(path, fps, on_fallback=log)
    total = max(motion_frames, 1) if source == "motion" else None
    return Recording(sink=sink, source=source, fps=fps, start=motion_start, total=total)
