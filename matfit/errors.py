"""Exceptions raised by matfit. Every message names the argument or file and the problem."""


class MatfitError(ValueError):
    """Base class of matfit's errors (a ``ValueError``)."""


class ParameterError(MatfitError):
    """A model parameter or argument is out of its documented range or of the wrong shape."""


class DataFormatError(MatfitError):
    """A data file is malformed: the message names the file, the field, expected vs found."""
