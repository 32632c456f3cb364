"""The machinery shared by the coated models (:class:`Plastic`, :class:`Layered`): the coat's
transmittance table, its delta lobe when smooth, and the two-lobe sample."""

from __future__ import annotations

import abc

import jax.numpy as jnp

from .._math import COS_EPS, mirror, safe_div
from ..fresnel import fresnel_dielectric
from ._base import AbstractBSDF
from ._coat import coat_transmittance_table, is_smooth


class AbstractCoatedBSDF(AbstractBSDF):
    """A model with a dielectric ``coat`` (a :class:`SmoothDielectric` or :class:`RoughDielectric`,
    seen from outside) on top: the coat lobe plus a lobe under it.

    Subclasses give ``_eval_t``/``_pdf_t`` (eval and pdf with the coat's transmittance table
    passed in, so that one sample builds it once), ``_p_coat`` (probability of sampling the coat
    lobe) and ``_sample_under`` (a direction from the lobe under the coat).
    """

    coat: AbstractBSDF

    @property
    def has_delta_lobe(self):
        """True for a smooth coat, whose reflection is a Dirac lobe."""
        return is_smooth(self.coat)

    def _table(self):
        return None if is_smooth(self.coat) else coat_transmittance_table(self.coat)

    @abc.abstractmethod
    def _eval_t(self, wo, wi, table):
        ...

    @abc.abstractmethod
    def _pdf_t(self, wo, wi, table):
        ...

    @abc.abstractmethod
    def _p_coat(self, wo, table):
        ...

    @abc.abstractmethod
    def _sample_under(self, wo, u, pc):
        """``(wi, ok)``: a direction from the lobe under the coat and whether it is usable."""

    def delta_albedo(self, wo):
        if not is_smooth(self.coat):
            return super().delta_albedo(wo)
        ok = wo[..., 2] > COS_EPS
        F = jnp.where(ok, fresnel_dielectric(wo[..., 2], self.coat.eta), 0)
        return jnp.broadcast_to(F[..., None], wo.shape[:-1] + (self.channels,))

    def _sample_coated(self, wo, u):
        table = self._table()
        pc = self._p_coat(wo, table)
        choose_c = u[..., 0] < pc
        wi_u, ok_u = self._sample_under(wo, u, pc)
        if is_smooth(self.coat):
            wi_c = mirror(wo)
        else:
            wi_c = self.coat.reflection_sample(wo, u[..., 1:3])
        wi = jnp.where(choose_c[..., None], wi_c, wi_u)
        pdf = self._pdf_t(wo, wi, table)
        weight = safe_div(self._eval_t(wo, wi, table) * jnp.abs(wi[..., 2])[..., None], pdf[..., None])
        ok = (pdf > 0) & (wi[..., 2] > COS_EPS) & jnp.where(choose_c, True, ok_u)
        if is_smooth(self.coat):
            # The delta lobe: weight F / P(coat), pdf = the discrete probability P(coat).
            F = fresnel_dielectric(wo[..., 2], self.coat.eta)
            w_delta = jnp.broadcast_to(safe_div(F, pc)[..., None], weight.shape)
            ok_c = (wo[..., 2] > COS_EPS) & (pc > 0)
            weight = jnp.where(choose_c[..., None], w_delta, weight)
            pdf = jnp.where(choose_c, pc, pdf)
            ok = jnp.where(choose_c, ok_c, ok)
        return wi, jnp.where(ok[..., None], weight, 0), jnp.where(ok, pdf, 0)
