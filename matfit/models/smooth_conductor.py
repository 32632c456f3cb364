"""Smooth conductor: a perfect mirror weighted by the exact conductor Fresnel (delta model)."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp

from .._math import COS_EPS, mirror
from ..fresnel import fresnel_conductor
from ._base import AbstractConductor, AbstractDeltaBSDF
from ._params import as_channels, check_directions, check_u

__all__ = ["SmoothConductor"]


class SmoothConductor(AbstractDeltaBSDF, AbstractConductor):
    r"""Perfect mirror with conductor Fresnel: the :math:`\alpha \to 0` limit of
    :class:`RoughConductor`. ``eval`` and ``pdf`` are zero (a Dirac lobe has no density);
    ``sample`` returns the mirror direction :math:`(-\omega_{o,x}, -\omega_{o,y}, \omega_{o,z})`,
    weight :math:`F(\cos\theta_o;\eta,k)` and pdf 1 (the discrete probability of the only lobe).

    Parameters
    ----------
    eta : array_like, scalar or (..., C); > 0; differentiable
        Real part of the conductor's complex index relative to the outside, per channel.
    k : array_like, scalar or (..., C); >= 0; differentiable
        Imaginary part (extinction coefficient), per channel.

    References
    ----------
    - M. Pharr, W. Jakob, G. Humphreys, *Physically Based Rendering*, 4th ed., Sec. 9.3.

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.models import SmoothConductor
    >>> wi, weight, pdf = SmoothConductor(0.2, 3.9).sample(jnp.array([0.6, 0.0, 0.8]), jnp.zeros(3))
    >>> [round(float(x), 6) + 0.0 for x in wi]
    [-0.6, 0.0, 0.8]
    """

    eta: jnp.ndarray = eqx.field(converter=as_channels)
    k: jnp.ndarray = eqx.field(converter=as_channels)

    def __init__(self, eta, k):
        self._init_index("SmoothConductor", eta, k)

    def delta_albedo(self, wo):
        ok = wo[..., 2] > COS_EPS
        return jnp.where(ok[..., None], fresnel_conductor(wo[..., 2:3], self.eta, self.k), 0)

    def sample(self, wo, u):
        check_directions("SmoothConductor.sample", wo=wo)
        check_u("SmoothConductor.sample", u, 3)
        shape = jnp.broadcast_shapes(wo.shape, u.shape[:-1] + (3,))
        wo = jnp.broadcast_to(wo, shape)
        wi = mirror(wo)
        ok = wo[..., 2] > COS_EPS
        return wi, self.delta_albedo(wo), jnp.where(ok, 1.0, 0.0).astype(wo.dtype)
