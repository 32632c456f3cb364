"""Independent pure-numpy reference for matfit (Fresnel, microfacet distributions, BSDF models).

Written from the formulas of the API contract, deliberately NOT a port of the JAX code and never
importing matfit:

* Fresnel equations use complex amplitude coefficients r_s, r_p with a complex refractive index and
  a complex cos(theta_t) (dielectric Fresnel is the k = 0 special case: total internal reflection
  then falls out of the complex square root, |r| = 1).
* D and Lambda are written in spherical form (cos/tan theta, cos^2/sin^2 phi, projected alpha(phi)).
* GGX Lambda uses the cancellation-free form t/(2(1+sqrt(1+t))); Beckmann Lambda uses the scaled
  complementary error function (erfcx) and an asymptotic series for large c, so that the reference is
  accurate to a few ulp in relative terms even where Lambda is tiny.

All functions work in float64 (inputs are converted) and broadcast numpy-style.
"""

from __future__ import annotations

import numpy as np
from scipy import special

__all__ = [
    "fresnel_complex",
    "fresnel_dielectric",
    "fresnel_conductor",
    "fresnel_conductor_real",
    "fresnel_schlick",
    "fresnel_dielectric_average",
    "Dist",
    "lambert_eval",
    "lambert_pdf",
    "conductor_eval",
    "conductor_pdf",
    "dielectric_eval",
    "dielectric_pdf",
    "random_directions",
    "random_normals_near_z",
]

_SQRT_PI = np.sqrt(np.pi)


def _f64(x):
    return np.asarray(x, dtype=np.float64)


# ----------------------------------------------------------------------------------------------
# Fresnel
# ----------------------------------------------------------------------------------------------
def fresnel_complex(cos_i, n):
    """Unpolarised reflectance at an interface from a medium of index 1 to complex index n.

    cos_i >= 0 is the cosine of the incidence angle. Uses complex Snell's law:
    sin^2 t = sin^2 i / n^2, cos t = sqrt(1 - sin^2 t) (principal branch),
    r_s = (cos i - n cos t)/(cos i + n cos t), r_p = (n cos i - cos t)/(n cos i + cos t).
    """
    cos_i = np.clip(_f64(cos_i), 0.0, 1.0).astype(np.complex128)
    n = np.asarray(n, dtype=np.complex128)
    sin2_i = 1.0 - cos_i * cos_i
    sin2_t = sin2_i / (n * n)
    cos_t = np.sqrt(1.0 - sin2_t)
    r_s = (cos_i - n * cos_t) / (cos_i + n * cos_t)
    r_p = (n * cos_i - cos_t) / (n * cos_i + cos_t)
    return 0.5 * (np.abs(r_s) ** 2 + np.abs(r_p) ** 2)


def fresnel_dielectric(cos_i, eta):
    """Exact unpolarised dielectric reflectance; cos_i < 0 means incidence from inside (eta -> 1/eta)."""
    cos_i, eta = np.broadcast_arrays(_f64(cos_i), _f64(eta))
    inside = cos_i < 0
    eta_eff = np.where(inside, 1.0 / eta, eta)
    c = np.abs(cos_i)
    with np.errstate(all="ignore"):
        r = fresnel_complex(c, eta_eff + 0j)
    # Under TIR the complex formula gives |r_s| = |r_p| = 1 up to rounding; make it exact.
    sin2_t = (1.0 - c * c) / (eta_eff * eta_eff)
    return np.where(sin2_t >= 1.0, 1.0, np.minimum(r, 1.0))


def fresnel_conductor(cos_i, eta, k):
    """Exact conductor reflectance with complex index eta + i k; |cos_i| is used."""
    c = np.abs(_f64(cos_i))
    n = _f64(eta) + 1j * _f64(k)
    return fresnel_complex(c, n)


def fresnel_conductor_real(cos_i, eta, k):
    """Classic real-arithmetic conductor Fresnel (pbrt-v3 FrConductor); used only to cross-check."""
    c = np.clip(np.abs(_f64(cos_i)), 0.0, 1.0)
    eta, k = _f64(eta), _f64(k)
    c2 = c * c
    s2 = 1.0 - c2
    eta2, k2 = eta * eta, k * k
    t0 = eta2 - k2 - s2
    a2pb2 = np.sqrt(t0 * t0 + 4 * eta2 * k2)
    t1 = a2pb2 + c2
    a = np.sqrt(0.5 * (a2pb2 + t0))
    t2 = 2 * c * a
    rs = (t1 - t2) / (t1 + t2)
    t3 = c2 * a2pb2 + s2 * s2
    t4 = t2 * s2
    rp = rs * (t3 - t4) / (t3 + t4)
    return 0.5 * (rp + rs)


