"""Lambertian diffuse reflection, and the density of cosine-weighted sampling."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp

from .._math import cosine_hemisphere
from ._base import AbstractBSDF
from ._pairs import valid_reflection
from ._params import as_channels, channel_count, check_directions, check_range, check_u

__all__ = ["Lambert", "cosine_pdf"]


def cosine_pdf(wo, wi):
    """Density ``cos(theta_i) / pi`` of cosine-weighted hemisphere sampling, 0 unless both
    directions are above the surface (:func:`~matfit.models.valid_reflection`).

    Parameters
    ----------
    wo, wi : array_like (..., 3)
        Unit directions.

    Returns
    -------
    jax.Array, shape (...)
    """
    return jnp.where(valid_reflection(wo, wi), wi[..., 2] / jnp.pi, 0)


class Lambert(AbstractBSDF):
    r"""Lambertian diffuse BRDF ``albedo / pi``:

    .. math:: f(\omega_o, \omega_i) = \frac{\rho}{\pi}\quad (\cos\theta_o > 0,\ \cos\theta_i > 0)

    One-sided: zero when either direction is at or below the horizon (|cos| <= ``COS_EPS``).
    Sampling is cosine-weighted (Malley's method, concentric disk map), pdf =
    cos(theta_i)/pi, so the weight is exactly ``albedo``.

    Parameters
    ----------
    albedo : array_like, scalar or (..., C); [0, 1]; differentiable
        Hemispherical reflectance :math:`\rho` per colour channel (stored as the field
        ``reflectance``: ``albedo(wo)`` is the directional-albedo method of every model).

    References
    ----------
    - J. H. Lambert, *Photometria*, 1760.
    - P. Shirley, K. Chiu, "A Low Distortion Map Between Disk and Square", JGT 2(3), 1997.

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.models import Lambert
    >>> m = Lambert(jnp.array([0.8, 0.5, 0.2]))
    >>> up = jnp.array([0.0, 0.0, 1.0])
    >>> bool(jnp.allclose(m.eval(up, up) * jnp.pi, m.reflectance))
    True
    """

    reflectance: jnp.ndarray = eqx.field(converter=as_channels)

    def __init__(self, albedo):
        check_range("Lambert", "albedo", albedo, 0.0, 1.0)
        self.reflectance = albedo

    @property
    def channels(self):
        return channel_count(self.reflectance)

    pair_kernels = True

    def eval(self, wo, wi):
        check_directions("Lambert.eval", wo=wo, wi=wi)
        return self._value(valid_reflection(wo, wi))

    def eval_pairs(self, pairs):
        return self._value(pairs.valid)

    def _value(self, ok):
        return jnp.where(ok[..., None], self.reflectance / jnp.pi, 0)

    def pdf(self, wo, wi):
        check_directions("Lambert.pdf", wo=wo, wi=wi)
        return cosine_pdf(wo, wi)

    def sample(self, wo, u):
        check_directions("Lambert.sample", wo=wo)
        check_u("Lambert.sample", u, 3)
        wi = cosine_hemisphere(u[..., 1], u[..., 2])
        wi = jnp.broadcast_to(wi, jnp.broadcast_shapes(wi.shape, wo.shape))
        pdf = self.pdf(wo, wi)
        ok = pdf > 0
        weight = jnp.where(ok[..., None], self.reflectance, 0)
        return wi, weight, pdf
