"""Parameter conversion and validation shared by the models."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import ParameterError


def as_param(x):
    """A floating JAX array (float64 when x64 is on and ``x`` is a Python number)."""
    x = jnp.asarray(x)
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.result_type(float))
    return x


def as_channels(x):
    """A floating JAX array with at least one axis: the last axis holds the colour channels."""
    return jnp.atleast_1d(as_param(x))


def check_range(owner, name, x, lo=None, hi=None, lo_open=False, hi_open=False):
    """Raise :class:`ParameterError` if a concrete ``x`` leaves [lo, hi] or is not finite.

    Traced values (inside ``jit``/``grad``) are not checked: validation happens where the values
    are known, at construction from concrete numbers.
    """
    if x is None or isinstance(x, jax.core.Tracer):
        return
    try:
        a = np.asarray(x, dtype=float)
    except Exception:  # pragma: no cover - exotic array types
        return
    where = f"{owner}: parameter {name!r}"
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


def check_choice(owner, name, value, choices):
    if value not in choices:
        raise ParameterError(f"{owner}: {name} must be one of {list(choices)}, got {value!r}")


def check_directions(owner, **dirs):
    """Static shape checks of direction arguments: a last axis of length 3."""
    for name, v in dirs.items():
        shape = np.shape(v)
        if len(shape) == 0 or shape[-1] != 3:
            raise ParameterError(f"{owner}: {name} must have shape (..., 3), found {shape}")


def check_u(owner, u, n):
    shape = np.shape(u)
    if len(shape) == 0 or shape[-1] < n:
        raise ParameterError(f"{owner}: u must have shape (..., {n}) (uniform numbers in [0, 1)), found {shape}")
