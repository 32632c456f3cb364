"""Fresnel reflectance, written from the amplitude coefficients (never from matfit).

The reference forms use complex arithmetic: complex refractive index ``n``, complex
``cos(theta_t)`` (dielectric Fresnel is the ``k = 0`` case; total internal reflection falls out of
the complex square root, ``|r| = 1``). The ``*_real`` forms are the classic real-arithmetic
formulas (Born & Wolf 14.2, pbrt's ``FrConductor``): the fast forms of the numpy baselines, also
used to cross-check the complex ones.
"""

from __future__ import annotations

import numpy as np

from ._array import f64

__all__ = [
    "fresnel_complex",
    "fresnel_dielectric",
    "fresnel_conductor",
    "fresnel_conductor_real",
    "fresnel_dielectric_real",
    "fresnel_schlick",
    "fresnel_dielectric_average",
    "thin_film_spectrum",
    "thin_film_rgb",
]


def fresnel_complex(cos_i, n):
    """Unpolarised reflectance at an interface from a medium of index 1 to complex index n.

    ``cos_i`` is the cosine of the incidence angle (clipped to [0, 1]). Complex Snell's law:
    ``sin^2 t = sin^2 i / n^2``, ``cos t = sqrt(1 - sin^2 t)`` (principal branch),
    ``r_s = (cos i - n cos t) / (cos i + n cos t)``, ``r_p = (n cos i - cos t) / (n cos i + cos t)``.
    """
    cos_i = np.clip(f64(cos_i), 0.0, 1.0).astype(np.complex128)
    n = np.asarray(n, dtype=np.complex128)
    sin2_i = 1.0 - cos_i * cos_i
    sin2_t = sin2_i / (n * n)
    cos_t = np.sqrt(1.0 - sin2_t)
    r_s = (cos_i - n * cos_t) / (cos_i + n * cos_t)
    r_p = (n * cos_i - cos_t) / (n * cos_i + cos_t)
    return 0.5 * (np.abs(r_s) ** 2 + np.abs(r_p) ** 2)


def fresnel_dielectric(cos_i, eta):
    """Exact unpolarised dielectric reflectance; ``cos_i < 0`` means incidence from inside
    (``eta -> 1 / eta``). Exactly 1 under total internal reflection."""
    cos_i, eta = np.broadcast_arrays(f64(cos_i), f64(eta))
    inside = cos_i < 0
    eta_eff = np.where(inside, 1.0 / eta, eta)
    c = np.abs(cos_i)
    with np.errstate(all="ignore"):
        r = fresnel_complex(c, eta_eff + 0j)
    # Under TIR the complex formula gives |r_s| = |r_p| = 1 up to rounding; make it exact.
    sin2_t = (1.0 - c * c) / (eta_eff * eta_eff)
    return np.where(sin2_t >= 1.0, 1.0, np.minimum(r, 1.0))


def fresnel_conductor(cos_i, eta, k):
    """Exact conductor reflectance with complex index ``eta + i k``; ``|cos_i|`` is used."""
    c = np.abs(f64(cos_i))
    n = f64(eta) + 1j * f64(k)
    return fresnel_complex(c, n)


def fresnel_conductor_real(cos_i, eta, k):
    """Conductor reflectance in real arithmetic (pbrt-v3 ``FrConductor``); ``|cos_i|`` is used,
    clipped to [0, 1], and the result to [0, 1]."""
    c2 = np.clip(np.abs(cos_i), 0, 1) ** 2
    s2 = 1 - c2
    t0 = eta * eta - k * k - s2
    a2b2 = np.sqrt(t0 * t0 + 4 * eta * eta * k * k)
    a = np.sqrt(np.maximum(0.5 * (a2b2 + t0), 0))
    t1 = a2b2 + c2
    t2 = 2 * a * np.sqrt(c2)
    rs = (t1 - t2) / (t1 + t2)
    t3 = c2 * a2b2 + s2 * s2
    t4 = t2 * s2
    rp = rs * (t3 - t4) / (t3 + t4)
    return np.clip(0.5 * (rs + rp), 0, 1)


