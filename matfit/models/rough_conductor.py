r"""Rough conductor: Cook-Torrance microfacet reflection with the exact conductor Fresnel.

.. math::
    f(\omega_o, \omega_i) = \frac{D(\omega_h)\,F(\omega_o\cdot\omega_h;\ \eta, k)\,
        G_2(\omega_o, \omega_i, \omega_h)}{4\cos\theta_o\cos\theta_i},\qquad
    \omega_h = \frac{\omega_o + \omega_i}{\lVert\omega_o + \omega_i\rVert}

for :math:`\cos\theta_o, \cos\theta_i > 0` (``COS_EPS``), else 0.

Parameters
----------
alpha : float or array, >= 0 (clamped to ``ALPHA_MIN`` = 1e-4 inside D), differentiable.
alpha_y : optional, anisotropic width along y, differentiable.
eta, k : (..., C) real and imaginary parts of the conductor's relative complex index,
    eta > 0, k >= 0, differentiable.
distribution : "ggx" | "beckmann" | "blinn_phong";  masking : "separable" | "height_correlated".

Sampling: visible normals of ``wo`` (GGX, Beckmann) or D cos (all), reflected about the sampled
normal; pdf = pdf_m(h) / (4 wo.h). Samples that leave below the horizon are invalid (pdf 0).

References
----------
- R. L. Cook, K. E. Torrance, "A Reflectance Model for Computer Graphics", ToG 1(1), 1982.
- B. Walter et al., "Microfacet Models for Refraction through Rough Surfaces", EGSR 2007.
- E. Heitz, "Understanding the Masking-Shadowing Function in Microfacet-Based BRDFs", JCGT 3(2), 2014.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp

from .._math import safe_div
from ..fresnel import fresnel_conductor
from ._microfacet import AbstractMicrofacetBSDF
from ._pairs import SoAPairs, valid_reflection
from ._params import as_channels, check_channels, check_directions, check_range, check_u


class RoughConductor(AbstractMicrofacetBSDF):
    """Rough metal: D F G / (4 cos cos) with the complex-index Fresnel.

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
        check_range("RoughConductor", "eta", eta, 0.0, lo_open=True)
        check_range("RoughConductor", "k", k, 0.0)
        check_channels("RoughConductor", eta=eta, k=k)
        self.eta = eta
        self.k = k

    @property
    def channels(self):
        return jnp.broadcast_shapes(self.eta.shape, self.k.shape)[-1]

    pair_kernels = True

    @staticmethod
    def valid_pair(wo, wi):
        """Where the lobe is defined: ``wo`` and ``wi`` above the surface (``cos > COS_EPS``)."""
        return valid_reflection(wo, wi)

    def eval(self, wo, wi):
        check_directions("RoughConductor.eval", wo=wo, wi=wi)
        return self.eval_pairs(SoAPairs.of(wo, wi))

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
        wi = self.reflection_sample(wo, u[..., 1:3])
        pdf = self.pdf(wo, wi)
        ok = pdf > 0
        weight = safe_div(self.eval(wo, wi) * jnp.abs(wi[..., 2])[..., None], pdf[..., None])
        return wi, jnp.where(ok[..., None], weight, 0), jnp.where(ok, pdf, 0)
