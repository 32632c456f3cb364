"""Shared parts of the rough (microfacet) models: the distribution and its sampling."""

from __future__ import annotations

from typing import Optional

import equinox as eqx
import jax.numpy as jnp

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

