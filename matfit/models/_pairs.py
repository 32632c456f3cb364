"""Direction pairs prepared once: what a model's ``eval`` derives from ``(wo, wi)`` before it
reads any parameter (components, half vector, Fresnel cosine, validity, cosines).

The ``eval`` of a model with :attr:`~matfit.models.AbstractBSDF.pair_kernels` is
``eval_pairs(SoAPairs.of(wo, wi))``, the pairs derived in the same compiled program; a fit keeps
them as a cache of the table (:mod:`matfit.fast`), so that only the parameter-dependent
arithmetic runs in its loop. :class:`SoAPairs` is the whole interface of that path: no other
model method takes an argument of the fast path.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

from .._math import COS_EPS, IsoDir, Vec3, dot, normalize
from ..fresnel import FresnelAngle, clamp_cos

__all__ = ["SoAPairs", "half_vector", "valid_reflection"]


def valid_reflection(wo, wi):
    """Where a reflection lobe is defined: ``wo`` and ``wi`` above the surface (``cos > COS_EPS``).

    Parameters
    ----------
    wo, wi : array_like (..., 3), or Vec3
        Directions; only their cosines ``w[..., 2]`` are read.

    Returns
    -------
    jax.Array of bool, shape (...)
    """
    return (wo[..., 2] > COS_EPS) & (wi[..., 2] > COS_EPS)


@jax.jit
def half_vector(wo, wi):
    """The reflection half vector and the cosine that the Fresnel term of a reflection lobe reads.

    Parameters
    ----------
    wo, wi : array_like (..., 3), or Vec3
        Unit directions.

    Returns
    -------
    h : jax.Array (..., 3), or Vec3
        ``normalize(wo + wi)`` (the normal where ``wo + wi`` vanishes), of the form of ``wo``.
    cos_d : jax.Array (...)
        ``wo . h``.
    """
    h = normalize(wo + wi)
    return h, dot(wo, h)


_clamp_cos = jax.jit(clamp_cos)


@jax.jit
def _iso_terms(wo, wi, h):
    ok = valid_reflection(wo, wi)
    # wo and wi keep only their cosines (1 where invalid; isotropic() rebuilds their sines,
    # cheaper than reading them for a million pairs); h keeps its exact squared sine
    h = IsoDir(h.z, h.tan_sq()).where_up(ok)
    return ok, jnp.where(ok, wo.z, 1), jnp.where(ok, wi.z, 1), h.z, h.t2


class SoAPairs(eqx.Module):
    """Direction pairs as structures of arrays, with their direction-only quantities.

    Attributes
    ----------
    wo, wi : Vec3
        Components of shape ``(...)`` each (``(n_padded,)`` for a table laid out by
        :func:`matfit.fast.soa_pairs`, sharded along the batch).
    h : Vec3
        Reflection half vector ``normalize(wo + wi)``.
    cos_d : jax.Array
        :func:`~matfit.fresnel.clamp_cos` of ``wo . h``, the Fresnel cosine of a reflection lobe
        (clamped once per pair, not once per channel and parameter value).
    iso : tuple of jax.Array
        The pairs' validity (:func:`valid_reflection`), the cosines of ``wo``, ``wi``, ``h`` and
        ``h``'s squared sine ``h_x^2 + h_y^2`` (from its components: ``1 - h_z^2`` would lose it
        to rounding near the normal, where ``D`` divides it by ``alpha^2``), invalid pairs mapped
        to the normal; read through :attr:`valid`, :attr:`cos_o`, :attr:`cos_i`, :meth:`isotropic`.
    n : int or None
        Number of valid pairs (the first ``n``) of a padded table; None for pairs of any shape
        (:meth:`of`). Static.

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.fast import SoAPairs
    >>> p = SoAPairs.of(jnp.array([[0.0, 0.6, 0.8]]), jnp.array([[0.0, -0.6, 0.8]]))
    >>> float(p.h.z[0]), round(float(p.cos_d[0]), 6), round(float(p.fresnel_angle().sin2[0]), 6)
    (1.0, 0.8, 0.36)
    """

    wo: Vec3
    wi: Vec3
    h: Vec3
    cos_d: jax.Array
    iso: tuple
    n: int | None = eqx.field(static=True, default=None)

    @classmethod
    def from_directions(cls, wo: Vec3, wi: Vec3, n=None) -> "SoAPairs":
        """The pairs of component directions ``wo``, ``wi`` (``n``: valid pairs of a padded table)."""
        h, cos_d = half_vector(wo, wi)
        return cls(wo, wi, h, _clamp_cos(cos_d), _iso_terms(wo, wi, h), None if n is None else int(n))

    @classmethod
    def of(cls, wo, wi) -> "SoAPairs":
        """The pairs of ``(..., 3)`` direction arrays (broadcast against each other)."""
        return cls.from_directions(Vec3.from_array(jnp.asarray(wo)), Vec3.from_array(jnp.asarray(wi)))

    @property
    def n_padded(self):
        """Length of the batch axis of a table laid out by :func:`matfit.fast.soa_pairs` (padding included)."""
        return int(self.wo.x.shape[0])

    @property
    def shape(self):
        """Shape ``(..., 3)`` of the equivalent direction arrays."""
        return self.iso[0].shape + (3,)

    @property
    def valid(self):
        """Where a pair is a valid reflection pair (:func:`valid_reflection`), shape ``(...)``."""
        return self.iso[0]

    @property
    def cos_o(self):
        """The cosine of ``wo``, 1 where the pair is invalid (guarded for the double where)."""
        return self.iso[1]

    @property
    def cos_i(self):
        """The cosine of ``wi``, 1 where the pair is invalid."""
        return self.iso[2]

    def isotropic(self):
        """``(wo, wi, h, ok)``: the directions as :class:`~matfit._math.IsoDir` (cosines and ``h``'s
        squared sine, what an isotropic lobe reads), mapped to the normal where ``ok`` (the
        pairs' validity) is False."""
        ok, oz, iz, hz, ht2 = self.iso
        return IsoDir.from_cos(oz), IsoDir.from_cos(iz), IsoDir(hz, ht2), ok

    def fresnel_angle(self):
        """The :class:`~matfit.fresnel.FresnelAngle` of :attr:`cos_d`."""
        return FresnelAngle.of_clamped(self.cos_d)
