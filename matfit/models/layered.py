"""Layered: a dielectric coat over any base, after Weidlich & Wilkie (2007); CoatedConductor."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp

from .._math import COS_EPS, Vec3, per_pair, refract, refract_into, safe_div, up_like
from ..errors import ParameterError
from ._base import AbstractBSDF
from ._coated import AbstractCoatedBSDF
from ._coat import coat_reflection, coat_transmittance, is_smooth, make_coat
from ._pairs import SoAPairs, valid_reflection
from ._params import as_channels, as_param, check_directions, check_range, check_u
from .rough_dielectric import RoughDielectric
from .smooth_dielectric import SmoothDielectric

__all__ = ["Layered", "CoatedConductor"]


class Layered(AbstractCoatedBSDF):
    r"""Any dielectric coat over any base model (stackable), after Weidlich & Wilkie (2007):

    .. math::
        f(\omega_o, \omega_i) = f_{coat}(\omega_o, \omega_i)
          + \frac{T(\mu_o)\,T(\mu_i)}{\eta^2}\, f_{base}(\omega_o', \omega_i')\,
            e^{-\sigma_a d\,(1/\mu_o' + 1/\mu_i')}

    :math:`\omega' = -\mathrm{refract}(\omega)` are the directions refracted through the coat's
    mean normal (pointing up inside the layer), :math:`T` the coat's directional energy
    transmittance (Fresnel ``1 - F`` in and out when smooth), :math:`\eta^2` the radiance
    compression of the refracted solid angle, and the exponential the Beer-Lambert absorption
    along both refracted paths, per channel. Multiple reflections between coat and base are
    neglected (as in Weidlich-Wilkie): :class:`Plastic` sums them for a Lambertian base,
    :class:`StochasticLayered` simulates them exactly. Reciprocal when the base is. Layers
    stack: the base may itself be a :class:`Layered`.

    Sampling: the coat lobe with probability ``R(mu_o) = 1 - T(mu_o)``, else the base's own
    sampler at ``wo'`` with the result refracted out; the pdf is the exact mixture, the base part
    carrying the Jacobian :math:`\mu_i/(\eta^2\mu_i')`. A smooth coat's delta lobe is sampled with
    its discrete probability as pdf.

    Parameters
    ----------
    coat : SmoothDielectric or RoughDielectric; differentiable (its array leaves)
        The coat, seen from outside (its ``alpha`` and ``eta`` are the coat's parameters).
    base : AbstractBSDF; no Dirac lobe; differentiable (its array leaves)
        Any reflective model without Dirac lobes (a smooth-coated stack cannot be a base),
        evaluated inside the layer (its indices relative to the coat).
    thickness : array_like, scalar or (...), default 0.0; >= 0; differentiable
        Layer thickness d, in the units of ``1 / sigma_a``.
    sigma_a : array_like, scalar or (..., C), default 0.0; >= 0; differentiable
        Absorption coefficient of the layer per colour channel.

    References
    ----------
    - A. Weidlich, A. Wilkie, "Arbitrarily Layered Micro-Facet Surfaces", GRAPHITE 2007.

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.models import Layered, Lambert, SmoothDielectric
    >>> varnish = Layered(SmoothDielectric(1.5), Lambert(jnp.array([0.5, 0.3, 0.1])), thickness=0.1, sigma_a=0.5)
    >>> varnish.eval(jnp.array([0.0, 0.0, 1.0]), jnp.array([0.6, 0.0, 0.8])).shape
    (3,)
    """

    base: AbstractBSDF
    thickness: jnp.ndarray
    sigma_a: jnp.ndarray = eqx.field(converter=as_channels)

    def __init__(self, coat, base, thickness=0.0, sigma_a=0.0):
        if not isinstance(coat, (SmoothDielectric, RoughDielectric)):
            raise ParameterError(f"Layered: coat must be a SmoothDielectric or RoughDielectric, got {type(coat).__name__}")
        if not isinstance(base, AbstractBSDF) or base.has_delta_lobe:
            raise ParameterError(
                f"Layered: base must be a matfit model without Dirac lobes (rough, or a stack whose coats are rough), "
                f"got {type(base).__name__}"
            )
        check_range("Layered", "thickness", thickness, 0.0)
        check_range("Layered", "sigma_a", sigma_a, 0.0)
        self.coat = coat
        self.base = base
        self.thickness = as_param(thickness)
        self.sigma_a = sigma_a

    @property
    def channels(self):
        return max(self.base.channels, self.sigma_a.shape[-1])

    def _inner(self, w):
        """Direction inside the layer (pointing up) for an outside direction ``w`` (a ``Vec3``
        or a ``(..., 3)`` array, returned in kind)."""
        t, ok = refract_into(w, self.coat.eta)
        return t, ok & (w[..., 2] > COS_EPS)

    def _outer(self, w_in):
        """Outside direction for an inside direction ``w_in`` pointing up (None under TIR)."""
        n = up_like(w_in)
        t, ok = refract(-w_in, n, self.coat.eta)
        return t, ok & (w_in[..., 2] > COS_EPS)

    def _absorption(self, wo_b, wi_b):
        mo = jnp.maximum(wo_b[..., 2], COS_EPS)
        mi = jnp.maximum(wi_b[..., 2], COS_EPS)
        return jnp.exp(-(self.sigma_a * self.thickness) * per_pair(1 / mo + 1 / mi)[..., None])

    def eval(self, wo, wi):
        check_directions("Layered.eval", wo=wo, wi=wi)
        return self._eval_t(wo, wi, self._table())

    def _eval_t(self, wo, wi, table):
        # The directions inside the layer as components (the base evaluates them as prepared
        # pairs, Vec3 throughout: no interleaved (N, 3) arrays in between), and every division
        # by the coat's index a product with its reciprocal, computed once.
        o, i = Vec3.from_array(wo), Vec3.from_array(wi)
        wo_b, ok_o = self._inner(o)
        wi_b, ok_i = self._inner(i)
        ok = ok_o & ok_i
        # per-pair factors computed once per pair (per_pair), not in every channel's loop
        T = coat_transmittance(self.coat, o.z, table) * coat_transmittance(self.coat, i.z, table)
        inv_eta = 1 / self.coat.eta
        scale = per_pair(jnp.where(ok, T * (inv_eta * inv_eta), 0))
        base = self.base.eval_pairs(SoAPairs.from_directions(wo_b, wi_b))
        inner = scale[..., None] * base * self._absorption(wo_b, wi_b)
        f = per_pair(coat_reflection(self.coat, wo, wi))[..., None] + jnp.where(ok[..., None], inner, 0)
        both = valid_reflection(wo, wi)
        return jnp.where(both[..., None], f, 0)

    def _p_coat(self, wo, table):
        return 1 - coat_transmittance(self.coat, wo[..., 2], table)

    def pdf(self, wo, wi):
        check_directions("Layered.pdf", wo=wo, wi=wi)
        return self._pdf_t(wo, wi, self._table())

    def _pdf_t(self, wo, wi, table):
        pc = self._p_coat(wo, table)
        wo_b, ok_o = self._inner(wo)
        wi_b, ok_i = self._inner(wi)
        jac = safe_div(jnp.abs(wi[..., 2]), self.coat.eta**2 * wi_b[..., 2])
        p_b = jnp.where(ok_o & ok_i, self.base.pdf(wo_b, wi_b) * jac, 0)
        p_c = 0.0 if is_smooth(self.coat) else self.coat.reflection_pdf(wo, wi)
        both = valid_reflection(wo, wi)
        return jnp.where(both, pc * p_c + (1 - pc) * p_b, 0)

    def _sample_under(self, wo, u, pc):
        # Re-use u0 for the base's own lobe choice, rescaled to [0, 1).
        u0_b = jnp.clip(safe_div(u[..., 0] - pc, 1 - pc), 0, 1 - 1e-7)
        wo_b, ok_o = self._inner(wo)
        u_b = jnp.concatenate([u0_b[..., None], u[..., 1:3]], axis=-1)
        wi_b, _, _ = self.base.sample(jnp.broadcast_to(wo_b, u_b.shape), u_b)
        wi_out, ok_out = self._outer(wi_b)
        return wi_out, ok_o & ok_out

    def sample(self, wo, u):
        check_directions("Layered.sample", wo=wo)
        check_u("Layered.sample", u, 3)
        return self._sample_coated(wo, u)


def CoatedConductor(alpha_base, eta_base, k_base, alpha_coat=0.0, eta_coat=1.5, thickness=0.0, sigma_a=0.0,
                    distribution="ggx", masking="separable") -> Layered:
    r"""Car paint: a rough conductor under a smooth or rough clear coat (a :class:`Layered`).

    The coat's Fresnel is applied on the way in and on the way out, directions are refracted into
    the layer, and the coat absorbs with ``sigma_a`` over ``thickness``. ``eta_base`` and
    ``k_base`` are the metal's index relative to the outside (air), as tabulated; inside the coat
    the conductor sees :math:`(\eta_b + i k_b)/\eta_{coat}`.

    Parameters
    ----------
    alpha_base : array_like, scalar or (...); >= 0; differentiable
        Width of the metal's microfacet distribution.
    eta_base : array_like, scalar or (..., C); > 0; differentiable
        Real part of the metal's complex index relative to the outside (air), per channel.
    k_base : array_like, scalar or (..., C); >= 0; differentiable
        Imaginary part of the metal's index relative to the outside, per channel.
    alpha_coat : array_like, scalar or (...), default 0.0; >= 0; differentiable when rough
        Width of the coat's distribution; a concrete 0 gives a smooth coat (a Dirac lobe).
    eta_coat : array_like, scalar or (...), default 1.5; > 0; differentiable
        Index of the coat relative to the outside.
    thickness : array_like, scalar or (...), default 0.0; >= 0; differentiable
        Coat thickness, in the units of ``1 / sigma_a`` (as in :class:`Layered`).
    sigma_a : array_like, scalar or (..., C), default 0.0; >= 0; differentiable
        Absorption coefficient of the coat per colour channel.
    distribution : {"ggx", "beckmann", "blinn_phong"}, default "ggx"; static, not differentiable
        Microfacet distribution of the coat and the metal.
    masking : {"separable", "height_correlated"}, default "separable"; static, not differentiable
        Smith masking form of the coat and the metal.

    Returns
    -------
    Layered
        The coat over a :class:`RoughConductor` of index ``(eta_base + i k_base) / eta_coat``.

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.models import CoatedConductor
    >>> paint = CoatedConductor(0.3, jnp.array([0.2, 0.9, 1.1]), jnp.array([3.9, 2.4, 2.2]), eta_coat=1.5)
    >>> paint.eval(jnp.array([0.0, 0.0, 1.0]), jnp.array([0.0, 0.0, 1.0])).shape
    (3,)
    """
    from .rough_conductor import RoughConductor

    check_range("CoatedConductor", "eta_coat", eta_coat, 0.0, lo_open=True)
    coat = make_coat(alpha_coat, eta_coat, distribution, masking)
    base = RoughConductor(alpha_base, as_channels(eta_base) / coat.eta, as_channels(k_base) / coat.eta,
                          distribution=distribution, masking=masking)
    return Layered(coat, base, thickness, sigma_a)
