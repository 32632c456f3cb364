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
