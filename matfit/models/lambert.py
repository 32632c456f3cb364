r"""Lambertian diffuse reflection.

.. math:: f(\omega_o, \omega_i) = \frac{\rho}{\pi}\quad (\cos\theta_o > 0,\ \cos\theta_i > 0)

Parameters
----------
albedo : (..., C), in [0, 1], differentiable. The hemispherical reflectance rho.

Sampling is cosine-weighted (Malley's method, concentric disk map), pdf = cos(theta_i)/pi, so the
weight is exactly ``albedo``. The model is one-sided: zero when either direction is at or below
the horizon (|cos| <= ``COS_EPS``).

References
----------
- J. H. Lambert, *Photometria*, 1760.
- P. Shirley, K. Chiu, "A Low Distortion Map Between Disk and Square", JGT 2(3), 1997.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp

from .._math import COS_EPS, cosine_hemisphere
from ._base import AbstractBSDF
from ._pairs import valid_reflection
from ._params import as_channels, check_directions, check_range, check_u


class Lambert(AbstractBSDF):
    """Lambertian diffuse BRDF ``albedo / pi``.

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.models import Lambert
    >>> m = Lambert(jnp.array([0.8, 0.5, 0.2]))
    >>> up = jnp.array([0.0, 0.0, 1.0])
    >>> m.eval(up, up).shape
    (3,)
    """

    reflectance: jnp.ndarray = eqx.field(converter=as_channels)

    def __init__(self, albedo):
        check_range("Lambert", "albedo", albedo, 0.0, 1.0)
        self.reflectance = albedo

    @property
    def channels(self):
        return self.reflectance.shape[-1]

    pair_kernels = True

    def eval(self, wo, wi):
        check_directions("Lambert.eval", wo=wo, wi=wi)
        return self._value(valid_reflection(wo, wi))

    def eval_pairs(self, pairs):
        return self._value(pairs.iso[0])

    def _value(self, ok):
        return jnp.where(ok[..., None], self.reflectance / jnp.pi, 0)

    def pdf(self, wo, wi):
        check_directions("Lambert.pdf", wo=wo, wi=wi)
        ok = (wo[..., 2] > COS_EPS) & (wi[..., 2] > COS_EPS)
        return jnp.where(ok, wi[..., 2] / jnp.pi, 0)

    def sample(self, wo, u):
        check_directions("Lambert.sample", wo=wo)
        check_u("Lambert.sample", u, 3)
        wi = cosine_hemisphere(u[..., 1], u[..., 2])
        wi = jnp.broadcast_to(wi, jnp.broadcast_shapes(wi.shape, wo.shape))
        pdf = self.pdf(wo, wi)
        ok = pdf > 0
        weight = jnp.where(ok[..., None], self.reflectance, 0)
        return wi, weight, pdf
