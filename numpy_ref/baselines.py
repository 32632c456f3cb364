"""Vectorized numpy baselines of the fitting families, for the benchmarks (written from the
formulas; the same parameters and conventions as ``matfit.fitting.FAMILIES``, whose bounds the
caller passes in: this package never imports matfit).

* :func:`conductor_ggx` ``(wo, wi, alpha, eta, k)``: Cook-Torrance GGX with separable Smith
  masking and the exact conductor Fresnel in real arithmetic (Born & Wolf 14.2).
* :func:`diffuse_specular_ggx` ``(wo, wi, albedo, f0, alpha)``: Lambert plus a GGX lobe with
  Schlick's Fresnel (the texel model of ``matfit.maps``).
* :func:`plastic_ggx` ``(wo, wi, albedo, alpha, eta)``: a rough GGX dielectric coat's reflection
  lobe plus ``T(mu_o) T(mu_i) rho / (pi eta^2 (1 - rho R_int))``, with the coat's directional
  transmittance ``T`` integrated over visible normals (Dupuy & Benyoub 2023 spherical caps) by a
  12 x 12 Gauss-Legendre rule in primary-sample space, tabulated at ``mu_j = (j/23)^2`` and
  interpolated linearly; ``R_int = 1 - Tbar/eta^2`` with a 64-point rule for
  ``Tbar = 2 int T(mu) mu dmu``. For a visible normal ``m`` and the refracted ``w_t``, the
  transmitted energy fraction of the sample is ``(1 - F(w_o.m)) G1(w_t, m)``.

All three use GGX in Cartesian form with the horizon threshold ``COS_EPS`` and roughness at least
``ALPHA_MIN`` (the library's conventions). :class:`FamilyModel` puts a family's baseline behind
the parameter bijections of ``matfit.fitting.params`` (sigmoid between finite bounds, exp above a
lower one), so that a numpy optimizer works in the same unconstrained space: residuals and a
Gaussian log-probability (the table's sigma, uniform priors, the bijections' log-Jacobian).
"""

from __future__ import annotations

import numpy as np

from ._array import dot, normalize
from .fresnel import fresnel_conductor_real, fresnel_dielectric_real
from .microfacet import GGXCartesian
from .models import conductor_eval, diffuse_specular_eval, reflection_lobe

__all__ = [
    "COS_EPS",
    "ALPHA_MIN",
    "ggx",
    "conductor_ggx",
    "diffuse_specular_ggx",
    "coat_transmittance_table",
    "plastic_ggx",
    "FAMILY_MODELS",
    "FamilyModel",
]

COS_EPS = 1e-7
ALPHA_MIN = 1e-4
COAT_ORDER, COAT_NODES = 12, 24


def ggx(alpha):
    """The baselines' GGX: Cartesian form, roughness at least ALPHA_MIN, horizon at COS_EPS."""
    return GGXCartesian(max(float(alpha), ALPHA_MIN), cos_eps=COS_EPS)


def conductor_ggx(wo, wi, alpha, eta, k):
    """(N, C) rough conductor BRDF (GGX, separable Smith, real-arithmetic Fresnel)."""
    return conductor_eval(wo, wi, ggx(alpha), np.asarray(eta), np.asarray(k), fresnel=fresnel_conductor_real,
                          horizon=COS_EPS)


def diffuse_specular_ggx(wo, wi, albedo, f0, alpha):
    """(N, C) albedo / pi plus a GGX lobe (separable Smith) with Schlick's Fresnel."""
    return diffuse_specular_eval(wo, wi, albedo, f0, ggx(alpha), horizon=COS_EPS)


def _gl01(n):
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (x + 1), 0.5 * w


def coat_transmittance_table(alpha, eta, order=COAT_ORDER, nodes=COAT_NODES):
    """(mu_j, T(mu_j)) of a rough GGX coat, see the module docstring."""
    d = ggx(alpha)
    a = d.ax
    mu = np.linspace(0.0, 1.0, nodes) ** 2
    me = np.maximum(mu, 1e-3)
    wo = np.stack([np.sqrt(1 - me * me), np.zeros_like(me), me], -1)[:, None, :]
    x, w = _gl01(order)
    u1, u2 = (g.reshape(-1) for g in np.meshgrid(x, x, indexing="ij"))
    wts = (w[:, None] * w[None, :]).reshape(-1)
    # Visible normal of wo (spherical caps).
    ws = normalize(np.concatenate([a * wo[..., :2], wo[..., 2:]], -1))
    phi = 2 * np.pi * u1
    z = (1 - u2) * (1 + ws[..., 2]) - ws[..., 2]
    s = np.sqrt(np.maximum(1 - z * z, 0))
    hh = np.stack([s * np.cos(phi), s * np.sin(phi), z], -1) + ws
    m = normalize(np.stack([a * hh[..., 0], a * hh[..., 1], np.maximum(hh[..., 2], 0)], -1))
    # Refraction into the coat.
    ci = dot(wo, m)
    cos2_t = (eta * eta - 1 + ci * ci) / (eta * eta)
    wt = -wo / eta + (ci / eta - np.sqrt(np.maximum(cos2_t, 0)))[..., None] * m
    ok = (cos2_t > 0) & (wt[..., 2] < -COS_EPS) & (ci > 0)
    e = np.where(ok, (1 - fresnel_dielectric_real(ci, eta)) * d.G1(wt, m), 0.0)
    return mu, np.sum(e * wts, axis=-1)


