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
    """Unit microfacet normal of slopes ``(sx, sy)``: ``normalize(-sx, -sy, 1)``.

    Parameters
    ----------
    sx, sy : array_like
        Slopes along x and y.

    Returns
    -------
    jax.Array, shape (..., 3)

    Examples
    --------
    >>> from matfit.microfacet._base import normal_from_slopes
    >>> import numpy as np
    >>> (np.asarray(normal_from_slopes(0.75, 0.0), float).round(6) + 0.0).tolist()
    [-0.6, 0.0, 0.8]
    """
    return normalize(jnp.stack([-sx, -sy, jnp.ones_like(sx)], axis=-1))


class AbstractDistribution(eqx.Module):
    r"""A microfacet normal distribution with Smith masking-shadowing.

    Subclasses define :meth:`D`, :meth:`Lambda` and :meth:`sample_dcos` (and
    :meth:`sample_visible` where an exact method exists). The projected-area normalization
    :math:`\int D(m)\,(m\cdot n)\,d\omega_m = 1` holds for every subclass.

    Directions and normals are ``(..., 3)`` arrays, :class:`~matfit._math.Vec3` or (for an
    isotropic distribution evaluating reflection pairs) :class:`~matfit._math.IsoDir`; the
    methods read them through :func:`~matfit._math.as_direction` and give the same numbers for
    every form.

    Parameters
    ----------
    alpha_x : array_like
        The distribution's own width along x, > 0; values below :data:`ALPHA_MIN` are clamped
        to it. Differentiable.
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
    >>> round(float(d.alpha_x), 6), float(d.alpha_y)
    (0.3, 0.5)
    """

    alpha_x: jnp.ndarray = eqx.field(converter=as_float)
    alpha_y: jnp.ndarray = eqx.field(converter=as_float)

    def __init__(self, alpha_x, alpha_y=None):
        self.alpha_x = alpha_x
        self.alpha_y = alpha_x if alpha_y is None else alpha_y

    # -- the parts a distribution defines ---------------------------------------------------
    @abc.abstractmethod
    def D(self, m):
        r"""Distribution of normals :math:`D(m)`, 0 for :math:`m_z \le 0`.

        Parameters
        ----------
        m : array_like, shape (..., 3), Vec3 or IsoDir
            Unit microfacet normals.

        Returns
        -------
        jax.Array, shape (...)
            Density per unit projected area and solid angle (1/sr).

        Examples
        --------
        >>> import jax.numpy as jnp
        >>> from matfit.microfacet import GGX
        >>> round(float(GGX(0.5).D(jnp.array([0.0, 0.0, 1.0])) * jnp.pi * 0.25), 5)  # 1 / (pi alpha^2) at the normal
        1.0
        """

    @abc.abstractmethod
    def Lambda(self, v):
        r"""Smith's auxiliary function :math:`\Lambda(v)` (0 at the normal, growing towards grazing).

        Parameters
        ----------
        v : array_like, shape (..., 3), Vec3 or IsoDir
            Unit directions; only :math:`\alpha^2\tan^2\theta_v` is read.

        Returns
        -------
        jax.Array, shape (...)

        Examples
        --------
        >>> import jax.numpy as jnp
        >>> from matfit.microfacet import Beckmann
        >>> float(Beckmann(0.3).Lambda(jnp.array([0.0, 0.0, 1.0])))
        0.0
        """

    @abc.abstractmethod
    def sample_dcos(self, u):
        r"""Sample normals with density :math:`D(m)\,m_z` (:meth:`pdf_dcos`).

        Parameters
        ----------
        u : array_like, shape (..., 2)
            Uniform numbers in [0, 1).

        Returns
        -------
        jax.Array, shape (..., 3)
            Unit normals in the upper hemisphere.

        Examples
        --------
        >>> import jax.numpy as jnp
        >>> from matfit.microfacet import BlinnPhong
        >>> m = BlinnPhong(0.3).sample_dcos(jnp.array([[0.2, 0.7], [0.9, 0.1]]))
        >>> m.shape, bool(jnp.all(m[:, 2] > 0)), bool(jnp.allclose(jnp.linalg.norm(m, axis=-1), 1))
        ((2, 3), True, True)
        """

    def sample_visible(self, wo, u):
        r"""Sample normals from the distribution of normals visible from ``wo``,
        :math:`G_1(\omega_o, m)\max(0, \omega_o\cdot m)\,D(m)/\cos\theta_o` (:meth:`pdf_visible`).

        ``wo`` below the surface is mirrored to the upper side first. Only where
        :attr:`has_visible_sampling` (GGX: the spherical caps of Dupuy & Benyoub 2023; Beckmann:
        the visible-slope inversion of Heitz & d'Eon 2014); other distributions raise.

        Parameters
        ----------
        wo : array_like, shape (..., 3)
            Unit viewing directions.
        u : array_like, shape (..., 2)
            Uniform numbers in [0, 1).

        Returns
        -------
        jax.Array, shape (..., 3)
            Unit normals in the upper hemisphere.

        Raises
        ------
        NotImplementedError
            For a distribution without visible-normal sampling (Blinn-Phong).

        Examples
        --------
        >>> import jax.numpy as jnp
        >>> from matfit.microfacet import GGX
        >>> wo = jnp.array([0.6, 0.0, 0.8])
        >>> m = GGX(0.3).sample_visible(wo, jnp.array([0.3, 0.6]))
        >>> bool(jnp.dot(wo, m) > 0), round(float(jnp.linalg.norm(m)), 5)
        (True, 1.0)
        """
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
        its own guards into ``den``: :meth:`~matfit.models.AbstractMicrofacetBSDF.reflection_lobe`).
        ``den`` is finite and ``> 0`` wherever ``visible``; reflection only (``wo``, ``wi`` above
        the surface).

        Parameters
        ----------
        wo, wi : array_like, shape (..., 3), Vec3 or IsoDir
            Unit directions above the surface.
        m : array_like, shape (..., 3), Vec3 or IsoDir
            Their half vector (unit).
        form : {"separable", "height_correlated"}, optional
            Smith masking form (see :meth:`G2`).

        Returns
        -------
        num, den : jax.Array, shape (...)
            :math:`D G_2` = ``num / den`` where ``visible``.
        visible : jax.Array of bool, shape (...)
            The indicators of :math:`D` and of the masking of both directions.

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
        visible = as_direction(wo).visible(m) & as_direction(wi).visible(m) & (m[..., 2] > 0)
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

    def G1(self, v, m):
        r"""Smith masking :math:`\chi^+((v\cdot m)(v\cdot n)) / (1 + \Lambda(v))`.

        Parameters
        ----------
        v : array_like, shape (..., 3), Vec3 or IsoDir
            Unit directions.
        m : array_like, shape (..., 3), Vec3 or IsoDir
            Unit microfacet normals.

        Returns
        -------
        jax.Array, shape (...)
            In [0, 1]; 1 at the normal.

        Examples
        --------
        >>> import jax.numpy as jnp
        >>> from matfit.microfacet import GGX
        >>> n = jnp.array([0.0, 0.0, 1.0])
        >>> float(GGX(0.3).G1(n, n)), float(GGX(0.3).G1(n, -n))
        (1.0, 0.0)
        """
        chi = as_direction(v).visible(m)
        num, den = self._g1_ratio(v)
        return jnp.where(chi, num / den, 0)

    def G2(self, wo, wi, m, form="separable"):
        r"""Masking-shadowing of ``wo`` and ``wi`` by microfacets of normal ``m``.

        ``form="separable"``: :math:`G_1(\omega_o, m)\,G_1(\omega_i, m)` (Smith product).
        ``form="height_correlated"``: :math:`1/(1 + \Lambda_o + \Lambda_i)` for reflection and
        :math:`B(1 + \Lambda_o, 1 + \Lambda_i)` (the Beta function) for transmission
        (Heitz 2014, Eq. 99), both times the visibility indicators.

        Parameters
        ----------
        wo, wi : array_like, shape (..., 3), Vec3 or IsoDir
            Unit directions (on either side for transmission).
        m : array_like, shape (..., 3), Vec3 or IsoDir
            Unit microfacet normals.
        form : {"separable", "height_correlated"}, optional
            Smith masking form (default ``"separable"``).

        Returns
        -------
        jax.Array, shape (...)
            In [0, 1].

        Raises
        ------
        ValueError
            For an unknown ``form``.

        Examples
        --------
        >>> import jax.numpy as jnp
        >>> from matfit.microfacet import GGX
        >>> wo = jnp.array([0.0, 0.6, 0.8]); m = jnp.array([0.0, 0.0, 1.0])
        >>> d = GGX(0.3)
        >>> bool(jnp.isclose(d.G2(wo, wo, m), d.G1(wo, m) ** 2)), bool(d.G2(wo, wo, m, "height_correlated") > d.G2(wo, wo, m))
        (True, True)
        """
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
        """Density of :meth:`sample_dcos` over the solid angle of ``m``: ``D(m) max(m_z, 0)``.

        Parameters
        ----------
        m : array_like, shape (..., 3)
            Unit normals.

        Returns
        -------
        jax.Array, shape (...)

        Examples
        --------
        >>> import jax.numpy as jnp
        >>> from matfit.microfacet import GGX
        >>> m = jnp.array([0.0, 0.6, 0.8])
        >>> bool(jnp.isclose(GGX(0.3).pdf_dcos(m), GGX(0.3).D(m) * 0.8))
        True
        """
        return self.D(m) * jnp.maximum(m[..., 2], 0)

    def pdf_visible(self, wo, m):
        r"""Density of visible normals :math:`G_1(\omega_o, m)\max(0, \omega_o\cdot m) D(m)/\cos\theta_o`.

        ``wo`` below the surface is mirrored to the upper side first (as in sampling).

        Parameters
        ----------
        wo : array_like, shape (..., 3)
            Unit viewing directions.
        m : array_like, shape (..., 3)
            Unit normals.

        Returns
        -------
        jax.Array, shape (...)
            Density over the solid angle of ``m`` (1/sr).

        Examples
        --------
        >>> import jax.numpy as jnp
        >>> from matfit.microfacet import GGX
        >>> n = jnp.array([0.0, 0.0, 1.0])
        >>> bool(jnp.isclose(GGX(0.3).pdf_visible(n, n), GGX(0.3).D(n)))  # at normal incidence: D(m) m_z
        True
        """
        w = flip_up(wo)
        wz = w[..., 2]
        return safe_div(self.G1(w, m) * jnp.maximum(dot(w, m), 0) * self.D(m), wz)
