"""The abstract microfacet distribution: D, Smith Lambda, G1, G2, and sampling."""

from __future__ import annotations

import abc

import equinox as eqx
import jax.numpy as jnp
import jax.scipy.special as jsp

from .._math import COS_EPS, as_direction, as_float, dot, flip_up, normalize, safe_div, sq

#: Roughness values below this are clamped to it inside the distributions, so that D stays
#: representable in float32 (D(n) = 1/(pi alpha^2) ~ 3e7). Below ALPHA_MIN use the smooth models.
ALPHA_MIN = 1e-4

MASKING_FORMS = ("separable", "height_correlated")


def normal_from_slopes(sx, sy):
    """Unit microfacet normal of slopes ``(sx, sy)``: ``normalize(-sx, -sy, 1)``, shape (..., 3)."""
    return normalize(jnp.stack([-sx, -sy, jnp.ones_like(sx)], axis=-1))


class AbstractDistribution(eqx.Module):
    r"""A microfacet normal distribution with Smith masking-shadowing.

    Subclasses define :meth:`D` (0 for :math:`m_z \le 0`), :meth:`Lambda` and :meth:`sample_dcos`,
    and :meth:`sample_visible` where an exact method exists. For every subclass

    .. math::
        \int D(m)\,(m\cdot n)\,d\omega_m = 1,\qquad
        G_1(v, m) = \frac{\chi^+((v\cdot m)(v\cdot n))}{1 + \Lambda(v)},\qquad
        D_v(m) = \frac{G_1(v, m)\max(0, v\cdot m)\,D(m)}{\cos\theta_v},

    where :math:`\Lambda` (0 at the normal, growing towards grazing) reads only
    :math:`\alpha^2\tan^2\theta_v = (v_x^2\alpha_x^2 + v_y^2\alpha_y^2)/v_z^2`. :math:`G_2` has two
    forms (:data:`MASKING_FORMS`): ``"separable"``, :math:`G_1(\omega_o, m)\,G_1(\omega_i, m)`;
    ``"height_correlated"``, :math:`1/(1 + \Lambda_o + \Lambda_i)` for reflection and
    :math:`B(1 + \Lambda_o, 1 + \Lambda_i)` (the Beta function) for transmission (Heitz 2014,
    Eq. 99); both times the visibility indicators. :meth:`sample_dcos` draws normals with density
    :math:`D(m)\,m_z` (:meth:`pdf_dcos`), :meth:`sample_visible` with :math:`D_{\omega_o}`
    (:meth:`pdf_visible`); a ``wo`` below the surface is mirrored to the upper side first.

    ``alpha`` is the distribution's own width, not a shared roughness: :math:`D(n) = 1/(\pi\alpha_x\alpha_y)`
    for all three (GGX, Beckmann, and Blinn-Phong through its exponent :math:`e = 2/\alpha^2 - 2`).
    Directions and normals are ``(..., 3)`` arrays, :class:`~matfit._math.Vec3` or (an isotropic
    distribution evaluating reflection pairs) :class:`~matfit._math.IsoDir`, read through
    :func:`~matfit._math.as_direction`: the same numbers for every form.

    Parameters
    ----------
    alpha_x : array_like
        Width along x, > 0; values below :data:`ALPHA_MIN` are clamped to it. Differentiable.
    alpha_y : array_like, optional
        Width along y (default: ``alpha_x``, isotropic). Differentiable.

    Attributes
    ----------
    has_visible_sampling : bool
        True when :meth:`sample_visible` exists (class attribute).

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.microfacet import GGX
    >>> d = GGX(0.3, 0.5)
    >>> n = jnp.array([0.0, 0.0, 1.0]); wo = jnp.array([0.0, 0.6, 0.8])
    >>> round(float(d.D(n) * jnp.pi * 0.3 * 0.5), 5), float(d.G1(wo, n)) < 1, float(d.G1(n, -n))
    (1.0, True, 0.0)
    >>> m = d.sample_visible(wo, jnp.array([0.3, 0.6]))        # a normal visible from wo
    >>> bool(jnp.dot(wo, m) > 0), bool(d.G2(wo, wo, n, "height_correlated") > d.G2(wo, wo, n))
    (True, True)
    """

    alpha_x: jnp.ndarray = eqx.field(converter=as_float)
    alpha_y: jnp.ndarray = eqx.field(converter=as_float)

    def __init__(self, alpha_x, alpha_y=None):
        self.alpha_x = alpha_x
        self.alpha_y = alpha_x if alpha_y is None else alpha_y

    # -- the parts a distribution defines ---------------------------------------------------
    @abc.abstractmethod
    def D(self, m):
        r"""Distribution of normals :math:`D(m)` (1/sr, per unit projected area), 0 for :math:`m_z \le 0`."""

    @abc.abstractmethod
    def Lambda(self, v):
        r"""Smith's auxiliary function :math:`\Lambda(v)` (see the class doc)."""

    @abc.abstractmethod
    def sample_dcos(self, u):
        """Sample unit normals (..., 3) with density :meth:`pdf_dcos` from uniform ``u`` (..., 2) in [0, 1)."""

    def sample_visible(self, wo, u):
        """Sample normals visible from ``wo`` with density :meth:`pdf_visible` from uniform ``u`` (..., 2).

        GGX: the spherical caps of Dupuy & Benyoub 2023; Beckmann: the visible-slope inversion of
        Heitz & d'Eon 2014; without :attr:`has_visible_sampling` (Blinn-Phong) NotImplementedError."""
        raise NotImplementedError(f"{type(self).__name__} has no visible-normal sampling; use sample_dcos")

    has_visible_sampling = False

    # -- shared machinery -------------------------------------------------------------------
    def _alphas(self):
        return jnp.maximum(self.alpha_x, ALPHA_MIN), jnp.maximum(self.alpha_y, ALPHA_MIN)

    def _slope2(self, m):
        """Stretched squared slope (mx^2/ax^2 + my^2/ay^2) / mz^2 for m_z > 0 (else inf-safe)."""
        ax, ay = self._alphas()
        mz2 = jnp.maximum(sq(m[..., 2]), COS_EPS * COS_EPS)
        return as_direction(m).tan_sq(1 / ax, 1 / ay) / mz2

    def _a2tan2(self, v):
        """Projected roughness times tan^2: (vx^2 ax^2 + vy^2 ay^2) / vz^2."""
        ax, ay = self._alphas()
        vz2 = jnp.maximum(sq(v[..., 2]), COS_EPS * COS_EPS)
        return as_direction(v).tan_sq(ax, ay) / vz2

    def _normal_from_radius(self, r, u_phi):
        """Normal of the alpha = 1 slope radius ``r`` at azimuth ``2 pi u_phi``, stretched by the alphas:
        GGX's and Beckmann's slope laws are stretch-invariant, so D cos sampling is the alpha = 1 law plus this map."""
        ax, ay = self._alphas()
        phi = 2 * jnp.pi * u_phi
        return normal_from_slopes(ax * r * jnp.cos(phi), ay * r * jnp.sin(phi))

    def _g1_ratio(self, v):
        r"""``(num, den)`` of :math:`1/(1 + \Lambda(v))`: one division for :meth:`G1` and for the separable
        :meth:`G2`; GGX overrides it with its closed form."""
        return 1.0, 1 + self.Lambda(v)

    def _D_ratio(self, m):
        """``(num, den)`` of :math:`D(m)` for :math:`m_z > 0` (``den > 0``, no indicator), so that
        :meth:`reflection_ratio` divides once; GGX overrides it with its rational form."""
        return self.D(m), 1.0

    def reflection_ratio(self, wo, wi, m, form="separable"):
        r"""``(num, den, visible)``: :math:`D(m)\,G_2(\omega_o, \omega_i, m)` = ``num / den`` where ``visible``.

        One quotient, so that an evaluator divides once and folds its guards into ``den``
        (:meth:`~matfit.models.AbstractMicrofacetBSDF.reflection_lobe`); ``den`` is finite and > 0
        wherever ``visible`` (the indicators of :math:`D` and of both maskings). Reflection only."""
        if form not in MASKING_FORMS:
            raise ValueError(f"masking form must be one of {MASKING_FORMS}, got {form!r}")
        visible = as_direction(wo).visible(m) & as_direction(wi).visible(m) & (m[..., 2] > 0)
        dn, dd = self._D_ratio(m)
        gn, gd = self._g2_reflection_ratio(wo, wi, form)
        return dn * gn, dd * gd, visible

    def _g2_reflection_ratio(self, wo, wi, form):
        r"""``(num, den)`` of the reflection :meth:`G2` without indicators: :math:`G_1 G_1` as one ratio,
        or :math:`1 / (1 + \Lambda_o + \Lambda_i)`."""
        if form == "separable":
            (no, do), (ni, di) = self._g1_ratio(wo), self._g1_ratio(wi)
            return no * ni, do * di
        return 1.0, 1 + self.Lambda(wo) + self.Lambda(wi)

    def G1(self, v, m):
        """Smith masking :math:`G_1(v, m)` in [0, 1] (the class doc)."""
        chi = as_direction(v).visible(m)
        num, den = self._g1_ratio(v)
        return jnp.where(chi, num / den, 0)

    def G2(self, wo, wi, m, form="separable"):
        """Masking-shadowing of ``wo`` and ``wi`` by normals ``m`` in a form of the class doc (else ValueError)."""
        if form not in MASKING_FORMS:
            raise ValueError(f"masking form must be one of {MASKING_FORMS}, got {form!r}")
        chi = as_direction(wo).visible(m) & as_direction(wi).visible(m)
        if form == "separable":  # G1(wo) G1(wi) as one ratio
            num, den = self._g2_reflection_ratio(wo, wi, form)
            return jnp.where(chi, num / den, 0)
        lo = self.Lambda(wo)
        li = self.Lambda(wi)
        refl = wo[..., 2] * wi[..., 2] > 0
        g_r = 1 / (1 + lo + li)
        # Beta(a, b) through log-gammas: jax's betaln is only ~1e-6 accurate in float64.
        a, b = 1 + lo, 1 + li
        g_t = jnp.exp(jsp.gammaln(a) + jsp.gammaln(b) - jsp.gammaln(a + b))
        return jnp.where(chi, jnp.where(refl, g_r, g_t), 0)

    def pdf_dcos(self, m):
        """Density of :meth:`sample_dcos` over the solid angle of ``m``: ``D(m) max(m_z, 0)``."""
        return self.D(m) * jnp.maximum(m[..., 2], 0)

    def pdf_visible(self, wo, m):
        r"""Density of :meth:`sample_visible`, :math:`D_{\omega_o}(m)` of the class doc (1/sr)."""
        w = flip_up(wo)
        wz = w[..., 2]
        return safe_div(self.G1(w, m) * jnp.maximum(dot(w, m), 0) * self.D(m), wz)
