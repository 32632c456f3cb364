"""Quadrature rules and reference integrals over the hemisphere (float64)."""

from __future__ import annotations

import math

import numpy as np

from .fresnel import fresnel_conductor

__all__ = ["upper_hemisphere_rule", "ggx_conductor_albedo"]


def upper_hemisphere_rule(n):
    """Tensor rule over the upper hemisphere: Gauss-Legendre in ``mu = cos theta`` (n nodes) x
    midpoint in phi (2n nodes). Returns ``(wi, weights)``, shapes (n, 2n, 3) and (n, 2n); the
    weights are of solid angle (``d omega = d mu d phi``)."""
    x, w = np.polynomial.legendre.leggauss(n)
    mu, wmu = 0.5 * (x + 1), 0.5 * w
    phi = (np.arange(2 * n) + 0.5) * np.pi / n
    MU, PH = np.meshgrid(mu, phi, indexing="ij")
    s = np.sqrt(1 - MU**2)
    wi = np.stack([s * np.cos(PH), s * np.sin(PH), MU], -1)
    return wi, np.broadcast_to(wmu[:, None] * (np.pi / n), MU.shape)


def ggx_conductor_albedo(mu_o, alpha, form, eta=None, k=None, n=256):
    """Directional albedo of the isotropic GGX conductor with Smith masking (``form``:
    "separable" or "height_correlated"), by :func:`upper_hemisphere_rule` quadrature of
    ``D G2 F / (4 cos_o)`` over wi. F = 1 when eta is None (a float), else per channel (C,)."""
    wi, wts = upper_hemisphere_rule(n)
    MU = wi[..., 2]
    wo = np.array([math.sqrt(1 - mu_o**2), 0.0, mu_o])
    h = wi + wo
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    a2 = alpha * alpha
    D = a2 / (np.pi * (h[..., 2] ** 2 * (a2 - 1) + 1) ** 2)

    def lam(z):
        return 0.5 * (-1 + np.sqrt(1 + a2 * (1 - z * z) / (z * z)))

    lo, li = lam(mu_o), lam(MU)
    G2 = 1 / (1 + lo + li) if form == "height_correlated" else 1 / ((1 + lo) * (1 + li))
    integrand = D * G2 / (4 * mu_o)
    if eta is None:
        return float(np.sum(integrand * wts))
    F = fresnel_conductor(np.sum(wo * h, -1)[..., None], np.asarray(eta), np.asarray(k))
    return np.sum(integrand[..., None] * F * wts[..., None], axis=(0, 1))
