"""Multi-lobe reflection: a Lambertian base plus a sum of weighted microfacet lobes."""

from __future__ import annotations

from typing import Optional

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._math import cosine_hemisphere, normalize, safe_div
from ..errors import ParameterError
from ..fresnel import fresnel_conductor, fresnel_dielectric, fresnel_schlick, fresnel_thin_film
from ._base import AbstractPairBSDF
from ._microfacet import AbstractMicrofacetBSDF
from ._params import (as_channels, channel_count, check_channels, check_choice, check_complex_index, check_directions,
                      check_range, check_u)
from .lambert import cosine_pdf

__all__ = ["SpecularLobe", "MultiLobe", "FRESNEL_KINDS"]

#: The Fresnel terms a :class:`SpecularLobe` takes.
FRESNEL_KINDS = ("schlick", "dielectric", "conductor", "thin_film")
#: The parameters each Fresnel term takes.
FRESNEL_PARAMS = {"schlick": ("f0",), "dielectric": ("eta",), "conductor": ("eta", "k"),
                  "thin_film": ("thickness", "film_eta", "eta")}

#: Cosine-weighted hemispherical average of Schlick's (1 - c)^5: 2 int_0^1 (1 - c)^5 c dc = 1/21.
_SCHLICK_AVERAGE = 1.0 / 21.0


