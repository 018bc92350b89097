"""Evaluated motion frames kept for playback and scrubbing: packed Gaussians under a byte budget, LRU.

A motion frame costs the model and skinning (~20-30 ms on 2 cores) to evaluate and a few
hundred kilobytes to keep, so after one pass over a clip every frame is drawn from memory.
A frame is stored packed (:class:`PackedFrame`): what decides a footprint (position, scale,
opacity) in float32, colours and normals in float16, which keeps the image within the
GL-vs-CPU bar (max abs error 2e-3, mean 1e-4; tests/test_gl_vs_cpu_avatar.py):

    per Gaussian: means 3 x 4 B + scales 4 B + opacities 4 B + colours 3 x 2 B + normals 3 x 2 B = 32 B

(44 B in float32); 11,156 Gaussians -> 357 KB a frame. Measured on the shipped avatar at
1280 x 720 (docs/viewer.md): float16 colours change a pixel by at most ~2.4e-4; float16
scales (and opacities) move the 1/255 footprint cut-off and flip pixels on silhouettes by
up to 1/255 = 3.9e-3, over the bar; float16 positions would round a coordinate near 1 m
by 0.5 mm, a fifth of a pixel.

:class:`FrameCache` maps a key (the scene state that made the frame, the frame index) to a
packed frame and evicts the least recently used frames while the total exceeds the budget.
It is shared by the model worker (puts) and the UI (gets), hence the lock.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Hashable, Iterator
from dataclasses import dataclass

import numpy as np

from pghm.errors import PghmError
from pghm.render.driver import GaussianArrays

DEFAULT_BUDGET_MB = 256.0
"""Default memory budget of the frame cache (~750 frames of the shipped avatar)."""
MEGABYTE = 1 << 20
FOOTPRINT_DTYPE = np.float32
"""Means, scales, opacities: in float16 they move footprint cut-offs (flips over the bar)."""
SHADE_DTYPE = np.float16
"""Colours and normals: within the GL-vs-CPU bar in half precision (measured)."""


@dataclass(frozen=True)
class PackedFrame:
    """One frame's Gaussians as stored in the cache.

    Attributes:
        means: (N, 3) float32.
        scales: (N,) float32.
        colors: (N, 3) float16.
        opacities: (N,) float32.
        normals: (N, 3) float16.
        view: what the view-dependent colour was evaluated for (compared by the caller).
    """

    means: np.ndarray
    scales: np.ndarray
    colors: np.ndarray
    opacities: np.ndarray
    normals: np.ndarray
    view: Hashable = None

    @staticmethod
    def pack(arrays: GaussianArrays, view: Hashable = None, exact: bool = False) -> PackedFrame:
        """``arrays`` rounded to the cache's precision (a copy); ``exact`` keeps every field float32."""
        shade = FOOTPRINT_DTYPE if exact else SHADE_DTYPE
        return PackedFrame(
            means=arrays.means.astype(FOOTPRINT_DTYPE),
            scales=arrays.scales.astype(FOOTPRINT_DTYPE),
            colors=arrays.colors.astype(shade),
            opacities=arrays.opacities.astype(FOOTPRINT_DTYPE),
            normals=arrays.normals.astype(shade),
            view=view,
        )

    def unpack(self) -> GaussianArrays:
        """The frame as float32 :class:`GaussianArrays` (what the renderer takes)."""
        return GaussianArrays(
            means=self.means,
            scales=self.scales,
            colors=self.colors.astype(np.float32),
            opacities=self.opacities,
            normals=self.normals.astype(np.float32),
        )

    @property
    def nbytes(self) -> int:
        return sum(a.nbytes for a in (self.means, self.scales, self.colors, self.opacities, self.normals))


class FrameCache:
    """Packed frames by key, least recently used evicted beyond ``budget_bytes``.

    Args:
        budget_bytes: the most the stored frames may take together (their array bytes).
    """

    def __init__(self, budget_bytes: int = int(DEFAULT_BUDGET_MB * MEGABYTE)) -> None:
        if budget_bytes < 0:
            raise PghmError(f"frame cache budget must be >= 0 bytes, got {budget_bytes}")
        self.budget_bytes = int(budget_bytes)
        self._frames: OrderedDict[Hashable, PackedFrame] = OrderedDict()
        self._nbytes = 0
        self._lock = threading.Lock()
        self.evictions = 0
        """Frames dropped to stay within the budget."""

    def get(self, key: Hashable) -> PackedFrame | None:
        """The frame stored under ``key`` (now the most recently used), or None."""
        with self._lock:
            frame = self._frames.get(key)
            if frame is not None:
                self._frames.move_to_end(key)
            return frame

    def peek(self, key: Hashable) -> PackedFrame | None:
        """Like :meth:`get` without touching the recency order (prefetching asks without using)."""
        with self._lock:
            return self._frames.get(key)

    def put(self, key: Hashable, frame: PackedFrame) -> None:
        """Store ``frame`` (most recently used), then evict the least recently used beyond the budget.

        A frame larger than the whole budget is not stored.
        """
        with self._lock:
            old = self._frames.pop(key, None)
            if old is not None:
                self._nbytes -= old.nbytes
            if frame.nbytes > self.budget_bytes:
                return
            self._frames[key] = frame
            self._nbytes += frame.nbytes
            while self._nbytes > self.budget_bytes:
                _, evicted = self._frames.popitem(last=False)
                self._nbytes -= evicted.nbytes
                self.evictions += 1

    def clear(self) -> None:
        with self._lock:
            self._frames.clear()
            self._nbytes = 0

    @property
    def nbytes(self) -> int:
        """Bytes of the frames stored now (<= ``budget_bytes``)."""
        with self._lock:
            return self._nbytes

    def __len__(self) -> int:
        with self._lock:
            return len(self._frames)

    def keys(self) -> Iterator[Hashable]:
        """Keys from least to most recently used (a snapshot)."""
        with self._lock:
            return iter(list(self._frames))


def frames_ahead(playhead: int, num_frames: int, loop: bool) -> list[int]:
    """Frame indices in the order a player reaches them from ``playhead``: playhead, playhead + 1, ...

    Wraps to the clip's start when looping; otherwise the frames before the playhead come
    last, nearest first (a scrub back reaches them next).
    """
    after = list(range(playhead, num_frames))
    before = list(range(playhead)) if loop else list(range(playhead - 1, -1, -1))
    return after + before
