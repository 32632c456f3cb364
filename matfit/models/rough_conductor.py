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

from .._math import COS_EPS, dot, normalize, safe_div, where_up
from ..fresnel import FresnelAngle, fresnel_conductor
from ._microfacet import AbstractMicrofacetBSDF
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

    @staticmethod
    def valid_pair(wo, wi):
        """Where the lobe is defined: ``wo`` and ``wi`` above the surface (``cos > COS_EPS``)."""
        return (wo[..., 2] > COS_EPS) & (wi[..., 2] > COS_EPS)

    def eval(self, wo, wi):
        check_directions("RoughConductor.eval", wo=wo, wi=wi)
        h = normalize(wo + wi)
        return self.eval_half(wo, wi, h, dot(wo, h))

    def eval_half(self, wo, wi, h, cos_d, ok=None):
        """:meth:`eval` with the half vector ``h = normalize(wo + wi)`` and ``cos_d = wo . h`` given.

        Both depend only on the directions: :mod:`matfit.fast` computes them once for many
        evaluations. ``wo, wi, h`` may be ``(..., 3)`` arrays or :class:`matfit._math.Vec3`;
        ``cos_d`` an array or its :class:`~matfit.fresnel.FresnelAngle` terms. ``ok``, when
        given, is :meth:`valid_pair` of the directions, which the caller has already mapped to
        the normal where it is False (:meth:`matfit.fast.SoAPairs.isotropic`).
        """
        d = self.dist()
        guarded = ok is not None
        if not guarded:
            ok = self.valid_pair(wo, wi)
            # double where: invalid pairs (at or below the horizon) are evaluated at the normal
            wo, wi, h = where_up(ok, wo), where_up(ok, wi), where_up(ok, h)
        # D G2 as one quotient, 0 on invalid pairs through its denominator (inf there): XLA
        # computes it in one loop of its own (a guard outside a division would be recomputed in
        # every loop that reads it), and F is guarded by spec alone, so a kernel per channel
        # reads only spec and cos_d, not the directions again (matfit.fast). 1 / (4 cos cos)
        # stays a factor of its own: inside the quotient, float32 gradients overflow near
        # grazing at alpha = ALPHA_MIN (den^-2 < 1e-38).
        num, den, visible = d.reflection_ratio(wo, wi, h, self.masking)
        # Both directions above the surface make their half vector visible from each (wo . h =
        # |wo + wi| / 2 > 0): a caller's own ok needs no check of it repeated per parameter.
        dg = num / jnp.where(ok if guarded else ok & visible, den, jnp.inf)
        spec = dg / jnp.where(ok, 4 * wo[..., 2] * wi[..., 2], jnp.inf)
        if isinstance(cos_d, FresnelAngle):  # precomputed, finite and in range by construction
            F = fresnel_conductor(cos_d.expand(), self.eta, self.k)
        else:
            F = fresnel_conductor(jnp.where(spec > 0, cos_d, 1)[..., None], self.eta, self.k)
        return spec[..., None] * F

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
