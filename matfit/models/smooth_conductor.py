r"""Smooth conductor: a perfect mirror weighted by the exact conductor Fresnel (delta model).

The :math:`\alpha \to 0` limit of :class:`RoughConductor`. ``eval`` and ``pdf`` are zero (a Dirac
lobe has no density); ``sample`` returns the mirror direction
:math:`(-\omega_{o,x}, -\omega_{o,y}, \omega_{o,z})`, weight :math:`F(\cos\theta_o;\eta,k)` and
pdf 1 (the discrete probability of the only lobe).

Parameters
----------
eta, k : (..., C) relative complex index, eta > 0, k >= 0, differentiable.

References
----------
- M. Pharr, W. Jakob, G. Humphreys, *Physically Based Rendering*, 4th ed., Sec. 9.3.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp

from .._math import COS_EPS
from ..fresnel import fresnel_conductor
from ._base import AbstractBSDF
from ._params import as_channels, check_channels, check_directions, check_range, check_u


class SmoothConductor(AbstractBSDF):
    """Perfect mirror with conductor Fresnel.

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.models import SmoothConductor
    >>> wi, weight, pdf = SmoothConductor(0.2, 3.9).sample(jnp.array([0.6, 0.0, 0.8]), jnp.zeros(3))
    >>> [round(float(x), 6) + 0.0 for x in wi]
    [-0.6, 0.0, 0.8]
    """

    is_delta = True
    eta: jnp.ndarray = eqx.field(converter=as_channels)
    k: jnp.ndarray = eqx.field(converter=as_channels)

    def __init__(self, eta, k):
        check_range("SmoothConductor", "eta", eta, 0.0, lo_open=True)
        check_range("SmoothConductor", "k", k, 0.0)
        check_channels("SmoothConductor", eta=eta, k=k)
        self.eta = eta
        self.k = k

    @property
    def channels(self):
        return jnp.broadcast_shapes(self.eta.shape, self.k.shape)[-1]

    def eval(self, wo, wi):
        check_directions("SmoothConductor.eval", wo=wo, wi=wi)
        shape = jnp.broadcast_shapes(wo.shape, wi.shape)[:-1] + (self.channels,)
        return jnp.zeros(shape, jnp.result_type(wo, self.eta))

    def pdf(self, wo, wi):
        check_directions("SmoothConductor.pdf", wo=wo, wi=wi)
        return jnp.zeros(jnp.broadcast_shapes(wo.shape, wi.shape)[:-1], jnp.result_type(wo))

    def delta_albedo(self, wo):
        ok = wo[..., 2] > COS_EPS
        return jnp.where(ok[..., None], fresnel_conductor(wo[..., 2:3], self.eta, self.k), 0)

    def sample(self, wo, u):
        check_directions("SmoothConductor.sample", wo=wo)
        check_u("SmoothConductor.sample", u, 3)
        shape = jnp.broadcast_shapes(wo.shape, u.shape[:-1] + (3,))
        wo = jnp.broadcast_to(wo, shape)
        wi = wo * jnp.array([-1, -1, 1], wo.dtype)
        ok = wo[..., 2] > COS_EPS
        return wi, self.delta_albedo(wo), jnp.where(ok, 1.0, 0.0).astype(wo.dtype)
