"""Microfacet distributions, written from the formulas (never from matfit).

* :class:`Dist` -- the reference: D and Lambda in spherical form (cos/tan theta, cos^2/sin^2 phi,
  projected alpha(phi)); GGX Lambda in the cancellation-free form ``t / (2 (1 + sqrt(1 + t)))``;
  Beckmann Lambda through the scaled complementary error function (erfcx) and an asymptotic
  series for large c, accurate to a few ulp in relative terms even where Lambda is tiny.
* :class:`GGXCartesian` -- GGX in Cartesian components (``D = 1 / (pi ax ay q^2)``,
  ``q = m_x^2 / ax^2 + m_y^2 / ay^2 + m_z^2``), optionally with the fitting code's horizon
  threshold in Lambda: the fast form of the numpy baselines.

Both have ``D(m)``, ``Lambda(v)``, ``G1(v, m)`` and ``G2(wo, wi, m, form)``, float64, broadcast
numpy-style.
"""

from __future__ import annotations

import numpy as np
from scipy import special

from ._array import dot, f64

__all__ = ["Dist", "GGXCartesian"]

_SQRT_PI = np.sqrt(np.pi)


def _trig(v):
    """cos^2 theta, tan^2 theta, cos^2 phi, sin^2 phi of (unnormalised) v (phi = 0 at the pole)."""
    v = f64(v)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    s2 = x * x + y * y
    c2 = z * z
    with np.errstate(all="ignore"):
        tan2 = s2 / c2
        cos2phi = np.where(s2 > 0, x * x / np.where(s2 > 0, s2, 1.0), 1.0)
        sin2phi = np.where(s2 > 0, y * y / np.where(s2 > 0, s2, 1.0), 0.0)
    return c2, tan2, cos2phi, sin2phi


def _beckmann_lambda_of_c(c):
    """Lambda(c) = (erf(c)-1)/2 + exp(-c^2)/(2 c sqrt(pi)), evaluated without cancellation."""
    c = f64(c)
    out = np.zeros_like(c)
    with np.errstate(all="ignore"):
        # c == 0 -> +inf (grazing); c == inf -> 0 (along the normal)
        out = np.where(c == 0, np.inf, out)
        mid = (c > 0) & (c < 6.0)
        cm = np.where(mid, c, 1.0)
        # Lambda = exp(-c^2)/2 * (1/(c sqrt(pi)) - erfcx(c))
        val_mid = 0.5 * np.exp(-cm * cm) * (1.0 / (cm * _SQRT_PI) - special.erfcx(cm))
        out = np.where(mid, val_mid, out)
        big = (c >= 6.0) & np.isfinite(c)
        cb = np.where(big, c, 10.0)
        x = 1.0 / (2.0 * cb * cb)
        # 1/(c sqrt pi) - erfcx(c) = 1/(c sqrt pi) * sum_{n>=1} (-1)^(n+1) (2n-1)!! x^n
        s = np.zeros_like(cb)
        term = np.ones_like(cb)
        for n in range(1, 16):
            term = term * (2 * n - 1) * x
            s = s + (term if n % 2 == 1 else -term)
        val_big = 0.5 * np.exp(-cb * cb) * s / (cb * _SQRT_PI)
        out = np.where(big, val_big, out)
    return out


class _Masking:
    """G1 and G2 from ``Lambda`` (shared by the distributions below)."""

    def G1(self, v, m):
        v = f64(v)
        chi = (dot(v, m) * v[..., 2]) > 0
        with np.errstate(all="ignore"):
            g = 1.0 / (1.0 + self.Lambda(v))
        return np.where(chi, g, 0.0)

    def G2(self, wo, wi, m, form="separable"):
        wo, wi = f64(wo), f64(wi)
        if form == "separable":
            return self.G1(wo, m) * self.G1(wi, m)
        assert form == "height_correlated", form
        chi = ((dot(wo, m) * wo[..., 2]) > 0) & ((dot(wi, m) * wi[..., 2]) > 0)
        lo, li = self.Lambda(wo), self.Lambda(wi)
        refl = wo[..., 2] * wi[..., 2] > 0
        with np.errstate(all="ignore"):
            g_r = 1.0 / (1.0 + lo + li)
            g_t = np.exp(special.betaln(1.0 + lo, 1.0 + li))
        g = np.where(refl, g_r, g_t)
        return np.where(chi & np.isfinite(lo) & np.isfinite(li), g, 0.0)


