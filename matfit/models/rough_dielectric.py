"""Rough dielectric: microfacet reflection and refraction (Walter et al. 2007)."""

from __future__ import annotations

import jax.numpy as jnp

from .._math import COS_EPS, Vec3, dot, normalize, per_pair, reflect, refract, safe_div, sq
from ..fresnel import fresnel_dielectric
from ._base import dielectric_energy_factor
from ._microfacet import AbstractMicrofacetBSDF, with_options_doc
from ._params import as_param, check_directions, check_range, check_u

__all__ = ["RoughDielectric", "ETA_PASS"]

#: |eta - 1| below which the interface is treated as index-matched (a straight pass-through).
ETA_PASS = 1e-5


@with_options_doc
class RoughDielectric(AbstractMicrofacetBSDF):
    r"""Frosted glass: rough reflection and refraction through a dielectric interface
    (one colour channel, ``C = 1``).

    With :math:`\cos\theta_o = \omega_o\cdot n`, :math:`\cos\theta_i = \omega_i\cdot n`, the pair is a
    reflection when both lie on the same side. The relative index across the pair is
    :math:`\eta_p = 1` (reflection), :math:`\eta` (``wo`` outside, ``wi`` inside) or :math:`1/\eta`
    (``wo`` inside), and the generalized half vector :math:`m \propto \eta_p\omega_i + \omega_o`,
    turned to the upper side. Pairs whose microfacet is back-facing for either direction
    (:math:`(m\cdot\omega)\cos\theta \le 0`) are rejected (value 0). With
    :math:`F = F_{\text{dielectric}}(\omega_o\cdot m, \eta)`:

    .. math::
        f_r = \frac{D(m)\,G_2\,F}{4|\cos\theta_i\cos\theta_o|},\qquad
        f_t = \frac{D(m)\,G_2\,(1-F)}{\eta_p^2}
              \left|\frac{(\omega_i\cdot m)(\omega_o\cdot m)}
              {\cos\theta_i\cos\theta_o\,(\omega_i\cdot m + \omega_o\cdot m/\eta_p)^2}\right|

    :math:`f_t` is the radiance BTDF (pbrt-v4's ``TransportMode::Radiance``): it obeys
    :math:`f_t(\omega_o,\omega_i)/\eta_o^2 = f_t(\omega_i,\omega_o)/\eta_i^2`, with
    :math:`\eta_o, \eta_i` the indices of the media that hold each direction.

    Sampling picks a visible microfacet normal of ``wo`` (or D cos), then reflection with
    probability F and refraction with probability 1 - F; the pdf carries the Jacobian of each lobe,
    :math:`1/(4|\omega_o\cdot m|)` and :math:`|\omega_i\cdot m|/(\omega_i\cdot m + \omega_o\cdot m/\eta_p)^2`.

    Index-matched interface: for :math:`|\eta - 1| <` ``ETA_PASS`` (1e-5) the surface is invisible:
    no reflection, and transmission is a Dirac lobe straight through (``wi = -wo``, weight 1, pdf 1
    as a discrete probability; eval and pdf 0). Just outside that band the transmission lobe is a
    very narrow but finite peak around ``-wo``.

    Parameters
    ----------
    alpha : array_like, scalar or (...); >= 0; differentiable
        Width of the microfacet distribution along x (both axes when isotropic): the GGX or
        Beckmann alpha, not a perceptual roughness; clamped to ``ALPHA_MIN`` = 1e-4 inside D.
    eta : array_like, scalar or (...); > 0; differentiable
        Relative index inside / outside (below 1 for an inside less dense than the outside);
        one value per batch element (a pixel), no channel axis.
    {microfacet options}

    References
    ----------
    - B. Walter, S. Marschner, H. Li, K. Torrance, "Microfacet Models for Refraction through Rough
      Surfaces", EGSR 2007.
    - M. Pharr, W. Jakob, G. Humphreys, *Physically Based Rendering*, 4th ed., Sec. 9.7.
    - E. Heitz, "Understanding the Masking-Shadowing Function", JCGT 3(2), 2014.

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.models import RoughDielectric
    >>> glass = RoughDielectric(0.1, 1.5)
    >>> wo = jnp.array([0.0, 0.0, 1.0]); wi = jnp.array([0.0, 0.0, -1.0])
    >>> bool(glass.eval(wo, wi)[0] > 0)  # light passes straight through
    True
    """

    eta: jnp.ndarray

    @property
    def transmits(self):
        return True

    def __init__(self, alpha, eta, distribution="ggx", masking="separable", alpha_y=None, sampling="visible"):
        self._init_microfacet("RoughDielectric", alpha, alpha_y, distribution, masking, sampling)
        check_range("RoughDielectric", "eta", eta, 0.0, lo_open=True)
        self.eta = as_param(eta)

    @property
    def channels(self):
        return 1

    def index_matched(self):
        """True where ``|eta - 1| < ETA_PASS``: index-matched, light passes straight through."""
        return jnp.abs(self.eta - 1) < ETA_PASS

    def _geometry(self, wo, wi):
        """Generalized half vector (a :class:`~matfit._math.Vec3`), lobe, relative index and validity for a pair."""
        co = wo[..., 2]
        ci = wi[..., 2]
        refl = co * ci > 0
        etap = jnp.where(refl, 1.0, jnp.where(co > 0, self.eta, 1 / self.eta))
        # m = wi etap + wo, normalized and turned up, component by component (a Vec3)
        g = normalize(Vec3(*(wi[..., j] * etap + wo[..., j] for j in range(3))))
        up = jnp.where(g.z < 0, -1.0, 1.0).astype(g.z.dtype)
        m = Vec3(g.x * up, g.y * up, g.z * up)
        wim = dot(wi, m)
        wom = dot(wo, m)
        ok = (jnp.abs(co) > COS_EPS) & (jnp.abs(ci) > COS_EPS) & (wim * ci > 0) & (wom * co > 0)
        ok = ok & ~self.index_matched()
        return m, wim, wom, co, ci, refl, etap, ok

    def energy_factor(self, wo, wi):
        return dielectric_energy_factor(wo, wi, self.eta)

    def eval(self, wo, wi):
        check_directions("RoughDielectric.eval", wo=wo, wi=wi)
        # components as separate arrays (Vec3): XLA keeps the half vector per component instead
        # of an interleaved (..., 3) array written out and read back
        wo, wi = Vec3.from_array(jnp.asarray(wo)), Vec3.from_array(jnp.asarray(wi))
        m, wim, wom, co, ci, refl, etap, ok = self._geometry(wo, wi)
        d = self.dist()
        DG = d.D(m) * d.G2(wo, wi, m, self.masking)
        F = fresnel_dielectric(wom, self.eta)
        co_s = jnp.where(ok, co, 1)
        ci_s = jnp.where(ok, ci, 1)
        f_r = DG * F / jnp.abs(4 * ci_s * co_s)
        denom = sq(wim + wom / etap) * ci_s * co_s
        f_t = DG * (1 - F) * jnp.abs(safe_div(wim * wom, denom)) / sq(etap)
        f = jnp.where(refl, f_r, f_t)
        return per_pair(jnp.where(ok, f, 0))[..., None]

    def pdf(self, wo, wi):
        check_directions("RoughDielectric.pdf", wo=wo, wi=wi)
        m, wim, wom, co, ci, refl, etap, ok = self._geometry(wo, wi)
        pdf_m = self._pdf_m(self.dist(), wo, m.to_array())
        R = fresnel_dielectric(wom, self.eta)
        p_r = safe_div(pdf_m, 4 * jnp.abs(wom)) * R
        p_t = pdf_m * jnp.abs(safe_div(wim, sq(wim + wom / etap))) * (1 - R)
        return jnp.where(ok, jnp.where(refl, p_r, p_t), 0)

    def sample(self, wo, u):
        check_directions("RoughDielectric.sample", wo=wo)
        check_u("RoughDielectric.sample", u, 3)
        m = self._sample_m(self.dist(), wo, u[..., 1:3])
        R = fresnel_dielectric(dot(wo, m), self.eta)
        choose_r = u[..., 0] < R
        wr = reflect(wo, m)
        wt, ok_t = refract(wo, m, self.eta)
        wi = jnp.where(choose_r[..., None], wr, wt)
        side_ok = jnp.where(choose_r, wr[..., 2] * wo[..., 2] > 0, ok_t & (wt[..., 2] * wo[..., 2] < 0))
        # A D cos sample may face away from wo: such a microfacet cannot be hit (and the pair's
        # generalized half vector would differ from m), so the sample is invalid.
        side_ok = side_ok & (dot(wo, m) * wo[..., 2] > 0)
        # computed once (per_pair): the validity test and the weight's divisor read the same value
        # (two loops recomputing a pdf near underflow could disagree on whether it is 0)
        pdf = per_pair(jnp.where(side_ok, self.pdf(wo, wi), 0))
        ok = pdf > 0
        weight = safe_div(self.eval(wo, wi) * jnp.abs(wi[..., 2])[..., None], pdf[..., None])
        weight = jnp.where(ok[..., None], weight, 0)
        # Index-matched: straight through, as a discrete lobe.
        through = self.index_matched() & (jnp.abs(wo[..., 2]) > COS_EPS)
        wi = jnp.where(through[..., None], -wo, wi)
        weight = jnp.where(through[..., None], 1.0, weight)
        pdf = jnp.where(through, 1.0, pdf)
        return wi, weight, pdf
