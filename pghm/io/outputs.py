"""Outputs are checked before the work starts, and multi-file outputs appear whole or not at all.

:func:`check_output` is called by every command on every output path before any slow work
(loading, training, rendering): it refuses, in one :class:`~pghm.errors.PghmError` line,

- a path that is an existing directory (for a file output) or an existing file or non-empty
  folder (for a folder output),
- a path that exists but is not a regular file (``/dev/full``, a FIFO: an atomic rename would
  replace the device node rather than write to it),
- a path under a file (``afile.txt/x.npz``),
- a folder that cannot be written (probed by creating and removing a hidden file in the
  nearest existing ancestor: ``os.access`` says yes to root on a read-only mount or ``/sys``),
- a path that is one of the inputs (same file by ``os.path.samefile``, through symlinks and
  hard links, or the same resolved path), which would be overwritten;
- a name whose suffix the writer cannot produce (a figure as ``.txt``, a PNG as ``.jpg``),
- a path inside an input folder (``capture FRAMES --out FRAMES/subject``: the input would change
  under the run, and the next run would read the output as input), and a folder output that
  holds an input.

Missing parent folders are not created here (a refused run leaves nothing); the writers of
:mod:`pghm.io.atomic` create them when they write.

:func:`staged_folder` builds a folder output (a PNG sequence, a synthetic dataset, a captured
subject) in a hidden sibling ``.NAME.XXXX.partial`` and renames it into place when the block
ends normally; on an error or Ctrl-C the sibling is removed, so an interrupted run leaves
nothing. A ``kill -9`` can leave the hidden sibling, never a half-filled ``NAME``.

Use in a new command, once per output::

    out = check_output(args.out, inputs=[args.avatar])            # a file
    out = check_output(args.out, inputs=[...], folder=True)        # a folder
    with staged_folder(out) as building:                           # fill ``building``
        ...
"""

from __future__ import annotations

import contextlib
import os
import secrets
import shutil
import stat
from collections.abc import Iterable, Iterator
from pathlib import Path

from pghm.errors import PghmError

FIGURE_SUFFIXES = (
    ".avif", ".eps", ".gif", ".jpeg", ".jpg", ".pdf", ".pgf", ".png", ".ps", ".raw", ".rgba", ".svg", ".svgz",
    ".tif", ".tiff", ".webp",
)  # fmt: skip
"""The suffixes matplotlib's Agg canvas saves a figure as (:func:`pghm.io.atomic.save_figure`)."""
PNG_SUFFIXES = (".png",)
"""Outputs written as PNG bytes whatever their name."""
STAGING_SUFFIX = ".partial"
"""Folder outputs are built in ``.<name>.<random>.partial`` beside their destination."""


def _nearest_existing(path: Path) -> Path:
    """``path`` or its nearest existing ancestor (the working directory for a relative name)."""
    current = path
    while not os.path.lexists(current):
        if current.parent == current:
            break
        current = current.parent
    return current


def _probe_writable(directory: Path) -> str | None:
    """None when a file can be created in ``directory``, else the reason (os error text)."""
    probe = directory / f".pghm-write-probe.{secrets.token_hex(6)}"
    try:
        fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except OSError as error:
        return error.strerror or type(error).__name__
    os.close(fd)
    with contextlib.suppress(OSError):
        os.unlink(probe)
    return None


def _same_file(a: Path, b: Path) -> bool:
    with contextlib.suppress(OSError):
        if os.path.samefile(a, b):
            return True
    return a.resolve() == b.resolve()


def _inside(inner: Path, outer: Path) -> bool:
    """Whether ``inner`` lies in the folder ``outer`` (resolved, through symlinks)."""
    return outer.resolve() in inner.resolve().parents


def _check_against_inputs(path: Path, inputs: Iterable[str | os.PathLike | None], text: str) -> None:
    """Refuse an output that is an input, lies inside an input folder, or holds an input."""
    for source in inputs:
        if source is None or not os.path.lexists(source):
            continue
        source = Path(source)
        if os.path.lexists(path) and _same_file(path, source):
            raise PghmError(f"{text}: is also an input ({source}); writing it would destroy that input")
        if source.is_dir() and _inside(path, source):
            raise PghmError(f"{text}: is inside the input folder {source}; write it elsewhere")
        if _inside(source, path):
            raise PghmError(f"{text}: holds the input {source}; write it elsewhere")


def check_output(
    path: str | os.PathLike,
    inputs: Iterable[str | os.PathLike | None] = (),
    folder: bool = False,
    option: str = "--out",
    suffixes: tuple[str, ...] = (),
) -> Path:
    """``path`` as a Path, after refusing what would fail or destroy an input (see the module doc).

    Args:
        inputs: the command's input files and folders (None entries and names that are not
            paths, like a procedural motion, are ignored).
        folder: the output is a folder, built with :func:`staged_folder` (it may exist as an
            empty folder, never a non-empty one: nothing of another run is mixed in or lost).
        option: the option's name, for the message.
        suffixes: the name endings the writer produces (lower case; empty: any name).
    """
    path = Path(path)
    text = f"{option} {path}"
    if suffixes and path.suffix.lower() not in suffixes:
        raise PghmError(f"{text}: must end in {', '.join(suffixes)} (the format written)")
    if os.path.lexists(path):
        mode = os.stat(path).st_mode if path.exists() else os.lstat(path).st_mode
        if folder and not stat.S_ISDIR(mode):
            raise PghmError(f"{text}: exists and is not a folder")
        if folder and any(path.iterdir()):
            raise PghmError(f"{text}: exists and is not empty; choose a new folder")
        if not folder and stat.S_ISDIR(mode):
            raise PghmError(f"{text}: is a folder; give a file name")
        if not folder and not stat.S_ISREG(mode):
            raise PghmError(f"{text}: exists and is not a regular file (a device, a pipe?); give a file name")
        directory = path.parent
    else:
        directory = _nearest_existing(path.parent)
        if not directory.is_dir():
            raise PghmError(f"{text}: cannot be created under {directory}, which is a file")
    reason = _probe_writable(directory)
    if reason is not None:
        raise PghmError(f"{text}: cannot write in {directory}: {reason}")
    _check_against_inputs(path, inputs, text)
    return path


class StagedFolder:
    """A new hidden folder beside ``path`` to build a folder output in (for writers with an
    open/close life, like a frame sink): :meth:`commit` renames it to ``path`` (which must then
    be absent or an empty folder), :meth:`discard` removes it and leaves ``path`` untouched."""

    def __init__(self, path: str | os.PathLike) -> None:
        self.destination = Path(path)
        self.destination.parent.mkdir(parents=True, exist_ok=True)
        self.path = self.destination.parent / f".{self.destination.name}.{secrets.token_hex(6)}{STAGING_SUFFIX}"
        self.path.mkdir()

    def commit(self) -> None:
        try:
            if self.destination.is_dir() and not any(self.destination.iterdir()):
                self.destination.rmdir()  # rename(2) may not replace even an empty folder everywhere
            if os.path.lexists(self.destination):
                raise PghmError(f"{self.destination}: appeared while it was being built; the new one was discarded")
            os.replace(self.path, self.destination)
        except BaseException:
            self.discard()
            raise

    def discard(self) -> None:
        shutil.rmtree(self.path, ignore_errors=True)


@contextlib.contextmanager
def staged_folder(path: str | os.PathLike) -> Iterator[Path]:
    """A :class:`StagedFolder`'s path, committed when the block ends normally, discarded otherwise."""
    staged = StagedFolder(path)
    try:
        yield staged.path
    except BaseException:
        staged.discard()
        raise
    staged.commit()
