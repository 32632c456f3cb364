"""The bytes of a reader's input, given as a path or as the file's contents."""
from __future__ import annotations

import os


def read_source(path, limit: int | None = None):
    """``(data, source, name)`` of a reader's input: ``path`` is a file (read whole, or its first
    ``limit`` bytes) or the contents as bytes; ``source`` is the path or None, ``name`` the path
    or ``"<bytes>"`` (for error messages).
    """
    if isinstance(path, (bytes, bytearray, memoryview)):
        return bytes(path), None, "<bytes>"
    src = os.fspath(path)
    with open(src, "rb") as fh:
        data = fh.read() if limit is None else fh.read(limit)
    return data, src, src
