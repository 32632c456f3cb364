r"""An isotropic microfacet distribution tabulated over :math:`\theta_m`, with its Smith masking
derived numerically.

Representation. :math:`D` is given at nodes :math:`0 = \theta_0 < \dots < \theta_{n-1} = \pi/2`;
between them :math:`\log D` is linear in :math:`x = \sin^2\theta` where both nodes are > 0 (exact
for exponential tails) and :math:`D` is linear where one is 0. In :math:`x` the projected solid
angle is :math:`\cos\theta\,d\omega = \pi\,dx` (times a uniform azimuth), so the normalization
:math:`\pi\int_0^1 D\,dx = 1` is exact for the tabulated function (a closed form per cell; the
constructor scales the table to it), and :math:`D\cos` sampling inverts the CDF of each cell in
closed form: :meth:`~TabulatedNDF.pdf_dcos` is exactly the density of :meth:`~TabulatedNDF.sample_dcos`.

Smith masking. For a normalized isotropic :math:`D`, :math:`\int m\,D(m)\,d\omega_m = n`, so the
projected area seen from :math:`v` is :math:`\int \max(0, v\cdot m) D\,d\omega_m = \mu + B(\mu)`,
:math:`\mu = \cos\theta_v`, with the *back-facing* area

.. math::
    B(\mu) = \int \max(0, -v\cdot m)\,D(m)\,d\omega_m
           = \int_{\arcsin\mu}^{\pi/2} D(\theta_m)\,2\Big(\sqrt{a^2 - b^2} - b\arccos\frac{b}{a}\Big)
             \sin\theta_m\,d\theta_m,\quad a = \sin\theta_v\sin\theta_m,\ b = \mu\cos\theta_m

(the azimuthal integral in closed form). Hence :math:`\Lambda(v) = B(\mu)/\mu` and
:math:`G_1 = \mu/(\mu + B(\mu))`, with no cancellation at the normal (:math:`B(1) = 0`). :math:`B` is
computed once at construction (Gauss-Legendre on every cell of :math:`D` from the onset
:math:`\theta_m = \arcsin\mu` of the back-facing normals) on nodes :math:`\mu_k = (k/(m-1))^2`,
dense towards grazing where :math:`B` varies on the scale of the lobe, and interpolated linearly.

References
----------
- E. Heitz, "Understanding the Masking-Shadowing Function in Microfacet-Based BRDFs", JCGT 3(2),
  2014 (Smith's :math:`\Lambda` from the projected area of an arbitrary :math:`D`).
- J. Dupuy, E. Heitz, J.-C. Iehl, P. Poulin, V. Ostromoukhov, "Extracting Microfacet-based BRDF
  Parameters from Arbitrary Materials with Power Iterations", CGF 34(4), 2015 (tabulated
  distributions and their projected area).
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._math import COS_EPS, as_direction, as_float, sq
from ..errors import ParameterError
from ._base import AbstractDistribution

__all__ = ["TabulatedNDF", "ndf_grid", "projected_mass", "back_facing_area", "interpolate_ndf"]

#: Gauss-Legendre order per cell of D in the projected-area integral.
_GL_ORDER = 6


def ndf_grid(n=256):
    r"""The default nodes of a tabulated distribution: :math:`\theta_j = (j/(n-1))^2\,\pi/2` (radians).

    Square-root spacing (as MERL's :math:`\theta_h` axis): the first cells resolve lobes down to
    :math:`\alpha \approx 10^{-2}` and the grid still reaches grazing.

    Parameters
    ----------
    n : int, optional
        Number of nodes, >= 3 (default 256); ParameterError otherwise.

    Returns
    -------
    numpy.ndarray, shape (n,)
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 3:
        raise ParameterError(f"ndf_grid: n must be an integer >= 3, got {n!r}")
    return (np.arange(n) / (n - 1)) ** 2 * (np.pi / 2)


def _check_table(owner, theta, d):
    """``theta``, ``d`` as float64 numpy arrays, checked (see :class:`TabulatedNDF`) and extended to [0, pi/2]."""
    for name, v in (("theta", theta), ("d", d)):
        if isinstance(v, jax.core.Tracer):
            raise ParameterError(f"{owner}: {name} must be concrete (a table is built outside jax.jit), found a tracer")
    theta = np.asarray(theta, np.float64)
    d = np.asarray(d, np.float64)
    if theta.ndim != 1 or d.shape != theta.shape or theta.size < 2:
        raise ParameterError(f"{owner}: theta and d must be 1-D arrays of one length >= 2, "
                             f"found shapes {theta.shape} and {d.shape}")
    if not (np.all(np.isfinite(theta)) and np.all(np.isfinite(d))):
        raise ParameterError(f"{owner}: theta and d must be finite")
    if theta[0] < 0 or theta[-1] > np.pi / 2 + 1e-6 or np.any(np.diff(theta) <= 0):
        raise ParameterError(f"{owner}: theta must increase strictly within [0, pi/2], "
                             f"found {theta[0]:.6g} ... {theta[-1]:.6g} rad")
    if np.any(d < 0):
        i = int(np.argmax(d < 0))
        raise ParameterError(f"{owner}: d must be >= 0, found {d[i]:.6g} at theta = {theta[i]:.6g} rad")
    theta = np.minimum(theta, np.pi / 2)
    # extend to the whole range [0, pi/2], holding the end values
    if theta[0] > 0:
        theta, d = np.concatenate([[0.0], theta]), np.concatenate([[d[0]], d])
    if theta[-1] < np.pi / 2:
        theta, d = np.concatenate([theta, [np.pi / 2]]), np.concatenate([d, [d[-1]]])
    return theta, d


def _log_ratio(d):
    """Per cell: whether D is log-linear in x there (both ends > 0) and ``log(d1/d0)`` (0 elsewhere)."""
    geo = (d[:-1] > 0) & (d[1:] > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        lr = np.where(geo, np.log(np.where(geo, d[1:], 1.0)) - np.log(np.where(geo, d[:-1], 1.0)), 0.0)
    return geo, lr


def _cell_masses(x, d):
    r""":math:`\int D\,dx` over every cell: the logarithmic mean of its ends times its width where
    :math:`D` is log-linear, the trapezoid elsewhere."""
    geo, lr = _log_ratio(d)
    small = np.abs(lr) < 1e-6
    with np.errstate(divide="ignore", invalid="ignore"):
        logmean = np.where(small, 1 + lr / 2 + lr * lr / 6, np.expm1(lr) / np.where(small, 1.0, lr)) * d[:-1]
    return np.diff(x) * np.where(geo, logmean, 0.5 * (d[1:] + d[:-1]))


def _values_in_cells(x, d, j, xq):
    """D at ``xq`` in cells ``j`` (numpy, vectorized), interpolated as the table defines it."""
    geo = (d[:-1] > 0) & (d[1:] > 0)
    w = np.clip((xq - x[j]) / (x[j + 1] - x[j]), 0.0, 1.0)
    lin = d[j] + w * (d[j + 1] - d[j])
    with np.errstate(divide="ignore"):
        ld = np.log(np.where(d > 0, d, 1.0))
    # d0^(1-w) d1^w: no overflow however far apart the two ends are
    return np.where(geo[j], np.exp((1 - w) * ld[j] + w * ld[j + 1]), lin)


def interpolate_ndf(theta, d, theta_q):
    """:math:`D` of a table at angles ``theta_q``, interpolated as :class:`TabulatedNDF` does (numpy,
    float64, not normalized).

    Parameters
    ----------
    theta, d : array_like, shape (n,)
        Increasing node angles in [0, pi/2] (radians) and :math:`D` there, >= 0.
    theta_q : array_like
        Query angles in [0, pi/2].

    Returns
    -------
    numpy.ndarray, shape of ``theta_q``
    """
    theta = np.asarray(theta, np.float64)
    d = np.asarray(d, np.float64)
    x = np.sin(theta) ** 2
    xq = np.sin(np.clip(np.asarray(theta_q, np.float64), 0, np.pi / 2)) ** 2
    j = np.clip(np.searchsorted(x, xq, side="right") - 1, 0, len(x) - 2)
    return _values_in_cells(x, d, j, xq)


def projected_mass(theta, d):
    r""":math:`\int D(m)\cos\theta_m\,d\omega_m = \pi\int_0^1 D\,dx` of a table, exact for the function it
    defines (:class:`TabulatedNDF`).

    Parameters
    ----------
    theta, d : array_like, shape (n,)
        Increasing node angles in [0, pi/2] (radians) and :math:`D` there (1/sr), >= 0.

    Returns
    -------
    float
    """
    x = np.sin(np.asarray(theta, np.float64)) ** 2
    return float(np.pi * np.sum(_cell_masses(x, np.asarray(d, np.float64))))


def back_facing_area(theta, d, mu):
    r"""The back-facing projected area :math:`B(\mu)` of the module docstring, for a table interpolated
    as :class:`TabulatedNDF` does; with :math:`D` normalized, Smith's :math:`\Lambda = B(\mu)/\mu`.

    Parameters
    ----------
    theta, d : array_like, shape (n,)
        Increasing node angles in [0, pi/2] (radians) and :math:`D` there, >= 0.
    mu : array_like, shape (m,)
        Cosines of the viewing directions, in [0, 1].

    Returns
    -------
    numpy.ndarray, shape (m,)
    """
    theta = np.asarray(theta, np.float64)
    mu = np.clip(np.asarray(mu, np.float64), 0.0, 1.0)
    x, j, xq, weight = _back_facing_kernel(theta.tobytes(), mu.tobytes())
    dm = _values_in_cells(x, np.asarray(d, np.float64), j, xq)
    return np.sum(weight * np.maximum(dm, 0.0), axis=(1, 2))


@functools.lru_cache(maxsize=8)
def _back_facing_kernel(theta_bytes, mu_bytes):
    """What :func:`back_facing_area` needs of the nodes and cosines alone (cached: an extraction calls
    it with the same ones every iteration): ``x = sin^2`` of the nodes, the cell ``j`` and ``sin^2``
    of every Gauss-Legendre point (m, n-1, order), and the weight of ``D`` there."""
    theta = np.frombuffer(theta_bytes, np.float64)
    mu = np.frombuffer(mu_bytes, np.float64)
    x = np.sin(theta) ** 2
    onset = np.arcsin(mu)[:, None]  # back-facing normals exist for theta_m > pi/2 - theta_v
    lo = np.maximum(theta[None, :-1], onset)
    hi = np.maximum(theta[None, 1:], onset)
    g, w = np.polynomial.legendre.leggauss(_GL_ORDER)
    g, w = 0.5 * (g + 1), 0.5 * w
    tm = lo[..., None] + (hi - lo)[..., None] * g  # (m, n-1, order)
    sm, cm = np.sin(tm), np.cos(tm)
    j = np.broadcast_to(np.arange(len(theta) - 1)[None, :, None], tm.shape)
    a = np.sqrt(np.maximum(1 - mu * mu, 0.0))[:, None, None] * sm
    b = mu[:, None, None] * cm
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.clip(np.where(a > 0, b / a, 1.0), -1.0, 1.0)
    kern = np.where(a > b, 2 * (np.sqrt(np.maximum(a * a - b * b, 0.0)) - b * np.arccos(ratio)), 0.0)
    out = (x, j, sm * sm, (hi - lo)[..., None] * w * kern * sm)
    for arr in out:  # shared by every later call
        arr.flags.writeable = False
    return out


class TabulatedNDF(AbstractDistribution):
    r"""An isotropic microfacet distribution tabulated over :math:`\theta_m`, with Smith masking derived
    from it (the module docstring has the representation and the formulas).

    The table is scaled so that :math:`\int D\cos\theta_m\,d\omega_m = 1`; :math:`\Lambda` is computed
    once here, so it is not recomputed when :math:`D` changes under ``jax.grad`` (the tables are data,
    not fit parameters; their dtype is that of ``d``, the default float for integer input). Build it
    outside ``jax.jit``. No visible-normal sampler. ``alpha_x`` = ``alpha_y`` = :math:`1/\sqrt{\pi D(0)}`,
    the width of the GGX (or Beckmann) lobe of the same peak, for information only.

    Parameters
    ----------
    theta : array_like, shape (n,)
        Node angles in radians, strictly increasing within :math:`[0, \pi/2]`; the table is extended
        to 0 and :math:`\pi/2` with its end values.
    d : array_like, shape (n,)
        :math:`D` at the nodes, >= 0, any scale (normalized here).
    n_lambda : int, optional
        Nodes :math:`\mu_k` of the :math:`\Lambda` table (default 256).

    Attributes
    ----------
    x_nodes, d_nodes : jax.Array, shape (n,)
        :math:`\sin^2\theta` and the normalized :math:`D` at the nodes.
    cdf : jax.Array, shape (n,)
        :math:`\pi\int_0^{x_j} D\,dx`: 0 at the normal, 1 at the horizon.
    b_nodes : jax.Array, shape (m,)
        :math:`B(\mu_k)` (:func:`back_facing_area`).

    Raises
    ------
    ParameterError
        For a table that is not 1-D and finite, angles out of order or range, negative or
        all-zero values, a traced table.

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.microfacet import GGX, TabulatedNDF
    >>> tab = TabulatedNDF.from_distribution(GGX(0.3))
    >>> n = jnp.array([0.0, 0.0, 1.0]); v = jnp.array([0.8, 0.0, 0.6])
    >>> round(float(tab.D(n) / GGX(0.3).D(n)), 3), round(float(tab.G1(v, n) / GGX(0.3).G1(v, n)), 3)
    (1.0, 1.0)
    """

    x_nodes: jnp.ndarray
    d_nodes: jnp.ndarray
    log_d: jnp.ndarray
    cdf: jnp.ndarray
    b_nodes: jnp.ndarray
    sqrt_grid: bool = eqx.field(static=True)

    def __init__(self, theta, d, n_lambda=256):
        owner = "TabulatedNDF"
        dtype = as_float(np.asarray(d) if not hasattr(d, "dtype") else d).dtype
        if isinstance(n_lambda, bool) or not isinstance(n_lambda, (int, np.integer)) or n_lambda < 3:
            raise ParameterError(f"{owner}: n_lambda must be an integer >= 3, got {n_lambda!r}")
        theta, d = _check_table(owner, theta, d)
        mass = projected_mass(theta, d)
        if not mass > 0:
            raise ParameterError(f"{owner}: d must have a positive projected area (int D cos > 0), found {mass:.6g}")
        d = d / mass
        x = np.sin(theta) ** 2
        x[-1] = 1.0
        cdf = np.concatenate([[0.0], np.cumsum(np.pi * _cell_masses(x, d))])
        cdf /= cdf[-1]
        mu = (np.arange(n_lambda) / (n_lambda - 1)) ** 2
        b = back_facing_area(theta, d, mu)
        alpha = 1 / np.sqrt(np.pi * max(d[0], 1e-300))
        self.alpha_x = jnp.asarray(alpha, dtype)
        self.alpha_y = jnp.asarray(alpha, dtype)
        self.x_nodes = jnp.asarray(x, dtype)
        self.d_nodes = jnp.asarray(d, dtype)
        with np.errstate(divide="ignore"):
            self.log_d = jnp.asarray(np.where(d > 0, np.log(np.where(d > 0, d, 1.0)), 0.0), dtype)
        # the nodes of ndf_grid: the cell of an angle is computed, not searched
        self.sqrt_grid = bool(np.allclose(theta, ndf_grid(len(theta)), rtol=0, atol=1e-6))
        self.cdf = jnp.asarray(cdf, dtype)
        self.b_nodes = jnp.asarray(b, dtype)

    @classmethod
    def from_function(cls, fn, n=256, n_lambda=256, dtype=None):
        """Tabulate ``fn(theta)`` (:math:`D`, any scale, of a numpy array of angles) on ``n`` :func:`ndf_grid` nodes.

        ``dtype`` defaults to JAX's default float."""
        theta = ndf_grid(n)
        d = np.asarray(fn(theta), np.float64)
        dtype = jnp.result_type(float) if dtype is None else dtype
        return cls(theta.astype(dtype), d.astype(dtype), n_lambda)

    @classmethod
    def from_distribution(cls, dist, n=256, n_lambda=256, dtype=None):
        r"""Tabulate an isotropic distribution's :math:`D` (its :math:`\Lambda` is derived anew).

        ``dtype`` defaults to that of ``dist.alpha_x``; an anisotropic ``dist`` raises ParameterError."""
        ax, ay = np.asarray(dist.alpha_x, np.float64), np.asarray(dist.alpha_y, np.float64)
        if ax.shape != () or not np.allclose(ax, ay, rtol=1e-6):
            raise ParameterError(f"TabulatedNDF.from_distribution: dist must be isotropic with scalar alphas, "
                                 f"found alpha_x={ax}, alpha_y={ay}")
        theta = ndf_grid(n)
        m = np.stack([np.sin(theta), np.zeros_like(theta), np.cos(theta)], -1)
        m[-1] = [np.sqrt(1 - 1e-12), 0.0, 1e-6]  # D at the horizon: its limit m_z -> 0+
        d = np.asarray(dist.D(jnp.asarray(m, jnp.asarray(dist.alpha_x).dtype)), np.float64)
        dtype = jnp.asarray(dist.alpha_x).dtype if dtype is None else dtype
        return cls(theta.astype(dtype), d.astype(dtype), n_lambda)

    @property
    def n_nodes(self):
        """Number of nodes of :math:`D`."""
        return int(self.x_nodes.shape[-1])

    def _cell(self, x, mz):
        """Cell j (x_j <= x < x_{j+1}) of sin^2 theta = x, cos theta = mz, and the weight of x in it."""
        xn = self.x_nodes
        n1 = xn.shape[-1] - 1
        if self.sqrt_grid:  # theta_j = (j / n1)^2 pi / 2, then one step against rounding
            theta = jnp.arctan2(jnp.sqrt(x), jnp.maximum(mz, 0))
            j = jnp.clip(jnp.floor(jnp.sqrt(theta * (2 / jnp.pi)) * n1), 0, n1 - 1).astype(jnp.int32)
            j = jnp.clip(j - (x < xn[j]) + (x >= xn[j + 1]), 0, n1 - 1)
        else:
            j = jnp.clip(jnp.searchsorted(xn, x, side="right") - 1, 0, n1 - 1)
        x0, x1 = xn[j], xn[j + 1]
        return j, jnp.clip((x - x0) / (x1 - x0), 0, 1)

    def D(self, m):
        mz = m[..., 2]
        x = jnp.clip(as_direction(m).tan_sq(), 0, 1)  # sin^2 theta_m of a unit normal
        j, w = self._cell(x, mz)
        d0, d1 = self.d_nodes[j], self.d_nodes[j + 1]
        # log-linear in x where both ends are > 0 (exact for exponential tails), linear elsewhere
        l0, l1 = self.log_d[j], self.log_d[j + 1]
        d = jnp.where((d0 > 0) & (d1 > 0), jnp.exp(l0 + w * (l1 - l0)), d0 + w * (d1 - d0))
        return jnp.where(mz > 0, d, 0)

    def _back_area(self, v):
        """B(mu) of |v_z| (linear in mu between mu_k = (k/(m-1))^2)."""
        mu = jnp.clip(jnp.abs(v[..., 2]), 0, 1)
        m1 = self.b_nodes.shape[-1] - 1
        k = jnp.clip(jnp.floor(jnp.sqrt(mu) * m1), 0, m1 - 1).astype(jnp.int32)
        mu0, mu1 = sq(k / m1), sq((k + 1) / m1)
        w = (mu - mu0) / (mu1 - mu0)
        b0, b1 = self.b_nodes[k], self.b_nodes[k + 1]
        return mu, jnp.maximum(b0 + w * (b1 - b0), 0)

    def Lambda(self, v):
        mu, b = self._back_area(v)
        return b / jnp.maximum(mu, COS_EPS)

    def _g1_ratio(self, v):
        # 1 / (1 + Lambda) = mu / (mu + B): no division by mu
        mu, b = self._back_area(v)
        den = mu + b
        return mu, jnp.where(den > 0, den, 1)

    def _g2_reflection_ratio(self, wo, wi, form):
        if form == "separable":
            (no, do), (ni, di) = self._g1_ratio(wo), self._g1_ratio(wi)
            return no * ni, do * di
        # 1 / (1 + B_o/mu_o + B_i/mu_i) = mu_o mu_i / (mu_o mu_i + B_o mu_i + B_i mu_o)
        mo, bo = self._back_area(wo)
        mi, bi = self._back_area(wi)
        den = mo * mi + bo * mi + bi * mo
        return mo * mi, jnp.where(den > 0, den, 1)

    def sample_dcos(self, u):
        xn, dn, cdf = self.x_nodes, self.d_nodes, self.cdf
        u1 = u[..., 0]
        j = jnp.clip(jnp.searchsorted(cdf, u1, side="right") - 1, 0, xn.shape[-1] - 2)
        x0, dx = xn[j], xn[j + 1] - xn[j]
        d0, d1 = dn[j], dn[j + 1]
        r = jnp.maximum(u1 - cdf[j], 0) / jnp.pi  # the mass int_{x0}^{x0 + t} D dx to reach
        # linear cell: d0 t + (d1 - d0) t^2 / (2 dx) = r, solved without cancellation
        root = d0 + jnp.sqrt(jnp.maximum(sq(d0) + 2 * (d1 - d0) * r / dx, 0))
        t_lin = jnp.where(root > 0, 2 * r / jnp.where(root > 0, root, 1), 0)
        # log-linear cell: d0 (exp(l t / dx) - 1) dx / l = r, t = (r / d0) log1p(z) / z, z = l r / (d0 dx)
        geo = (d0 > 0) & (d1 > 0)
        g0 = jnp.where(geo, d0, 1)
        lr = self.log_d[j + 1] - self.log_d[j]
        z = jnp.maximum(lr * r / (g0 * dx), -1 + 1e-7)
        small = jnp.abs(z) < 1e-4
        zs = jnp.where(small, 1, z)
        ratio = jnp.where(small, 1 - z / 2 + sq(z) / 3, jnp.log1p(zs) / zs)
        t = jnp.where(geo, r / g0 * ratio, t_lin)
        x = jnp.clip(x0 + jnp.clip(t, 0, dx), 0, 1)
        sin_t, cos_t = jnp.sqrt(x), jnp.sqrt(1 - x)
        phi = 2 * jnp.pi * u[..., 1]
        return jnp.stack([sin_t * jnp.cos(phi), sin_t * jnp.sin(phi), cos_t], axis=-1)
