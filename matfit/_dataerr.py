"""Uniform construction of :class:`~matfit.errors.DataFormatError` messages.

Every message has the form ``"<file>: field '<field>': expected <expected>, found <found> (<detail>)"``;
parts that are unknown are left out. The parts are also attached to the exception as attributes
``file``, ``field``, ``expected`` and ``found`` so callers and tests can inspect them.
"""
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
    """Return (not raise) a DataFormatError naming the file, the field, expected vs found.

    Parameters
    ----------
    field : str
        The field, header line or column that is wrong.
    expected, found : object, optional
        What the format requires and what the file holds.
    file : str, PathLike or bytes, optional
        The file; data given as bytes is named ``"<bytes>"``.
    detail : str, optional
        Where in the file, or more about the problem.

    Returns
    -------
    DataFormatError
        With the message of :func:`matfit.errors.problem_message` and its parts as the
        attributes ``file``, ``field``, ``expected``, ``found`` and ``detail``.

    Examples
    --------
    >>> e = data_error("dims", "(90, 90, 180)", "(1, 2, 3)", file=b"...")
    >>> str(e), e.file, e.field
    ("<bytes>: field 'dims': expected (90, 90, 180), found (1, 2, 3)", '<bytes>', 'dims')
    """
    fname = _describe_file(file)
    err = DataFormatError(problem_message(field, expected, found, file=fname, detail=detail))
    err.file = fname
    err.field = field
    err.expected = expected
    err.found = found
    err.detail = detail
    return err


def with_file(err: DataFormatError, file) -> DataFormatError:
    """Re-issue a file-less DataFormatError (e.g. from Table validation) with the file named.

    Parameters
    ----------
    err : DataFormatError
        The error; returned as it is when it already names a file.
    file : str, PathLike or bytes, optional
        The file to name; ``err`` is returned as it is when None.

    Returns
    -------
    DataFormatError
        An error naming ``file``; an error not built by :func:`data_error` becomes the detail
        of a field ``'?'``.

    Examples
    --------
    >>> str(with_file(data_error("wo", "unit vectors"), "t.csv"))
    "t.csv: field 'wo': expected unit vectors"
    """
    if getattr(err, "file", None) is not None or file is None:
        return err
    return data_error(getattr(err, "field", "?"), getattr(err, "expected", None), getattr(err, "found", None),
                      file=file, detail=getattr(err, "detail", None) if hasattr(err, "field") else str(err))
