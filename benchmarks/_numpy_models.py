"""Vectorized numpy baselines for the fitting benchmarks, written from the formulas (no matfit import).

Families with the same parameters and conventions as ``matfit.fitting.FAMILIES``:

* ``conductor_eval(wo, wi, alpha, eta, k)``: Cook-Torrance GGX with separable Smith masking
  and the exact conductor Fresnel in real arithmetic (Born & Wolf 14.2).
* ``diffuse_specular_eval(wo, wi, albedo, f0, alpha)``: Lambert plus a GGX lobe with Schlick's
  Fresnel (the texel model of ``matfit.maps``).
* ``plastic_eval(wo, wi, albedo, alpha, eta)``: a rough GGX dielectric coat's reflection lobe
  plus ``T(mu_o) T(mu_i) rho / (pi eta^2 (1 - rho R_int))``, with the coat's directional
  transmittance ``T`` integrated over visible normals (Dupuy & Benyoub 2023 spherical caps) by a
  12 x 12 Gauss-Legendre rule in primary-sample space, tabulated at ``mu_j = (j/23)^2`` and
  interpolated linearly; ``R_int = 1 - Tbar/eta^2`` with a 64-point rule for
  ``Tbar = 2 int T(mu) mu dmu``. For a visible normal ``m`` and the refracted ``w_t``, the
  transmitted energy fraction of the sample is ``(1 - F(w_o.m)) G1(w_t, m)``.

Also the parameter bijections (sigmoid / exp) of ``matfit.fitting.params`` so that a numpy
optimizer works in the same unconstrained space, and ``log_prob_plastic`` / ``log_prob_conductor``
(Gaussian likelihood with the table's sigma, uniform priors, the bijections' log-Jacobian).
"""

from __future__ import annotations

import numpy as np

COS_EPS = 1e-7
ALPHA_MIN = 1e-4
COAT_ORDER, COAT_NODES = 12, 24


def _dot(a, b):
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def _normalize(v):
    n = np.sqrt(_dot(v, v))
    return v / np.where(n > 0, n, 1.0)[..., None]


def _lambda_ggx(v, a):
    """Smith Lambda of GGX: t / (2 (1 + sqrt(1 + t))), t = alpha^2 tan^2 theta."""
    t = (v[..., 0] ** 2 + v[..., 1] ** 2) * a * a / np.maximum(v[..., 2] ** 2, COS_EPS**2)
    return t / (2 * (1 + np.sqrt(1 + t)))


def _g1(v, m, a):
    return np.where(_dot(v, m) * v[..., 2] > 0, 1 / (1 + _lambda_ggx(v, a)), 0.0)


def _d_ggx(m, a):
    t = (m[..., 0] ** 2 + m[..., 1] ** 2) / (a * a) + m[..., 2] ** 2
    return np.where(m[..., 2] > 0, 1 / (np.pi * a * a * t * t), 0.0)


def fresnel_dielectric(c, eta):
    c = np.clip(c, -1, 1)
    eta = np.where(c < 0, 1 / eta, eta)
    c = np.abs(c)
    cos2_t = (eta * eta - 1 + c * c) / (eta * eta)
    cos_t = np.sqrt(np.maximum(cos2_t, 0))
    with np.errstate(all="ignore"):
        rpa = (eta * c - cos_t) / (eta * c + cos_t)
        rpe = (c - eta * cos_t) / (c + eta * cos_t)
    return np.where((cos2_t <= 0) | (c <= 0), 1.0, 0.5 * (rpa * rpa + rpe * rpe))


def fresnel_conductor(c, eta, k):
    c2 = np.clip(np.abs(c), 0, 1) ** 2
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


def _ggx_lobe(wo, wi, alpha):
    """``(ok, h, D G2 / (4 cos cos))`` of (N, 3) reflection pairs (GGX, separable Smith)."""
    a = max(float(alpha), ALPHA_MIN)
    co, ci = wo[:, 2], wi[:, 2]
    ok = (co > COS_EPS) & (ci > COS_EPS)
    h = _normalize(wo + wi)
    return ok, h, _d_ggx(h, a) * _g1(wo, h, a) * _g1(wi, h, a) / (4 * np.where(ok, co * ci, 1.0))


def conductor_eval(wo, wi, alpha, eta, k):
    """(N, C) rough conductor BRDF (GGX, separable Smith)."""
    ok, h, spec = _ggx_lobe(wo, wi, alpha)
    F = fresnel_conductor(_dot(wo, h)[:, None], np.asarray(eta), np.asarray(k))
    return np.where(ok[:, None], spec[:, None] * F, 0.0)


def diffuse_specular_eval(wo, wi, albedo, f0, alpha):
    """(N, C) albedo / pi plus a GGX lobe (separable Smith) with Schlick's Fresnel."""
    ok, h, spec = _ggx_lobe(wo, wi, alpha)
    F = np.asarray(f0) + (1 - np.asarray(f0)) * (1 - np.clip(_dot(wo, h), 0, 1)[:, None]) ** 5
    return np.where(ok[:, None], np.asarray(albedo) / np.pi + spec[:, None] * F, 0.0)


def _gl01(n):
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (x + 1), 0.5 * w


