"""Construction of :class:`~matfit.errors.DataFormatError`: the message of
:func:`~matfit.errors.problem_message`, its parts also attached as the attributes ``file``,
``field``, ``expected``, ``found`` and ``detail`` so that callers and tests can inspect them."""
from __future__ import annotations

import os

from .errors import DataFormatError, problem_message


def _describe_file(file) -> str | None:
    if file is None:
        return None
    if isinstance(file, (bytes, bytearray, memoryview)):
        return "<bytes>"
    return os.fspath(file) if isinstance(file, (str, os.PathLike)) else str(file)


def data_error(field: str, expected=None, found=None, *, file=None, detail: str | None = None) -> DataFormatError:
    """Return (not raise) a DataFormatError naming the file, the field, expected vs found (data
    given as bytes is named ``"<bytes>"``)."""
    fname = _describe_file(file)
    err = DataFormatError(problem_message(field, expected, found, file=fname, detail=detail))
    err.file = fname
    err.field = field
    err.expected = expected
    err.found = found
    err.detail = detail
    return err


def with_file(err: DataFormatError, file) -> DataFormatError:
    """Re-issue a file-less DataFormatError (e.g. from Table validation) with ``file`` named.

    ``err`` comes back as it is when it already names a file or ``file`` is None; an error not
    built by :func:`data_error` becomes the detail of a field ``'?'``.
    """
    if getattr(err, "file", None) is not None or file is None:
        return err
    return data_error(getattr(err, "field", "?"), getattr(err, "expected", None), getattr(err, "found", None),
                      file=file, detail=getattr(err, "detail", None) if hasattr(err, "field") else str(err))
