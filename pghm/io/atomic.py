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

A kill test chooses where a save is interrupted through :func:`pghm._fault_injection.save_point`,
called at the three states a save can be in: ``created``, ``written`` and ``renamed``.
"""

from __future__ import annotations

import contextlib
import io
import os
import secrets
import stat
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import BinaryIO

from pghm._fault_injection import save_point

TEMPORARY_SUFFIX = ".tmp"
"""Temporary files are ``.<name>.<random>.tmp`` (plus ``suffix`` when one is asked for)."""


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
        save_point("created", path)
        return fd, candidate
    raise FileExistsError(f"{path.parent}: could not create a temporary file for {path.name}")


def _commit(temporary: Path, path: Path) -> None:
    """Rename ``temporary`` (complete and fsynced) over ``path`` and make the rename durable."""
    save_point("written", path)
    os.replace(temporary, path)
    _fsync_directory(path.parent)
    save_point("renamed", path)


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
