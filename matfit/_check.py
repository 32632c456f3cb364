"""Validation of concrete parameter values, shared by :mod:`matfit.fresnel` and the models.

Kept outside :mod:`matfit.models` so that low-level modules can use it without importing the
models package.
"""

from __future__ import annotations

import jax
import numpy as np

from .errors import ParameterError


def real_dtype(where, x) -> None:
    """Raise :class:`ParameterError` unless ``x`` is a rectangular array of real numbers (integer or
    floating; not bool, complex, text, objects); ``where`` starts the message
    (``"Lambert: parameter 'albedo'"``)."""
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
    """Raise :class:`ParameterError` if a concrete ``x`` is not real, not finite, or leaves
    ``[lo, hi]`` (``lo_open``/``hi_open`` exclude a bound; None: unbounded).

    The message names ``owner``, ``name``, the bound and up to three offending values. None and
    traced values (inside ``jit``/``grad``) pass: validation happens where the values are known,
    at construction from concrete numbers.
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
