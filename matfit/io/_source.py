"""The bytes of a reader's input, given as a path or as the file's contents."""
from __future__ import annotations

import os


def read_source(path, limit: int | None = None):
    """The bytes of ``path``, where it came from, and how error messages name it.

    Parameters
    ----------
    path : str, PathLike, bytes, bytearray or memoryview
        A file to read, or the file's contents.
    limit : int, optional
        Read at most this many bytes of a file (the whole file when None).

    Returns
    -------
    data : bytes
        The contents.
    source : str or None
        The file's path, None for contents given as bytes.
    name : str
        The file's path, or ``"<bytes>"``.

    Examples
    --------
    >>> read_source(b"#DIM 1 1")
    (b'#DIM 1 1', None, '<bytes>')
    >>> import os, tempfile
    >>> with tempfile.TemporaryDirectory() as d:
    ...     p = os.path.join(d, "x.bin")
    ...     with open(p, "wb") as fh:
    ...         _ = fh.write(b"abcdef")
    ...     data, source, name = read_source(p, limit=4)
    ...     data, source == p == name
    (b'abcd', True)
    """
    if isinstance(path, (bytes, bytearray, memoryview)):
        return bytes(path), None, "<bytes>"
    src = os.fspath(path)
    with open(src, "rb") as fh:
        data = fh.read() if limit is None else fh.read(limit)
    return data, src, src