class SpecularLobe(AbstractMicrofacetBSDF, AbstractPairBSDF):
    r"""One weighted microfacet reflection lobe, a model on its own and the component of
    :class:`MultiLobe`:

    .. math:: f = w\,F(\omega_o\cdot\omega_h)\,\frac{D(\omega_h)\,G_2(\omega_o, \omega_i,
              \omega_h)}{4\cos\theta_o\cos\theta_i}

    for :math:`\cos\theta_o, \cos\theta_i > 0` (``COS_EPS``), else 0. The distribution options
    (``alpha``, ``alpha_y``, ``distribution``, ``masking``, ``sampling``) are those of
    :class:`~matfit.models.RoughConductor`, whose lobe this is. :math:`F` is Schlick's
    :math:`F_0 + (1 - F_0)(1 - c)^5`, the exact dielectric Fresnel of :math:`\eta`, the exact
    conductor Fresnel of :math:`\eta + ik`, or the RGB reflectance of a thin film
    (:func:`~matfit.fresnel.fresnel_thin_film`: the Airy sum per wavelength, integrated to linear
    sRGB), whose hue turns with the angle (iridescence; three channels).

    The weight :math:`w` per channel is the ``k_s`` of Cook-Torrance fits (Löw et al. 2012, Ngan
    et al. 2005): ``w = k_s`` with a Schlick or dielectric Fresnel gives a coloured or white
    specular lobe; ``w = 1`` with a conductor Fresnel is the rough conductor.

    Parameters
    ----------
    alpha : array_like, scalar or (...), default 0.2; >= 0; differentiable
        The lobe's own GGX, Beckmann or Blinn-Phong alpha (along x when ``alpha_y`` is given).
    alpha_y : array_like or None, scalar or (...), default None; >= 0 or None; differentiable
        The lobe's alpha along y (anisotropic), or None for an isotropic lobe.
    fresnel : {"schlick", "dielectric", "conductor", "thin_film"}, default "schlick"; static, not differentiable
        The Fresnel term: Schlick's curve of ``f0``, the exact dielectric Fresnel of ``eta``, 
        the exact conductor Fresnel of ``eta + i k``, or a thin film of ``thickness`` and
        ``film_eta`` on a dielectric of index ``eta``.
    weight : array_like, scalar or (..., C), default 1.0; >= 0; differentiable
        The lobe's weight :math:`w` per colour channel (a Cook-Torrance ``k_s``).
    f0 : array_like or None, scalar or (..., C), default None; [0, 1] or None; differentiable
        Normal-incidence reflectance :math:`F_0` of a Schlick lobe, per channel (None: 0.04);
        only for ``fresnel="schlick"``.
    eta : array_like or None, scalar or (..., C), default None; > 0 or None; differentiable
        Relative index of a dielectric lobe (None: 1.5), real part of a conductor's complex
        index (required), per channel, or the index (>= 1) of a thin film's base (None: 1.5);
        not for ``fresnel="schlick"``.
    k : array_like or None, scalar or (..., C), default None; >= 0 or None; differentiable
        Extinction coefficient of a conductor lobe, per channel (required); only for
        ``fresnel="conductor"``.
    thickness : array_like or None, scalar or (..., 1), default None; >= 0 or None; differentiable
        A thin film's thickness in nm (required for ``fresnel="thin_film"``, else not taken).
    film_eta : array_like or None, scalar or (..., 1), default None; >= 1 or None; differentiable
        A thin film's index (required for ``fresnel="thin_film"``, else not taken).
    distribution : {"ggx", "beckmann", "blinn_phong"}, default "ggx"; static, not differentiable
        Which distribution of normals the lobe has (``alpha <= 1`` for Blinn-Phong).
    masking : {"separable", "height_correlated"}, default "separable"; static, not differentiable
        The form of its Smith masking-shadowing term.
    sampling : {"visible", "dcos"}, default "visible"; static, not differentiable
        Its normals drawn from those visible from ``wo`` or from D cos (always D cos for
        Blinn-Phong).

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.models import RoughConductor, SpecularLobe
    >>> eta, k = jnp.array([0.143, 0.374, 1.442]), jnp.array([3.983, 2.385, 1.603])
    >>> lobe = SpecularLobe(0.2, "conductor", eta=eta, k=k)
    >>> wo = jnp.array([0.0, 0.6, 0.8]); wi = jnp.array([0.0, -0.6, 0.8])
    >>> bool(jnp.allclose(lobe.eval(wo, wi), RoughConductor(0.2, eta, k).eval(wo, wi)))
    True
    """

    weight: jnp.ndarray
    f0: Optional[jnp.ndarray]
    eta: Optional[jnp.ndarray]
    k: Optional[jnp.ndarray]
    thickness: Optional[jnp.ndarray]
    film_eta: Optional[jnp.ndarray]
    fresnel: str = eqx.field(static=True)

    def __init__(self, alpha=0.2, fresnel="schlick", weight=1.0, f0=None, eta=None, k=None, distribution="ggx",
                 masking="separable", alpha_y=None, sampling="visible", thickness=None, film_eta=None):
        owner = "SpecularLobe"
        check_choice(owner, "fresnel", fresnel, FRESNEL_KINDS)
        self._init_microfacet(owner, alpha, alpha_y, distribution, masking, sampling)
        check_range(owner, "weight", weight, 0.0)
        given = {n for n, v in (("f0", f0), ("eta", eta), ("k", k), ("thickness", thickness), ("film_eta", film_eta))
                 if v is not None}
        takes = set(FRESNEL_PARAMS[fresnel])
        if given - takes:
            raise ParameterError(f"{owner}: {', '.join(sorted(given - takes))} does not apply to a {fresnel!r} lobe "
                                 f"(it takes {', '.join(sorted(takes))})")
        if fresnel == "schlick":
            f0 = 0.04 if f0 is None else f0
            check_range(owner, "f0", f0, 0.0, 1.0)
        elif fresnel == "dielectric":
            eta = 1.5 if eta is None else eta
            check_range(owner, "eta", eta, 0.0, lo_open=True)
        elif fresnel == "thin_film":
            if thickness is None or film_eta is None:
                raise ParameterError(f"{owner}: a 'thin_film' lobe needs thickness (nm) and film_eta")
            eta = 1.5 if eta is None else eta
            check_range(owner, "thickness", thickness, 0.0)
            check_range(owner, "film_eta", film_eta, 1.0)
            check_range(owner, "eta", eta, 1.0)
            for n, v in (("thickness", thickness), ("film_eta", film_eta), ("eta", eta)):
                if np.ndim(v) and np.shape(v)[-1] != 1:
                    raise ParameterError(f"{owner}: a thin film's {n} is one value for every channel (its colour "
                                         f"comes from the film): the last axis must have length 1, got shape "
                                         f"{np.shape(v)}")
        else:
            if eta is None or k is None:
                raise ParameterError(f"{owner}: a 'conductor' lobe needs eta and k (its complex index)")
            check_complex_index(owner, eta, k)
        check_channels(owner, weight=weight, f0=f0, eta=eta, k=k)
        self.fresnel = fresnel
        self.weight = as_channels(weight)
        self.f0 = None if f0 is None else as_channels(f0)
        self.eta = None if eta is None else as_channels(eta)
        self.k = None if k is None else as_channels(k)
        self.thickness = None if thickness is None else as_channels(thickness)
        self.film_eta = None if film_eta is None else as_channels(film_eta)

    @property
    def pair_kernels(self):
        # a film's three channels come from one spectrum: not one kernel per channel
        return self.fresnel != "thin_film"

    @property
    def channels(self):
        if self.fresnel == "thin_film":
            return 3
        return channel_count(*(p for p in (self.weight, self.f0, self.eta, self.k) if p is not None))

    def pdf(self, wo, wi):
        check_directions("SpecularLobe.pdf", wo=wo, wi=wi)
        return self.reflection_pdf(wo, wi)

    def fresnel_term(self, pairs):
        """The lobe's weighted Fresnel factor ``w F(wo . h)`` of prepared pairs, ``(..., C)``."""
        if self.fresnel == "schlick":
            F = fresnel_schlick(pairs.cos_d[..., None], self.f0)
        elif self.fresnel == "dielectric":
            F = fresnel_dielectric(pairs.cos_d[..., None], self.eta)
        elif self.fresnel == "thin_film":
            # the film's parameters have one channel: (..., 1) -> RGB (..., 3)
            F = fresnel_thin_film(pairs.cos_d[..., None], self.thickness, self.film_eta, self.eta)[..., 0, :]
        else:
            F = fresnel_conductor(pairs.fresnel_angle().expand(), self.eta, self.k)
        return self.weight * F

    def normal_reflectance(self):
        """The lobe's Fresnel term at normal incidence, ``F(1)`` per channel, without the weight."""
        if self.fresnel == "schlick":
            return self.f0
        if self.fresnel == "dielectric":
            return fresnel_dielectric(jnp.ones((), self.eta.dtype), self.eta)
        if self.fresnel == "thin_film":
            return fresnel_thin_film(jnp.ones((), self.eta.dtype), self.thickness, self.film_eta, self.eta)[..., 0, :]
        return fresnel_conductor(jnp.ones((), self.eta.dtype), self.eta, self.k)

    def reflectance_estimate(self):
        r"""The lobe's reflectance estimate :math:`w\,(F(1) + (1 - F(1))/21)` per channel (the
        weight of its sampling probability in :class:`MultiLobe`)."""
        r0 = self.normal_reflectance()
        return self.weight * (r0 + (1 - r0) * _SCHLICK_AVERAGE)

    def eval_pairs(self, pairs):
        # D G2 / (4 cos cos) once per pair (0 where invalid); the weighted Fresnel per channel
        return self.reflection_lobe(pairs)[..., None] * self.fresnel_term(pairs)

    def sample(self, wo, u):
        check_directions("SpecularLobe.sample", wo=wo)
        check_u("SpecularLobe.sample", u, 3)
        return self._weighted(wo, self.reflection_sample(wo, u[..., 1:3]), above=True)


