"""Rough conductor on a tabulated microfacet distribution (:class:`~matfit.microfacet.TabulatedNDF`)."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp

from .._math import dot, normalize, reflect, safe_div
from ..errors import ParameterError
from ..fresnel import fresnel_conductor
from ..microfacet import MASKING_FORMS, TabulatedNDF
from ._base import AbstractConductor, AbstractPairBSDF
from ._pairs import valid_reflection
from ._params import as_channels, check_choice, check_directions, check_u

__all__ = ["TabulatedMicrofacet"]


class TabulatedMicrofacet(AbstractConductor, AbstractPairBSDF):
    r"""Rough metal on a tabulated isotropic distribution, with the conductor Fresnel:

    .. math::
        f(\omega_o, \omega_i) = \frac{D(\omega_h)\,F(\omega_o\cdot\omega_h;\ \eta, k)\,
            G_2(\omega_o, \omega_i, \omega_h)}{4\cos\theta_o\cos\theta_i}

    for :math:`\cos\theta_o, \cos\theta_i >` ``COS_EPS``, else 0: :class:`RoughConductor`'s
    Cook-Torrance form with :math:`D` read from a table (e.g. extracted from a measurement by
    :func:`matfit.microfacet.extract_ndf`) and Smith's :math:`G_2` derived from it. Sampling:
    normals from :math:`D\cos` (the table's exact inverse CDF), reflected about the sampled
    normal; pdf = :math:`D(\omega_h)\cos\theta_h / (4\,\omega_o\cdot\omega_h)`. Samples that leave
    below the horizon, or come from a microfacet facing away from ``wo``, are invalid (pdf 0).

    Parameters
    ----------
    ndf : TabulatedNDF; not differentiable (tables fixed at construction)
        The distribution of normals (:class:`~matfit.microfacet.TabulatedNDF`), with its Smith
        masking derived from it.
    eta : array_like, scalar or (..., C); > 0; differentiable
        Real part of the conductor's complex index relative to the outside, per channel.
    k : array_like, scalar or (..., C); >= 0; differentiable
        Imaginary part (extinction coefficient), per channel.
    masking : {"separable", "height_correlated"}, default "separable"; static, not differentiable
        Smith masking form (:meth:`~matfit.microfacet.AbstractDistribution.G2`).

    Raises
    ------
    ParameterError
        For an ``ndf`` that is not a :class:`~matfit.microfacet.TabulatedNDF`, an index out of
        range, an unknown masking form.

    References
    ----------
    - R. L. Cook, K. E. Torrance, "A Reflectance Model for Computer Graphics", ToG 1(1), 1982.
    - J. Dupuy, E. Heitz, J.-C. Iehl, P. Poulin, V. Ostromoukhov, "Extracting Microfacet-based BRDF
      Parameters from Arbitrary Materials with Power Iterations", CGF 34(4), 2015.

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.microfacet import GGX, TabulatedNDF
    >>> from matfit.models import RoughConductor, TabulatedMicrofacet
    >>> eta, k = jnp.array([0.143, 0.374, 1.442]), jnp.array([3.983, 2.385, 1.603])
    >>> tab = TabulatedMicrofacet(TabulatedNDF.from_distribution(GGX(0.2)), eta, k)
    >>> wo = jnp.array([0.0, 0.6, 0.8]); wi = jnp.array([0.3, -0.5, 0.81]); wi = wi / jnp.linalg.norm(wi)
    >>> ref = RoughConductor(0.2, eta, k).eval(wo, wi)
    >>> bool(jnp.allclose(tab.eval(wo, wi), ref, rtol=1e-3))
    True
    """

    ndf: TabulatedNDF
    eta: jnp.ndarray = eqx.field(converter=as_channels)
    k: jnp.ndarray = eqx.field(converter=as_channels)
    masking: str = eqx.field(static=True)

    def __init__(self, ndf, eta, k, masking="separable"):
        if not isinstance(ndf, TabulatedNDF):
            raise ParameterError(f"TabulatedMicrofacet: ndf must be a matfit.microfacet.TabulatedNDF, "
                                 f"got {type(ndf).__name__}")
        check_choice("TabulatedMicrofacet", "masking", masking, MASKING_FORMS)
        self._init_index("TabulatedMicrofacet", eta, k)
        self.ndf = ndf
        self.masking = masking

    def eval_pairs(self, pairs):
        # the isotropic lobe reads cosines and h's squared sine only; invalid pairs map to the normal
        wo, wi, h, ok = pairs.isotropic()
        num, den, _ = self.ndf.reflection_ratio(wo, wi, h, self.masking)
        dg = num / jnp.where(ok, den, jnp.inf)
        spec = dg / jnp.where(ok, 4 * wo[..., 2] * wi[..., 2], jnp.inf)
        return spec[..., None] * fresnel_conductor(pairs.fresnel_angle().expand(), self.eta, self.k)

    def pdf(self, wo, wi):
        check_directions("TabulatedMicrofacet.pdf", wo=wo, wi=wi)
        ok = valid_reflection(wo, wi)
        h = normalize(wo + wi)
        p = safe_div(self.ndf.pdf_dcos(h), 4 * dot(wo, h))
        return jnp.where(ok, p, 0)

    def sample(self, wo, u):
        check_directions("TabulatedMicrofacet.sample", wo=wo)
        check_u("TabulatedMicrofacet.sample", u, 3)
        return self._weighted(wo, reflect(wo, self.ndf.sample_dcos(u[..., 1:3])))
