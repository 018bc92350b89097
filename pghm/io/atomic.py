"""Atomic file writes: a reader (or a kill -9) never sees a half-written file.

Write to a temporary file in the destination's directory, flush and fsync it, rename it
over the destination (atomic on POSIX), then fsync the directory so the rename itself is
durable. On any error the temporary file is removed and the destination is untouched; a
kill -9 mid-write leaves the destination as it was plus a hidden ``.NAME.XXXX.tmp`` beside it.

The temporary file gets the permissions a plain ``open(path, "w")`` would (0o666 minus the
umask), or the destination's own when it replaces an existing file, so an atomic save never
makes an output private (``tempfile.mkstemp`` would create it 0o600).

Every writer in pghm and the viewer goes through here: ``tests/stress/test_nothing_lost.py``
checks each one and kills writers mid-save. A write that fails (a full disk, a quota, an I/O
error) is one line naming the file, ``OUT: no space left on device (N MB free)``
(:func:`write_failure`), and a command with several outputs writes them all or none
(:func:`all_or_none`).

A kill test chooses where a save is interrupted through :func:`pghm._fault_injection.save_point`,
called at the three states a save can be in: ``created``, ``written`` and ``renamed``.
"""

from __future__ import annotations

import contextlib
import errno
import io
import os
import secrets
import stat
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import BinaryIO

from pghm._fault_injection import save_point
from pghm.errors import PghmError

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


SPACE_ERRORS = (errno.ENOSPC, errno.EDQUOT)
"""Write errors for which the free space is worth stating."""


def free_megabytes(path: Path) -> float | None:
    """Megabytes free to an unprivileged writer on the filesystem holding ``path``'s folder."""
    try:
        status = os.statvfs(path.parent)
    except OSError:
        return None
    return status.f_bavail * status.f_frsize / 2**20


def free_space_note(path: Path) -> str:
    """`` (12 MB free)`` of the filesystem ``path`` would be written to, or nothing when unknown."""
    free = free_megabytes(path)
    return f" ({free:.0f} MB free)" if free is not None else ""


def check_free_space(path: str | os.PathLike, needed_bytes: int) -> None:
    """Refuse, before the work that would fill it, an output whose filesystem has less room than
    the ``needed_bytes`` its files will roughly take: ``PATH: needs about N MB, M MB free``. A
    rough check (other writers may come and go); the writes themselves still check their bytes."""
    path = Path(path)
    free = free_megabytes(path)
    needed = needed_bytes / 2**20
    if free is not None and free < needed:
        raise PghmError(
            f"{path}: needs about {max(needed, 0.1):.1f} MB, {free:.1f} MB free; free some space or write elsewhere"
        )


def write_failure(path: Path, error: OSError) -> PghmError:
    """The one line for a failed write of ``path``: ``path: no space left on device (12 MB free)``."""
    reason = (error.strerror or str(error)).lower() if error.errno else str(error)
    return PghmError(f"{path}: {reason}" + (free_space_note(path) if error.errno in SPACE_ERRORS else ""))


@contextlib.contextmanager
def _written(path: Path, temporary: Path) -> Iterator[None]:
    """Remove ``temporary`` if the block fails; an OSError becomes :func:`write_failure`'s line."""
    try:
        yield
    except OSError as error:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(temporary)
        raise write_failure(path, error) from None
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(temporary)
        raise


def _write_temporary(path: Path, write: Callable[[BinaryIO], object]) -> Path:
    """``write(file)`` into a new fsynced temporary beside ``path``; its path (removed on failure)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, temporary = _create_temporary(path, "")
    with _written(path, temporary), os.fdopen(fd, "wb") as file:
        write(file)
        file.flush()
        os.fsync(file.fileno())
    return temporary


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike) -> Iterator[BinaryIO]:
    """Open a binary temporary file that replaces ``path`` atomically on success."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, temporary = _create_temporary(path, "")
    with _written(path, temporary):
        with os.fdopen(fd, "wb") as file:
            yield file
            file.flush()
            os.fsync(file.fileno())
        _commit(temporary, path)


class Outputs:
    """A command's outputs, written together (:func:`all_or_none`): each write goes to a fsynced
    temporary beside its file, and only when every one has succeeded are they all renamed into
    place; then the ``after`` callbacks run (what may go only once the outputs exist: a checkpoint)."""

    def __init__(self) -> None:
        self.pending: list[tuple[Path, Path]] = []
        self.after: list[Callable[[], object]] = []

    def write(self, path: str | os.PathLike, write: Callable[[BinaryIO], object]) -> None:
        path = Path(path)
        self.pending.append((_write_temporary(path, write), path))

    def write_bytes(self, path: str | os.PathLike, data: bytes) -> None:
        self.write(path, lambda file: file.write(data))

    def commit(self) -> None:
        for temporary, path in self.pending:
            with _written(path, temporary):
                _commit(temporary, path)
        self.pending = []
        for callback in self.after:
            callback()

    def discard(self) -> None:
        for temporary, _ in self.pending:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(temporary)
        self.pending = []


@contextlib.contextmanager
def all_or_none() -> Iterator[Outputs]:
    """Outputs written in the block appear together when it ends normally, none if it fails."""
    outputs = Outputs()
    try:
        yield outputs
    except BaseException:
        outputs.discard()
        raise
    try:
        outputs.commit()
    except BaseException:
        outputs.discard()
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
        with _written(self.destination, self.path):
            fd = os.open(self.path, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
            _commit(self.path, self.destination)

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
    path = Path(path)
    temporary = _write_temporary(path, write)
    with _written(path, temporary):
        _commit(temporary, path)


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    atomic_write(path, lambda file: file.write(data))


def save_figure(figure, path: str | os.PathLike, **options) -> None:
    """Save a matplotlib figure atomically, in the format its suffix names (.png, .pdf, .svg, ...)."""
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
