r"""A dielectric coat seen from outside: its reflection lobe and its directional transmittance.

Shared by :class:`Plastic` and :class:`Layered`. A coat is a :class:`SmoothDielectric` (alpha = 0)
or a :class:`RoughDielectric`. Its energy transmittance for light arriving at
:math:`\cos\theta = \mu` is :math:`T(\mu) = 1 - F(\mu)` when smooth; when rough it is

.. math:: T(\mu) = \int_{[0,1]^2} (1 - F(\omega_o\cdot m(u)))\,w_t(u)\,\eta_p^2\,du

the transmission lobe's sample weights integrated in primary-sample space by a tensor
Gauss-Legendre rule (``order`` points per axis), tabulated at ``nodes`` cosines (crowded towards
grazing as :math:`\mu_j = (j/(n-1))^2`, the first evaluated at :math:`\mu = 10^{-3}`) and
interpolated linearly. The coat's internal diffuse reflectance is :math:`R_{int} = 1 - \bar T/\eta^2`
with :math:`\bar T = 2\int_0^1 T(\mu)\mu\,d\mu`: the exact hemispherical average of the internal
Fresnel reflectance for a smooth coat, and reciprocal and energy-conserving for a rough one.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .._math import COS_EPS, dot, refract, safe_div
from ..fresnel import fresnel_dielectric, fresnel_dielectric_average
from ._pairs import valid_reflection
from .rough_dielectric import RoughDielectric
from .smooth_dielectric import SmoothDielectric

#: Default Gauss-Legendre order per axis of the rough-coat transmittance quadrature.
COAT_ORDER = 12
#: Default number of tabulated cosines for the rough-coat transmittance.
COAT_NODES = 24


def make_coat(alpha, eta, distribution="ggx", masking="separable"):
    """A smooth coat when ``alpha`` is a concrete 0, else (traced values too) a rough one."""
    try:
        smooth = float(np.max(np.asarray(alpha))) == 0.0
    except Exception:  # traced alpha: rough
        smooth = False
    if smooth:
        return SmoothDielectric(eta)
    return RoughDielectric(alpha, eta, distribution=distribution, masking=masking)


def is_smooth(coat):
    """True for a smooth coat (a :class:`SmoothDielectric`)."""
    return isinstance(coat, SmoothDielectric)


def coat_reflection(coat, wo, wi):
    """Value ``(...)`` of the coat's (non-delta) reflection lobe: 0 for a smooth coat and wherever
    the pair is not a reflection pair above the surface."""
    if is_smooth(coat):
        return jnp.zeros(jnp.broadcast_shapes(wo.shape, wi.shape)[:-1], jnp.result_type(wo))
    return jnp.where(valid_reflection(wo, wi), coat.eval(wo, wi)[..., 0], 0)


def coat_reflection_pairs(coat, pairs):
    """:func:`coat_reflection` of a rough coat on prepared pairs: the lobe ``D G2 / (4 cos cos)``
    times the dielectric Fresnel at ``wo . h``; 0 where a pair is invalid or the coat is
    index-matched (it then reflects nothing)."""
    F = fresnel_dielectric(pairs.cos_d, coat.eta)
    return jnp.where(coat.index_matched(), 0, coat.reflection_lobe(pairs) * F)


def _gl01(n, dtype):
    x, w = np.polynomial.legendre.leggauss(n)
    return jnp.asarray(0.5 * (x + 1), dtype), jnp.asarray(0.5 * w, dtype)


def coat_transmittance_table(coat, order=COAT_ORDER, nodes=COAT_NODES, dtype=None):
    """Tabulated energy transmittance ``(mu, T)`` of a rough coat, each ``(nodes,)`` (module
    docstring): ``order`` Gauss-Legendre points per axis, ``nodes`` cosines
    ``mu_j = (j / (nodes - 1))^2``, ``dtype`` default that of ``coat.eta``."""
    dtype = jnp.result_type(coat.eta, float) if dtype is None else dtype
    # Nodes crowd towards grazing incidence (mu = s^2), where T changes fastest.
    mu = jnp.linspace(0.0, 1.0, nodes, dtype=dtype) ** 2
    mu_e = jnp.maximum(mu, 1e-3)
    wo = jnp.stack([jnp.sqrt(1 - mu_e**2), jnp.zeros_like(mu_e), mu_e], -1)
    x, w = _gl01(order, dtype)
    u1, u2 = jnp.meshgrid(x, x, indexing="ij")
    wts = (w[:, None] * w[None, :]).reshape(-1)
    u = jnp.stack([u1.reshape(-1), u2.reshape(-1)], -1)
    wob = jnp.broadcast_to(wo[:, None, :], (nodes, u.shape[0], 3))
    ub = jnp.broadcast_to(u[None], (nodes,) + u.shape)
    # Visible normals m from wo; the refracted direction wt carries the energy fraction
    # (1 - F(wo.m)) G2(wo, wt, m) / G1(wo, m): the transmission sample weight times the lobe's
    # probability, written without eval/pdf (same integral, a much smaller program to compile).
    d = coat.dist()
    m = d.sample_visible(wob, ub)
    c = dot(wob, m)
    wt, ok = refract(wob, m, coat.eta)
    ok = ok & (wt[..., 2] < -COS_EPS) & (c > 0)
    g1o = d.G1(wob, m)
    wt = jnp.where(ok[..., None], wt, jnp.asarray([0.0, 0.0, -1.0], dtype))  # double where
    ratio = safe_div(d.G2(wob, wt, m, coat.masking), g1o)
    e = jnp.where(ok, (1 - fresnel_dielectric(c, coat.eta)) * ratio, 0)
    T = jnp.sum(e * wts, axis=-1)
    # an index-matched coat (|eta - 1| < ETA_PASS) lets everything straight through, as its sampler
    T = jnp.where(coat.index_matched(), 1.0, T)
    return mu, T


def coat_transmittance(coat, mu, table=None):
    """Energy transmittance at incidence cosines ``mu`` (clamped to [0, 1]): ``1 - F(mu)`` when
    smooth, the ``table`` (:func:`coat_transmittance_table`, built when None) interpolated
    linearly when rough."""
    mu = jnp.clip(jnp.asarray(mu), 0, 1)
    if is_smooth(coat):
        return 1 - fresnel_dielectric(mu, coat.eta)
    grid, T = coat_transmittance_table(coat) if table is None else table
    # The nodes are mu_j = (j / (n - 1))^2, so the interval of mu is found in closed form
    # (j = floor(sqrt(mu) (n - 1))) instead of by jnp.interp's search: the same linear
    # interpolation without a search per value. Each interval's line T = a + b mu is tabulated
    # first (n values), so that a value reads two coefficients and divides nothing; two 1-D
    # takes (XLA's CPU gather of a (n, 2) row is several times slower than two 1-D gathers).
    n = grid.shape[0]
    b = (T[1:] - T[:-1]) / (grid[1:] - grid[:-1])
    a = T[:-1] - b * grid[:-1]
    j = jnp.clip(jnp.floor(jnp.sqrt(mu) * (n - 1)).astype(jnp.int32), 0, n - 2)
    return jnp.take(a, j, mode="clip") + jnp.take(b, j, mode="clip") * mu


def coat_internal_reflectance(coat, table=None, order=64):
    """Hemispherical internal reflectance ``R_int = 1 - Tbar / eta^2`` of the coat (``order``:
    Gauss-Legendre points of the average over the cosine)."""
    if is_smooth(coat):
        return fresnel_dielectric_average(1 / coat.eta, n=order)
    x, w = _gl01(order, jnp.result_type(coat.eta, float))
    tbar = 2 * jnp.sum(w * x * coat_transmittance(coat, x, table))
    return 1 - tbar / coat.eta**2