def fresnel_schlick(cos_i, f0):
    c = _f64(cos_i)
    f0 = _f64(f0)
    return f0 + (1.0 - f0) * (1.0 - c) ** 5


def fresnel_dielectric_average(eta):
    """2 * int_0^1 F(mu) mu dmu by adaptive quadrature, split at the critical angle if eta < 1."""
    from scipy import integrate

    eta = float(eta)
    f = lambda mu: 2.0 * mu * float(fresnel_dielectric(mu, eta))
    pts = None
    if eta < 1.0:
        pts = [np.sqrt(1.0 - eta * eta)]
    val, _ = integrate.quad(f, 0.0, 1.0, points=pts, epsabs=1e-13, epsrel=1e-12, limit=200)
    return val


# ----------------------------------------------------------------------------------------------
# Microfacet distributions
# ----------------------------------------------------------------------------------------------
def _split(v):
    v = _f64(v)
    return v[..., 0], v[..., 1], v[..., 2]


def _dot(a, b):
    return np.sum(_f64(a) * _f64(b), axis=-1)


def _trig(v):
    """cos^2 theta, tan^2 theta, cos^2 phi, sin^2 phi of (unnormalised) v (phi = 0 at the pole)."""
    x, y, z = _split(v)
    s2 = x * x + y * y
    c2 = z * z
    with np.errstate(all="ignore"):
        tan2 = s2 / c2
        cos2phi = np.where(s2 > 0, x * x / np.where(s2 > 0, s2, 1.0), 1.0)
        sin2phi = np.where(s2 > 0, y * y / np.where(s2 > 0, s2, 1.0), 0.0)
    return c2, tan2, cos2phi, sin2phi


def _beckmann_lambda_of_c(c):
    """Lambda(c) = (erf(c)-1)/2 + exp(-c^2)/(2 c sqrt(pi)), evaluated without cancellation."""
    c = _f64(c)
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


class Dist:
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
        m = _f64(m)
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

    def G1(self, v, m):
        v = _f64(v)
        chi = (_dot(v, m) * v[..., 2]) > 0
        with np.errstate(all="ignore"):
            g = 1.0 / (1.0 + self.Lambda(v))
        return np.where(chi, g, 0.0)

    def G2(self, wo, wi, m, form="separable"):
        wo, wi = _f64(wo), _f64(wi)
        if form == "separable":
            return self.G1(wo, m) * self.G1(wi, m)
        assert form == "height_correlated", form
        chi = ((_dot(wo, m) * wo[..., 2]) > 0) & ((_dot(wi, m) * wi[..., 2]) > 0)
        lo, li = self.Lambda(wo), self.Lambda(wi)
        refl = wo[..., 2] * wi[..., 2] > 0
        with np.errstate(all="ignore"):
            g_r = 1.0 / (1.0 + lo + li)
            g_t = np.exp(special.betaln(1.0 + lo, 1.0 + li))
        g = np.where(refl, g_r, g_t)
        return np.where(chi & np.isfinite(lo) & np.isfinite(li), g, 0.0)

    def pdf_visible(self, wo, m):
        wo = _f64(wo)
        s = np.where(wo[..., 2] < 0, -1.0, 1.0)
        wo_up = wo * s[..., None]
        cz = np.abs(wo[..., 2])
        with np.errstate(all="ignore"):
            p = self.G1(wo_up, m) * np.maximum(0.0, _dot(wo_up, m)) * self.D(m) / cz
        return np.where(cz > 0, p, 0.0)

    def pdf_dcos(self, m):
        return self.D(m) * _f64(m)[..., 2]


def _pdf_m(dist, wo, m, sampling):
    if dist.kind == "blinn_phong" or sampling == "dcos":
        return dist.pdf_dcos(m)
    assert sampling == "visible", sampling
    return dist.pdf_visible(wo, m)


# ----------------------------------------------------------------------------------------------
# Models
# ----------------------------------------------------------------------------------------------
def lambert_eval(wo, wi, albedo):
    wo, wi = _f64(wo), _f64(wi)
    albedo = np.atleast_1d(_f64(albedo))
    ok = (wo[..., 2] > 0) & (wi[..., 2] > 0)
    return np.where(ok[..., None], albedo / np.pi, 0.0)


def lambert_pdf(wo, wi):
    wo, wi = _f64(wo), _f64(wi)
    ok = (wo[..., 2] > 0) & (wi[..., 2] > 0)
    return np.where(ok, wi[..., 2] / np.pi, 0.0)


def _half(wo, wi):
    h = _f64(wo) + _f64(wi)
    n = np.linalg.norm(h, axis=-1, keepdims=True)
    with np.errstate(all="ignore"):
        return h / n


