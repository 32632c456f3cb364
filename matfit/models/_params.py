"""Parameter conversion and validation shared by the models.

Validation runs on concrete values only. Inside ``jax.jit``/``grad``/``vmap`` the arguments are
tracers: their shapes are still checked, their values are not (a traced function cannot raise
on data). Direction and random-number values are checked on the outermost model call only:
composite models (``Layered``, ``Blend``, ...) pass masked, possibly non-unit directions to
their components, and those inner calls are not the user's input.
"""

from __future__ import annotations

import sys

import jax
import jax.numpy as jnp
import numpy as np

from .._check import real_dtype, check_range  # noqa: F401  (re-exported for the models)
from .._math import as_float
from ..errors import ParameterError

#: Largest accepted deviation ``|norm(w) - 1|`` of a direction (at least 16 ulp of its dtype).
UNIT_TOL = 1e-4


#: A model parameter as a floating JAX array (float64 when x64 is on and ``x`` is a Python number).
as_param = as_float


def as_channels(x):
    """A floating JAX array ``(..., C)`` whose last axis holds the colour channels (a scalar: ``(1,)``)."""
    return jnp.atleast_1d(as_param(x))


def channel_count(*params):
    """The colour channel count ``C`` of arrays ``(..., C)`` or ``(..., 1)`` whose last axes broadcast."""
    return jnp.broadcast_shapes(*(jnp.shape(p) for p in params))[-1]


def check_channels(owner, **params) -> None:
    """Raise :class:`ParameterError` unless the colour axes (last axis) of ``params`` (arrays, or
    ints: a model's ``channels``) broadcast: equal lengths, or 1. ``owner`` is named first."""
    lens = {n: (int(v) if isinstance(v, int) else (np.shape(v)[-1] if np.ndim(v) else 1)) for n, v in params.items()}
    c = {n: k for n, k in lens.items() if k != 1}
    if len(set(c.values())) > 1:
        found = ", ".join(f"{n} has {k}" for n, k in lens.items())
        raise ParameterError(f"{owner}: the colour channels (last axis) must match or be 1, found {found}")


def check_complex_index(owner, eta, k) -> None:
    """Check a conductor's complex index ``eta + i k``: ``eta > 0``, ``k >= 0`` and colour
    channels that broadcast (else :class:`ParameterError`)."""
    check_range(owner, "eta", eta, 0.0, lo_open=True)
    check_range(owner, "k", k, 0.0)
    check_channels(owner, eta=eta, k=k)


def check_choice(owner, name, value, choices) -> None:
    """Raise :class:`ParameterError` unless option ``name``'s ``value`` is one of the strings ``choices``."""
    if not isinstance(value, str) or value not in choices:
        raise ParameterError(f"{owner}: {name} must be one of {list(choices)}, got {value!r}")


def _nested_call(depth=2):
    """True when the model method that called the check was itself called by a model method
    (a composite model evaluating a component), rather than by user code."""
    f = sys._getframe(depth + 1)  # the caller of the model method
    while f is not None:
        mod = f.f_globals.get("__name__", "")
        if mod.startswith("matfit.models.") and f.f_code.co_name != "albedo":
            return True
        f = f.f_back
    return False


def _concrete(v):
    """A numpy or JAX array holding values (not a tracer, not a :class:`~matfit._math.Vec3`)."""
    return isinstance(v, np.ndarray) or (isinstance(v, jax.Array) and not isinstance(v, jax.core.Tracer))


def check_directions(owner, **dirs) -> None:
    """Check directions (by argument name): arrays ``(..., 3)`` with broadcastable batch shapes;
    on concrete values of the outermost model call also a real dtype, finite entries and unit
    length (``|norm - 1| <= UNIT_TOL``). Raises :class:`ParameterError` naming ``owner``."""
    for name, v in dirs.items():
        if not hasattr(v, "shape"):
            raise ParameterError(f"{owner}: {name} must be an array (numpy or JAX) of shape (..., 3), "
                                 f"found {type(v).__name__}")
        shape = np.shape(v)
        if len(shape) == 0 or shape[-1] != 3:
            raise ParameterError(f"{owner}: {name} must have shape (..., 3), found {shape}")
        real_dtype(f"{owner}: {name}", v)
    if len(dirs) > 1:
        try:
            np.broadcast_shapes(*(np.shape(v)[:-1] for v in dirs.values()))
        except ValueError:
            shapes = ", ".join(f"{k} {np.shape(v)}" for k, v in dirs.items())
            raise ParameterError(f"{owner}: direction batch shapes do not broadcast: {shapes}") from None
    concrete = {k: v for k, v in dirs.items() if _concrete(v)}
    if not concrete or _nested_call():
        return
    for name, v in concrete.items():
        a = np.asarray(v)
        if not np.all(np.isfinite(a)):
            i = tuple(int(j) for j in np.argwhere(~np.isfinite(a))[0])
            raise ParameterError(f"{owner}: {name} must be finite, found {a[i]} at index {i}")
        norm = np.linalg.norm(a.astype(float), axis=-1)
        tol = max(UNIT_TOL, 16 * float(np.finfo(a.dtype).eps)) if a.dtype.kind == "f" else UNIT_TOL
        dev = np.abs(norm - 1.0)
        if np.any(dev > tol):
            i = np.unravel_index(int(np.argmax(dev)), norm.shape)
            raise ParameterError(f"{owner}: {name} must be unit vectors (|norm - 1| <= {tol:g}), found norm "
                                 f"{float(norm[i]):.6g} at index {tuple(int(j) for j in i)} "
                                 f"({int((dev > tol).sum())} of {norm.size} off)")


def check_u(owner, u, n) -> None:
    """Check a sampler's random numbers: an array ``(..., m)`` of reals, ``m >= n`` (the count it
    reads); on concrete values of the outermost model call also that they lie in [0, 1].
    Raises :class:`ParameterError` naming ``owner``."""
    if not hasattr(u, "shape"):
        raise ParameterError(f"{owner}: u must be an array (numpy or JAX) of shape (..., {n}), found {type(u).__name__}")
    shape = np.shape(u)
    if len(shape) == 0 or shape[-1] < n:
        raise ParameterError(f"{owner}: u must have shape (..., {n}) (uniform numbers in [0, 1)), found {shape}")
    real_dtype(f"{owner}: u", u)
    if not _concrete(u) or _nested_call():
        return
    a = np.asarray(u)
    bad = ~((a >= 0) & (a <= 1))  # NaN is bad too
    if np.any(bad):
        i = tuple(int(j) for j in np.argwhere(bad)[0])
        raise ParameterError(f"{owner}: u must be uniform numbers in [0, 1), found {a[i]} at index {i}")
