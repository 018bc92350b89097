"""What reading a damaged file can raise, per format, so every reader turns all of it into one PghmError.

Besides the documented ``OSError`` and ``ValueError``: fuzzing the readers
(``benchmarks/fuzz_loaders.py``) found ``zlib.error`` (a damaged deflate stream in an
``.npz``) and ``tokenize.TokenError`` (a damaged ``.npy`` header: numpy tokenizes
version 1-2 headers); the rest are what ``zipfile``, numpy and Pillow raise for other damage
(``NotImplementedError`` for an unknown compression method, ``RuntimeError`` for the
"encrypted" flag, ``struct.error`` or ``KeyError`` for a broken zip directory, ``MemoryError``
for an array header claiming a huge shape; ``SyntaxError`` for Pillow's "broken PNG file",
``DecompressionBombError`` for a PNG claiming billions of pixels).
"""

from __future__ import annotations

import struct
import tokenize
import zipfile
import zlib

from PIL import Image

NPZ_READ_ERRORS: tuple[type[BaseException], ...] = (
    OSError,
    EOFError,
    ValueError,
    KeyError,
    NotImplementedError,
    RuntimeError,
    MemoryError,
    zipfile.BadZipFile,
    zlib.error,
    struct.error,
    tokenize.TokenError,
    SyntaxError,
)
"""Raised by ``numpy.load(path, allow_pickle=False)`` and by reading its arrays, for a damaged file."""

IMAGE_READ_ERRORS: tuple[type[BaseException], ...] = (
    OSError,
    ValueError,
    SyntaxError,
    EOFError,
    MemoryError,
    zlib.error,
    struct.error,
    Image.DecompressionBombError,
)
"""Raised by ``PIL.Image.open`` and decoding, for a damaged or hostile image file."""
