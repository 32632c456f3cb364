r"""Diffuse plus specular: a Lambertian albedo and a microfacet lobe with Schlick's Fresnel.

The model of spatially varying captures (an albedo, a specular colour :math:`F_0` and a width
per texel), and of the article's Cook-Torrance section with a diffuse term added:

.. math::
    f(\omega_o, \omega_i) = \frac{\rho}{\pi}
        + \frac{D(\omega_h)\,F_s(\omega_o\cdot\omega_h)\,G_2(\omega_o, \omega_i, \omega_h)}
               {4\cos\theta_o\cos\theta_i},\qquad
    F_s(c) = F_0 + (1 - F_0)(1 - c)^5

for :math:`\cos\theta_o, \cos\theta_i > 0` (``COS_EPS``), else 0. The two terms are added, not
coupled: the diffuse part does not lose what the lobe reflects, so the hemispherical
reflectance is :math:`\rho` plus the lobe's, and can exceed 1: Schlick's grazing term is there
even at :math:`F_0 = 0` (at :math:`\cos\theta_o = 0.4`, :math:`\alpha = 0.1` it is 1.013 for
:math:`\rho = F_0 = 0.5`). It is the phenomenological texel model of SVBRDF
capture, not a layered material (see :class:`~matfit.models.Plastic` for a diffuse base under a
Fresnel-weighted coat).

Parameters
----------
albedo : (..., C) in [0, 1], differentiable. Diffuse albedo :math:`\rho` (stored as the field
    ``diffuse``: ``albedo(wo)`` is the directional-albedo method of every model).
f0 : (..., C) in [0, 1], differentiable. Normal-incidence specular reflectance :math:`F_0`.
alpha : float or array, >= 0 (clamped to ``ALPHA_MIN`` inside D), differentiable.
alpha_y : optional, anisotropic width along y.
distribution : "ggx" (default) | "beckmann" | "blinn_phong";  masking : "separable" | "height_correlated".

Sampling: the cosine-weighted hemisphere with probability
:math:`p_d = \bar\rho / (\bar\rho + \bar F_0)` (channel means; 1/2 when both are 0), else the
lobe's visible normals (or D cos); the pdf is the exact mixture.

References
----------
- R. L. Cook, K. E. Torrance, "A Reflectance Model for Computer Graphics", ToG 1(1), 1982.
- C. Schlick, "An Inexpensive BRDF Model for Physically-based Rendering", CGF 13(3), 1994.
- M. Aittala, T. Weyrich, J. Lehtinen, "Two-Shot SVBRDF Capture for Stationary Materials",
  ToG 34(4), 2015 (the diffuse + specular texel model of captures).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp

from .._math import COS_EPS, cosine_hemisphere, normalize, safe_div
from ..fresnel import fresnel_schlick
from ._microfacet import AbstractMicrofacetBSDF
from ._pairs import SoAPairs
from ._params import as_channels, check_channels, check_directions, check_range, check_u


class DiffuseSpecular(AbstractMicrofacetBSDF):
    """Lambertian albedo plus a Schlick-Fresnel microfacet lobe (the texel model of captures).

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.models import DiffuseSpecular
    >>> m = DiffuseSpecular(jnp.array([0.5, 0.3, 0.2]), f0=0.04, alpha=0.2)
    >>> up = jnp.array([0.0, 0.0, 1.0])
    >>> m.eval(up, up).shape
    (3,)
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
        return jnp.broadcast_shapes(self.diffuse.shape, self.f0.shape)[-1]

    pair_kernels = True

    def eval(self, wo, wi):
        check_directions("DiffuseSpecular.eval", wo=wo, wi=wi)
        return self.eval_pairs(SoAPairs.of(wo, wi))

    def eval_pairs(self, pairs):
        ok = pairs.iso[0]
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
        ok = (wo[..., 2] > COS_EPS) & (wi[..., 2] > COS_EPS)
        p_d = jnp.where(ok, jnp.maximum(wi[..., 2], 0) / jnp.pi, 0)
        return pd * p_d + (1 - pd) * self.reflection_pdf(wo, wi)

    def sample(self, wo, u):
        check_directions("DiffuseSpecular.sample", wo=wo)
        check_u("DiffuseSpecular.sample", u, 3)
        pd = self._p_diffuse()
        wi_d = cosine_hemisphere(u[..., 1], u[..., 2])
        wi_s = self.reflection_sample(wo, u[..., 1:3])
        wi = normalize(jnp.where((u[..., 0] < pd)[..., None], wi_d, wi_s))
        pdf = self.pdf(wo, wi)
        ok = (pdf > 0) & (wi[..., 2] > COS_EPS) & (wo[..., 2] > COS_EPS)
        weight = safe_div(self.eval(wo, wi) * jnp.abs(wi[..., 2])[..., None], pdf[..., None])
        return wi, jnp.where(ok[..., None], weight, 0), jnp.where(ok, pdf, 0)