def conductor_eval(wo, wi, dist, eta, k, masking="separable"):
    wo, wi = _f64(wo), _f64(wi)
    co, ci = wo[..., 2], wi[..., 2]
    ok = (co > 0) & (ci > 0)
    h = _half(wo, wi)
    eta_b, k_b = np.broadcast_arrays(np.atleast_1d(_f64(eta)), np.atleast_1d(_f64(k)))
    F = fresnel_conductor(_dot(wo, h)[..., None], eta_b, k_b)
    with np.errstate(all="ignore"):
        f = (dist.D(h) * dist.G2(wo, wi, h, masking) / (4.0 * co * ci))[..., None] * F
    return np.where(ok[..., None], f, 0.0)


def conductor_pdf(wo, wi, dist, sampling="visible"):
    wo, wi = _f64(wo), _f64(wi)
    ok = (wo[..., 2] > 0) & (wi[..., 2] > 0)
    h = _half(wo, wi)
    with np.errstate(all="ignore"):
        p = _pdf_m(dist, wo, h, sampling) / (4.0 * _dot(wo, h))
    return np.where(ok, p, 0.0)


def _dielectric_geometry(wo, wi, eta):
    wo, wi = _f64(wo), _f64(wi)
    co, ci = wo[..., 2], wi[..., 2]
    reflect = co * ci > 0
    etap = np.where(reflect, 1.0, np.where(co > 0, eta, 1.0 / eta))
    m = etap[..., None] * wi + wo
    ln = np.linalg.norm(m, axis=-1)
    with np.errstate(all="ignore"):
        m = m / ln[..., None]
    m = np.where((m[..., 2] < 0)[..., None], -m, m)
    dwi, dwo = _dot(m, wi), _dot(m, wo)
    valid = (co != 0) & (ci != 0) & (ln > 0) & (dwi * ci > 0) & (dwo * co > 0)
    return co, ci, reflect, etap, m, dwo, dwi, valid


def dielectric_eval(wo, wi, dist, eta, masking="separable"):
    """Rough dielectric radiance BSDF (Walter 2007 / pbrt-v4), shape (..., 1)."""
    eta = float(eta)
    co, ci, reflect, etap, m, dwo, dwi, valid = _dielectric_geometry(wo, wi, eta)
    F = fresnel_dielectric(dwo, eta)
    D = dist.D(m)
    G = dist.G2(wo, wi, m, masking)
    with np.errstate(all="ignore"):
        fr = D * G * F / np.abs(4.0 * ci * co)
        denom = (dwi + dwo / etap) ** 2
        ft = D * G * (1.0 - F) * np.abs(dwi * dwo / (ci * co * denom)) / etap**2
    f = np.where(reflect, fr, ft)
    return np.where(valid, f, 0.0)[..., None]


def dielectric_pdf(wo, wi, dist, eta, sampling="visible"):
    eta = float(eta)
    co, ci, reflect, etap, m, dwo, dwi, valid = _dielectric_geometry(wo, wi, eta)
    R = fresnel_dielectric(dwo, eta)
    T = 1.0 - R
    pm = _pdf_m(dist, wo, m, sampling)
    with np.errstate(all="ignore"):
        pr = pm / (4.0 * np.abs(dwo)) * R / (R + T)
        pt = pm * np.abs(dwi) / (dwi + dwo / etap) ** 2 * T / (R + T)
    p = np.where(reflect, pr, pt)
    return np.where(valid, p, 0.0)


# ----------------------------------------------------------------------------------------------
# Random directions
# ----------------------------------------------------------------------------------------------
def random_directions(rng, n, hemisphere="upper", min_abs_cos=0.0):
    """n uniformly distributed unit vectors (float64, shape (n, 3)).

    hemisphere: "upper" (z > 0), "lower" (z < 0) or "both". Directions with |z| < min_abs_cos are
    redrawn (use it to stay away from grazing angles).
    """
    out = np.empty((0, 3))
    while out.shape[0] < n:
        v = rng.normal(size=(2 * n + 8, 3))
        v /= np.linalg.norm(v, axis=-1, keepdims=True)
        if hemisphere == "upper":
            v[:, 2] = np.abs(v[:, 2])
        elif hemisphere == "lower":
            v[:, 2] = -np.abs(v[:, 2])
        else:
            assert hemisphere == "both", hemisphere
        v = v[np.abs(v[:, 2]) > max(min_abs_cos, 1e-6)]
        out = np.concatenate([out, v])
    return out[:n]


