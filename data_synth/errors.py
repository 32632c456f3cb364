"""Scene-file errors: every one is a :class:`matfit.errors.MatfitError` naming the file and the key.

Messages have the form ``"<file>: key '<key>': expected <expected>, found <found>"`` on one line. The
parts are attributes of the exception (``file``, ``key``, ``expected``, ``found``).
"""
from __future__ import annotations

from matfit.errors import MatfitError, problem_message


class SceneError(MatfitError):
    """Base class of scene-file errors.

    Parameters
    ----------
    file : str or PathLike, optional
        The scene file.
    key : str, optional
        The dotted key that is wrong (``"material.alpha"``).
    expected, found : object, optional
        What the scene format requires, and what the file holds.
    detail : str, optional
        More about the problem, in parentheses at the end.

    Examples
    --------
    >>> from data_synth.errors import SceneError
    >>> e = SceneError("a.toml", "geometry.n", "an integer >= 1", "0")
    >>> str(e), e.key
    ("a.toml: key 'geometry.n': expected an integer >= 1, found 0", 'geometry.n')
    """

    def __init__(self, file=None, key=None, expected=None, found=None, detail=None):
        self.file = None if file is None else str(file)
        self.key = key
        self.expected = expected
        self.found = found
        self.detail = detail
        msg = problem_message(key, expected, found, file=self.file, detail=detail, kind="key")
        super().__init__(" ".join(msg.split("\n")))


class SceneSyntaxError(SceneError):
    """The file is not valid TOML (or not UTF-8)."""


class UnknownKeyError(SceneError):
    """A key that the scene format does not define (often a typo)."""


class MissingKeyError(SceneError):
    """A required key is absent."""


class SceneTypeError(SceneError):
    """A value has the wrong TOML type (e.g. a string where a number is expected)."""


class UnknownModelError(SceneError):
    """``material.model`` (or a nested ``model``) names no matfit model."""


class UnknownParameterError(SceneError):
    """A material key that is not a parameter of the chosen model."""


class SceneValueError(SceneError):
    """A value of the right type but out of its range or not one of the allowed choices."""


__all__ = ["SceneError", "SceneSyntaxError", "UnknownKeyError", "MissingKeyError", "SceneTypeError",
           "UnknownModelError", "UnknownParameterError", "SceneValueError"]
