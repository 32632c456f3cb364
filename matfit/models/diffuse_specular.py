"""Diffuse plus specular: a Lambertian albedo and a microfacet lobe with Schlick's Fresnel."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp

from .._math import cosine_hemisphere, normalize, safe_div
from ..fresnel import fresnel_schlick
from ._base import AbstractPairBSDF
from ._microfacet import AbstractMicrofacetBSDF, with_options_doc
from ._params import as_channels, channel_count, check_channels, check_directions, check_range, check_u
from .lambert import cosine_pdf

__all__ = ["DiffuseSpecular"]


@with_options_doc
class DiffuseSpecular(AbstractMicrofacetBSDF, AbstractPairBSDF):
    r"""Lambertian albedo plus a Schlick-Fresnel microfacet lobe: the texel model of spatially
    varying captures (an albedo, a specular colour :math:`F_0` and a width per texel), and the
    article's Cook-Torrance section with a diffuse term added:

    .. math::
        f(\omega_o, \omega_i) = \frac{\rho}{\pi}
            + \frac{D(\omega_h)\,F_s(\omega_o\cdot\omega_h)\,G_2(\omega_o, \omega_i, \omega_h)}
                   {4\cos\theta_o\cos\theta_i},\qquad
        F_s(c) = F_0 + (1 - F_0)(1 - c)^5

    for :math:`\cos\theta_o, \cos\theta_i > 0` (``COS_EPS``), else 0. The terms are added, not
    coupled: the diffuse part does not lose what the lobe reflects, so the hemispherical
    reflectance is :math:`\rho` plus the lobe's, and can exceed 1: Schlick's grazing term is
    there even at :math:`F_0 = 0` (at :math:`\cos\theta_o = 0.4`, :math:`\alpha = 0.1` it is
    1.013 for :math:`\rho = F_0 = 0.5`). A phenomenological texel model, not a layered material
    (see :class:`~matfit.models.Plastic` for a diffuse base under a Fresnel-weighted coat).

    Sampling: the cosine-weighted hemisphere with probability
    :math:`p_d = \bar\rho / (\bar\rho + \bar F_0)` (channel means; 1/2 when both are 0), else
    the lobe's visible normals (or D cos); the pdf is the exact mixture.

    Parameters
    ----------
    albedo : array_like, scalar or (..., C); [0, 1]; differentiable
        Diffuse albedo :math:`\rho` per colour channel (stored as the field ``diffuse``:
        ``albedo(wo)`` is the directional-albedo method of every model).
    f0 : array_like, scalar or (..., C), default 0.04; [0, 1]; differentiable
        Normal-incidence specular reflectance :math:`F_0` per colour channel.
    alpha : array_like, scalar or (...), default 0.2; >= 0; differentiable
        Width of the microfacet distribution along x (both axes when isotropic): the GGX or
        Beckmann alpha, not a perceptual roughness; clamped to ``ALPHA_MIN`` = 1e-4 inside D.
    {microfacet options}

    References
    ----------
    - R. L. Cook, K. E. Torrance, "A Reflectance Model for Computer Graphics", ToG 1(1), 1982.
    - C. Schlick, "An Inexpensive BRDF Model for Physically-based Rendering", CGF 13(3), 1994.
    - M. Aittala, T. Weyrich, J. Lehtinen, "Two-Shot SVBRDF Capture for Stationary Materials",
      ToG 34(4), 2015 (the diffuse + specular texel model of captures).

    Examples
    --------
    The reflectance above 1 of the text (:math:`\cos\theta_o = 0.4`, :math:`\alpha = 0.1`,
    :math:`\rho = F_0 = 0.5`):

    >>> import jax.numpy as jnp
    >>> from matfit.models import DiffuseSpecular
    >>> wo = jnp.array([0.84 ** 0.5, 0.0, 0.4])
    >>> [round(float(e), 3) for e in DiffuseSpecular(0.5, f0=0.5, alpha=0.1).albedo(wo)]
    [1.013]
    """

    diffuse: jnp.ndarray = eqx.field(converter=as_channels)  # the albedo rho (``albedo`` is the method)
    f0: jnp.ndarray = eqx.field(converter=as_channels)

    def __init__(self, albedo, f0=0.04, alpha=0.2, distribution="ggx", masking="separable", alpha_y=None,
                 sampling="visible"):
        self._init_microfacet("DiffuseSpecular", alpha, alpha_y, distribution, masking, sampling)
        check_range("DiffuseSpecular", "albedo", albedo, 0.0, 1.0)
        check_range("DiffuseSpecular", "f0", f0, 0.0, 1.0)
        check_channels("DiffuseSpecular", albedo=albedo, f0=f0)
        self.diffuse = albedo
        self.f0 = f0

    @property
    def channels(self):
        return channel_count(self.diffuse, self.f0)

    def eval_pairs(self, pairs):
        ok = pairs.valid
        spec = self.reflection_lobe(pairs)[..., None]
        F = fresnel_schlick(pairs.cos_d[..., None], self.f0)
        return jnp.where(ok[..., None], self.diffuse / jnp.pi, 0) + spec * F

    def _p_diffuse(self):
        a = jnp.mean(self.diffuse, axis=-1)
        s = jnp.mean(self.f0, axis=-1)
        return jnp.where(a + s > 0, safe_div(a, a + s), 0.5)

    def pdf(self, wo, wi):
        check_directions("DiffuseSpecular.pdf", wo=wo, wi=wi)
        pd = self._p_diffuse()
        return pd * cosine_pdf(wo, wi) + (1 - pd) * self.reflection_pdf(wo, wi)

    def sample(self, wo, u):
        check_directions("DiffuseSpecular.sample", wo=wo)
        check_u("DiffuseSpecular.sample", u, 3)
        pd = self._p_diffuse()
        wi_d = cosine_hemisphere(u[..., 1], u[..., 2])
        wi_s = self.reflection_sample(wo, u[..., 1:3])
        return self._weighted(wo, normalize(jnp.where((u[..., 0] < pd)[..., None], wi_d, wi_s)), above=True)
