"""BSDF models in numpy, written from the formulas of the API contract and docs/models.md (never
from matfit). ``eval`` values are radiance BSDFs without the cosine factor, shape (..., C); pdfs
are solid-angle densities, shape (...).

The microfacet models take a distribution object (:class:`~numpy_ref.microfacet.Dist`, or
:class:`~numpy_ref.microfacet.GGXCartesian` for the fast GGX of the baselines).
"""

from __future__ import annotations

import numpy as np

from ._array import dot, f64, flip_up, normalize
from .fresnel import fresnel_conductor, fresnel_dielectric, fresnel_dielectric_average, fresnel_schlick

__all__ = [
    "lambert_eval",
    "lambert_pdf",
    "reflection_lobe",
    "conductor_eval",
    "conductor_pdf",
    "dielectric_eval",
    "dielectric_pdf",
    "diffuse_specular_eval",
    "diffuse_specular_pdf",
    "diffuse_probability",
    "plastic_smooth_eval",
    "coated_conductor_smooth_eval",
]


def _upper(wo, wi, horizon=0.0):
    return (wo[..., 2] > horizon) & (wi[..., 2] > horizon)


def lambert_eval(wo, wi, albedo):
    wo, wi = f64(wo), f64(wi)
    albedo = np.atleast_1d(f64(albedo))
    return np.where(_upper(wo, wi)[..., None], albedo / np.pi, 0.0)


def lambert_pdf(wo, wi):
    wo, wi = f64(wo), f64(wi)
    return np.where(_upper(wo, wi), wi[..., 2] / np.pi, 0.0)


def _pdf_m(dist, wo, m, sampling):
    if dist.kind == "blinn_phong" or sampling == "dcos":
        return dist.pdf_dcos(m)
    assert sampling == "visible", sampling
    return dist.pdf_visible(wo, m)


def reflection_lobe(wo, wi, dist, masking="separable", horizon=0.0):
    """``(ok, h, D(h) G2(wo, wi, h) / (4 cos_o cos_i))`` of reflection pairs; ``ok``: both
    directions above ``horizon`` (the lobe is not masked by it)."""
    wo, wi = f64(wo), f64(wi)
    ok = _upper(wo, wi, horizon)
    h = normalize(wo + wi)
    with np.errstate(all="ignore"):
        lobe = dist.D(h) * dist.G2(wo, wi, h, masking) / (4.0 * np.where(ok, wo[..., 2] * wi[..., 2], 1.0))
    return ok, h, lobe


def conductor_eval(wo, wi, dist, eta, k, masking="separable", fresnel=fresnel_conductor, horizon=0.0):
    """Rough conductor ``D G2 F(wo.h) / (4 cos_o cos_i)``, shape (..., C); ``fresnel(cos, eta, k)``
    (default the exact complex form)."""
    ok, h, lobe = reflection_lobe(wo, wi, dist, masking, horizon)
    eta_b, k_b = np.broadcast_arrays(np.atleast_1d(f64(eta)), np.atleast_1d(f64(k)))
    F = fresnel(dot(wo, h)[..., None], eta_b, k_b)
    return np.where(ok[..., None], lobe[..., None] * F, 0.0)


def conductor_pdf(wo, wi, dist, sampling="visible"):
    wo, wi = f64(wo), f64(wi)
    h = normalize(wo + wi)
    with np.errstate(all="ignore"):
        p = _pdf_m(dist, wo, h, sampling) / (4.0 * dot(wo, h))
    return np.where(_upper(wo, wi), p, 0.0)


def _dielectric_geometry(wo, wi, eta):
    wo, wi = f64(wo), f64(wi)
    co, ci = wo[..., 2], wi[..., 2]
    reflect = co * ci > 0
    etap = np.where(reflect, 1.0, np.where(co > 0, eta, 1.0 / eta))
    m = etap[..., None] * wi + wo
    ln = np.sqrt(dot(m, m))
    with np.errstate(all="ignore"):
        m = m / ln[..., None]
    m = flip_up(m)
    dwi, dwo = dot(m, wi), dot(m, wo)
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


def diffuse_specular_eval(wo, wi, albedo, f0, dist, masking="separable", horizon=0.0):
    """``albedo / pi + D G2 F_s(wo.h) / (4 cos_o cos_i)`` with Schlick's ``F_s``, shape (..., C)."""
    ok, h, lobe = reflection_lobe(wo, wi, dist, masking, horizon)
    albedo, f0 = np.atleast_1d(f64(albedo)), np.atleast_1d(f64(f0))
    F = fresnel_schlick(np.clip(dot(wo, h), 0, 1)[..., None], f0)
    return np.where(ok[..., None], albedo / np.pi + lobe[..., None] * F, 0.0)


def diffuse_probability(albedo, f0):
    """Probability of the cosine branch of DiffuseSpecular's sampler: ``mean(albedo) / (mean(albedo)
    + mean(f0))`` (1/2 when both are 0)."""
    a, s = float(np.mean(albedo)), float(np.mean(f0))
    return 0.5 if a + s == 0 else a / (a + s)


def diffuse_specular_pdf(wo, wi, albedo, f0, dist, sampling="visible"):
    """``p_d cos_i / pi + (1 - p_d) pdf_m(h) / (4 wo.h)``, pdf_m of visible normals (or D cos)."""
    pd = diffuse_probability(albedo, f0)
    return pd * lambert_pdf(wo, wi) + (1 - pd) * conductor_pdf(wo, wi, dist, sampling)


def plastic_smooth_eval(wo, wi, albedo, eta):
    """Smooth plastic, internal reflection summed (docs/models.md):
    ``f = T(mu_o) T(mu_i) rho / (pi eta^2 (1 - rho R_int))``, ``T = 1 - F``,
    ``R_int = 1 - (1 - Fbar(eta)) / eta^2``."""
    wo, wi = f64(wo), f64(wi)
    albedo = f64(albedo)
    To = 1 - fresnel_dielectric(wo[..., 2], eta)
    Ti = 1 - fresnel_dielectric(wi[..., 2], eta)
    r_int = 1 - (1 - fresnel_dielectric_average(eta)) / eta**2
    f = (To * Ti)[..., None] * albedo / (np.pi * eta**2 * (1 - albedo * r_int))
    return np.where(_upper(wo, wi)[..., None], f, 0.0)


def _inner(w, eta):
    """Direction inside a smooth coat of index eta, pointing up, for an outside direction w."""
    s = w[..., :2] / eta
    z = np.sqrt(np.maximum(1 - np.sum(s * s, axis=-1), 0))
    return np.concatenate([s, z[..., None]], axis=-1)


def coated_conductor_smooth_eval(wo, wi, dist, eta_b, k_b, eta_c):
    """Smooth coat over a rough conductor, no absorption (Weidlich-Wilkie, docs/models.md):
    ``f = T(mu_o) T(mu_i) / eta_c^2 * f_base(wo', wi')`` with the base's index relative to the coat."""
    wo, wi = f64(wo), f64(wi)
    To = 1 - fresnel_dielectric(wo[..., 2], eta_c)
    Ti = 1 - fresnel_dielectric(wi[..., 2], eta_c)
    fb = conductor_eval(_inner(wo, eta_c), _inner(wi, eta_c), dist, f64(eta_b) / eta_c, f64(k_b) / eta_c)
    return np.where(_upper(wo, wi)[..., None], (To * Ti)[..., None] / eta_c**2 * fb, 0.0)
