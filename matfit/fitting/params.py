"""Fittable parameters: bounds, smooth bijections to an unconstrained space, and model families.

Every bounded parameter ``theta in (lo, hi)`` is fitted through ``z`` with
``theta = lo + (hi - lo) * sigmoid(z)``; a parameter bounded below only uses
``theta = lo + exp(z)``. Both maps are smooth and bijective, so unconstrained optimizers and
samplers never leave the physical range. Parameters can be fixed (``fixed={"eta": 1.5}``) or
tied across channels (``tied=("eta",)``: one value shared by all channels).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import ParameterError
from ..models import CoatedConductor, Lambert, Plastic, RoughConductor, RoughDielectric


@dataclass(frozen=True)
class Param:
    """One fittable parameter: its name, bounds and whether it has a colour-channel axis."""

    name: str
    lower: float
    upper: float  # np.inf: bounded below only
    per_channel: bool = False
    doc: str = ""

    def to_unconstrained(self, theta):
        theta = jnp.asarray(theta)
        if np.isinf(self.upper):
            return jnp.log(jnp.maximum(theta - self.lower, 1e-30))
        t = jnp.clip((theta - self.lower) / (self.upper - self.lower), 1e-9, 1 - 1e-9)
        return jnp.log(t) - jnp.log1p(-t)

    def from_unconstrained(self, z):
        if np.isinf(self.upper):
            return self.lower + jnp.exp(z)
        return self.lower + (self.upper - self.lower) * jax.nn.sigmoid(z)

    def log_jacobian(self, z):
        """log |d theta / d z| (for priors expressed on theta when sampling in z)."""
        if np.isinf(self.upper):
            return z
        return jnp.log(self.upper - self.lower) + jax.nn.log_sigmoid(z) + jax.nn.log_sigmoid(-z)


@dataclass(frozen=True)
class Family:
    """A model family: its parameters and how to build the model from their values."""

    name: str
    params: tuple[Param, ...]
    build: Callable[..., object]
    doc: str = ""


def _conductor(distribution):
    return lambda p, C: RoughConductor(p["alpha"], p["eta"], p["k"], distribution=distribution)


FAMILIES: dict[str, Family] = {
    "lambert": Family(
        "lambert", (Param("albedo", 0.0, 1.0, True, "diffuse albedo"),),
        lambda p, C: Lambert(p["albedo"]), "Lambertian diffuse"),
    "conductor": Family(
        "conductor",
        (Param("alpha", 1e-3, 1.5, False, "GGX width"), Param("eta", 0.05, 8.0, True, "real index"),
         Param("k", 0.0, 12.0, True, "extinction")),
        _conductor("ggx"), "rough conductor, GGX, separable Smith"),
    "conductor_beckmann": Family(
        "conductor_beckmann",
        (Param("alpha", 1e-3, 1.5, False, "Beckmann width"), Param("eta", 0.05, 8.0, True, "real index"),
         Param("k", 0.0, 12.0, True, "extinction")),
        _conductor("beckmann"), "rough conductor, Beckmann, separable Smith"),
    "dielectric": Family(
        "dielectric",
        (Param("alpha", 1e-3, 1.5, False, "GGX width"), Param("eta", 1.01, 4.0, False, "relative index")),
        lambda p, C: RoughDielectric(p["alpha"], p["eta"]), "rough dielectric (reflection and transmission)"),
    "plastic": Family(
        "plastic",
        (Param("albedo", 0.0, 1.0, True, "base albedo"), Param("alpha", 1e-3, 1.5, False, "coat GGX width"),
         Param("eta", 1.05, 3.0, False, "coat index")),
        lambda p, C: Plastic(p["albedo"], p["alpha"], p["eta"]), "Lambertian base under a rough coat"),
    "car_paint": Family(
        "car_paint",
        (Param("alpha_base", 1e-3, 1.5, False, "metal GGX width"), Param("eta_base", 0.05, 8.0, True, "metal index"),
         Param("k_base", 0.0, 12.0, True, "metal extinction"), Param("alpha_coat", 1e-3, 1.0, False, "coat GGX width"),
         Param("eta_coat", 1.05, 2.5, False, "coat index")),
        lambda p, C: CoatedConductor(p["alpha_base"], p["eta_base"], p["k_base"], p["alpha_coat"], p["eta_coat"]),
        "rough metal under a rough clear coat"),
}


def get_family(name) -> Family:
    """The family called ``name`` (see :data:`FAMILIES`)."""
    if name not in FAMILIES:
        raise ParameterError(f"model must be one of {sorted(FAMILIES)}, got {name!r}")
    return FAMILIES[name]


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
        self.family = get_family(family) if isinstance(family, str) else family
        self.channels = int(channels)
        self.fixed = dict(fixed or {})
        self.tied = tuple(tied)
        names = {p.name for p in self.family.params}
        for n in list(self.fixed) + list(self.tied):
            if n not in names:
                raise ParameterError(f"family {self.family.name!r} has no parameter {n!r}; it has {sorted(names)}")
        for n, v in self.fixed.items():
            p = self._param(n)
            a = np.asarray(v, float)
            if np.any(a < p.lower) or np.any(a > p.upper):
                raise ParameterError(f"fixed {n}={v} is outside its range [{p.lower}, {p.upper}]")
        self.free = [p for p in self.family.params if p.name not in self.fixed]
        self.sizes = [self._size(p) for p in self.free]
        self.size = int(sum(self.sizes))

    def _param(self, name):
        return next(p for p in self.family.params if p.name == name)

    def _size(self, p):
        return self.channels if (p.per_channel and p.name not in self.tied) else 1

    @property
    def labels(self):
        out = []
        for p, n in zip(self.free, self.sizes):
            out += [p.name] if n == 1 and not (p.per_channel and p.name not in self.tied) else [f"{p.name}[{i}]" for i in range(n)]
        return out

    def lower_upper(self):
        lo, hi = [], []
        for p, n in zip(self.free, self.sizes):
            lo += [p.lower] * n
            hi += [p.upper] * n
        return np.array(lo), np.array(hi)

    def split(self, vec):
        """Cut a flat vector into per-parameter pieces (per-channel pieces keep their axis)."""
        out, i = {}, 0
        for p, n in zip(self.free, self.sizes):
            v = vec[..., i:i + n]
            out[p.name] = v if p.per_channel else v[..., 0]
            i += n
        return out

    def theta(self, z):
        """Natural parameter values (dict) for an unconstrained vector ``z`` (..., size)."""
        out, i = {}, 0
        for p, n in zip(self.free, self.sizes):
            v = p.from_unconstrained(z[..., i:i + n])
            out[p.name] = v if p.per_channel else v[..., 0]
            i += n
        return out

    def theta_vector(self, z):
        """Natural values as a flat vector, same layout as ``z``."""
        parts, i = [], 0
        for p, n in zip(self.free, self.sizes):
            parts.append(p.from_unconstrained(z[..., i:i + n]))
            i += n
        return jnp.concatenate(parts, axis=-1)

    def z_from_theta(self, theta):
        """Unconstrained vector for natural values given as a dict (per-channel broadcast)."""
        parts = []
        for p, n in zip(self.free, self.sizes):
            v = jnp.broadcast_to(jnp.asarray(theta[p.name], dtype=float), (n,)) if n > 1 else jnp.reshape(
                jnp.mean(jnp.asarray(theta[p.name], dtype=float)), (1,))
            parts.append(p.to_unconstrained(v))
        return jnp.concatenate(parts)

    def log_jacobian(self, z):
        tot, i = 0.0, 0
        for p, n in zip(self.free, self.sizes):
            tot = tot + jnp.sum(p.log_jacobian(z[..., i:i + n]), axis=-1)
            i += n
        return tot

    def full(self, theta):
        """All parameter values (free and fixed), per-channel ones broadcast to C."""
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
