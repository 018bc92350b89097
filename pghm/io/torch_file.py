"""Reading ``torch.save`` files from strangers without running code or leaking exception types.

``torch.save`` has written a zip archive (``data.pkl`` plus tensor records) since torch 1.6;
anything else is checked for that magic first, so random or foreign bytes never reach the
legacy pickle path. The weights-only unpickler then refuses globals other than tensors and
plain containers, so a hostile file cannot run code; but on damaged bytes it raises whatever
its stack machine trips over (``IndexError`` from an empty mark stack, ``struct.error``,
``UnicodeDecodeError``, ``AttributeError``, ...), so every exception it raises is a damaged
file and becomes one line.
"""

from __future__ import annotations

import pickle
from pathlib import Path

import torch

ZIP_MAGIC = b"PK\x03\x04"
"""First bytes of a local zip file header: every file ``torch.save`` writes starts with them."""


class TorchFileError(Exception):
    """Why a file is not a readable ``torch.save`` file, in one line (callers add the path)."""


def load_torch_file(path: Path) -> object:
    """``torch.load(path, weights_only=True)`` on CPU; :class:`TorchFileError` for any damage.

    Raises:
        TorchFileError: the file is missing, not a torch zip archive, holds code, or is damaged.
    """
    if not path.is_file():
        raise TorchFileError("file not found")
    with path.open("rb") as handle:
        if handle.read(len(ZIP_MAGIC)) != ZIP_MAGIC:
            raise TorchFileError("not a torch.save zip archive (random or foreign bytes?)")
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # noqa: BLE001 - the weights-only unpickler raises many types on damaged bytes
        if isinstance(error, pickle.UnpicklingError) and ("Unsupported global" in str(error) or "GLOBAL" in str(error)):
            raise TorchFileError(
                "refusing to load objects other than tensors and plain data (the file may contain code)"
            ) from None
        raise TorchFileError(f"truncated or corrupted: {_first_line(error)}") from None


def _first_line(error: BaseException) -> str:
    text = str(error).strip()
    return f"{type(error).__name__}: {text.splitlines()[0]}" if text else type(error).__name__
