"""Validation of concrete parameter values, shared by :mod:`matfit.fresnel` and the models.

Kept outside :mod:`matfit.models` so that low-level modules can use it without importing the
models package.
"""

from __future__ import annotations

import jax
import numpy as np

from .errors import ParameterError


def real_dtype(where, x) -> None:
    """Raise unless ``x`` holds real numbers (integer or floating; not bool, complex, text, objects).

    Parameters
    ----------
    where : str
        The start of the message (``"Lambert: parameter 'albedo'"``).
    x : array_like
        The value to check.

    Raises
    ------
    ParameterError
        ``x`` is not a rectangular array of integers or floats.

    Examples
    --------
    >>> real_dtype("f: x", [1, 2.5])
    >>> real_dtype("f: x", [True])
    Traceback (most recent call last):
    ...
    matfit.errors.ParameterError: f: x must be real numbers (integer or floating dtype), found dtype bool
    """
    dt = getattr(x, "dtype", None)
    if dt is None:
        try:
            dt = np.asarray(x).dtype
        except Exception:  # ragged nested sequences
            raise ParameterError(f"{where} must be real numbers, found a {type(x).__name__} "
                                 "that is not a rectangular array") from None
    dt = np.dtype(dt)
    if dt.kind not in "iuf":
        raise ParameterError(f"{where} must be real numbers (integer or floating dtype), found dtype {dt}")


def check_range(owner, name, x, lo=None, hi=None, lo_open=False, hi_open=False) -> None:
    """Raise :class:`ParameterError` if a concrete ``x`` is not real, leaves [lo, hi] or is not finite.

    Traced values (inside ``jit``/``grad``) are not checked: validation happens where the values
    are known, at construction from concrete numbers.

    Parameters
    ----------
    owner : str
        The class or function, named first in the message.
    name : str
        The parameter.
    x : array_like, jax tracer or None
        The value (None and tracers pass).
    lo, hi : float, optional
        The bounds (None: unbounded on that side).
    lo_open, hi_open : bool, default False
        Exclude the bound itself.

    Raises
    ------
    ParameterError
        Naming ``owner``, ``name``, the bound and up to three offending values.

    Examples
    --------
    >>> from matfit.errors import ParameterError
    >>> check_range("Plastic", "eta", 1.5, lo=1.0, lo_open=True)
    >>> try:
    ...     check_range("Plastic", "eta", [1.5, 0.9], lo=1.0, lo_open=True)
    ... except ParameterError as e:
    ...     print(str(e).split(", found")[0])
    Plastic: parameter 'eta' must be > 1.0
    """
    if x is None or isinstance(x, jax.core.Tracer):
        return
    where = f"{owner}: parameter {name!r}"
    real_dtype(where, x)
    a = np.asarray(x, dtype=float)
    if not np.all(np.isfinite(a)):
        raise ParameterError(f"{where} must be finite, found {a.ravel()[~np.isfinite(a.ravel())][:3]}")
    if lo is not None:
        bad = a <= lo if lo_open else a < lo
        if np.any(bad):
            rel = ">" if lo_open else ">="
            raise ParameterError(f"{where} must be {rel} {lo}, found {a[bad].ravel()[:3]}")
    if hi is not None:
        bad = a >= hi if hi_open else a > hi
        if np.any(bad):
            rel = "<" if hi_open else "<="
            raise ParameterError(f"{where} must be {rel} {hi}, found {a[bad].ravel()[:3]}")
