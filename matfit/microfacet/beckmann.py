r"""Beckmann distribution.

.. math::
    D(m) = \frac{\exp\!\big(-(m_x^2/\alpha_x^2 + m_y^2/\alpha_y^2)/m_z^2\big)}{\pi\alpha_x\alpha_y m_z^4},\qquad
    \Lambda(v) = \frac{\operatorname{erf}(c) - 1}{2} + \frac{e^{-c^2}}{2c\sqrt\pi},\quad
    c = \frac{1}{\alpha\tan\theta_v}

References
----------
- P. Beckmann, A. Spizzichino, *The Scattering of Electromagnetic Waves from Rough Surfaces*, 1963.
- B. Walter et al., "Microfacet Models for Refraction through Rough Surfaces", EGSR 2007.
- E. Heitz, E. d'Eon, "Importance Sampling Microfacet-Based BSDFs using the Distribution of
  Visible Normals", CGF 33(4), 2014 (visible-slope sampling, inverted here by safeguarded Newton
  iterations on the CDF written in the erf domain).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import jax.scipy.special as jsp

from .._math import COS_EPS, flip_up, normalize, safe_div, safe_sqrt, sq
from ._base import AbstractDistribution, normal_from_slopes

__all__ = ["Beckmann", "beckmann_lambda"]

_INV_SQRT_PI = 0.5641895835477563


def beckmann_lambda(a2tan2):
    r"""Beckmann's Smith :math:`\Lambda` (module docstring) of :math:`\alpha^2\tan^2\theta_v`; shared with Blinn-Phong.

    Parameters
    ----------
    a2tan2 : array_like
        :math:`\alpha^2\tan^2\theta_v \ge 0`.

    Returns
    -------
    jax.Array
        :math:`\Lambda`, 0 at the normal.
    """
    pos = a2tan2 > 0
    c = jnp.where(pos, jax.lax.rsqrt(jnp.where(pos, a2tan2, 1)), 1)  # c = 1/(alpha tan)
    lam = -0.5 * jsp.erfc(c) + 0.5 * _INV_SQRT_PI * jnp.exp(-c * c) / c
    return jnp.where(pos, jnp.maximum(lam, 0), 0)


def _sample_slope_x(cos_t, u, iters=14):
    """Visible slope x~ for alpha = 1 at incidence theta (phi = 0): invert the CDF.

    In the erf domain b = erf(x~), the unnormalized CDF is (1 + b) + tan(theta)/sqrt(pi) *
    exp(-x~^2), with derivative 1 - x~ tan(theta) (> 0 below the cut-off x~ < cot(theta)).
    """
    cos_t = jnp.clip(cos_t, COS_EPS, 1)
    sin_t = safe_sqrt(1 - cos_t * cos_t)
    tan_t = sin_t / cos_t
    cot_t = safe_div(cos_t, sin_t, 1e30)
    b_max = jsp.erf(jnp.minimum(cot_t, 1e4))
    norm = 1 / (1 + b_max + _INV_SQRT_PI * tan_t * jnp.exp(-sq(jnp.minimum(cot_t, 1e4))))
    lo = -jnp.ones_like(b_max)
    hi = b_max
    b = -1 + (1 + b_max) * u  # exact at normal incidence

    def body(_, state):
        b, lo, hi = state
        b = jnp.where((b > lo) & (b < hi), b, 0.5 * (lo + hi))
        x = jsp.erfinv(b)
        val = norm * (1 + b + _INV_SQRT_PI * tan_t * jnp.exp(-x * x)) - u
        der = norm * (1 - x * tan_t)
        hi = jnp.where(val > 0, b, hi)
        lo = jnp.where(val > 0, lo, b)
        b = b - safe_div(val, der)
        return b, lo, hi

    b, lo, hi = jax.lax.fori_loop(0, iters, body, (b, lo, hi))
    b = jnp.where((b > lo) & (b < hi), b, 0.5 * (lo + hi))
    return jsp.erfinv(jnp.clip(b, -1 + 1e-7, 1 - 1e-7))


class Beckmann(AbstractDistribution):
    """Beckmann microfacet distribution, isotropic or anisotropic.

    Visible normals: stretch ``wo``, invert the alpha = 1 visible-slope CDF, rotate and unstretch.

    Examples
    --------
    >>> import math
    >>> import jax.numpy as jnp
    >>> from matfit.microfacet import Beckmann
    >>> c = 1 / (0.5 * 4 / 3)  # 1 / (alpha tan theta_v) for v = (0.8, 0, 0.6)
    >>> lam = (math.erf(c) - 1) / 2 + math.exp(-c * c) / (2 * c * math.sqrt(math.pi))
    >>> round(float(Beckmann(0.5).Lambda(jnp.array([0.8, 0.0, 0.6]))), 6), round(lam, 6)
    (0.002874, 0.002874)
    """

    has_visible_sampling = True

    def D(self, m):
        ax, ay = self._alphas()
        mz = m[..., 2]
        pos = mz > 0
        mz_s = jnp.where(pos, mz, 1)
        # exp(-s) / mz^4 as one exponential: far from the normal exp(-s) underflows to 0 while
        # the derivative of 1/mz^4 overflows (0 * inf); the log form keeps both finite.
        d = jnp.exp(-self._slope2(m) - 4 * jnp.log(mz_s)) / (jnp.pi * ax * ay)
        return jnp.where(pos, d, 0)

    def Lambda(self, v):
        return beckmann_lambda(self._a2tan2(v))

    def sample_dcos(self, u):
        r = safe_sqrt(-jnp.log(jnp.maximum(1 - u[..., 0], 1e-30)))  # slope radius law for alpha = 1
        return self._normal_from_radius(r, u[..., 1])

    def sample_visible(self, wo, u):
        # stretch, sample the alpha = 1 visible slopes, rotate, unstretch
        ax, ay = self._alphas()
        w = flip_up(wo)
        ws = normalize(jnp.stack([ax * w[..., 0], ay * w[..., 1], w[..., 2]], axis=-1))
        rxy = safe_sqrt(sq(ws[..., 0]) + sq(ws[..., 1]))
        cos_p = safe_div(ws[..., 0], rxy, 1.0)
        sin_p = safe_div(ws[..., 1], rxy, 0.0)
        # Keep u inside (0, 1) so the slopes stay finite.
        u1 = jnp.clip(u[..., 0], 1e-6, 1 - 1e-6)
        u2 = jnp.clip(u[..., 1], 1e-6, 1 - 1e-6)
        x = _sample_slope_x(ws[..., 2], u1)
        y = jsp.erfinv(2 * u2 - 1)
        return normal_from_slopes((cos_p * x - sin_p * y) * ax, (sin_p * x + cos_p * y) * ay)
