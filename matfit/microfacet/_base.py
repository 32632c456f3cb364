"""The abstract microfacet distribution: D, Smith Lambda, G1, G2, and sampling."""

from __future__ import annotations

import abc

import equinox as eqx
import jax.numpy as jnp
import jax.scipy.special as jsp

from .._math import COS_EPS, IsoDir, dot, flip_up, normalize, safe_div, sq, tan_sq

#: Roughness values below this are clamped to it inside the distributions, so that D stays
#: representable in float32 (D(n) = 1/(pi alpha^2) ~ 3e7). Below ALPHA_MIN use the smooth models.
ALPHA_MIN = 1e-4

MASKING_FORMS = ("separable", "height_correlated")


def normal_from_slopes(sx, sy):
    """Unit microfacet normal of slopes (sx, sy): normalize(-sx, -sy, 1)."""
    return normalize(jnp.stack([-sx, -sy, jnp.ones_like(sx)], axis=-1))


def _as_alpha(a):
    a = jnp.asarray(a)
    if not jnp.issubdtype(a.dtype, jnp.floating):
        a = a.astype(jnp.result_type(float))
    return a


class AbstractDistribution(eqx.Module):
    r"""A microfacet normal distribution with Smith masking-shadowing.

    Subclasses define :meth:`D`, :meth:`Lambda` and :meth:`sample_dcos` (and
    :meth:`sample_visible` where an exact method exists). The projected-area normalization
    :math:`\int D(m)\,(m\cdot n)\,d\omega_m = 1` holds for every subclass.

    Attributes
    ----------
    alpha_x, alpha_y : jax.Array
        The distribution's own width along x and y (equal when isotropic), > 0; values below
        :data:`ALPHA_MIN` are clamped to it.
    """

    alpha_x: jnp.ndarray = eqx.field(converter=_as_alpha)
    alpha_y: jnp.ndarray = eqx.field(converter=_as_alpha)

    def __init__(self, alpha_x, alpha_y=None):
        self.alpha_x = alpha_x
        self.alpha_y = alpha_x if alpha_y is None else alpha_y

    # -- the parts a distribution defines ---------------------------------------------------
    @abc.abstractmethod
    def D(self, m):
        """Distribution of normals ``m`` (..., 3) -> (...); 0 for ``m_z <= 0``."""

    @abc.abstractmethod
    def Lambda(self, v):
        """Smith's auxiliary function Lambda(v) for a direction ``v`` (..., 3) -> (...)."""

    @abc.abstractmethod
    def sample_dcos(self, u):
        """Sample ``m`` with density ``D(m) m_z``; ``u`` (..., 2) -> ``m`` (..., 3)."""

    def sample_visible(self, wo, u):
        """Sample ``m`` from the distribution of normals visible from ``wo``."""
        raise NotImplementedError(f"{type(self).__name__} has no visible-normal sampling; use sample_dcos")

    has_visible_sampling = False

    # -- shared machinery -------------------------------------------------------------------
    def _alphas(self):
        return jnp.maximum(self.alpha_x, ALPHA_MIN), jnp.maximum(self.alpha_y, ALPHA_MIN)

    def _slope2(self, m):
        """Stretched squared slope (mx^2/ax^2 + my^2/ay^2) / mz^2 for m_z > 0 (else inf-safe)."""
        ax, ay = self._alphas()
        mz2 = jnp.maximum(sq(m[..., 2]), COS_EPS * COS_EPS)
        return tan_sq(m, 1 / ax, 1 / ay) / mz2

    def _a2tan2(self, v):
        """Projected roughness times tan^2: (vx^2 ax^2 + vy^2 ay^2) / vz^2."""
        ax, ay = self._alphas()
        vz2 = jnp.maximum(sq(v[..., 2]), COS_EPS * COS_EPS)
        return tan_sq(v, ax, ay) / vz2

    def _normal_from_radius(self, r, u_phi):
        """Microfacet normal for the alpha = 1 slope radius ``r`` at azimuth ``2 pi u_phi``,
        stretched by (alpha_x, alpha_y): the slope distributions of GGX and Beckmann are
        stretch-invariant, so D cos sampling is the alpha = 1 radius law plus this map."""
        ax, ay = self._alphas()
        phi = 2 * jnp.pi * u_phi
        return normal_from_slopes(ax * r * jnp.cos(phi), ay * r * jnp.sin(phi))

    def _g1_ratio(self, v):
        r"""``(num, den)`` with :math:`1 / (1 + \Lambda(v))` = ``num / den``: one division for
        :meth:`G1`, and one for both factors of the separable :meth:`G2`. A distribution with a
        closed form of its own (GGX) overrides it."""
        return 1.0, 1 + self.Lambda(v)

    def _D_ratio(self, m):
        r"""``(num, den)`` with :math:`D(m)` = ``num / den`` for :math:`m_z > 0` (``den > 0``, no
        indicator): lets :meth:`reflection_ratio` fold :math:`D` and :math:`G_2` into one
        division. A distribution with a rational closed form (GGX) overrides it."""
        return self.D(m), 1.0

    def reflection_ratio(self, wo, wi, m, form="separable"):
        r"""``(num, den, visible)``: :math:`D(m)\,G_2(\omega_o, \omega_i, m)` = ``num / den`` where
        ``visible`` (the indicators of :math:`D` and of Smith's masking), else 0.

        The product written as one quotient, so that an evaluator divides once (and can fold
        its own guards into ``den``: :class:`~matfit.models.RoughConductor`). ``den`` is finite
        and ``> 0`` wherever ``visible``; reflection only (``wo``, ``wi`` above the surface).

        Examples
        --------
        >>> import jax.numpy as jnp
        >>> from matfit.microfacet import GGX
        >>> d = GGX(0.3)
        >>> wo = jnp.array([0.0, 0.6, 0.8]); wi = jnp.array([0.6, 0.0, 0.8])
        >>> m = (wo + wi) / jnp.linalg.norm(wo + wi)
        >>> num, den, vis = d.reflection_ratio(wo, wi, m)
        >>> bool(jnp.isclose(num / den, d.D(m) * d.G2(wo, wi, m)))
        True
        """
        if form not in MASKING_FORMS:
            raise ValueError(f"masking form must be one of {MASKING_FORMS}, got {form!r}")
        visible = self._visible(wo, m) & self._visible(wi, m) & (m[..., 2] > 0)
        dn, dd = self._D_ratio(m)
        gn, gd = self._g2_reflection_ratio(wo, wi, form)
        return dn * gn, dd * gd, visible

    def _g2_reflection_ratio(self, wo, wi, form):
        r"""``(num, den)`` with :meth:`G2` for reflection = ``num / den`` where both directions
        are visible (without the indicators): :math:`G_1 G_1` as one ratio, or
        :math:`1 / (1 + \Lambda_o + \Lambda_i)`."""
        if form == "separable":
            (no, do), (ni, di) = self._g1_ratio(wo), self._g1_ratio(wi)
            return no * ni, do * di
        return 1.0, 1 + self.Lambda(wo) + self.Lambda(wi)

    @staticmethod
    def _visible(v, m):
        r"""The local visibility indicator :math:`\chi^+((v\cdot m)(v\cdot n))` of Smith's masking
        (for an :class:`~matfit._math.IsoDir`, :math:`v_z > 0`: ``m`` is then its reflection
        half vector, so :math:`v\cdot m > 0`)."""
        if isinstance(v, IsoDir):
            return v.z > 0
        return dot(v, m) * v[..., 2] > 0

    def G1(self, v, m):
        r"""Smith masking :math:`\chi^+((v\cdot m)/(v\cdot n)) / (1 + \Lambda(v))`."""
        chi = self._visible(v, m)
        num, den = self._g1_ratio(v)
        return jnp.where(chi, num / den, 0)

    def G2(self, wo, wi, m, form="separable"):
        r"""Masking-shadowing of ``wo`` and ``wi`` by microfacets of normal ``m``.

        ``form="separable"``: :math:`G_1(\omega_o, m)\,G_1(\omega_i, m)` (Smith product).
        ``form="height_correlated"``: :math:`1/(1 + \Lambda_o + \Lambda_i)` for reflection and
        :math:`B(1 + \Lambda_o, 1 + \Lambda_i)` (the Beta function) for transmission
        (Heitz 2014, Eq. 99), both times the visibility indicators.
        """
        if form not in MASKING_FORMS:
            raise ValueError(f"masking form must be one of {MASKING_FORMS}, got {form!r}")
        chi = self._visible(wo, m) & self._visible(wi, m)
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
        """Density of :meth:`sample_dcos` over solid angle of ``m``: ``D(m) m_z``."""
        return self.D(m) * jnp.maximum(m[..., 2], 0)

    def pdf_visible(self, wo, m):
        r"""Density of visible normals :math:`G_1(\omega_o, m)\max(0, \omega_o\cdot m) D(m)/\cos\theta_o`.

        ``wo`` below the surface is mirrored to the upper side first (as in sampling).
        """
        w = flip_up(wo)
        wz = w[..., 2]
        return safe_div(self.G1(w, m) * jnp.maximum(dot(w, m), 0) * self.D(m), wz)