def random_normals_near_z(rng, n, alpha_x, alpha_y=None, spread=3.0):
    """Unit vectors in the upper hemisphere concentrated where a distribution of roughness alpha
    has its mass: tan(theta) ~ alpha(phi) * U(0, spread)."""
    alpha_y = alpha_x if alpha_y is None else alpha_y
    phi = rng.uniform(0, 2 * np.pi, n)
    r = rng.uniform(0, spread, n)
    tx = r * alpha_x * np.cos(phi)
    ty = r * alpha_y * np.sin(phi)
    v = np.stack([tx, ty, np.ones(n)], axis=-1)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def hemisphere_quadrature(alpha=1.0, n_gl=24, n_phi=96):
    """Upper-hemisphere quadrature (directions (N,3), solid-angle weights (N,)).

    Composite Gauss-Legendre in theta with panel breaks at atan(alpha * 2^j) (so that peaked
    distributions of roughness ~alpha are resolved), uniform (spectrally accurate) rule in phi.
    """
    breaks = [0.0]
    for j in range(-4, 12):
        t = np.arctan(alpha * 2.0**j)
        if t < np.pi / 2 - 1e-9 and t > breaks[-1] + 1e-12:
            breaks.append(t)
    breaks.append(np.pi / 2)
    x, w = np.polynomial.legendre.leggauss(n_gl)
    th, wt = [], []
    for a, b in zip(breaks[:-1], breaks[1:]):
        th.append(0.5 * (b - a) * x + 0.5 * (a + b))
        wt.append(0.5 * (b - a) * w)
    th, wt = np.concatenate(th), np.concatenate(wt)
    phi = (np.arange(n_phi) + 0.5) * 2 * np.pi / n_phi
    T, P = np.meshgrid(th, phi, indexing="ij")
    W = (wt * np.sin(th))[:, None] * np.full(n_phi, 2 * np.pi / n_phi)[None, :]
    d = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], axis=-1)
    return d.reshape(-1, 3), W.reshape(-1)


# ----------------------------------------------------------------------------------------------
# Comparison helper (test utility)
# ----------------------------------------------------------------------------------------------
def rel_err(actual, expected, floor):
    """|a - e| / max(|e|, floor), elementwise (0 where both are exactly 0)."""
    a = np.asarray(actual, dtype=np.float64)
    e = np.asarray(expected, dtype=np.float64)
    a, e = np.broadcast_arrays(a, e)
    with np.errstate(all="ignore"):
        err = np.abs(a - e) / np.maximum(np.abs(e), floor)
    err = np.where((a == e), 0.0, err)  # includes both exactly 0 and equal infinities
    return np.where(np.isnan(err), np.inf, err)


def assert_rel(actual, expected, rtol, floor, what="", **inputs):
    """Assert max relative error <= rtol; on failure report the worst entries with their inputs."""
    a = np.asarray(actual, dtype=np.float64)
    e = np.asarray(expected, dtype=np.float64)
    assert a.shape == e.shape, f"{what}: shape {a.shape} != reference {e.shape}"
    err = rel_err(a, e, floor)
    if not np.all(err <= rtol):
        flat = err.reshape(err.shape[0], -1).max(axis=-1) if err.ndim > 1 else err
        bad = np.argsort(-flat)[:5]
        lines = [f"{what}: max rel err {flat.max():.3e} > {rtol:.1e} ({int((flat > rtol).sum())}/{flat.size} bad)"]
        for i in bad:
            if flat[i] <= rtol:
                break
            ins = ", ".join(f"{k}={np.asarray(v)[i].tolist() if np.ndim(v) else v}" for k, v in inputs.items())
            lines.append(f"  [{i}] lib={a[i].tolist()} ref={e[i].tolist()} err={flat[i]:.3e} | {ins}")
        raise AssertionError("\n".join(lines))


def input_sensitivity(fn, arrays, u, rng, trials=6, floor=1e-300):
    """Estimated relative sensitivity of fn(*arrays) (per point, first axis) to random relative
    perturbations of size ~u of every input component (a backward-error view of rounding to a
    precision with unit roundoff u). Large values mark ill-conditioned points, where no
    implementation in that precision can be accurate (e.g. 1 - F at the critical angle)."""
    base = np.asarray(fn(*arrays), dtype=np.float64)
    base = base.reshape(base.shape[0], -1)
    worst = np.zeros(base.shape[0])
    for _ in range(trials):
        pert = [a * (1.0 + u * rng.standard_normal(a.shape)) for a in arrays]
        p = np.asarray(fn(*pert), dtype=np.float64).reshape(base.shape)
        with np.errstate(all="ignore"):
            r = np.abs(p - base) / np.maximum(np.abs(base), floor)
        r = np.where(p == base, 0.0, r)
        worst = np.maximum(worst, np.nan_to_num(r, nan=np.inf).max(axis=-1))
    return worst
