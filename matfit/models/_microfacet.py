"""Shared parts of the rough (microfacet) models: the distribution and its sampling."""

from __future__ import annotations

from typing import Optional

import equinox as eqx
import jax.numpy as jnp

from .._math import COS_EPS, dot, normalize, reflect, safe_div
from ..microfacet import DISTRIBUTIONS, MASKING_FORMS, make_distribution
from ._base import AbstractBSDF
from ._params import as_param, check_choice, check_range

SAMPLING = ("visible", "dcos")


class AbstractMicrofacetBSDF(AbstractBSDF):
    """A model built on one microfacet distribution.

    Attributes
    ----------
    alpha : distribution width (x, or both when isotropic), >= 0, differentiable.
    alpha_y : width along y for anisotropy, or ``None`` (isotropic: tied to ``alpha``).
    distribution : "ggx", "beckmann" or "blinn_phong" (static).
    masking : "separable" (Smith product) or "height_correlated" (static).
    sampling : "visible" (visible normals; GGX and Beckmann) or "dcos" (D cos) (static).
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
        """The microfacet distribution object at the current parameters."""
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
        """Sample the microfacet reflection lobe: ``wi = reflect(wo, m)`` with ``m`` sampled."""
        return reflect(wo, self._sample_m(self.dist(), wo, u2))

    def reflection_pdf(self, wo, wi):
        """Density of :meth:`reflection_sample`: ``pdf_m(h) / (4 wo.h)`` (0 below the horizon)."""
        ok = (wo[..., 2] > COS_EPS) & (wi[..., 2] > COS_EPS)
        h = normalize(wo + wi)
        p = safe_div(self._pdf_m(self.dist(), wo, h), 4 * dot(wo, h))
        return jnp.where(ok, p, 0)
