"""Shared parts of the rough (microfacet) models: the distribution and its sampling."""

from __future__ import annotations

from typing import Optional

import equinox as eqx
import jax.numpy as jnp

from .._math import dot, normalize, reflect, safe_div
from ..microfacet import DISTRIBUTIONS, MASKING_FORMS, make_distribution
from ._base import AbstractBSDF
from ._pairs import valid_reflection
from ._params import as_param, check_choice, check_range

SAMPLING = ("visible", "dcos")

#: The ``Parameters`` entries of the options that :meth:`AbstractMicrofacetBSDF._init_microfacet`
#: checks and sets, written once for the models that take them all (:func:`with_options_doc`).
OPTIONS_DOC = '''    distribution : {"ggx", "beckmann", "blinn_phong"}, default "ggx"; static, not differentiable
        The microfacet distribution (:mod:`matfit.microfacet`); Blinn-Phong needs alpha <= 1.
    masking : {"separable", "height_correlated"}, default "separable"; static, not differentiable
        Smith masking form (:meth:`~matfit.microfacet.AbstractDistribution.G2`).
    alpha_y : array_like or None, scalar or (...), default None; >= 0 or None; differentiable
        Width along y for an anisotropic lobe; None ties it to ``alpha`` (isotropic).
    sampling : {"visible", "dcos"}, default "visible"; static, not differentiable
        Normals sampled from the normals visible from ``wo``, or from D cos; "visible" becomes
        "dcos" for Blinn-Phong, which has no visible-normal sampler.
'''


def with_options_doc(cls):
    """Class decorator: the line ``{microfacet options}`` of ``cls``'s docstring becomes :data:`OPTIONS_DOC`."""
    if cls.__doc__ is not None:  # None under python -OO
        if "    {microfacet options}\n" not in cls.__doc__:
            raise ValueError(f"{cls.__name__}: its docstring has no line '{{microfacet options}}'")
        cls.__doc__ = cls.__doc__.replace("    {microfacet options}\n", OPTIONS_DOC)
    return cls


class AbstractMicrofacetBSDF(AbstractBSDF):
    """A model built on one microfacet distribution: the distribution's fields, its reflection
    lobe on prepared pairs, and the sampling of its normals.

    The reflection lobe is sampled as ``wi = reflect(wo, m)`` with ``m`` drawn as :attr:`sampling`
    says; its density is ``pdf_m(h) / (4 wo.h)``, 0 below the horizon (an invalid sample).

    Attributes
    ----------
    alpha : jax.Array
        Distribution width along x (both axes when isotropic), >= 0; differentiable.
    alpha_y : jax.Array or None
        Width along y for anisotropy, or None (isotropic: tied to ``alpha``); differentiable.
    distribution : {"ggx", "beckmann", "blinn_phong"}
        The microfacet distribution (static).
    masking : {"separable", "height_correlated"}
        Smith masking form (static).
    sampling : {"visible", "dcos"}
        Normals from the visible normals of ``wo`` (GGX and Beckmann) or from D cos (static).

    Examples
    --------
    >>> from matfit.models import AbstractMicrofacetBSDF, RoughConductor
    >>> m = RoughConductor(0.3, 1.5, 3.0, distribution="blinn_phong")
    >>> isinstance(m, AbstractMicrofacetBSDF), m.sampling, type(m.dist()).__name__  # Blinn-Phong samples D cos
    (True, 'dcos', 'BlinnPhong')
    """

    alpha: jnp.ndarray
    alpha_y: Optional[jnp.ndarray]
    distribution: str = eqx.field(static=True)
    masking: str = eqx.field(static=True)
    sampling: str = eqx.field(static=True)

    def _init_microfacet(self, owner, alpha, alpha_y, distribution, masking, sampling):
        check_choice(owner, "distribution", distribution, tuple(DISTRIBUTIONS))
        check_choice(owner, "masking", masking, MASKING_FORMS)
        check_choice(owner, "sampling", sampling, SAMPLING)
        check_range(owner, "alpha", alpha, 0.0)
        check_range(owner, "alpha_y", alpha_y, 0.0)
        if distribution == "blinn_phong":
            # e = 2/alpha^2 - 2 < 0 beyond alpha = 1, where Beckmann's Lambda no longer matches.
            check_range(owner, "alpha (blinn_phong)", alpha, 0.0, 1.0)
            check_range(owner, "alpha_y (blinn_phong)", alpha_y, 0.0, 1.0)
        self.alpha = as_param(alpha)
        self.alpha_y = None if alpha_y is None else as_param(alpha_y)
        self.distribution = distribution
        self.masking = masking
        # Blinn-Phong has no visible-normal sampler: it always samples D cos.
        if sampling == "visible" and not DISTRIBUTIONS[distribution].has_visible_sampling:
            sampling = "dcos"
        self.sampling = sampling

    def dist(self):
        """The microfacet distribution of kind :attr:`distribution`, widths ``(alpha, alpha_y)``."""
        return make_distribution(self.distribution, self.alpha, self.alpha_y)

    def _sample_m(self, d, wo, u2):
        if self.sampling == "visible":
            return d.sample_visible(wo, u2)
        return d.sample_dcos(u2)

    def _pdf_m(self, d, wo, m):
        if self.sampling == "visible":
            return d.pdf_visible(wo, m)
        return d.pdf_dcos(m)

    def reflection_sample(self, wo, u2):
        """Sample the reflection lobe from uniform ``u2`` ``(..., 2)``: ``wi = reflect(wo, m)``."""
        return reflect(wo, self._sample_m(self.dist(), wo, u2))

    def reflection_pdf(self, wo, wi):
        """Density of :meth:`reflection_sample`: ``pdf_m(h) / (4 wo.h)`` (0 below the horizon)."""
        ok = valid_reflection(wo, wi)
        h = normalize(wo + wi)
        p = safe_div(self._pdf_m(self.dist(), wo, h), 4 * dot(wo, h))
        return jnp.where(ok, p, 0)

    def reflection_lobe(self, pairs):
        """``D G2 / (4 cos theta_o cos theta_i)`` of prepared pairs, ``(...)``, 0 where a pair is
        invalid: the Fresnel-free part of a reflection lobe."""
        # An isotropic lobe reads only cosines and h's squared sine, already guarded per pair.
        # D G2 is one quotient, 0 on invalid pairs through its denominator (inf there): XLA
        # computes it in one loop of its own (a guard outside a division would be recomputed in
        # every loop that reads it), so that the per-channel work of a lobe (its Fresnel factor)
        # reads only this and the Fresnel cosine. 1 / (4 cos cos) stays a factor of its own:
        # inside the quotient, float32 gradients overflow near grazing at alpha = ALPHA_MIN.
        if self.alpha_y is None:
            wo, wi, h, ok = pairs.isotropic()
            num, den, _ = self.dist().reflection_ratio(wo, wi, h, self.masking)
            keep = ok  # both directions above the surface make their half vector visible from each
        else:
            ok = pairs.valid
            wo, wi, h = pairs.wo.where_up(ok), pairs.wi.where_up(ok), pairs.h.where_up(ok)
            num, den, visible = self.dist().reflection_ratio(wo, wi, h, self.masking)
            keep = ok & visible
        dg = num / jnp.where(keep, den, jnp.inf)
        return dg / jnp.where(ok, 4 * wo[..., 2] * wi[..., 2], jnp.inf)
