"""Smooth dielectric: specular reflection and refraction (delta model)."""

from __future__ import annotations

import jax.numpy as jnp

from .._math import COS_EPS, mirror, refract, sq, up_like
from ..fresnel import fresnel_dielectric
from ._base import AbstractDeltaBSDF, dielectric_energy_factor
from ._params import as_param, check_directions, check_range, check_u

__all__ = ["SmoothDielectric"]


class SmoothDielectric(AbstractDeltaBSDF):
    r"""Clear glass interface (one colour channel, ``C = 1``): the :math:`\alpha \to 0` limit of
    :class:`RoughDielectric`. With :math:`F` the exact dielectric Fresnel at
    :math:`\cos\theta_o`, ``sample`` reflects with probability F (weight 1) and refracts by
    Snell's law with probability 1 - F (weight :math:`1/\eta_p^2`, the radiance scaling); under
    total internal reflection F = 1. The returned pdf is the discrete lobe probability; ``eval``
    and ``pdf`` are zero everywhere.

    Parameters
    ----------
    eta : array_like, scalar or (...); > 0; differentiable
        Relative index inside / outside; one value per batch element, no channel axis.

    References
    ----------
    - M. Pharr, W. Jakob, G. Humphreys, *Physically Based Rendering*, 4th ed., Sec. 9.5.

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.models import SmoothDielectric
    >>> wi, weight, pdf = SmoothDielectric(1.5).sample(jnp.array([0.0, 0.0, 1.0]), jnp.array([0.5, 0.0, 0.0]))
    >>> [round(float(x), 6) + 0.0 for x in wi], round(float(pdf), 2)
    ([0.0, 0.0, -1.0], 0.96)
    """

    eta: jnp.ndarray

    @property
    def transmits(self):
        return True

    def __init__(self, eta):
        check_range("SmoothDielectric", "eta", eta, 0.0, lo_open=True)
        self.eta = as_param(eta)

    @property
    def channels(self):
        return 1

    def energy_factor(self, wo, wi):
        return dielectric_energy_factor(wo, wi, self.eta)

    def delta_albedo(self, wo):
        ok = jnp.abs(wo[..., 2]) > COS_EPS
        return jnp.where(ok, 1.0, 0.0).astype(wo.dtype)[..., None]

    def sample(self, wo, u):
        check_directions("SmoothDielectric.sample", wo=wo)
        check_u("SmoothDielectric.sample", u, 3)
        shape = jnp.broadcast_shapes(wo.shape, u.shape[:-1] + (3,))
        wo = jnp.broadcast_to(wo, shape)
        F = fresnel_dielectric(wo[..., 2], self.eta)
        n = up_like(wo)
        wr = mirror(wo)
        wt, _ = refract(wo, n, self.eta)
        choose_r = u[..., 0] < F
        etap = jnp.where(wo[..., 2] > 0, self.eta, 1 / self.eta)
        wi = jnp.where(choose_r[..., None], wr, wt)
        weight = jnp.where(choose_r, 1.0, 1 / sq(etap))
        pdf = jnp.where(choose_r, F, 1 - F)
        ok = jnp.abs(wo[..., 2]) > COS_EPS
        return wi, jnp.where(ok, weight, 0)[..., None], jnp.where(ok, pdf, 0)