class MultiLobe(AbstractPairBSDF):
    r"""A Lambertian base plus a sum of weighted microfacet lobes (:class:`SpecularLobe`).

    Measured materials often show more than one specular scale: a sharp highlight over a wide
    haze (brushed or sand-blasted finishes, plastics with a dust layer, satin paints), a metal
    whose roughness has two scales. With :math:`K` lobes,

    .. math::
        f(\omega_o, \omega_i) = \frac{\rho}{\pi} + \sum_{j=1}^{K} w_j\,F_j(\omega_o\cdot\omega_h)\,
            \frac{D_j(\omega_h)\,G_{2,j}(\omega_o, \omega_i, \omega_h)}{4\cos\theta_o\cos\theta_i}

    for :math:`\cos\theta_o, \cos\theta_i > 0` (``COS_EPS``), else 0, each lobe with its own
    distribution, width, masking form, Fresnel term and weight. The terms are added, not coupled
    (as in :class:`~matfit.models.DiffuseSpecular`): a lobe with ``F <= 1`` reflects at most
    ``w_j`` of the light, so the directional albedo is at most :math:`\rho + \sum_j w_j` per
    channel, and at most 1 when that sum is.

    Sampling: one-sample MIS over the components. The cosine-weighted hemisphere is chosen with a
    probability proportional to :math:`\bar\rho` (the channel mean of the albedo), lobe ``j``
    with one proportional to the channel mean of its
    :meth:`~SpecularLobe.reflectance_estimate`, :math:`w_j (F_j(1) + (1 - F_j(1))/21)` (the
    cosine-weighted hemispherical average of Schlick's curve through the lobe's normal-incidence
    reflectance; masking and the loss below the horizon left out); equal probabilities when all
    are 0. The lobe's sample is its visible normal (or D cos) reflected about ``wo``; the pdf is
    the exact mixture.

    Parameters
    ----------
    albedo : array_like, scalar or (..., C); [0, 1]; differentiable
        Diffuse albedo :math:`\rho` of the Lambertian base per colour channel, 0 for none (stored
        as the field ``diffuse``: ``albedo(wo)`` is the directional-albedo method of every model).
    lobes : sequence of SpecularLobe; one or more; differentiable (their array leaves)
        The microfacet lobes, each with its own distribution, width, Fresnel term and weight;
        channel counts equal to the albedo's, or 1.

    References
    ----------
    - R. L. Cook, K. E. Torrance, "A Reflectance Model for Computer Graphics", ToG 1(1), 1982.
    - A. Ngan, F. Durand, W. Matusik, "Experimental Analysis of BRDF Models", EGSR 2005 (two-lobe fits).
    - J. Löw, J. Kronander, A. Ynnerman, J. Unger, "BRDF Models for Accurate and Efficient
      Rendering of Glossy Surfaces", ToG 31(1), 2012.
    - C. Schlick, "An Inexpensive BRDF Model for Physically-based Rendering", CGF 13(3), 1994.

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.models import MultiLobe, SpecularLobe
    >>> sharp_over_haze = [SpecularLobe(0.05, weight=1.0, f0=0.04), SpecularLobe(0.4, weight=0.1, f0=0.04)]
    >>> m = MultiLobe(jnp.array([0.5, 0.3, 0.2]), sharp_over_haze)
    >>> m.eval(jnp.array([0.0, 0.6, 0.8]), jnp.array([0.0, -0.6, 0.8])).shape
    (3,)
    """

    diffuse: jnp.ndarray  # the albedo rho (``albedo`` is the method)
    lobes: tuple

    def __init__(self, albedo, lobes):
        owner = "MultiLobe"
        check_range(owner, "albedo", albedo, 0.0, 1.0)
        if isinstance(lobes, SpecularLobe) or not isinstance(lobes, (list, tuple)):
            raise ParameterError(f"{owner}: lobes must be a list or tuple of SpecularLobe, got {type(lobes).__name__}")
        if not lobes:
            raise ParameterError(f"{owner}: lobes must hold at least one SpecularLobe (a base alone is Lambert)")
        for i, lobe in enumerate(lobes):
            if not isinstance(lobe, SpecularLobe):
                raise ParameterError(f"{owner}: lobes[{i}] must be a SpecularLobe, got {type(lobe).__name__}")
        check_channels(owner, albedo=albedo, **{f"lobes[{i}]": lobe.channels for i, lobe in enumerate(lobes)})
        self.diffuse = as_channels(albedo)
        self.lobes = tuple(lobes)

    @property
    def pair_kernels(self):
        return all(lobe.pair_kernels for lobe in self.lobes)

    @property
    def channels(self):
        return max(channel_count(self.diffuse), *(lobe.channels for lobe in self.lobes))

    def eval_pairs(self, pairs):
        # the base on valid pairs, then every lobe's own pair kernel (each 0 on invalid pairs)
        f = jnp.where(pairs.valid[..., None], self.diffuse / jnp.pi, 0)
        for lobe in self.lobes:
            f = f + lobe.eval_pairs(pairs)
        return f

    def probabilities(self):
        """The ``K + 1`` sampling probabilities ``(...)``: the cosine hemisphere first, then the lobes."""
        w = [jnp.mean(self.diffuse, axis=-1)] + [jnp.mean(lobe.reflectance_estimate(), axis=-1) for lobe in self.lobes]
        w = jnp.broadcast_arrays(*w)
        total = sum(w)
        n = len(w)
        return tuple(jnp.where(total > 0, safe_div(x, total), 1.0 / n) for x in w)

    def pdf(self, wo, wi):
        check_directions("MultiLobe.pdf", wo=wo, wi=wi)
        p = self.probabilities()
        out = p[0] * cosine_pdf(wo, wi)
        for pj, lobe in zip(p[1:], self.lobes):
            out = out + pj * lobe.reflection_pdf(wo, wi)
        return out

    def sample(self, wo, u):
        check_directions("MultiLobe.sample", wo=wo)
        check_u("MultiLobe.sample", u, 3)
        p = self.probabilities()
        u0 = u[..., 0]
        wi = cosine_hemisphere(u[..., 1], u[..., 2])
        wi = jnp.broadcast_to(wi, jnp.broadcast_shapes(wi.shape, wo.shape))
        start = p[0]  # lobe j takes u0 in [p_0 + ... + p_{j-1}, ... + p_j)
        for pj, lobe in zip(p[1:], self.lobes):
            pick = (u0 >= start) & (pj > 0)
            wi = jnp.where(pick[..., None], lobe.reflection_sample(wo, u[..., 1:3]), wi)
            start = start + pj
        return self._weighted(wo, normalize(wi), above=True)
