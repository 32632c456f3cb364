"""Exceptions raised by matfit. Every message names the argument or file and the problem.

:func:`problem_message` builds the one-line message of a malformed file or document, in the form
shared by matfit's readers and the scene files of ``data_synth``.
"""

from __future__ import annotations

__all__ = ["MatfitError", "ParameterError", "DataFormatError", "problem_message"]


class MatfitError(ValueError):
    """Base class of matfit's errors (a ``ValueError``).

    Parameters
    ----------
    *args : object
        As for :class:`ValueError`: one message naming the argument or file and the problem.

    Examples
    --------
    >>> from matfit.errors import MatfitError, ParameterError
    >>> issubclass(ParameterError, MatfitError) and issubclass(MatfitError, ValueError)
    True
    """


class ParameterError(MatfitError):
    """A model parameter or argument is out of its documented range or of the wrong shape.

    Parameters
    ----------
    *args : object
        The message: the owner (a class or function), the parameter, the range and the value.

    Examples
    --------
    >>> from matfit.errors import ParameterError
    >>> from matfit.models import Lambert
    >>> try:
    ...     Lambert(-0.5)
    ... except ParameterError as e:
    ...     print(str(e).split(":")[0])
    Lambert
    """


class DataFormatError(MatfitError):
    """A data file is malformed: the message (:func:`problem_message`) names the file, the field,
    expected vs found. The readers of :mod:`matfit.io` and :class:`matfit.table.Table` also attach
    those parts as attributes (None where unknown).

    Attributes
    ----------
    file : str or None
        The file (``"<bytes>"`` for data given as bytes).
    field : str
        The field, header line or column that is wrong.
    expected, found : object or None
        What the format requires, and what the file holds.
    detail : str or None
        Where in the file (``"line 12"``) or more about the problem.

    Examples
    --------
    >>> from matfit.errors import DataFormatError
    >>> from matfit.io import read_alta
    >>> try:
    ...     read_alta(b"#PARAM_IN COS_TH\\n0.5 0.1\\n")
    ... except DataFormatError as e:
    ...     print(e)
    ...     print(e.field, e.found)
    <bytes>: field '#DIM': expected a '#DIM <n_in> <n_out>' header line, found none
    #DIM none
    """


def problem_message(name=None, expected=None, found=None, *, file=None, detail=None, kind="field") -> str:
    """The one-line message of a malformed file or document (that of :class:`DataFormatError`).

    Parameters
    ----------
    name : str, optional
        The field (or key) that is wrong.
    expected, found : object, optional
        What the format requires and what was found.
    file, detail : str, optional
        The file, named first; a line number or hint, appended in parentheses.
    kind : str, default "field"
        The word naming ``name``: ``"field"`` for data files, ``"key"`` for scene files.

    Returns
    -------
    str
        ``"<file>: <kind> '<name>': expected <expected>, found <found> (<detail>)"``, without the
        parts that are None.

    Examples
    --------
    >>> from matfit.errors import problem_message
    >>> problem_message("#DIM", "two integers", "'3'", file="a.alta", detail="line 2")
    "a.alta: field '#DIM': expected two integers, found '3' (line 2)"
    >>> problem_message("seed", found="-1", kind="key")
    "key 'seed': found -1"
    >>> problem_message(expected="a TOML table", file="scene.toml")
    'scene.toml: expected a TOML table'
    """
    msg = "" if file is None else f"{file}: "
    if name is not None:
        msg += f"{kind} '{name}'"
    parts = []
    if expected is not None:
        parts.append(f"expected {expected}")
    if found is not None:
        parts.append(f"found {found}")
    if parts:
        msg += (": " if name is not None else "") + ", ".join(parts)
    if detail:
        msg += f" ({detail})"
    return msg
