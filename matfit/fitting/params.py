"""How a family's parameters are fitted: bounds, smooth bijections to an unconstrained space,
fixed and tied parameters (:class:`Parametrization`; the families are in
:mod:`matfit.fitting.families`).

Every bounded parameter ``theta in (lo, hi)`` is fitted through ``z`` with
``theta = lo + (hi - lo) * sigmoid(z)``; a parameter bounded below only uses
``theta = lo + exp(z)``. Both maps are smooth and bijective, so unconstrained optimizers and
samplers never leave the physical range. Parameters can be fixed (``fixed={"eta": 1.5}``) or
tied across channels (``tied=("eta",)``: one value shared by all channels).
"""

from __future__ import annotations

from collections.abc import Mapping

import jax.numpy as jnp
import numpy as np

from ..errors import ParameterError
from .families import Family, check_param_value, get_family

__all__ = ["check_solver_options", "Parametrization"]


def _count(owner, name, v, lo):
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
        raise ParameterError(f"{owner}: {name} must be an integer >= {lo}, got {v!r}")


def _real(owner, name, v, positive=False):
    ok = not isinstance(v, bool) and isinstance(v, (int, float, np.integer, np.floating)) and np.isfinite(v)
    if not ok or (v <= 0 if positive else v < 0):
        raise ParameterError(f"{owner}: {name} must be a finite number {'> 0' if positive else '>= 0'}, got {v!r}")


def check_solver_options(owner, *, starts=1, max_steps=1, rtol=0.0, atol=0.0, robust_scale=1.0, dtype=None) -> None:
    """Validate the solver options shared by :func:`~matfit.fitting.fit` and
    :func:`~matfit.fitting.fit_batch`.

    Parameters
    ----------
    owner : str
        The caller, named in errors.
    starts, max_steps : int
        Counts (>= 1).
    rtol, atol : float
        Tolerances (finite, >= 0).
    robust_scale : float
        Scale of a robust loss (finite, > 0).
    dtype : dtype, optional
        float32 or float64.

    Raises
    ------
    matfit.ParameterError
        Naming the option and the value.
    """
    _count(owner, "starts", starts, 1)
    _count(owner, "max_steps", max_steps, 1)
    _real(owner, "rtol", rtol)
    _real(owner, "atol", atol)
    _real(owner, "robust_scale", robust_scale, positive=True)
    if dtype is not None:
        try:
            dt = np.dtype(dtype)
        except TypeError:
            dt = None
        if dt is None or dt.kind != "f" or dt.itemsize < 4:
            raise ParameterError(f"{owner}: dtype must be None, float32 or float64, got {dtype!r}")


