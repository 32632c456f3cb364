"""Uniform construction of :class:`~matfit.errors.DataFormatError` messages.

Every message has the form ``"<file>: field '<field>': expected <expected>, found <found> (<detail>)"``;
parts that are unknown are left out. The parts are also attached to the exception as attributes
``file``, ``field``, ``expected`` and ``found`` so callers and tests can inspect them.
"""
from __future__ import annotations

import os

from .errors import DataFormatError


def _describe_file(file) -> str | None:
    if file is None:
        return None
    if isinstance(file, (bytes, bytearray, memoryview)):
        return "<bytes>"
    return os.fspath(file) if isinstance(file, (str, os.PathLike)) else str(file)


def data_error(field: str, expected=None, found=None, *, file=None, detail: str | None = None) -> DataFormatError:
    """Return (not raise) a DataFormatError naming the file, the field, expected vs found."""
    fname = _describe_file(file)
    msg = f"field '{field}'"
    if fname is not None:
        msg = f"{fname}: {msg}"
    parts = []
    if expected is not None:
        parts.append(f"expected {expected}")
    if found is not None:
        parts.append(f"found {found}")
    if parts:
        msg += ": " + ", ".join(parts)
    if detail:
        msg += f" ({detail})"
    err = DataFormatError(msg)
    err.file = fname
    err.field = field
    err.expected = expected
    err.found = found
    err.detail = detail
    return err


def with_file(err: DataFormatError, file) -> DataFormatError:
    """Re-issue a file-less DataFormatError (e.g. from Table validation) with the file named."""
    if getattr(err, "file", None) is not None or file is None:
        return err
    return data_error(getattr(err, "field", "?"), getattr(err, "expected", None), getattr(err, "found", None),
                      file=file, detail=getattr(err, "detail", None) if hasattr(err, "field") else str(err))
