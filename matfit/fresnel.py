r"""Fresnel reflectance: exact dielectric, exact conductor (complex index) and Schlick.

Each formula lives here once and is used by every model.

References
----------
- M. Born, E. Wolf, *Principles of Optics*, 7th ed., Sec. 1.5.2 (dielectric) and 14.2 (metals).
- M. Pharr, W. Jakob, G. Humphreys, *Physically Based Rendering*, 4th ed. (pbrt-v4), Sec. 9.3.
- C. Schlick, "An Inexpensive BRDF Model for Physically-based Rendering", CGF 13(3), 1994.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ._math import refracted_cos2, safe_div, safe_sqrt, sq
from ._check import check_range
from .errors import ParameterError

__all__ = ["fresnel_dielectric", "fresnel_conductor", "fresnel_schlick", "fresnel_dielectric_average", "clamp_cos", "FresnelAngle"]


def fresnel_dielectric(cos_theta_i, eta):
    r"""Unpolarized Fresnel reflectance of a smooth dielectric interface.

    .. math::
        r_\parallel = \frac{\eta\cos\theta_i - \cos\theta_t}{\eta\cos\theta_i + \cos\theta_t},\quad
        r_\perp = \frac{\cos\theta_i - \eta\cos\theta_t}{\cos\theta_i + \eta\cos\theta_t},\quad
        F = \tfrac12 (r_\parallel^2 + r_\perp^2)

    with :math:`\sin\theta_t = \sin\theta_i / \eta`.

    Parameters
    ----------
    cos_theta_i : array_like
        Cosine of the incidence angle, in [-1, 1]. A negative value means the light arrives
        from inside the medium; the relative index is then inverted (``eta -> 1/eta``).
    eta : array_like
        Relative index of refraction (inside / outside), > 0. Broadcasts against ``cos_theta_i``.

    Returns
    -------
    jax.Array
        Reflectance in [0, 1]; exactly 1 under total internal reflection.

    Examples
    --------
    >>> from matfit.fresnel import fresnel_dielectric
    >>> float(fresnel_dielectric(1.0, 1.5))  # normal incidence, ((1.5-1)/(1.5+1))**2
    0.04...
    """
    check_range("fresnel_dielectric", "eta", eta, 0.0, lo_open=True)
    c = jnp.clip(jnp.asarray(cos_theta_i), -1, 1)
    eta = jnp.asarray(eta)
    inside = c < 0
    inv = 1 / eta
    # 1/eta from the (usually scalar) index, so that no division is left per direction before
    # the reflectances' own: the whole formula is then one loop (see matfit._math.per_pair)
    eta, inv = jnp.where(inside, inv, eta), jnp.where(inside, eta, inv)
    c = jnp.abs(c)
    cos2_t = refracted_cos2(c, eta, inv)
    tir = cos2_t <= 0
    grazing = c <= 0
    cos_t = safe_sqrt(cos2_t)
    den_parl = jnp.where(grazing, 1.0, eta * c + cos_t)
    den_perp = jnp.where(grazing, 1.0, c + eta * cos_t)
    r_parl = (eta * c - cos_t) / den_parl
    r_perp = (c - eta * cos_t) / den_perp
    return jnp.where(tir | grazing, 1.0, 0.5 * (sq(r_parl) + sq(r_perp)))


def clamp_cos(cos_theta):
    """``|cos_theta|`` clamped to [0, 1]: the cosine every Fresnel formula here reads.

    Parameters
    ----------
    cos_theta : array_like
        Cosines of any sign.

    Returns
    -------
    jax.Array

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.fresnel import clamp_cos
    >>> clamp_cos(jnp.array([-0.5, 1.5])).tolist()
    [0.5, 1.0]
    """
    return jnp.clip(jnp.abs(jnp.asarray(cos_theta)), 0, 1)


class FresnelAngle(NamedTuple):
    r"""The angle terms the Fresnel equations read of :math:`\cos\theta`: ``c`` =
    :math:`|\cos\theta|` clamped to [0, 1], ``cos2`` = ``c**2`` and ``sin2`` = ``1 - cos2``.

    :func:`fresnel_conductor` takes one in place of the cosine: where the angle depends only on
    the directions (:class:`matfit.fast.SoAPairs`), they are computed once for every channel
    and every parameter value instead of in each kernel.

    Attributes
    ----------
    c : jax.Array
        :math:`|\cos\theta|` clamped to [0, 1].
    cos2 : jax.Array
        ``c**2``.
    sin2 : jax.Array
        ``1 - cos2``.

    Examples
    --------
    >>> from matfit.fresnel import FresnelAngle, fresnel_conductor
    >>> import jax.numpy as jnp
    >>> ang = FresnelAngle.of(jnp.array([0.5]))
    >>> float(ang.sin2[0])
    0.75
    >>> eta, k = jnp.array([0.2]), jnp.array([3.6])
    >>> bool(jnp.allclose(fresnel_conductor(ang, eta, k), fresnel_conductor(jnp.array([0.5]), eta, k)))
    True
    """

    c: jax.Array
    cos2: jax.Array
    sin2: jax.Array

    @classmethod
    def of(cls, cos_theta) -> "FresnelAngle":
        """The terms of the cosine(s) ``cos_theta`` (any sign; its absolute value is used).

        Parameters
        ----------
        cos_theta : array_like
            Cosines.

        Returns
        -------
        FresnelAngle

        Examples
        --------
        >>> from matfit.fresnel import FresnelAngle
        >>> float(FresnelAngle.of(-0.5).cos2)
        0.25
        """
        return cls.of_clamped(clamp_cos(cos_theta))

    @classmethod
    def of_clamped(cls, c) -> "FresnelAngle":
        """The terms of ``c`` = :func:`clamp_cos` of a cosine (stored once per pair: the two
        products are cheaper to redo than to read from memory for a million pairs).

        Parameters
        ----------
        c : array_like
            A clamped cosine, in [0, 1].

        Returns
        -------
        FresnelAngle

        Examples
        --------
        >>> from matfit.fresnel import FresnelAngle
        >>> float(FresnelAngle.of_clamped(0.5).sin2)
        0.75
        """
        cos2 = c * c
        return cls(c, cos2, 1 - cos2)

    def expand(self) -> "FresnelAngle":
        """The terms with a trailing axis of length 1 (to broadcast against channels).

        Returns
        -------
        FresnelAngle
            Each term of shape ``(..., 1)``.

        Examples
        --------
        >>> import jax.numpy as jnp
        >>> from matfit.fresnel import FresnelAngle
        >>> FresnelAngle.of(jnp.array([0.5, 0.8])).expand().c.shape
        (2, 1)
        """
        return FresnelAngle(*(x[..., None] for x in self))


def fresnel_conductor(cos_theta_i, eta, k):
    r"""Unpolarized Fresnel reflectance of a conductor with complex index :math:`\eta + i k`.

    Written in real arithmetic (Born & Wolf 14.2):
    :math:`a^2+b^2 = \sqrt{(\eta^2-k^2-\sin^2\theta)^2 + 4\eta^2k^2}`,
    :math:`a = \sqrt{(a^2+b^2+\eta^2-k^2-\sin^2\theta)/2}`,

    .. math::
        R_s = \frac{a^2+b^2 - 2a\cos\theta + \cos^2\theta}{a^2+b^2 + 2a\cos\theta + \cos^2\theta},\quad
        R_p = R_s\,\frac{\cos^2\theta(a^2+b^2) - 2a\cos\theta\sin^2\theta + \sin^4\theta}
                       {\cos^2\theta(a^2+b^2) + 2a\cos\theta\sin^2\theta + \sin^4\theta}

    and :math:`F = (R_s + R_p)/2`.

    Parameters
    ----------
    cos_theta_i : array_like or FresnelAngle
        Cosine of the incidence angle; its absolute value is used. Or its precomputed
        :class:`FresnelAngle` terms.
    eta, k : array_like
        Real and imaginary parts of the relative complex index (per channel, last axis),
        ``eta > 0``, ``k >= 0``. With ``k = 0`` this equals :func:`fresnel_dielectric`.

    Returns
    -------
    jax.Array
        Reflectance in [0, 1], broadcast over the arguments.

    Examples
    --------
    >>> from matfit.fresnel import fresnel_conductor
    >>> import jax.numpy as jnp
    >>> gold = fresnel_conductor(1.0, jnp.array([0.143, 0.374, 1.442]), jnp.array([3.983, 2.385, 1.603]))
    >>> gold.shape, bool(gold[0] > gold[2])  # reflects red more than blue
    ((3,), True)
    """
    check_range("fresnel_conductor", "eta", eta, 0.0, lo_open=True)
    check_range("fresnel_conductor", "k", k, 0.0)
    c, cos2, sin2 = cos_theta_i if isinstance(cos_theta_i, FresnelAngle) else FresnelAngle.of(cos_theta_i)
    eta = jnp.asarray(eta)
    k = jnp.asarray(k)
    fi = jnp.finfo(jnp.result_type(c, eta, k))
    # eta and k clamped at max^(1/4) / 4 of the dtype (float32: 1.07e9, where F is 1 to float32
    # precision), so that t0^2 and the products below stay finite.
    lim = float(fi.max) ** 0.25 / 4
    eta, k = jnp.minimum(eta, lim), jnp.minimum(k, lim)
    # eta^2 - k^2 - sin^2 written as t0 = (eta^2 - k^2 - 1) + cos^2: exact for an index-matched
    # surface (eta = 1, k = 0, where F must be exactly 0) and without cancellation near it.
    t0 = (sq(eta) - sq(k) - 1) + cos2
    # a^2 + b^2 = hypot(t0, u), u = 2 eta k, as sqrt(t0^2 + u^2): no division (a scaled hypot
    # divides twice per direction). Where t0^2 + u^2 is below the
    # smallest normal number (|t0| and |u| both < 1.1e-19 in float32) it is max(|t0|, |u|):
    # exact for u = 0, which keeps an index-matched surface at F = 0 at every angle.
    u = 2 * eta * k
    s2 = sq(t0) + sq(u)
    normal = s2 >= fi.tiny
    a2b2 = jnp.where(normal, jnp.sqrt(jnp.where(normal, s2, 1)), jnp.maximum(jnp.abs(t0), jnp.abs(u)))
    a = safe_sqrt(0.5 * (a2b2 + t0))
    t1 = a2b2 + cos2
    t2 = 2 * a * c
    t3 = cos2 * a2b2 + sq(sin2)
    t4 = t2 * sin2
    # F = (R_s + R_p) / 2 = R_s (1 + (t3 - t4) / (t3 + t4)) / 2 = R_s t3 / (t3 + t4): one division.
    # The denominator is 0 only at grazing incidence on an index-matched surface, where F = 1.
    F = safe_div((t1 - t2) * t3, (t1 + t2) * (t3 + t4), 1.0)
    # Rounding can leave R a few ulps below 0 near eta = 1, k = 0 (float32): clamp to [0, 1].
    return jnp.clip(F, 0.0, 1.0)


def fresnel_schlick(cos_theta_i, f0, f90=1.0):
    r"""Schlick's approximation :math:`F_0 + (F_{90} - F_0)(1 - \cos\theta)^5`.

    Parameters
    ----------
    cos_theta_i : array_like
        Cosine of the incidence angle; its absolute value is used (:func:`clamp_cos`).
    f0 : array_like
        Reflectance at normal incidence, in [0, 1].
    f90 : array_like, optional
        Reflectance at grazing incidence (default 1; the glTF specular extension scales it).

    Returns
    -------
    jax.Array
        The reflectance, broadcast over the arguments.

    References
    ----------
    - C. Schlick, "An Inexpensive BRDF Model for Physically-based Rendering", CGF 13(3), 1994.

    Examples
    --------
    >>> from matfit.fresnel import fresnel_schlick
    >>> float(fresnel_schlick(0.0, 0.04)), round(float(fresnel_schlick(1.0, 0.04)), 6)
    (1.0, 0.04)
    """
    m = 1 - clamp_cos(cos_theta_i)
    m2 = m * m
    return f0 + (f90 - f0) * (m2 * m2 * m)


def fresnel_dielectric_average(eta, n=64):
    r"""Hemispherical (cosine-weighted) average :math:`2\int_0^1 F(\mu)\,\mu\,d\mu`.

    Computed by Gauss-Legendre quadrature of order ``n`` for ``eta >= 1``; for ``eta < 1``
    (total internal reflection) through the exact energy balance
    :math:`\bar F(\eta) = 1 - \eta^2 (1 - \bar F(1/\eta))`, which avoids the kink at the
    critical angle.

    Parameters
    ----------
    eta : array_like
        Relative index (inside / outside) seen by the incident light.
    n : int
        Quadrature order.

    Returns
    -------
    jax.Array
        The average, of the shape of ``eta``.

    Examples
    --------
    >>> from matfit.fresnel import fresnel_dielectric_average
    >>> round(float(fresnel_dielectric_average(1.5)), 4)
    0.0918
    """
    check_range("fresnel_dielectric_average", "eta", eta, 0.0, lo_open=True)
    if not (isinstance(n, (int, np.integer)) and n > 0):
        raise ParameterError(f"fresnel_dielectric_average: n must be a positive integer, got {n!r}")
    eta = jnp.asarray(eta)
    x, w = np.polynomial.legendre.leggauss(n)
    x = jnp.asarray(0.5 * (x + 1), dtype=jnp.result_type(eta, float))
    w = jnp.asarray(0.5 * w, dtype=x.dtype)
    # Integrate from the denser side's complement: for eta < 1 use the exact balance
    # F_avg(eta) = 1 - eta^2 (1 - F_avg(1/eta)), whose integrand has no kink.
    inv = eta < 1
    e = jnp.where(inv, 1 / eta, eta)
    f = fresnel_dielectric(x, e[..., None])
    avg = 2 * jnp.sum(w * f * x, axis=-1)
    return jnp.where(inv, 1 - sq(eta) * (1 - avg), avg)
