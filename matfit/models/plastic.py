"""Plastic: a Lambertian base under a smooth or rough dielectric coat."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp

from .._math import cosine_hemisphere, per_pair, safe_div
from ._base import AbstractPairBSDF
from ._coated import AbstractCoatedBSDF
from ._coat import coat_internal_reflectance, coat_reflection_pairs, coat_transmittance, is_smooth, make_coat
from ._params import as_channels, channel_count, check_directions, check_range, check_u
from ._pairs import SoAPairs
from .lambert import cosine_pdf

__all__ = ["Plastic"]


class Plastic(AbstractCoatedBSDF, AbstractPairBSDF):
    r"""Diffuse base under a dielectric clear coat (plastic, varnished wood):

    .. math:: f(\omega_o, \omega_i) = f_{coat}(\omega_o, \omega_i) + f_d(\omega_o, \omega_i)

    :math:`f_{coat}` is the coat's reflection lobe (a delta when smooth, :class:`RoughDielectric`'s
    reflection when rough). With :math:`T(\mu)` the coat's directional energy transmittance
    (``1 - F`` when smooth; see :mod:`matfit.models._coat`):

    - ``internal_reflection=False`` (the article's Fresnel-weighted sum):
      :math:`f_d = T(\mu_o)\,T(\mu_i)\,\rho/\pi`.
    - ``internal_reflection=True`` (light bouncing between base and coat, summed as a geometric
      series): :math:`f_d = \dfrac{T(\mu_o)\,T(\mu_i)\,\rho}{\pi\,\eta^2\,(1 - \rho\,R_{int})}`,
      :math:`R_{int} = 1 - \bar T/\eta^2` (the internal hemispherical Fresnel average for a
      smooth coat). A white base under a lossless smooth coat then reflects all the energy, and
      :math:`E(\mu) = F(\mu) + (1 - F(\mu))\,\rho\,(1 - \bar F_{int})/(1 - \rho\,\bar F_{int})`.

    Both forms are reciprocal. Sampling picks the coat lobe with probability
    :math:`R/(R + T\bar\rho)` (``R = 1 - T(mu_o)``), else the diffuse lobe (cosine-weighted);
    the pdf is the exact mixture. With a smooth coat the coat lobe is a delta: its sample has
    the discrete probability as pdf, and eval/pdf cover the diffuse part only.

    Parameters
    ----------
    albedo : array_like, scalar or (..., C); [0, 1]; differentiable
        Diffuse albedo :math:`\rho` of the base per colour channel (stored as the field
        ``reflectance``).
    alpha : array_like, scalar or (...), default 0.0; >= 0; differentiable when rough
        Width of the coat's microfacet distribution; a concrete 0 gives a smooth coat (a
        :class:`SmoothDielectric`, whose reflection is a Dirac lobe), anything else a
        :class:`RoughDielectric`. Stored in ``coat``.
    eta : array_like, scalar or (...), default 1.5; > 0; differentiable
        Index of the coat relative to the outside, typically 1.3-1.8. Stored in ``coat``.
    distribution : {"ggx", "beckmann", "blinn_phong"}, default "ggx"; static, not differentiable
        The coat's microfacet distribution (rough coat only).
    internal_reflection : bool, default True; static, not differentiable
        Sum the light bouncing between base and coat (a geometric series in :math:`\rho R_{int}`).
    masking : {"separable", "height_correlated"}, default "separable"; static, not differentiable
        Smith masking form of the rough coat.

    References
    ----------
    - A. Weidlich, A. Wilkie, "Arbitrarily Layered Micro-Facet Surfaces", GRAPHITE 2007.
    - W. Jakob, "Mitsuba 0.6 documentation: plastic / roughplastic", 2014 (internal scattering term).
    - Article in ``shared/seed`` (Fresnel-weighted sum of a coat lobe and a diffuse lobe).

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.models import Plastic
    >>> up = jnp.array([0.0, 0.0, 1.0])
    >>> round(float(Plastic(1.0).albedo(up)[0]), 3)  # a white base under a lossless smooth coat
    1.0
    """

    reflectance: jnp.ndarray = eqx.field(converter=as_channels)
    internal_reflection: bool = eqx.field(static=True)

    def __init__(self, albedo, alpha=0.0, eta=1.5, distribution="ggx", internal_reflection=True, masking="separable"):
        check_range("Plastic", "albedo", albedo, 0.0, 1.0)
        check_range("Plastic", "alpha", alpha, 0.0)
        check_range("Plastic", "eta", eta, 0.0, lo_open=True)
        self.reflectance = albedo
        self.coat = make_coat(alpha, eta, distribution, masking)
        self.internal_reflection = bool(internal_reflection)

    @property
    def channels(self):
        return channel_count(self.reflectance)

    @property
    def eta(self):
        """The coat's index relative to the outside."""
        return self.coat.eta

    def _channel_scale(self, table):
        # the per-channel factor of the diffuse lobe (no pair axis)
        k = self.reflectance / jnp.pi
        if self.internal_reflection:
            r_int = coat_internal_reflectance(self.coat, table)
            k = k / (self.coat.eta**2 * (1 - self.reflectance * r_int))
        return k

    def eval_pairs(self, pairs):
        return self._eval_p(pairs, self._table())

    def _eval_t(self, wo, wi, table):
        return self._eval_p(SoAPairs.of(wo, wi), table)

    def _eval_p(self, pairs, table):
        # the pairs' cosines are already mapped to the normal where a pair is invalid (double
        # where: finite gradients for directions a denormal above the horizon)
        # per-pair scalars (0 on invalid pairs), each computed whole in one loop (per_pair), then
        # one per-channel loop: f = To Ti k + R
        ok, cos_o, cos_i = pairs.valid, pairs.cos_o, pairs.cos_i
        To = coat_transmittance(self.coat, cos_o, table)
        Ti = coat_transmittance(self.coat, cos_i, table)
        f = per_pair(jnp.where(ok, To * Ti, 0))[..., None] * self._channel_scale(table)
        if not is_smooth(self.coat):
            f = f + per_pair(jnp.where(ok, coat_reflection_pairs(self.coat, pairs), 0))[..., None]
        return f

    def _p_coat(self, wo, table):
        R = 1 - coat_transmittance(self.coat, wo[..., 2], table)
        rho = jnp.mean(self.reflectance, axis=-1)
        return safe_div(R, R + (1 - R) * rho, 0.5)

    def pdf(self, wo, wi):
        check_directions("Plastic.pdf", wo=wo, wi=wi)
        return self._pdf_t(wo, wi, self._table())

    def _pdf_t(self, wo, wi, table):
        pc = self._p_coat(wo, table)
        p_d = cosine_pdf(wo, wi)
        p_c = 0.0 if is_smooth(self.coat) else self.coat.reflection_pdf(wo, wi)
        return pc * p_c + (1 - pc) * p_d

    def _sample_under(self, wo, u, pc):
        return cosine_hemisphere(u[..., 1], u[..., 2]), True

    def sample(self, wo, u):
        check_directions("Plastic.sample", wo=wo)
        check_u("Plastic.sample", u, 3)
        return self._sample_coated(wo, u)
