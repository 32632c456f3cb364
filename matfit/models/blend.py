"""Blend: linear interpolation of two BSDFs."""

from __future__ import annotations

import jax.numpy as jnp

from .._math import safe_div
from ._base import AbstractBSDF
from ._pairs import SoAPairs
from ._params import as_param, check_channels, check_directions, check_range, check_u
from ..errors import ParameterError

__all__ = ["Blend"]


class Blend(AbstractBSDF):
    r"""Linear interpolation of two models, ``(1 - weight) a + weight b``:

    .. math:: f = (1 - w)\,f_a + w\,f_b,\qquad p = (1 - w)\,p_a + w\,p_b

    Sampling picks ``b`` with probability ``w`` (reusing the rescaled ``u[..., 0]`` for the
    chosen model's own lobe choice); the pdf is the exact mixture of the non-delta parts, and a
    delta lobe of either model keeps its discrete probability scaled by its selection
    probability.

    Parameters
    ----------
    a : AbstractBSDF; no mixed Dirac lobe; differentiable (its array leaves)
        The model at ``weight = 0``: free of Dirac lobes or a pure delta model (a smooth-coated
        Plastic or Layered is rejected).
    b : AbstractBSDF; no mixed Dirac lobe; differentiable (its array leaves)
        The model at ``weight = 1``, as ``a``; channel counts equal or 1.
    weight : array_like, scalar or (...); [0, 1]; differentiable
        The mixing weight ``w``.

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.models import Blend, Lambert, RoughConductor
    >>> a, b = Lambert(0.5), RoughConductor(0.2, 1.5, 3.0)
    >>> up = jnp.array([0.0, 0.0, 1.0])
    >>> bool(jnp.allclose(Blend(a, b, 0.25).eval(up, up), 0.75 * a.eval(up, up) + 0.25 * b.eval(up, up)))
    True
    """

    a: AbstractBSDF
    b: AbstractBSDF
    weight: jnp.ndarray

    def __init__(self, a, b, weight):
        for name, m in (("a", a), ("b", b)):
            if not isinstance(m, AbstractBSDF):
                raise ParameterError(f"Blend: {name} must be a matfit model, got {type(m).__name__}")
            if m.has_delta_lobe and not m.is_delta:
                raise ParameterError(
                    f"Blend: {name} ({type(m).__name__}) mixes a Dirac lobe with a continuous one, which Blend cannot "
                    "sample consistently; blend rough-coated models, or pure delta models (SmoothConductor, SmoothDielectric)"
                )
        check_range("Blend", "weight", weight, 0.0, 1.0)
        check_channels("Blend", a=a.channels, b=b.channels, weight=weight)
        self.a = a
        self.b = b
        self.weight = as_param(weight)

    @property
    def channels(self):
        return max(self.a.channels, self.b.channels)

    @property
    def has_delta_lobe(self):
        return self.a.has_delta_lobe or self.b.has_delta_lobe

    @property
    def transmits(self):
        return self.a.transmits or self.b.transmits

    @property
    def pair_kernels(self):
        """True when both parts have pair kernels."""
        return self.a.pair_kernels and self.b.pair_kernels

    def eval(self, wo, wi):
        check_directions("Blend.eval", wo=wo, wi=wi)
        if self.pair_kernels:  # both parts read the pairs derived once
            return self.eval_pairs(SoAPairs.of(wo, wi))
        return self.mix(self.a.eval(wo, wi), self.b.eval(wo, wi))

    def eval_pairs(self, pairs):
        return self.mix(self.a.eval_pairs(pairs), self.b.eval_pairs(pairs))

    def mix(self, fa, fb):
        """The blend ``(1 - weight) fa + weight fb`` of values ``(..., C)`` of ``a`` and ``b``."""
        w = self.weight[..., None]
        return (1 - w) * fa + w * fb

    def pdf(self, wo, wi):
        check_directions("Blend.pdf", wo=wo, wi=wi)
        return (1 - self.weight) * self.a.pdf(wo, wi) + self.weight * self.b.pdf(wo, wi)

    def energy_factor(self, wo, wi):
        # transmission in either part: the part that transmits (they agree on reflection)
        return jnp.maximum(self.a.energy_factor(wo, wi), self.b.energy_factor(wo, wi))

    def delta_albedo(self, wo):
        w = self.weight[..., None]
        return (1 - w) * self.a.delta_albedo(wo) + w * self.b.delta_albedo(wo)

    def sample(self, wo, u):
        check_directions("Blend.sample", wo=wo)
        check_u("Blend.sample", u, 3)
        w = self.weight
        choose_b = u[..., 0] < w
        u0 = jnp.where(choose_b, safe_div(u[..., 0], w), safe_div(u[..., 0] - w, 1 - w))
        u2 = jnp.concatenate([jnp.clip(u0, 0, 1 - 1e-7)[..., None], u[..., 1:3]], axis=-1)
        wi_a, wt_a, p_a = self.a.sample(wo, u2)
        wi_b, wt_b, p_b = self.b.sample(wo, u2)
        wi = jnp.where(choose_b[..., None], wi_b, wi_a)
        pdf = self.pdf(wo, wi)
        weight = safe_div(self.eval(wo, wi) * jnp.abs(wi[..., 2])[..., None], pdf[..., None])
        # A delta sample of the chosen part: its own weight, discrete pdf scaled by the choice.
        delta_a = self.a.is_delta
        delta_b = self.b.is_delta
        if delta_a or delta_b:
            is_d = jnp.where(choose_b, delta_b, delta_a)
            w_d = jnp.where(choose_b[..., None], wt_b, wt_a)
            p_d = jnp.where(choose_b, w * p_b, (1 - w) * p_a)
            weight = jnp.where(is_d[..., None], w_d, weight)
            pdf = jnp.where(is_d, p_d, pdf)
        ok = pdf > 0
        return wi, jnp.where(ok[..., None], weight, 0), jnp.where(ok, pdf, 0)
