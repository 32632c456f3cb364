r"""GGX / Trowbridge-Reitz distribution.

.. math::
    D(m) = \frac{1}{\pi\alpha_x\alpha_y\,(m_x^2/\alpha_x^2 + m_y^2/\alpha_y^2 + m_z^2)^2},\qquad
    \Lambda(v) = \frac{-1 + \sqrt{1 + \alpha^2\tan^2\theta_v}}{2}

with the projected roughness :math:`\alpha^2\tan^2\theta_v = (v_x^2\alpha_x^2 + v_y^2\alpha_y^2)/v_z^2`.
Smith's :math:`G_1 = 1/(1 + \Lambda)` is evaluated as
:math:`2|v_z| / (|v_z| + \sqrt{v_z^2 + v_x^2\alpha_x^2 + v_y^2\alpha_y^2})` (Walter et al. 2007, Eq. 34).

References
----------
- T. S. Trowbridge, K. P. Reitz, JOSA 65(5), 1975.
- B. Walter, S. Marschner, H. Li, K. Torrance, "Microfacet Models for Refraction through Rough
  Surfaces", EGSR 2007.
- E. Heitz, "Sampling the GGX Distribution of Visible Normals", JCGT 7(4), 2018.
- J. Dupuy, A. Benyoub, "Sampling Visible GGX Normals with Spherical Caps", CGF 42(8), 2023.
"""

from __future__ import annotations

import jax.numpy as jnp

from .._math import as_direction, flip_up, normalize, safe_sqrt, sq
from ._base import AbstractDistribution

__all__ = ["GGX"]


class GGX(AbstractDistribution):
    """GGX (Trowbridge-Reitz) microfacet distribution, isotropic or anisotropic.

    Visible normals by the spherical caps of Dupuy & Benyoub (2023); :math:`G_1` without a division
    by :math:`v_z` (module docstring).

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.microfacet import GGX
    >>> v = jnp.array([0.6, 0.0, 0.8])  # alpha^2 tan^2 theta_v = 0.09 * 0.5625
    >>> round(float(GGX(0.3).Lambda(v)), 6), round((-1 + (1 + 0.09 * 0.5625) ** 0.5) / 2, 6)
    (0.0125, 0.0125)
    """

    has_visible_sampling = True

    def D(self, m):
        num, den = self._D_ratio(m)
        return jnp.where(m[..., 2] > 0, num / den, 0)

    def _D_ratio(self, m):
        ax, ay = self._alphas()
        # 1 / alpha once per model, not a division per normal
        t = as_direction(m).tan_sq(1 / ax, 1 / ay) + sq(m[..., 2])
        return 1.0, jnp.pi * ax * ay * sq(t)

    def Lambda(self, v):
        t = self._a2tan2(v)
        # (sqrt(1 + t) - 1)/2 written without cancellation near the normal (t -> 0).
        return t / (2 * (1 + jnp.sqrt(1 + t)))

    def _g1_ratio(self, v):
        # 1 / (1 + Lambda) = 2 |v_z| / (|v_z| + sqrt(v_z^2 + v_x^2 a_x^2 + v_y^2 a_y^2)) (Walter et
        # al. 2007, Eq. 34, times |v_z| / |v_z|): no division inside, none by v_z, no cancellation.
        ax, ay = self._alphas()
        vz = jnp.abs(v[..., 2])
        return 2 * vz, vz + jnp.sqrt(sq(v[..., 2]) + as_direction(v).tan_sq(ax, ay))

    def sample_dcos(self, u):
        u1 = u[..., 0]
        r = safe_sqrt(u1 / jnp.maximum(1 - u1, 1e-12))  # slope radius law for alpha = 1
        return self._normal_from_radius(r, u[..., 1])

    def sample_visible(self, wo, u):
        # the spherical-cap method of Dupuy & Benyoub (2023)
        ax, ay = self._alphas()
        w = flip_up(wo)
        ws = normalize(jnp.stack([ax * w[..., 0], ay * w[..., 1], w[..., 2]], axis=-1))
        phi = 2 * jnp.pi * u[..., 0]
        z = (1 - u[..., 1]) * (1 + ws[..., 2]) - ws[..., 2]
        s = safe_sqrt(1 - z * z)
        c = jnp.stack([s * jnp.cos(phi), s * jnp.sin(phi), z], axis=-1)
        h = c + ws
        m = jnp.stack([ax * h[..., 0], ay * h[..., 1], jnp.maximum(h[..., 2], 0)], axis=-1)
        return normalize(m)
