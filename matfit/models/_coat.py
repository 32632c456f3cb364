r"""A dielectric coat seen from outside: its reflection lobe and its directional transmittance.

Shared by :class:`Plastic` and :class:`Layered`. A coat is a :class:`SmoothDielectric` (alpha = 0)
or a :class:`RoughDielectric`. Its energy transmittance for light arriving at
:math:`\cos\theta = \mu` is :math:`T(\mu) = 1 - F(\mu)` when smooth; when rough it is

.. math:: T(\mu) = \int_{[0,1]^2} (1 - F(\omega_o\cdot m(u)))\,w_t(u)\,\eta_p^2\,du

the transmission lobe's sample weights integrated in primary-sample space by a tensor
Gauss-Legendre rule (``order`` points per axis), tabulated at ``nodes`` cosines (crowded towards grazing as :math:`\mu_j = (j/(n-1))^2`, the
first evaluated at :math:`\mu = 10^{-3}`) and interpolated linearly. The internal diffuse reflectance of the coat is
:math:`R_{int} = 1 - \bar T/\eta^2` with :math:`\bar T = 2\int_0^1 T(\mu)\mu\,d\mu`, which is
the exact hemispherical average of the internal Fresnel reflectance for a smooth coat and keeps
reciprocity and energy balance for a rough one.
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
    """A smooth coat when ``alpha`` is a concrete 0, else a rough one.

    Parameters
    ----------
    alpha : array_like
        Width of the coat's distribution (traced values give a rough coat).
    eta : array_like
        Index of the coat relative to the outside.
    distribution, masking : str, optional
        Options of a rough coat.

    Returns
    -------
    SmoothDielectric or RoughDielectric

    Examples
    --------
    >>> from matfit.models._coat import make_coat
    >>> type(make_coat(0.0, 1.5)).__name__, type(make_coat(0.1, 1.5)).__name__
    ('SmoothDielectric', 'RoughDielectric')
    """
    try:
        smooth = float(np.max(np.asarray(alpha))) == 0.0
    except Exception:  # traced alpha: rough
        smooth = False
    if smooth:
        return SmoothDielectric(eta)
    return RoughDielectric(alpha, eta, distribution=distribution, masking=masking)


def is_smooth(coat):
    """True for a smooth coat (a :class:`SmoothDielectric`).

    Parameters
    ----------
    coat : SmoothDielectric or RoughDielectric
        The coat.

    Returns
    -------
    bool

    Examples
    --------
    >>> from matfit.models import SmoothDielectric
    >>> from matfit.models._coat import is_smooth
    >>> is_smooth(SmoothDielectric(1.5))
    True
    """
    return isinstance(coat, SmoothDielectric)


def coat_reflection(coat, wo, wi):
    """Value of the coat's (non-delta) reflection lobe: 0 for a smooth coat and wherever the
    pair is not a reflection pair above the surface.

    Parameters
    ----------
    coat : SmoothDielectric or RoughDielectric
        The coat.
    wo, wi : array_like, shape (..., 3)
        Unit directions.

    Returns
    -------
    jax.Array, shape (...)

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.models import RoughDielectric
    >>> from matfit.models._coat import coat_reflection
    >>> up = jnp.array([0.0, 0.0, 1.0])
    >>> bool(coat_reflection(RoughDielectric(0.2, 1.5), up, up) > 0)
    True
    """
    if is_smooth(coat):
        return jnp.zeros(jnp.broadcast_shapes(wo.shape, wi.shape)[:-1], jnp.result_type(wo))
    return jnp.where(valid_reflection(wo, wi), coat.eval(wo, wi)[..., 0], 0)


def coat_reflection_pairs(coat, pairs):
    """:func:`coat_reflection` of a rough coat on prepared pairs (:class:`~matfit.models.SoAPairs`):
    the lobe ``D G2 / (4 cos cos)`` times the dielectric Fresnel at ``wo . h``; 0 where the pair
    is invalid or the coat is index-matched (it then reflects nothing).

    Parameters
    ----------
    coat : RoughDielectric
        The rough coat.
    pairs : SoAPairs
        Prepared direction pairs.

    Returns
    -------
    jax.Array, shape (...)

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.models import RoughDielectric, SoAPairs
    >>> from matfit.models._coat import coat_reflection, coat_reflection_pairs
    >>> coat = RoughDielectric(0.2, 1.5)
    >>> wo = jnp.array([[0.0, 0.6, 0.8]]); wi = jnp.array([[0.0, -0.6, 0.8]])
    >>> bool(jnp.allclose(coat_reflection_pairs(coat, SoAPairs.of(wo, wi)), coat_reflection(coat, wo, wi)))
    True
    """
    F = fresnel_dielectric(pairs.cos_d, coat.eta)
    return jnp.where(coat.index_matched(), 0, coat.reflection_lobe(pairs) * F)


def _gl01(n, dtype):
    x, w = np.polynomial.legendre.leggauss(n)
    return jnp.asarray(0.5 * (x + 1), dtype), jnp.asarray(0.5 * w, dtype)


def coat_transmittance_table(coat, order=COAT_ORDER, nodes=COAT_NODES, dtype=None):
    """Tabulated energy transmittance ``(mu, T(mu))`` of a rough coat (see the module docstring).

    Parameters
    ----------
    coat : RoughDielectric
        The rough coat.
    order : int, optional
        Gauss-Legendre order per axis of the primary-sample quadrature.
    nodes : int, optional
        Number of tabulated cosines, ``mu_j = (j / (nodes - 1))^2``.
    dtype : dtype, optional
        Floating type of the table (default: that of ``coat.eta``).

    Returns
    -------
    mu, T : jax.Array, shape (nodes,)
        The cosines and the transmittance there.

    Examples
    --------
    >>> from matfit.models import RoughDielectric
    >>> from matfit.models._coat import coat_transmittance_table
    >>> mu, T = coat_transmittance_table(RoughDielectric(0.2, 1.5), order=4, nodes=5)
    >>> mu.shape, bool(0.9 < float(T[-1]) < 1.0)
    ((5,), True)
    """
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
    """Energy transmittance of the coat at incidence cosine ``mu``: ``1 - F(mu)`` when smooth,
    the table linearly interpolated when rough.

    Parameters
    ----------
    coat : SmoothDielectric or RoughDielectric
        The coat.
    mu : array_like
        Cosines, clamped to [0, 1].
    table : tuple of jax.Array, optional
        :func:`coat_transmittance_table` of a rough coat (built when not given).

    Returns
    -------
    jax.Array
        Of the shape of ``mu``.

    Examples
    --------
    >>> from matfit.models import SmoothDielectric
    >>> from matfit.models._coat import coat_transmittance
    >>> round(float(coat_transmittance(SmoothDielectric(1.5), 1.0)), 6)  # 1 - ((1.5 - 1) / 2.5)^2
    0.96
    """
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
    """Hemispherical internal reflectance ``R_int = 1 - Tbar / eta^2`` of the coat.

    Parameters
    ----------
    coat : SmoothDielectric or RoughDielectric
        The coat.
    table : tuple of jax.Array, optional
        :func:`coat_transmittance_table` of a rough coat.
    order : int, optional
        Gauss-Legendre order of the average over the cosine.

    Returns
    -------
    jax.Array
        A scalar (or the batch shape of ``coat.eta``).

    Examples
    --------
    >>> from matfit.models import SmoothDielectric
    >>> from matfit.models._coat import coat_internal_reflectance
    >>> round(float(coat_internal_reflectance(SmoothDielectric(1.5))), 3)  # the internal Fresnel average
    0.596
    """
    if is_smooth(coat):
        return fresnel_dielectric_average(1 / coat.eta, n=order)
    x, w = _gl01(order, jnp.result_type(coat.eta, float))
    tbar = 2 * jnp.sum(w * x * coat_transmittance(coat, x, table))
    return 1 - tbar / coat.eta**2
