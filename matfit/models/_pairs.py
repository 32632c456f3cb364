"""Direction pairs prepared once: the quantities a model's ``eval`` derives from ``(wo, wi)``
before it reads any parameter (components, half vector, Fresnel cosine, validity, cosines).

:meth:`AbstractBSDF.eval` of the models with pair kernels is ``eval_pairs(SoAPairs.of(wo, wi))``:
the pairs are derived inside the same compiled program as the model's arithmetic. A fit, which
evaluates the same directions many times, keeps them as a cache of the table
(:mod:`matfit.fast`), so that only the parameter-dependent arithmetic runs in its loop.

:class:`SoAPairs` is the whole interface of that path: a model with
:attr:`~matfit.models.AbstractBSDF.pair_kernels` overrides
:meth:`~matfit.models.AbstractBSDF.eval_pairs` and reads what it needs of the pairs (their
components, half vector, Fresnel angle, validity and guarded cosines, or their
:meth:`~SoAPairs.isotropic` form); no other model method takes an argument of the fast path.
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
    wo, wi : array_like, shape (..., 3), or Vec3
        Directions; only their cosines ``w[..., 2]`` are read.

    Returns
    -------
    jax.Array of bool, shape (...)

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.models import valid_reflection
    >>> up = jnp.array([0.0, 0.0, 1.0])
    >>> bool(valid_reflection(up, up)), bool(valid_reflection(up, -up))
    (True, False)
    """
    return (wo[..., 2] > COS_EPS) & (wi[..., 2] > COS_EPS)


@jax.jit
def half_vector(wo, wi):
    """The reflection half vector and the cosine that the Fresnel term of a reflection lobe reads.

    Parameters
    ----------
    wo, wi : array_like, shape (..., 3), or Vec3
        Unit directions.

    Returns
    -------
    h : jax.Array, shape (..., 3), or Vec3
        ``normalize(wo + wi)`` (the normal where ``wo + wi`` vanishes), of the form of ``wo``.
    cos_d : jax.Array, shape (...)
        ``wo . h``.

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.fast import half_vector
    >>> h, cos_d = half_vector(jnp.array([0.6, 0.0, 0.8]), jnp.array([-0.6, 0.0, 0.8]))
    >>> h.tolist(), round(float(cos_d), 6)
    ([0.0, 0.0, 1.0], 0.8)
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
        ``wo . h``, the cosine that the Fresnel term of a reflection lobe takes, as
        :func:`~matfit.fresnel.clamp_cos` of it (once per pair instead of once per channel and
        parameter value); :meth:`fresnel_angle` gives its :class:`~matfit.fresnel.FresnelAngle`.
    iso : tuple of jax.Array
        What :meth:`isotropic` hands an isotropic lobe: the pairs' validity
        (:func:`valid_reflection`), the cosines of ``wo``, ``wi``, ``h`` and ``h``'s squared sine
        ``h_x^2 + h_y^2`` (from its components: ``1 - h_z^2`` would lose it to rounding near the
        normal, where ``D`` divides it by ``alpha^2``), with invalid pairs mapped to the normal.
        A model reads them through :attr:`valid`, :attr:`cos_o`, :attr:`cos_i` and
        :meth:`isotropic`.
    n : int or None
        Number of valid pairs (the first ``n`` entries) of a padded table; None for pairs of
        any shape (:meth:`of`). Static.

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.fast import SoAPairs
    >>> p = SoAPairs.of(jnp.array([[0.0, 0.6, 0.8]]), jnp.array([[0.0, -0.6, 0.8]]))
    >>> float(p.h.z[0]), round(float(p.cos_d[0]), 6)
    (1.0, 0.8)
    """

    wo: Vec3
    wi: Vec3
    h: Vec3
    cos_d: jax.Array
    iso: tuple
    n: int | None = eqx.field(static=True, default=None)

    @classmethod
    def from_directions(cls, wo: Vec3, wi: Vec3, n=None) -> "SoAPairs":
        """The pairs of component directions ``wo``, ``wi``, with their direction-only
        quantities computed once.

        Parameters
        ----------
        wo, wi : Vec3
            Unit directions, components of one shape ``(...)``.
        n : int, optional
            Number of valid pairs of a padded table (:func:`matfit.fast.soa_pairs`).

        Returns
        -------
        SoAPairs

        Examples
        --------
        >>> import jax.numpy as jnp
        >>> from matfit._math import Vec3
        >>> from matfit.models import SoAPairs
        >>> up = Vec3(jnp.zeros(2), jnp.zeros(2), jnp.ones(2))
        >>> SoAPairs.from_directions(up, up, n=1).n
        1
        """
        h, cos_d = half_vector(wo, wi)
        return cls(wo, wi, h, _clamp_cos(cos_d), _iso_terms(wo, wi, h), None if n is None else int(n))

    @classmethod
    def of(cls, wo, wi) -> "SoAPairs":
        """The pairs of ``(..., 3)`` direction arrays (broadcast against each other).

        Parameters
        ----------
        wo, wi : array_like, shape (..., 3)
            Unit directions.

        Returns
        -------
        SoAPairs

        Examples
        --------
        >>> import jax.numpy as jnp
        >>> from matfit.models import SoAPairs
        >>> SoAPairs.of(jnp.array([[0.0, 0.0, 1.0]]), jnp.array([[0.6, 0.0, 0.8]])).shape
        (1, 3)
        """
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
        """The directions as :class:`~matfit._math.IsoDir`: what an isotropic microfacet lobe
        reads of them (cosines, and ``h``'s squared sine), as
        :meth:`~matfit.models.AbstractMicrofacetBSDF.reflection_lobe` reads them.

        Returns
        -------
        wo, wi, h : IsoDir
            The directions and their half vector, mapped to the normal where ``ok`` is False.
        ok : jax.Array of bool, shape (...)
            The pairs' validity (:attr:`valid`).

        Examples
        --------
        >>> import jax.numpy as jnp
        >>> from matfit.models import SoAPairs
        >>> wo, wi, h, ok = SoAPairs.of(jnp.array([[0.0, 0.6, 0.8]]), jnp.array([[0.0, 0.0, -1.0]])).isotropic()
        >>> bool(ok[0]), float(wo.z[0]), float(h.z[0])  # an invalid pair: mapped to the normal
        (False, 1.0, 1.0)
        """
        ok, oz, iz, hz, ht2 = self.iso
        return IsoDir.from_cos(oz), IsoDir.from_cos(iz), IsoDir(hz, ht2), ok

    def fresnel_angle(self):
        """The :class:`~matfit.fresnel.FresnelAngle` of :attr:`cos_d`.

        Returns
        -------
        FresnelAngle

        Examples
        --------
        >>> import jax.numpy as jnp
        >>> from matfit.models import SoAPairs
        >>> p = SoAPairs.of(jnp.array([[0.0, 0.6, 0.8]]), jnp.array([[0.0, -0.6, 0.8]]))
        >>> round(float(p.fresnel_angle().sin2[0]), 6)
        0.36
        """
        return FresnelAngle.of_clamped(self.cos_d)