class Dist(_Masking):
    """Reference microfacet distribution: kind in {"ggx", "beckmann", "blinn_phong"}."""

    def __init__(self, kind, alpha_x, alpha_y=None):
        assert kind in ("ggx", "beckmann", "blinn_phong"), kind
        self.kind = kind
        self.ax = float(alpha_x)
        self.ay = float(alpha_x if alpha_y is None else alpha_y)

    # Blinn-Phong exponents (Ashikhmin-Shirley): alpha = sqrt(2/(e+2))
    @property
    def exponent(self):
        return 2.0 / self.ax**2 - 2.0, 2.0 / self.ay**2 - 2.0

    def D(self, m):
        m = f64(m)
        mz = m[..., 2]
        c2, tan2, cos2phi, sin2phi = _trig(m)
        ax, ay = self.ax, self.ay
        with np.errstate(all="ignore"):
            if self.kind == "ggx":
                e = tan2 * (cos2phi / ax**2 + sin2phi / ay**2)
                d = 1.0 / (np.pi * ax * ay * c2 * c2 * (1.0 + e) ** 2)
            elif self.kind == "beckmann":
                e = tan2 * (cos2phi / ax**2 + sin2phi / ay**2)
                d = np.exp(-e) / (np.pi * ax * ay * c2 * c2)
            else:
                ex, ey = self.exponent
                expo = ex * cos2phi + ey * sin2phi
                d = np.sqrt((ex + 2.0) * (ey + 2.0)) / (2.0 * np.pi) * np.power(np.where(mz > 0, mz, 1.0), expo)
        return np.where(mz > 0, d, 0.0)

    def alpha2_tan2(self, v):
        """Projected roughness alpha(phi)^2 tan^2 theta."""
        c2, tan2, cos2phi, sin2phi = _trig(v)
        a2 = cos2phi * self.ax**2 + sin2phi * self.ay**2
        with np.errstate(all="ignore"):
            return np.where(tan2 == 0, 0.0, tan2 * a2)

    def Lambda(self, v):
        t = self.alpha2_tan2(v)
        with np.errstate(all="ignore"):
            if self.kind == "ggx":
                # (-1 + sqrt(1+t))/2 == t / (2 (1 + sqrt(1+t)))
                lam = np.where(np.isinf(t), np.inf, t / (2.0 * (1.0 + np.sqrt(1.0 + t))))
            else:  # Beckmann and Blinn-Phong (Walter 2007: Beckmann Lambda with the same alpha)
                c = 1.0 / np.sqrt(t)
                lam = _beckmann_lambda_of_c(c)
        return lam

    def pdf_visible(self, wo, m):
        wo = f64(wo)
        s = np.where(wo[..., 2] < 0, -1.0, 1.0)
        wo_up = wo * s[..., None]
        cz = np.abs(wo[..., 2])
        with np.errstate(all="ignore"):
            p = self.G1(wo_up, m) * np.maximum(0.0, dot(wo_up, m)) * self.D(m) / cz
        return np.where(cz > 0, p, 0.0)

    def pdf_dcos(self, m):
        return self.D(m) * f64(m)[..., 2]


class GGXCartesian(_Masking):
    """GGX in Cartesian components; ``cos_eps`` bounds ``cos^2 theta`` below by ``cos_eps^2`` in
    Lambda (the fitting code's horizon threshold; 0: none)."""

    kind = "ggx"

    def __init__(self, alpha_x, alpha_y=None, cos_eps=0.0):
        self.ax = float(alpha_x)
        self.ay = float(alpha_x if alpha_y is None else alpha_y)
        self.cos_eps = float(cos_eps)

    def D(self, m):
        """``1 / (pi ax ay (m_x^2 / ax^2 + m_y^2 / ay^2 + m_z^2)^2)``, 0 for ``m_z <= 0``."""
        m = f64(m)
        if self.ax == self.ay:
            q = (m[..., 0] ** 2 + m[..., 1] ** 2) / (self.ax * self.ax) + m[..., 2] ** 2
        else:
            q = m[..., 0] ** 2 / self.ax**2 + m[..., 1] ** 2 / self.ay**2 + m[..., 2] ** 2
        with np.errstate(all="ignore"):
            return np.where(m[..., 2] > 0, 1.0 / (np.pi * self.ax * self.ay * q * q), 0.0)

    def Lambda(self, v):
        """``t / (2 (1 + sqrt(1 + t)))``, ``t = (ax^2 v_x^2 + ay^2 v_y^2) / v_z^2``."""
        v = f64(v)
        if self.ax == self.ay:
            a2s2 = (v[..., 0] ** 2 + v[..., 1] ** 2) * self.ax * self.ax
        else:
            a2s2 = self.ax**2 * v[..., 0] ** 2 + self.ay**2 * v[..., 1] ** 2
        with np.errstate(all="ignore"):
            t = a2s2 / np.maximum(v[..., 2] ** 2, self.cos_eps**2)
            return t / (2.0 * (1.0 + np.sqrt(1.0 + t)))