def coat_transmittance_table(alpha, eta, order=COAT_ORDER, nodes=COAT_NODES):
    """(mu_j, T(mu_j)) of a rough GGX coat, see the module docstring."""
    a = max(float(alpha), ALPHA_MIN)
    mu = np.linspace(0.0, 1.0, nodes) ** 2
    me = np.maximum(mu, 1e-3)
    wo = np.stack([np.sqrt(1 - me * me), np.zeros_like(me), me], -1)[:, None, :]
    x, w = _gl01(order)
    u1, u2 = (g.reshape(-1) for g in np.meshgrid(x, x, indexing="ij"))
    wts = (w[:, None] * w[None, :]).reshape(-1)
    # Visible normal of wo (spherical caps).
    ws = _normalize(np.concatenate([a * wo[..., :2], wo[..., 2:]], -1))
    phi = 2 * np.pi * u1
    z = (1 - u2) * (1 + ws[..., 2]) - ws[..., 2]
    s = np.sqrt(np.maximum(1 - z * z, 0))
    hh = np.stack([s * np.cos(phi), s * np.sin(phi), z], -1) + ws
    m = _normalize(np.stack([a * hh[..., 0], a * hh[..., 1], np.maximum(hh[..., 2], 0)], -1))
    # Refraction into the coat.
    ci = _dot(wo, m)
    cos2_t = (eta * eta - 1 + ci * ci) / (eta * eta)
    wt = -wo / eta + (ci / eta - np.sqrt(np.maximum(cos2_t, 0)))[..., None] * m
    ok = (cos2_t > 0) & (wt[..., 2] < -COS_EPS) & (ci > 0)
    e = np.where(ok, (1 - fresnel_dielectric(ci, eta)) * _g1(wt, m, a), 0.0)
    return mu, np.sum(e * wts, axis=-1)


def plastic_eval(wo, wi, albedo, alpha, eta, table=None):
    """(N, C) rough plastic BRDF (internal reflection on), ``table`` from coat_transmittance_table."""
    grid, T = coat_transmittance_table(alpha, eta) if table is None else table
    co, ci = wo[:, 2], wi[:, 2]
    ok, m, lobe = _ggx_lobe(wo, wi, alpha)
    wom = _dot(wo, m)
    f_r = lobe * fresnel_dielectric(wom, eta)
    f_r = np.where((wom > 0) & (abs(eta - 1) >= 1e-5), f_r, 0.0)
    x, w = _gl01(64)
    r_int = 1 - 2 * np.sum(w * x * np.interp(x, grid, T)) / eta**2
    rho = np.asarray(albedo)
    To = np.interp(np.clip(co, 0, 1), grid, T)
    Ti = np.interp(np.clip(ci, 0, 1), grid, T)
    diff = (To * Ti)[:, None] * rho / (np.pi * eta**2 * (1 - rho * r_int))
    return np.where(ok[:, None], f_r[:, None] + diff, 0.0)


# ---------------------------------------------------------------- parametrization (same bijections)
BOUNDS = {
    "conductor": [("alpha", 1e-3, 1.5, 1), ("eta", 0.05, 8.0, 3), ("k", 0.0, 12.0, 3)],
    "plastic": [("albedo", 0.0, 1.0, 3), ("alpha", 1e-3, 1.5, 1), ("eta", 1.05, 3.0, 1)],
}


def theta_from_z(family, z):
    """dict of natural parameters and the log |d theta/dz| for an unconstrained vector z."""
    out, i, logj = {}, 0, 0.0
    for name, lo, hi, n in BOUNDS[family]:
        zz = z[i:i + n]
        s = 1 / (1 + np.exp(-zz))
        v = lo + (hi - lo) * s
        logj += np.sum(np.log(hi - lo) + np.log(s) + np.log1p(-s))
        out[name] = v if n > 1 else float(v[0])
        i += n
    return out, logj


def model_eval(family, wo, wi, z):
    th, _ = theta_from_z(family, np.asarray(z, float))
    if family == "conductor":
        return conductor_eval(wo, wi, th["alpha"], th["eta"], th["k"])
    return plastic_eval(wo, wi, th["albedo"], th["alpha"], th["eta"])


def residuals(family, z, wo, wi, values, sqrt_w, loss="l2"):
    """Flat residual vector sqrt(w) (f - y) (``"l2"``) or sqrt(w) (log(1 + f cos_i) - log(1 + y cos_i))
    (``"e2"``, Löw et al. 2012)."""
    f = model_eval(family, wo, wi, z)
    if loss == "e2":
        c = wi[:, 2:3]
        r = np.log1p(np.maximum(f * c, -0.999)) - np.log1p(np.maximum(values * c, -0.999))
    else:
        r = f - values
    return (sqrt_w * r).reshape(-1)


def log_prob(family, z, wo, wi, values, sigma):
    """Gaussian log-likelihood with the table's sigma, uniform priors within the bounds, in z."""
    th, logj = theta_from_z(family, np.asarray(z, float))
    r = (model_eval(family, wo, wi, z) - values) / sigma
    prior = -sum(np.log(hi - lo) * n for _, lo, hi, n in BOUNDS[family])
    ll = -0.5 * np.sum(r * r) - np.sum(np.log(sigma)) - 0.5 * r.size * np.log(2 * np.pi)
    tot = ll + prior + logj
    return tot if np.isfinite(tot) else -np.inf
