"""Atomic file writes: a reader (or a kill -9) never sees a half-written file.

Write to a temporary file in the destination's directory, flush and fsync it, rename it
over the destination (atomic on POSIX), then fsync the directory so the rename itself is
durable. On any error the temporary file is removed and the destination is untouched; a
kill -9 mid-write leaves the destination as it was plus a hidden ``.NAME.XXXX.tmp`` beside it.

The temporary file gets the permissions a plain ``open(path, "w")`` would (0o666 minus the
umask), or the destination's own when it replaces an existing file, so an atomic save never
makes an output private (``tempfile.mkstemp`` would create it 0o600).

Every writer in pghm and the viewer goes through here: ``tests/stress/test_nothing_lost.py``
checks each one and kills writers mid-save.

**Test hook (fault injection), off unless set.** A kill test must kill a writer at a moment it
chooses, not at one it hopes to catch by polling (a fast machine finishes a save between two
polls). With ``PGHM_TEST_PAUSE_SAVE="POINT:N:NAME"`` and ``PGHM_TEST_PAUSE_MARKER=PATH`` in the
environment, the N-th time (1-based, counted per process) this process reaches POINT for a
destination whose file name is NAME, it creates PATH and then sleeps until it is killed. The
points are the three states a save can be interrupted in:

* ``created``: the temporary file exists, empty; the destination is untouched;
* ``written``: the temporary file holds the whole new content, fsynced; not yet renamed;
* ``renamed``: the new content is under the destination's name (the save is complete).

Without the variables the hook is one dictionary look-up per save.
"""

from __future__ import annotations

import contextlib
import io
import os
import secrets
import stat
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import BinaryIO, Literal

TEMPORARY_SUFFIX = ".tmp"
"""Temporary files are ``.<name>.<random>.tmp`` (plus ``suffix`` when one is asked for)."""

PAUSE_VARIABLE = "PGHM_TEST_PAUSE_SAVE"
"""Test hook: ``POINT:N:NAME``, pause at the N-th ``POINT`` of a save to a file named ``NAME``."""
PAUSE_MARKER_VARIABLE = "PGHM_TEST_PAUSE_MARKER"
"""Test hook: the file created once the writer has paused (the test's cue to kill it)."""
SavePoint = Literal["created", "written", "renamed"]
_points_reached: dict[tuple[str, str], int] = {}
"""(point, file name) -> how many times this process has reached it (for the test hook)."""


def _test_pause(point: SavePoint, path: Path) -> None:
    """The fault-injection point described in the module docstring; returns at once unless asked to pause here."""
    request = os.environ.get(PAUSE_VARIABLE)
    if request is None:
        return
    key = (point, path.name)
    _points_reached[key] = _points_reached.get(key, 0) + 1
    wanted_point, wanted_count, wanted_name = request.split(":", 2)
    if (wanted_point, int(wanted_count), wanted_name) != (point, _points_reached[key], path.name):
        return
    marker = os.open(os.environ[PAUSE_MARKER_VARIABLE], os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    os.close(marker)
    while True:  # until the test's SIGKILL
        time.sleep(60)


def _create_temporary(path: Path, suffix: str) -> tuple[int, Path]:
    """A new empty file beside ``path``, open for writing, with the permissions described above."""
    for _ in range(100):
        candidate = path.parent / f".{path.name}.{secrets.token_hex(6)}{TEMPORARY_SUFFIX}{suffix}"
        try:
            fd = os.open(candidate, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0), 0o666)
        except FileExistsError:
            continue
        with contextlib.suppress(FileNotFoundError):
            os.fchmod(fd, stat.S_IMODE(os.stat(path).st_mode))
        _test_pause("created", path)
        return fd, candidate
    raise FileExistsError(f"{path.parent}: could not create a temporary file for {path.name}")


def _commit(temporary: Path, path: Path) -> None:
    """Rename ``temporary`` (complete and fsynced) over ``path`` and make the rename durable."""
    _test_pause("written", path)
    os.replace(temporary, path)
    _fsync_directory(path.parent)
    _test_pause("renamed", path)


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike) -> Iterator[BinaryIO]:
    """Open a binary temporary file that replaces ``path`` atomically on success."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, temporary = _create_temporary(path, "")
    try:
        with os.fdopen(fd, "wb") as file:
            yield file
            file.flush()
            os.fsync(file.fileno())
        _commit(temporary, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(temporary)
        raise


class PendingFile:
    """A temporary file beside ``path`` for a writer that needs a file name (an encoder
    subprocess, a library that opens the file itself): :meth:`commit` fsyncs it and renames
    it over ``path``; :meth:`discard` removes it and leaves ``path`` untouched.

    Args:
        path: the destination.
        suffix: appended to the temporary name, for writers that choose a format by it (".mp4").
    """

    def __init__(self, path: str | os.PathLike, suffix: str = "") -> None:
        self.destination = Path(path)
        self.destination.parent.mkdir(parents=True, exist_ok=True)
        fd, self.path = _create_temporary(self.destination, suffix)
        os.close(fd)

    def commit(self) -> None:
        try:
            fd = os.open(self.path, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
            _commit(self.path, self.destination)
        except BaseException:
            self.discard()
            raise

    def discard(self) -> None:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(self.path)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str = "") -> Iterator[Path]:
    """A :class:`PendingFile`'s temporary path, committed when the block ends normally, discarded otherwise."""
    pending = PendingFile(path, suffix)
    try:
        yield pending.path
    except BaseException:
        pending.discard()
        raise
    pending.commit()


def atomic_write(path: str | os.PathLike, write: Callable[[BinaryIO], object]) -> None:
    """Call ``write(file)`` on a temporary file, then move it over ``path`` atomically."""
    with atomic_open(path) as file:
        write(file)


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    atomic_write(path, lambda file: file.write(data))


def save_figure(figure, path: str | os.PathLike, **options) -> None:
    """Save a matplotlib figure atomically, in the format its suffix names (.png, .pdf, .svg, ...)."""
    from pghm.errors import PghmError

    path = Path(path)
    buffer = io.BytesIO()
    try:
        figure.savefig(buffer, format=path.suffix.lstrip(".").lower() or "png", **options)
    except ValueError as error:  # an unknown format
        raise PghmError(f"{path}: {str(error).splitlines()[0]}") from None
    atomic_write_bytes(path, buffer.getvalue())


def _fsync_directory(directory: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
