"""glTF 2.0 metallic-roughness material: the BRDF of the glTF specification (Appendix B) with the
KHR_materials_ior, KHR_materials_specular, KHR_materials_clearcoat, KHR_materials_iridescence and
KHR_materials_anisotropy extensions."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp

from .._math import cosine_hemisphere, normalize, turn_about_z
from ._base import AbstractBSDF
from ._pairs import SoAPairs
from ..microfacet import MASKING_FORMS
from ._params import (as_channels, as_param, channel_count, check_channels, check_choice, check_directions, check_range,
                      check_u)
from ..fresnel import fresnel_schlick, fresnel_thin_film
from .lambert import cosine_pdf
from .rough_conductor import RoughConductor

__all__ = ["GltfPBR"]


class GltfPBR(AbstractBSDF):
    r"""The glTF metallic-roughness BRDF (with the ior, specular, clear coat and iridescence extensions).

    The BRDF a glTF viewer renders, as a matfit model: matfit can fit it to any of its own
    models (:mod:`matfit.export`) and measure how close the glTF material comes. With
    :math:`S_\alpha = D\,G_2/(4|\cos\theta_o\cos\theta_i|)` the GGX specular lobe
    (:math:`\alpha = \text{roughness}^2`, the height-correlated Smith masking of the
    specification's visibility term), :math:`c` the base colour, :math:`h` the half vector and
    :math:`s(f_0, f_{90}) = f_0 + (f_{90} - f_0)(1 - |\omega_o\cdot h|)^5` (Schlick):

    .. math::
        f_{diel} &= (1 - \max_c F_d)\,\frac{c}{\pi} + F_d\,S_\alpha,\qquad
          F_d = s\big(\min(f_0(\eta)\,c_s, 1)\,w_s,\ w_s\big),\quad
          f_0(\eta) = \left(\frac{\eta-1}{\eta+1}\right)^2\\
        f_{metal} &= s(c, 1)\,S_\alpha\\
        f_{base} &= (1 - m)\,f_{diel} + m\,f_{metal}\\
        f &= (1 - w_c F_c)\,f_{base} + w_c F_c\,S_{\alpha_c},\qquad
          F_c = 0.04 + 0.96\,(1 - |\cos\theta_o|)^5

    (:math:`m` metallic, :math:`w_s, c_s` the specular factor and colour, :math:`w_c` the clear
    coat factor, :math:`\max_c` the largest colour channel; the coat's Fresnel reads the viewing
    angle to the coat's normal, as the clear coat extension specifies). Reflection only: zero
    when either direction is below the horizon. With iridescence (factor :math:`w_i`, a film of
    index :math:`\eta_i` and thickness :math:`d_i`) the dielectric's Fresnel becomes
    :math:`(1 - w_i) F_d + w_i F_{film}(|\omega_o\cdot h|)`, the film's reflectance on a base of
    index :math:`\eta` (:func:`~matfit.fresnel.fresnel_thin_film`: the Airy sum integrated per
    wavelength; the extension's reference shader integrates the same sum analytically, after
    Belcour & Barla 2017). The metal part keeps Schlick's Fresnel (the extension's film over a
    metal is not modelled).

    With anisotropy (KHR_materials_anisotropy, strength :math:`a`, rotation :math:`r`) the
    specular lobe is an anisotropic GGX of widths :math:`\alpha_t = \alpha + (1 - \alpha)\,a^2`
    along the direction at azimuth :math:`r` of the tangent frame and :math:`\alpha_b = \alpha`
    across it (:class:`~matfit.models.Rotated`); the coat stays isotropic.

    Sampling: a mixture of the cosine-weighted hemisphere, the specular lobe's visible normals
    and the coat lobe's, picked with probabilities proportional to ``(1 - m) / 2``,
    ``(1 + m) / 2`` and ``w_c / 2``; the pdf is the exact mixture.

    Parameters
    ----------
    base_color : array_like, scalar or (..., C); [0, 1]; differentiable
        The ``baseColorFactor`` :math:`c`, per colour channel.
    metallic : array_like, scalar or (...), default 0.0; [0, 1]; differentiable
        The ``metallicFactor`` :math:`m`.
    alpha : array_like, scalar or (...), default 0.25; > 0; differentiable
        GGX width :math:`\alpha` of the specular lobe, ``roughnessFactor**2``.
    ior : array_like, scalar or (...), default 1.5; > 0; differentiable
        Index of refraction :math:`\eta` (KHR_materials_ior).
    specular : array_like, scalar or (...), default 1.0; [0, 1]; differentiable
        Specular factor :math:`w_s` (KHR_materials_specular).
    specular_color : array_like, scalar or (..., C), default 1.0; >= 0; differentiable
        Specular colour factor :math:`c_s`, per colour channel (KHR_materials_specular).
    clearcoat : array_like, scalar or (...), default 0.0; [0, 1]; differentiable
        Clear coat factor :math:`w_c` (KHR_materials_clearcoat).
    clearcoat_alpha : array_like, scalar or (...), default 0.01; > 0; differentiable
        GGX width :math:`\alpha_c` of the coat lobe, ``clearcoatRoughnessFactor**2``.
    iridescence : array_like, scalar or (...), default 0.0; [0, 1]; differentiable
        Iridescence factor :math:`w_i` (KHR_materials_iridescence ``iridescenceFactor``).
    iridescence_ior : array_like, scalar or (...), default 1.3; >= 1; differentiable
        Index :math:`\eta_i` of the thin film (``iridescenceIor``).
    iridescence_thickness : array_like, scalar or (...), default 400.0; >= 0; differentiable
        Film thickness :math:`d_i` in nm (``iridescenceThicknessMaximum``, no thickness texture).
    anisotropy : array_like, scalar or (...), default 0.0; [0, 1]; differentiable
        Anisotropy strength :math:`a` (``anisotropyStrength``).
    anisotropy_rotation : array_like, scalar or (...), default 0.0; radians; differentiable
        Azimuth :math:`r` of the wide axis from the tangent (``anisotropyRotation``).
    masking : {"height_correlated", "separable"}, default "height_correlated"; static, not differentiable
        Smith form of both lobes; the default is the specification's visibility term
        ``V_GGX = 1 / (2 (|n.l| sqrt(a^2 + (1 - a^2)(n.v)^2) + |n.v| sqrt(a^2 + (1 - a^2)(n.l)^2)))``.

    References
    ----------
    - The Khronos Group, "glTF 2.0 Specification", Appendix B: BRDF Implementation, 2021.
    - The Khronos Group, KHR_materials_ior, KHR_materials_specular, KHR_materials_clearcoat,
      KHR_materials_iridescence extension specifications.

    Examples
    --------
    A metal's Fresnel at normal incidence is its base colour, :math:`s(c, 1) = c`:

    >>> import jax.numpy as jnp
    >>> from matfit.models import GltfPBR
    >>> up = jnp.array([0.0, 0.0, 1.0])
    >>> f = GltfPBR(jnp.array([0.8, 0.2, 0.1]), metallic=1.0, alpha=0.25).eval(up, up)
    >>> [round(float(x), 4) for x in f / f[0] * 0.8]
    [0.8, 0.2, 0.1]
    """

    base_color: jnp.ndarray = eqx.field(converter=as_channels)
    metallic: jnp.ndarray
    alpha: jnp.ndarray
    ior: jnp.ndarray
    specular: jnp.ndarray
    specular_color: jnp.ndarray = eqx.field(converter=as_channels)
    clearcoat: jnp.ndarray
    clearcoat_alpha: jnp.ndarray
    iridescence: jnp.ndarray
    iridescence_ior: jnp.ndarray
    iridescence_thickness: jnp.ndarray
    masking: str = eqx.field(static=True)
    # whether the film is evaluated at all: a static choice at construction (an iridescence
    # factor given as anything but the number 0), so that a glTF material without the extension
    # never pays for the 81-wavelength film, traced or not
    has_film: bool = eqx.field(static=True)
    anisotropy: jnp.ndarray
    anisotropy_rotation: jnp.ndarray
    # likewise: a material without KHR_materials_anisotropy evaluates the isotropic lobe alone
    has_anisotropy: bool = eqx.field(static=True)

    def __init__(self, base_color, metallic=0.0, alpha=0.25, ior=1.5, specular=1.0, specular_color=1.0, clearcoat=0.0,
                 clearcoat_alpha=0.01, masking="height_correlated", iridescence=0.0, iridescence_ior=1.3,
                 iridescence_thickness=400.0, anisotropy=0.0, anisotropy_rotation=0.0):
        check_range("GltfPBR", "base_color", base_color, 0.0, 1.0)
        check_range("GltfPBR", "metallic", metallic, 0.0, 1.0)
        check_range("GltfPBR", "alpha", alpha, 0.0, lo_open=True)
        check_range("GltfPBR", "ior", ior, 0.0, lo_open=True)
        check_range("GltfPBR", "specular", specular, 0.0, 1.0)
        check_range("GltfPBR", "specular_color", specular_color, 0.0)
        check_range("GltfPBR", "clearcoat", clearcoat, 0.0, 1.0)
        check_range("GltfPBR", "clearcoat_alpha", clearcoat_alpha, 0.0, lo_open=True)
        check_range("GltfPBR", "iridescence", iridescence, 0.0, 1.0)
        check_range("GltfPBR", "iridescence_ior", iridescence_ior, 1.0)
        check_range("GltfPBR", "iridescence_thickness", iridescence_thickness, 0.0)
        check_range("GltfPBR", "anisotropy", anisotropy, 0.0, 1.0)
        check_range("GltfPBR", "anisotropy_rotation", anisotropy_rotation)
        check_channels("GltfPBR", base_color=base_color, specular_color=specular_color)
        check_choice("GltfPBR", "masking", masking, MASKING_FORMS)
        self.base_color = base_color
        self.metallic = as_param(metallic)
        self.alpha = as_param(alpha)
        self.ior = as_param(ior)
        self.specular = as_param(specular)
        self.specular_color = specular_color
        self.clearcoat = as_param(clearcoat)
        self.clearcoat_alpha = as_param(clearcoat_alpha)
        self.has_film = not (isinstance(iridescence, (int, float)) and not isinstance(iridescence, bool)
                             and iridescence == 0)
        self.iridescence = as_param(iridescence)
        self.iridescence_ior = as_param(iridescence_ior)
        self.iridescence_thickness = as_param(iridescence_thickness)
        self.masking = masking
        self.has_anisotropy = not (isinstance(anisotropy, (int, float)) and not isinstance(anisotropy, bool)
                                   and anisotropy == 0)
        self.anisotropy = as_param(anisotropy)
        self.anisotropy_rotation = as_param(anisotropy_rotation)

    @property
    def channels(self):
        return channel_count(self.base_color, self.specular_color)

    def _lobe(self, alpha):
        # the Fresnel-free GGX lobe D G2 / (4 cos cos) and its sampler, shared with RoughConductor
        return RoughConductor(alpha, 1.0, 0.0, masking=self.masking)

    def anisotropic_widths(self):
        """``(alpha_t, alpha_b)``: the specular lobe's GGX widths along and across the anisotropy direction."""
        return self.alpha + (1 - self.alpha) * self.anisotropy ** 2, self.alpha

    def _specular(self):
        """The specular lobe and the turn ``(cos r, sin r)`` into its frame (None: isotropic)."""
        if not self.has_anisotropy:
            return self._lobe(self.alpha), None
        a_t, a_b = self.anisotropic_widths()
        lobe = RoughConductor(a_t, 1.0, 0.0, masking=self.masking, alpha_y=a_b)
        return lobe, (jnp.cos(self.anisotropy_rotation), jnp.sin(self.anisotropy_rotation))

    @staticmethod
    def _into(w, turn):
        """``w`` in the specular lobe's frame."""
        return w if turn is None else turn_about_z(w, turn[0], -turn[1])

    def eval(self, wo, wi):
        check_directions("GltfPBR.eval", wo=wo, wi=wi)
        pairs = SoAPairs.of(wo, wi)
        ok, cos_o = pairs.valid, pairs.cos_o
        vh = pairs.fresnel_angle().c[..., None]
        lobe, turn = self._specular()
        spec = lobe.reflection_lobe(pairs if turn is None else SoAPairs.of(self._into(wo, turn),
                                                                            self._into(wi, turn)))[..., None]
        c = self.base_color
        f0 = ((self.ior - 1) / (self.ior + 1)) ** 2
        ws = self.specular[..., None]
        Fd = fresnel_schlick(vh, jnp.minimum(f0[..., None] * self.specular_color, 1) * ws, ws)
        if self.has_film:
            # KHR_materials_iridescence: the dielectric's Fresnel mixed with the film's (3 channels)
            wi_ = self.iridescence[..., None]
            film = fresnel_thin_film(vh[..., 0], self.iridescence_thickness[..., None], self.iridescence_ior[..., None],
                                     self.ior[..., None])
            Fd = (1 - wi_) * Fd + wi_ * film
        # KHR_materials_specular: the diffuse part loses the largest channel of the Fresnel term
        diel = (1 - jnp.max(Fd, axis=-1, keepdims=True)) * c / jnp.pi + Fd * spec
        metal = fresnel_schlick(vh, c) * spec
        m = self.metallic[..., None]
        f = (1 - m) * diel + m * metal
        wc = self.clearcoat[..., None]
        Fc = (fresnel_schlick(cos_o, 0.04) * wc[..., 0])[..., None]
        coat = self._lobe(self.clearcoat_alpha).reflection_lobe(pairs)[..., None]
        f = (1 - Fc) * f + Fc * coat
        return jnp.where(ok[..., None], f, 0)

    def _probs(self):
        pd, ps, pc = (1 - self.metallic) / 2, (1 + self.metallic) / 2, self.clearcoat / 2
        tot = pd + ps + pc
        return pd / tot, ps / tot, pc / tot

    def pdf(self, wo, wi):
        check_directions("GltfPBR.pdf", wo=wo, wi=wi)
        pd, ps, pc = self._probs()
        lobe, turn = self._specular()
        return (pd * cosine_pdf(wo, wi) + ps * lobe.reflection_pdf(self._into(wo, turn), self._into(wi, turn))
                + pc * self._lobe(self.clearcoat_alpha).reflection_pdf(wo, wi))

    def sample(self, wo, u):
        check_directions("GltfPBR.sample", wo=wo)
        check_u("GltfPBR.sample", u, 3)
        pd, ps, _ = self._probs()
        wi_d = cosine_hemisphere(u[..., 1], u[..., 2])
        lobe, turn = self._specular()
        wi_s = lobe.reflection_sample(self._into(wo, turn), u[..., 1:3])
        if turn is not None:
            wi_s = turn_about_z(wi_s, turn[0], turn[1])
        wi_c = self._lobe(self.clearcoat_alpha).reflection_sample(wo, u[..., 1:3])
        u0 = u[..., 0][..., None]
        wi = jnp.where(u0 < pd[..., None], wi_d, jnp.where(u0 < (pd + ps)[..., None], wi_s, wi_c))
        return self._weighted(wo, normalize(wi), above=True)