class Parametrization:
    """Flattening of a family's free parameters into one unconstrained vector ``z``.

    Parameters
    ----------
    family : Family or str
    channels : int
        Number of colour channels C of the table.
    fixed : dict, optional
        Values for parameters held fixed (scalar or per-channel).
    tied : sequence of str, optional
        Per-channel parameters fitted as one value shared by all channels.

    Examples
    --------
    >>> from matfit.fitting import Parametrization
    >>> p = Parametrization("plastic", channels=3, fixed={"eta": 1.5})
    >>> p.labels
    ['albedo[0]', 'albedo[1]', 'albedo[2]', 'alpha']
    """

    def __init__(self, family, channels, fixed=None, tied=()):
        if not isinstance(family, (str, Family)):
            raise ParameterError(f"model must be a family name (str) or a Family, got {type(family).__name__}")
        self.family = get_family(family) if isinstance(family, str) else family
        if isinstance(channels, bool) or not isinstance(channels, (int, np.integer)) or channels < 1:
            raise ParameterError(f"channels must be a positive integer, got {channels!r}")
        self.channels = int(channels)
        if fixed is not None and not isinstance(fixed, Mapping):
            raise ParameterError(f"fixed must be a dict of parameter values, got {type(fixed).__name__}")
        if isinstance(tied, str):
            raise ParameterError(f"tied must be a sequence of parameter names, got the string {tied!r} "
                                 f"(write tied=({tied!r},))")
        self.fixed = dict(fixed or {})
        self.tied = tuple(tied)
        names = {p.name for p in self.family.params}
        for n in list(self.fixed) + list(self.tied):
            if n not in names:
                raise ParameterError(f"family {self.family.name!r} has no parameter {n!r}; it has {sorted(names)}")
        self.fixed = {n: self.check_value("fixed", n, v) for n, v in self.fixed.items()}
        self.free = [p for p in self.family.params if p.name not in self.fixed]
        self.sizes = [self._size(p) for p in self.free]
        self.size = int(sum(self.sizes))

    def _param(self, name):
        return next(p for p in self.family.params if p.name == name)

    def check_value(self, what, name, v):
        """``v`` unchanged when it is a valid value of parameter ``name`` (:func:`check_param_value`)."""
        return check_param_value(self._param(name), self.channels, what, v)

    def check_theta(self, what, theta) -> None:
        """Validate free parameters' values (e.g. ``fit(init=...)``); a fixed or unknown name raises."""
        if not isinstance(theta, Mapping):
            raise ParameterError(f"{what} must be a dict of parameter values, got {type(theta).__name__}")
        free = [p.name for p in self.free]
        for n, v in theta.items():
            if n not in free:
                why = "is fixed" if n in self.fixed else f"is not a parameter of family {self.family.name!r}"
                raise ParameterError(f"{what}: {n!r} {why}; the free parameters are {free}")
            self.check_value(what, n, v)

    def _pieces(self, vec, f):
        """``{name: f(param, piece)}`` over the free parameters' pieces of ``vec`` (..., size);
        shared parameters lose their length-1 axis."""
        out, i = {}, 0
        for p, n in zip(self.free, self.sizes):
            v = f(p, vec[..., i:i + n])
            out[p.name] = v if p.per_channel else v[..., 0]
            i += n
        return out

    def _size(self, p):
        return self.channels if (p.per_channel and p.name not in self.tied) else 1

    @property
    def labels(self):
        out = []
        for p, n in zip(self.free, self.sizes):
            out += [p.name] if n == 1 and not (p.per_channel and p.name not in self.tied) else [f"{p.name}[{i}]" for i in range(n)]
        return out

    def lower_upper(self):
        """The bounds ``(lower, upper)`` of every free coordinate, in the order of :attr:`labels`."""
        lo, hi = [], []
        for p, n in zip(self.free, self.sizes):
            lo += [p.lower] * n
            hi += [p.upper] * n
        return np.array(lo), np.array(hi)

    def physical_bounds(self):
        """Whether each free coordinate's (lower, upper) bound is physical (:class:`Param`), (size, 2)."""
        return np.array([p.physical for p, n in zip(self.free, self.sizes) for _ in range(n)], bool).reshape(-1, 2)

    def split(self, vec):
        """``{name: piece}`` of a flat vector (..., size): per-channel pieces keep their axis."""
        return self._pieces(vec, lambda p, v: v)

    def theta(self, z):
        """``{name: value}`` of the free parameters at unconstrained ``z`` (..., size)."""
        return self._pieces(z, lambda p, v: p.from_unconstrained(v))

    def _flat_map(self, vec, f):
        """``f(param, piece)`` over each free parameter's piece of the flat ``vec`` (..., size), concatenated."""
        parts, i = [], 0
        for p, n in zip(self.free, self.sizes):
            parts.append(f(p, vec[..., i:i + n]))
            i += n
        return jnp.concatenate(parts, axis=-1)

    def theta_vector(self, z):
        """Natural values as a flat vector, in the layout of ``z``."""
        return self._flat_map(z, lambda p, v: p.from_unconstrained(v))

    def z_vector(self, theta):
        """The inverse of :meth:`theta_vector` (each value clipped just inside its range)."""
        return self._flat_map(jnp.asarray(theta), lambda p, v: p.to_unconstrained(v))

    def z_from_theta(self, theta):
        """The ``z`` of ``{name: value}``: per-channel values broadcast, a shared one takes their mean."""
        parts = []
        for p, n in zip(self.free, self.sizes):
            v = jnp.broadcast_to(jnp.asarray(theta[p.name], dtype=float), (n,)) if n > 1 else jnp.reshape(
                jnp.mean(jnp.asarray(theta[p.name], dtype=float)), (1,))
            parts.append(p.to_unconstrained(v))
        return jnp.concatenate(parts)

    def log_jacobian(self, z):
        """``log |d theta / d z|`` summed over the free coordinates (for priors on theta)."""
        tot, i = 0.0, 0
        for p, n in zip(self.free, self.sizes):
            tot = tot + jnp.sum(p.log_jacobian(z[..., i:i + n]), axis=-1)
            i += n
        return tot

    def full(self, theta):
        """Every parameter's value (free from ``theta``, and fixed), per-channel ones broadcast to C."""
        out = {}
        for p in self.family.params:
            v = theta[p.name] if p.name in theta else jnp.asarray(self.fixed[p.name], dtype=float)
            v = jnp.asarray(v)
            if p.per_channel:
                v = jnp.atleast_1d(v)
                v = jnp.broadcast_to(v, v.shape[:-1] + (self.channels,))
            out[p.name] = v
        return out

    def model(self, z):
        """The model at unconstrained parameters ``z``."""
        return self.family.build(self.full(self.theta(z)), self.channels)


