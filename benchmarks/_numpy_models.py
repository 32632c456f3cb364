"""The numpy baselines of the fitting benchmarks (and of experiments/pareto.py), by family name.

The models are numpy_ref's vectorized family baselines (``numpy_ref/baselines.py``, written from the
formulas, no matfit import): ``conductor`` (GGX, separable Smith, real-arithmetic conductor Fresnel),
``plastic`` (a rough GGX coat over Lambert, tabulated coat transmittance) and ``diffuse_specular``.
Each family's parameters and bounds are read from ``matfit.fitting.FAMILIES`` (per-channel ones get
as many entries as the table has channels), so that a numpy optimizer works in the library's
unconstrained space ``z`` (sigmoid / exp bijections of ``matfit.fitting.params``)::

    nm.residuals("conductor", z, wo, wi, values, sqrt_w, loss)   # flat sqrt(w) (f - y), or the E2 form
    nm.log_prob("conductor", z, wo, wi, values, sigma)           # Gaussian likelihood, uniform priors, in z
"""

from __future__ import annotations

import functools

from _common import REPO_ROOT  # noqa: F401  (puts the repository root, numpy_ref's home, on sys.path)

import numpy_ref as R


@functools.lru_cache(maxsize=None)
def family(name, channels=3):
    """numpy_ref's baseline of the family ``name`` with the library's bounds for ``channels`` channels."""
    from matfit.fitting import FAMILIES

    bounds = [(p.name, p.lower, p.upper, channels if p.per_channel else 1) for p in FAMILIES[name].params]
    return R.FamilyModel(name, bounds)


def theta_from_z(name, z, channels=3):
    """dict of natural parameters and the log |d theta/dz| for an unconstrained vector z."""
    return family(name, channels).theta(z)


def model_eval(name, wo, wi, z, channels=3):
    return family(name, channels).eval(wo, wi, z)


def residuals(name, z, wo, wi, values, sqrt_w, loss="l2"):
    """Flat residual vector sqrt(w) (f - y) (``"l2"``) or sqrt(w) (log(1 + f cos_i) - log(1 + y cos_i))
    (``"e2"``, Löw et al. 2012)."""
    return family(name, values.shape[-1]).residuals(z, wo, wi, values, sqrt_w, loss)


def log_prob(name, z, wo, wi, values, sigma):
    """Gaussian log-likelihood with the table's sigma, uniform priors within the bounds, in z."""
    return family(name, values.shape[-1]).log_prob(z, wo, wi, values, sigma)
