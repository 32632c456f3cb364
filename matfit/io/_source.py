"""The bytes of a reader's input, given as a path or as the file's contents."""
from __future__ import annotations

import os

from .._dataerr import data_error


def read_source(path, limit: int | None = None, expected: str | None = None):
    """``(data, source, name)`` of a reader's input: ``path`` is a file (read whole, or its first
    ``limit`` bytes) or the contents as bytes; ``source`` is the path or None, ``name`` the path
    or ``"<bytes>"`` (for error messages). With ``expected`` (what the file holds), an empty input
    raises :class:`~matfit.errors.DataFormatError` (field ``file``: expected that, found an empty file).
    """
    if isinstance(path, (bytes, bytearray, memoryview)):
        data, src, name = bytes(path), None, "<bytes>"
    else:
        src = name = os.fspath(path)
        with open(src, "rb") as fh:
            data = fh.read() if limit is None else fh.read(limit)
    if expected is not None and not data:
        raise data_error("file", expected, "an empty file", file=name)
    return data, src, name