def fresnel_dielectric_real(cos_i, eta):
    """Dielectric reflectance in real arithmetic; ``cos_i < 0``: from inside (``1 / eta``); 1 under
    total internal reflection and at grazing incidence."""
    c = np.clip(cos_i, -1, 1)
    eta = np.where(c < 0, 1 / eta, eta)
    c = np.abs(c)
    cos2_t = (eta * eta - 1 + c * c) / (eta * eta)
    cos_t = np.sqrt(np.maximum(cos2_t, 0))
    with np.errstate(all="ignore"):
        rpa = (eta * c - cos_t) / (eta * c + cos_t)
        rpe = (c - eta * cos_t) / (c + eta * cos_t)
    return np.where((cos2_t <= 0) | (c <= 0), 1.0, 0.5 * (rpa * rpa + rpe * rpe))


def fresnel_schlick(cos_i, f0):
    """Schlick's approximation ``f0 + (1 - f0) (1 - cos_i)^5``."""
    c = f64(cos_i)
    f0 = f64(f0)
    return f0 + (1.0 - f0) * (1.0 - c) ** 5


def fresnel_dielectric_average(eta):
    """``2 int_0^1 F(mu) mu dmu`` by adaptive quadrature, split at the critical angle if eta < 1."""
    from scipy import integrate

    eta = float(eta)
    pts = None
    if eta < 1.0:
        pts = [np.sqrt(1.0 - eta * eta)]
    val, _ = integrate.quad(lambda mu: 2.0 * mu * float(fresnel_dielectric(mu, eta)), 0.0, 1.0, points=pts,
                            epsabs=1e-13, epsrel=1e-12, limit=200)
    return val


def thin_film_spectrum(cos_i, d, n_film, n_base, lam):
    """Reflectance spectrum of one film (thickness ``d`` nm, index ``n_film``) on a base
    (``n_base``, may be complex) from outside (index 1), by the characteristic matrix of the
    layer (Born & Wolf 1.6.2), not by the Airy sum: per polarization the tilted admittances
    ``y_j = n_j cos_j`` (s) or ``n_j / cos_j`` (p), the layer's matrix
    ``[[cos b, i sin b / y1], [i y1 sin b, cos b]]`` with ``b = 2 pi n1 d cos_1 / lam``,
    ``(B, C) = M (1, y2)`` and ``r = (y0 B - C) / (y0 B + C)``. Returns ``(..., L)``."""
    c0 = np.clip(np.abs(f64(cos_i)), 1e-7, 1.0)[..., None].astype(np.complex128)
    n1 = np.asarray(n_film, np.complex128)[..., None]
    n2 = np.asarray(n_base, np.complex128)[..., None]
    d = f64(d)[..., None]
    lam = f64(lam)
    s2 = 1.0 - c0 * c0
    c1 = np.sqrt(1.0 - s2 / (n1 * n1))
    c2 = np.sqrt(1.0 - s2 / (n2 * n2))
    b = 2 * np.pi * n1 * d * c1 / lam
    out = 0.0
    for y0, y1, y2 in ((c0, n1 * c1, n2 * c2), (1.0 / c0, n1 / c1, n2 / c2)):
        B = np.cos(b) + 1j * np.sin(b) / y1 * y2
        C = 1j * y1 * np.sin(b) + np.cos(b) * y2
        r = (y0 * B - C) / (y0 * B + C)
        out = out + 0.5 * np.abs(r) ** 2
    return out


def thin_film_rgb(cos_i, d, n_film, n_base):
    """``thin_film_spectrum`` at 380-780 nm every 5 nm in linear sRGB: the CIE 1931 2-degree
    observer and D65 read from ``colour``'s tables (linear interpolation), XYZ -> sRGB by the
    IEC 61966-2-1 matrix written here, each channel's weights normalized to sum to 1."""
    import colour

    lam = np.arange(380.0, 781.0, 5.0)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    d65 = colour.SDS_ILLUMINANTS["D65"]
    xyz = np.stack([np.interp(lam, cmfs.wavelengths, cmfs.values[:, i]) for i in range(3)], -1)
    xyz = xyz * np.interp(lam, d65.wavelengths, d65.values)[:, None]
    m = np.array([[3.2406, -1.5372, -0.4986], [-0.9689, 1.8758, 0.0415], [0.0557, -0.2040, 1.0570]])
    w = xyz @ m.T
    w = w / w.sum(axis=0)
    return np.clip(thin_film_spectrum(cos_i, d, n_film, n_base, lam) @ w, 0.0, 1.0)