def plastic_ggx(wo, wi, albedo, alpha, eta, table=None):
    """(N, C) rough plastic BRDF (internal reflection on), ``table`` from coat_transmittance_table."""
    grid, T = coat_transmittance_table(alpha, eta) if table is None else table
    co, ci = wo[:, 2], wi[:, 2]
    ok, m, lobe = reflection_lobe(wo, wi, ggx(alpha), horizon=COS_EPS)
    wom = dot(wo, m)
    f_r = lobe * fresnel_dielectric_real(wom, eta)
    f_r = np.where((wom > 0) & (abs(eta - 1) >= 1e-5), f_r, 0.0)
    x, w = _gl01(64)
    r_int = 1 - 2 * np.sum(w * x * np.interp(x, grid, T)) / eta**2
    rho = np.asarray(albedo)
    To = np.interp(np.clip(co, 0, 1), grid, T)
    Ti = np.interp(np.clip(ci, 0, 1), grid, T)
    diff = (To * Ti)[:, None] * rho / (np.pi * eta**2 * (1 - rho * r_int))
    return np.where(ok[:, None], f_r[:, None] + diff, 0.0)


#: family name -> baseline ``f(wo, wi, theta)`` of its natural parameters (a dict of names)
FAMILY_MODELS = {
    "conductor": lambda wo, wi, p: conductor_ggx(wo, wi, p["alpha"], p["eta"], p["k"]),
    "plastic": lambda wo, wi, p: plastic_ggx(wo, wi, p["albedo"], p["alpha"], p["eta"]),
    "diffuse_specular": lambda wo, wi, p: diffuse_specular_ggx(wo, wi, p["albedo"], p["f0"], p["alpha"]),
}


class FamilyModel:
    """A family's baseline in the unconstrained space ``z`` of the fitting code.

    ``bounds``: ``[(name, lower, upper, size)]`` in the order of ``z`` (``size`` entries each;
    ``upper = inf``: bounded below only, ``theta = lower + exp(z)``)."""

    def __init__(self, family, bounds):
        if family not in FAMILY_MODELS:
            raise KeyError(f"no numpy baseline for the family {family!r} (have {sorted(FAMILY_MODELS)})")
        self.family = family
        self.bounds = tuple((str(n), float(lo), float(hi), int(size)) for n, lo, hi, size in bounds)
        self._eval = FAMILY_MODELS[family]

    @property
    def size(self):
        return sum(b[3] for b in self.bounds)

    def theta(self, z):
        """dict of natural parameters and the log |d theta/dz| for an unconstrained vector z."""
        z = np.asarray(z, float)
        out, i, logj = {}, 0, 0.0
        for name, lo, hi, n in self.bounds:
            zz = z[i:i + n]
            if np.isinf(hi):
                v = lo + np.exp(zz)
                logj += np.sum(zz)
            else:
                s = 1 / (1 + np.exp(-zz))
                v = lo + (hi - lo) * s
                logj += np.sum(np.log(hi - lo) + np.log(s) + np.log1p(-s))
            out[name] = v if n > 1 else float(v[0])
            i += n
        return out, logj

    def eval(self, wo, wi, z):
        return self._eval(wo, wi, self.theta(z)[0])

    def residuals(self, z, wo, wi, values, sqrt_w, loss="l2"):
        """Flat residual vector sqrt(w) (f - y) (``"l2"``) or sqrt(w) (log(1 + f cos_i) - log(1 + y cos_i))
        (``"e2"``, Löw et al. 2012)."""
        f = self.eval(wo, wi, z)
        if loss == "e2":
            c = wi[:, 2:3]
            r = np.log1p(np.maximum(f * c, -0.999)) - np.log1p(np.maximum(values * c, -0.999))
        else:
            r = f - values
        return (sqrt_w * r).reshape(-1)

    def log_prob(self, z, wo, wi, values, sigma):
        """Gaussian log-likelihood with the table's sigma, uniform priors within the bounds, in z."""
        if any(np.isinf(hi) for _, _, hi, _ in self.bounds):
            raise ValueError(f"{self.family}: a uniform prior needs finite bounds")
        th, logj = self.theta(z)
        r = (self._eval(wo, wi, th) - values) / sigma
        prior = -sum(np.log(hi - lo) * n for _, lo, hi, n in self.bounds)
        ll = -0.5 * np.sum(r * r) - np.sum(np.log(sigma)) - 0.5 * r.size * np.log(2 * np.pi)
        tot = ll + prior + logj
        return tot if np.isfinite(tot) else -np.inf
