"""Measurement effects: the detector's finite aperture and the noise models.

Aperture
    The detector integrates over a cone of half-angle ``gamma`` around ``wo``. The recorded value is the
    solid-angle average ``(1/Omega) int_cone f(w, wi) dw`` with ``Omega = 2 pi (1 - cos gamma)``,
    computed by a product rule: Gauss-Legendre in the cone's polar angle ``t in [0, gamma]`` (weight
    ``sin t``) times ``n_azimuth`` equally spaced azimuths. The rule is exact for the constant and
    converges to the point value as ``gamma -> 0`` (error O(gamma^2) for smooth lobes).

Noise (applied in this order, each optional; ``v`` the noise-free value, ``rng`` seeded by the scene)
    * jitter: the directions actually measured are the nominal ones turned by a random angle, a 2-D
      Gaussian of standard deviation ``jitter`` (degrees) per tangent axis; the table stores the nominal
      directions (evaluation uses the jittered ones).
    * gain: one calibration factor per channel, ``g_c ~ N(1, gain)`` (or given explicitly), v -> g v.
    * photons (Poisson): ``counts ~ Poisson(v * photons / reference)``, v -> counts * reference / photons.
    * relative (Gaussian): v -> v (1 + relative * N(0, 1)).
    * outliers: a fraction of valid rows (chosen at random) is multiplied by ``outlier_scale`` or
      divided by it (sign at random); their indices go into the ground truth.
    The stored ``sigma`` is the declared model's standard deviation at the (gained) noise-free value,
    ``sqrt((relative v)^2 + v reference / photons + sigma_floor^2)``.
"""
from __future__ import annotations

import numpy as np


def cone_rule(half_angle_deg, n_polar=4, n_azimuth=8):
    """Nodes ``(t, phi)`` (radians) and weights summing to 1 for the cone average."""
    g = np.radians(float(half_angle_deg))
    x, w = np.polynomial.legendre.leggauss(int(n_polar))
    t = 0.5 * g * (x + 1.0)
    wt = 0.5 * g * w * np.sin(t)
    phi = (np.arange(n_azimuth) + 0.5) / n_azimuth * 2 * np.pi
    T, P = np.meshgrid(t, phi, indexing="ij")
    W = np.broadcast_to(wt[:, None] / n_azimuth, T.shape)
    W = W / W.sum()  # == dividing by Omega = 2 pi (1 - cos g) up to the rule's error on sin t
    return T.ravel(), P.ravel(), W.ravel()


def tangent_frame(w):
    """Two unit vectors (..., 3) orthogonal to ``w`` and to each other (Duff et al. 2017)."""
    s = np.where(w[..., 2] >= 0, 1.0, -1.0)
    a = -1.0 / (s + w[..., 2])
    b = w[..., 0] * w[..., 1] * a
    t = np.stack([1.0 + s * w[..., 0] ** 2 * a, s * b, -s * w[..., 0]], -1)
    bt = np.stack([b, s + w[..., 1] ** 2 * a, -w[..., 1]], -1)
    return t, bt


def cone_directions(wo, half_angle_deg, n_polar=4, n_azimuth=8):
    """(N, Q, 3) directions of the cone rule around each ``wo`` (N, 3) and the (Q,) weights."""
    t, p, w = cone_rule(half_angle_deg, n_polar, n_azimuth)
    e1, e2 = tangent_frame(wo)
    st, ct = np.sin(t), np.cos(t)
    d = (ct[None, :, None] * wo[:, None, :]
         + (st * np.cos(p))[None, :, None] * e1[:, None, :]
         + (st * np.sin(p))[None, :, None] * e2[:, None, :])
    return d / np.linalg.norm(d, axis=-1, keepdims=True), w


def jitter_directions(w, sigma_deg, rng):
    """``w`` (N, 3) turned by a random angle: tangent-plane Gaussian offsets of std ``sigma_deg``."""
    e1, e2 = tangent_frame(w)
    s = np.radians(sigma_deg)
    a = rng.normal(0.0, s, size=(len(w), 2))
    ang = np.hypot(a[:, 0], a[:, 1])
    axis = (a[:, :1] * e1 + a[:, 1:] * e2) / np.where(ang > 0, ang, 1.0)[:, None]
    out = np.cos(ang)[:, None] * w + np.sin(ang)[:, None] * axis
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


def predicted_sigma(v, relative=0.0, photons=None, reference=1.0, floor=0.0):
    """Standard deviation of the declared noise model at the noise-free value ``v``."""
    var = (relative * v) ** 2 + floor ** 2
    if photons:
        var = var + np.maximum(v, 0.0) * reference / photons
    return np.sqrt(var)


def apply_noise(v, valid, rng, *, gain=None, photons=None, reference=1.0, relative=0.0,
                outliers=0.0, outlier_scale=5.0):
    """Noisy values and a record ``{'gain': [...], 'outlier_rows': [...]}`` (see the module doc).

    ``gain`` is None (no gain), a float (std of ``g_c ~ N(1, gain)``) or a sequence of per-channel factors.
    """
    v = np.array(v, dtype=np.float64, copy=True)
    rec = {}
    c = v.shape[1]
    if gain is not None:
        g = np.asarray(gain, dtype=np.float64)
        if g.ndim == 0:
            g = 1.0 + float(g) * rng.standard_normal(c)
        g = np.broadcast_to(g, (c,)).copy()
        v = v * g
        rec["gain"] = g.tolist()
    clean = v.copy()
    if photons:
        lam = np.maximum(v, 0.0) * (photons / reference)
        v = rng.poisson(lam).astype(np.float64) * (reference / photons)
    if relative:
        v = v * (1.0 + relative * rng.standard_normal(v.shape))
    if outliers:
        rows = np.flatnonzero(valid)
        k = int(round(outliers * rows.size))
        pick = np.sort(rng.choice(rows, size=k, replace=False)) if k else np.zeros(0, int)
        up = rng.random(k) < 0.5
        fac = np.where(up, outlier_scale, 1.0 / outlier_scale)
        v[pick] *= fac[:, None]
        rec["outlier_rows"] = pick.tolist()
    v[~valid] = 0.0
    return v, clean, rec
