"""Rough conductor: Cook-Torrance microfacet reflection with the exact conductor Fresnel."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp

from ..fresnel import fresnel_conductor
from ._base import AbstractConductor, AbstractPairBSDF
from ._microfacet import AbstractMicrofacetBSDF, with_options_doc
from ._params import as_channels, check_directions, check_u

__all__ = ["RoughConductor"]


@with_options_doc
class RoughConductor(AbstractMicrofacetBSDF, AbstractConductor, AbstractPairBSDF):
    r"""Rough metal: Cook-Torrance microfacet reflection with the complex-index Fresnel,

    .. math::
        f(\omega_o, \omega_i) = \frac{D(\omega_h)\,F(\omega_o\cdot\omega_h;\ \eta, k)\,
            G_2(\omega_o, \omega_i, \omega_h)}{4\cos\theta_o\cos\theta_i},\qquad
        \omega_h = \frac{\omega_o + \omega_i}{\lVert\omega_o + \omega_i\rVert}

    for :math:`\cos\theta_o, \cos\theta_i > 0` (``COS_EPS``), else 0. Sampling: visible normals
    of ``wo`` (GGX, Beckmann) or D cos (all), reflected about the sampled normal; pdf =
    pdf_m(h) / (4 wo.h). Samples that leave below the horizon are invalid (pdf 0).

    Parameters
    ----------
    alpha : array_like, scalar or (...); >= 0; differentiable
        Width of the microfacet distribution along x (both axes when isotropic): the GGX or
        Beckmann alpha, not a perceptual roughness; clamped to ``ALPHA_MIN`` = 1e-4 inside D.
    eta : array_like, scalar or (..., C); > 0; differentiable
        Real part of the conductor's complex index relative to the outside, per channel.
    k : array_like, scalar or (..., C); >= 0; differentiable
        Imaginary part (extinction coefficient), per channel.
    {microfacet options}

    References
    ----------
    - R. L. Cook, K. E. Torrance, "A Reflectance Model for Computer Graphics", ToG 1(1), 1982.
    - B. Walter et al., "Microfacet Models for Refraction through Rough Surfaces", EGSR 2007.
    - E. Heitz, "Understanding the Masking-Shadowing Function in Microfacet-Based BRDFs", JCGT 3(2), 2014.

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.models import RoughConductor
    >>> gold = RoughConductor(0.2, jnp.array([0.143, 0.374, 1.442]), jnp.array([3.983, 2.385, 1.603]))
    >>> wo = jnp.array([0.0, 0.6, 0.8]); wi = jnp.array([0.0, -0.6, 0.8])
    >>> gold.eval(wo, wi).shape
    (3,)
    """

    eta: jnp.ndarray = eqx.field(converter=as_channels)
    k: jnp.ndarray = eqx.field(converter=as_channels)

    def __init__(self, alpha, eta, k, distribution="ggx", masking="separable", alpha_y=None, sampling="visible"):
        self._init_microfacet("RoughConductor", alpha, alpha_y, distribution, masking, sampling)
        self._init_index("RoughConductor", eta, k)

    def eval_pairs(self, pairs):
        # D G2 / (4 cos cos) is one loop over the pairs; F, per channel, reads it and cos_d only
        spec = self.reflection_lobe(pairs)
        return spec[..., None] * fresnel_conductor(pairs.fresnel_angle().expand(), self.eta, self.k)

    def pdf(self, wo, wi):
        check_directions("RoughConductor.pdf", wo=wo, wi=wi)
        return self.reflection_pdf(wo, wi)

    def sample(self, wo, u):
        check_directions("RoughConductor.sample", wo=wo)
        check_u("RoughConductor.sample", u, 3)
        return self._weighted(wo, self.reflection_sample(wo, u[..., 1:3]))
