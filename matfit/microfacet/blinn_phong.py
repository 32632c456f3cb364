r"""Normalized Blinn-Phong distribution, mapped to alpha by :math:`e = 2/\alpha^2 - 2`.

Isotropic: :math:`D(m) = \frac{e + 2}{2\pi}\cos^e\theta_m`. Anisotropic (Ashikhmin-Shirley form,
exactly normalized): :math:`D(m) = \frac{\sqrt{(e_x+2)(e_y+2)}}{2\pi}\cos^{e(\phi)}\theta_m` with
:math:`e(\phi) = e_x\cos^2\phi_m + e_y\sin^2\phi_m`. The Smith term uses Beckmann's Lambda at the
same alpha (Walter et al. 2007, Sec. 5.2): Blinn-Phong has no closed-form Smith Lambda; the
mapping :math:`e = 2/\alpha^2 - 2` makes the two distributions agree closely for small alpha.

References
----------
- J. F. Blinn, "Models of Light Reflection for Computer Synthesized Pictures", SIGGRAPH 1977.
- M. Ashikhmin, P. Shirley, "An Anisotropic Phong BRDF Model", JGT 5(2), 2000.
- B. Walter et al., EGSR 2007.
"""

from __future__ import annotations

import jax.numpy as jnp

from .._math import as_direction, sq
from ._base import AbstractDistribution
from .beckmann import beckmann_lambda

__all__ = ["BlinnPhong"]


class BlinnPhong(AbstractDistribution):
    """Normalized Blinn-Phong distribution (exponent ``2/alpha^2 - 2``).

    Smith's Lambda is Beckmann's at the same alpha; keep alpha <= 1 (the exponent is negative
    beyond). No visible-normal sampling: :meth:`sample_dcos` only.

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.microfacet import BlinnPhong
    >>> d = BlinnPhong(0.5)
    >>> [float(e) for e in d.exponent]
    [6.0, 6.0]
    """

    @property
    def exponent(self):
        """Blinn-Phong exponents ``(e_x, e_y) = 2/alpha^2 - 2``."""
        ax, ay = self._alphas()
        return 2 / sq(ax) - 2, 2 / sq(ay) - 2

    def D(self, m):
        ex, ey = self.exponent
        mz = m[..., 2]
        pos = mz > 0
        # cos^e = exp(e log cos): log cos from sin^2 by log1p keeps float32 accurate at e ~ 1e6.
        m = as_direction(m)
        sin2 = jnp.minimum(m.tan_sq(), 1.0)
        # Near the normal log1p(-sin^2) is exact; near grazing log(m_z) is (no cancellation).
        near = sq(mz) >= 0.5
        log_cos = jnp.where(near, 0.5 * jnp.log1p(-jnp.where(near, sin2, 0.0)), jnp.log(jnp.where(pos & ~near, mz, 1.0)))
        d = jnp.sqrt((ex + 2) * (ey + 2)) / (2 * jnp.pi) * jnp.exp(m.along_azimuth(*self.exponent) * log_cos)
        return jnp.where(pos, d, 0)

    def Lambda(self, v):
        return beckmann_lambda(self._a2tan2(v))

    def sample_dcos(self, u):
        ex, ey = self.exponent
        a = ex + 2
        b = ey + 2
        # phi: density proportional to 1/(a cos^2 + b sin^2), inverted per quadrant.
        q = jnp.floor(4 * u[..., 1])
        t = 4 * u[..., 1] - q
        phi0 = jnp.arctan(jnp.sqrt(a / b) * jnp.tan(0.5 * jnp.pi * jnp.clip(t, 0, 1 - 1e-7)))
        phi = jnp.select([q < 1, q < 2, q < 3], [phi0, jnp.pi - phi0, jnp.pi + phi0], 2 * jnp.pi - phi0)
        cp = jnp.cos(phi)
        sp = jnp.sin(phi)
        e = ex * sq(cp) + ey * sq(sp)
        # cos(theta) = u^(1/(e+2)); sin^2 = -expm1(2 log(u)/(e+2)) stays accurate for huge e.
        u1 = jnp.maximum(u[..., 0], 1e-30)
        sin2 = -jnp.expm1(2 * jnp.log(u1) / (e + 2))
        sin_t = jnp.sqrt(jnp.clip(sin2, 0, 1))
        cos_t = jnp.sqrt(jnp.clip(1 - sin2, 0, 1))
        return jnp.stack([sin_t * cp, sin_t * sp, cos_t], axis=-1)
