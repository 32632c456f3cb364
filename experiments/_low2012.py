"""The Löw et al. 2012 Cook-Torrance fits of the MERL materials, and the E2 metric under its readings.

Published fits: ``shared/data/published_fits/low_cooktorrance_E2.fit`` (from the bsdfbenchmark/bbm
collection, which transcribes the supplemental material of Löw, Kronander, Ynnerman, Unger 2012,
"BRDF models for accurate and efficient rendering of glossy surfaces", ACM TOG 31(1),
https://doi.org/10.1145/2077341.2077350). One line per material::

    name = Aggregate(Lambertian(albedo = [kd_r, kd_g, kd_b]),
                     LowCookTorrance(albedo = [ks_r, ks_g, ks_b], roughness = m, eta = eta))

Model, as bbm defines ``LowCookTorrance`` (= its ``cooktorrance``: a ``scaledmodel`` of a
``microfacet`` with ``ndf::beckmann<..., Normalize=false>``, ``maskingshadowing::vgroove``,
``fresnel::cook`` and normalization factor ``microfacet_n::Cook`` = pi), plus bbm's Lambertian
``albedo / pi``::

    f(i, o) = kd / pi + ks * D(h) G(i, o, h) F(c) / (pi cos_i cos_o),      h = (i + o) / |i + o|
    D = exp(-tan^2 th_h / m^2) / (m^2 cos^4 th_h)                      (Beckmann, no 1/pi)
    G = min(1, 2 cos_h cos_i / (i.h), 2 cos_h cos_o / (o.h))           (V-groove, Torrance-Sparrow)
    F = 1/2 (g - c)^2 / (g + c)^2 [1 + ((c (g + c) - 1) / (c (g - c) + 1))^2],
        g = sqrt(eta^2 + c^2 - 1),  c = (i.h + o.h) / 2  (= i.h)        (Cook-Torrance dielectric Fresnel)

kd, ks per RGB channel; m and eta shared by the channels. f is in 1/sr, the unit of the MERL
tables after the MERL scale factors (1/1500, 1.15/1500, 1.66/1500) that bbm's MERL reader and
matfit.io.merl both apply. This is the original Cook & Torrance (1982) form (their D has no 1/pi
either, their specular term divides by pi).

E2 (Löw 2012's log metric; bbm ``lowLog_error``): per sample
``sum_channels (log(1 + f cos_i) - log(1 + y cos_i))^2``, with ``cos_i`` the cosine of the incident
(light) direction. What the samples are and how they are weighted has two readings, both computed
here (see :func:`e2_readings`):

* ``cells``: the mean over the table's valid cells (and channels), every MERL cell weighted
  equally. This is what matfit's ``loss="e2"`` minimizes on a MERL table (matfit.fitting.residuals).
  MERL cells crowd near the specular direction (theta_h index ~ sqrt(theta_h)), so this reading
  weights near-specular configurations far more than a uniform sampling of directions does.
* ``low_sin``: bbm's ``lowLog`` loss, its re-implementation of Löw's metric: incident directions on
  a regular (theta_i, phi_i) grid over the hemisphere, outgoing directions on a regular theta_o
  grid in the plane phi_o = 0, each sample weighted by sin(theta_i). Reported here as the weighted
  mean (sum w e / sum w, per channel).

Both are means of squared log differences (not their square roots).
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

__all__ = ["parse_low_fits", "low_cooktorrance", "e2_cells", "direction_grid",
           "e2_weighted", "best_scale"]

_FIT_RE = re.compile(
    r"^(?P<name>[\w\-]+)\s*=\s*Aggregate\(\s*Lambertian\(\s*albedo\s*=\s*\[(?P<kd>[^\]]*)\]\s*\)\s*,\s*"
    r"LowCookTorrance\(\s*albedo\s*=\s*\[(?P<ks>[^\]]*)\]\s*,\s*roughness\s*=\s*(?P<m>[-+\deE.]+)\s*,\s*"
    r"eta\s*=\s*(?P<eta>[-+\deE.]+)\s*\)\s*\)\s*$")


def parse_low_fits(path):
    """``{material: {"kd": [3], "ks": [3], "m": float, "eta": float}}`` from ``low_cooktorrance_E2.fit``."""
    out = {}
    for ln, line in enumerate(Path(path).read_text().splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        mt = _FIT_RE.match(line)
        if mt is None:
            raise ValueError(f"{path}, line {ln}: not an Aggregate(Lambertian, LowCookTorrance) fit: {line[:80]!r}")
        out[mt["name"]] = {"kd": [float(x) for x in mt["kd"].split(",")],
                           "ks": [float(x) for x in mt["ks"].split(",")],
                           "m": float(mt["m"]), "eta": float(mt["eta"])}
    return out


def _cook_fresnel(eta, c):
    g = np.sqrt(np.maximum(eta * eta + c * c - 1.0, 0.0))
    a = (g - c) / (g + c)
    b = (c * (g + c) - 1.0) / (c * (g - c) + 1.0)
    return np.maximum(0.5 * a * a * (1.0 + b * b), 0.0)


def low_cooktorrance(p, wo, wi, d_norm=1.0):
    """Löw 2012 Cook-Torrance BRDF (N, 3) in 1/sr for directions ``wo``, ``wi`` (N, 3), local frame.

    ``p``: a :func:`parse_low_fits` entry. ``d_norm`` multiplies D (1 = the published form; 1/pi
    = a normalized Beckmann, for the sensitivity check only). Zero below either horizon.
    """
    kd, ks = np.asarray(p["kd"], float), np.asarray(p["ks"], float)
    m, eta = float(p["m"]), float(p["eta"])
    wo, wi = np.asarray(wo, float), np.asarray(wi, float)
    co, ci = wo[:, 2], wi[:, 2]
    h = wo + wi
    h = h / np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-300)
    ch = h[:, 2]
    ih, oh = np.sum(wi * h, 1), np.sum(wo * h, 1)
    ok = (ci > 0) & (co > 0) & (ch > 0) & (ih > 0) & (oh > 0)
    chs = np.where(ok, ch, 1.0)
    ihs, ohs = np.where(ok, ih, 1.0), np.where(ok, oh, 1.0)
    tan2 = (1.0 - chs * chs) / (chs * chs)
    D = d_norm * np.exp(-tan2 / (m * m)) / (m * m * chs ** 4)
    G = np.minimum(1.0, np.minimum(2 * chs * np.where(ok, ci, 1.0) / ihs, 2 * chs * np.where(ok, co, 1.0) / ohs))
    F = _cook_fresnel(eta, 0.5 * (ihs + ohs))
    spec = np.where(ok, D * G * F / (np.pi * np.where(ok, ci * co, 1.0)), 0.0)
    diff = np.where((ci >= 0) & (co >= 0), 1.0, 0.0)
    return kd[None, :] / np.pi * diff[:, None] + ks[None, :] * spec[:, None]


def e2_cells(pred, y, cos_i, valid=None):
    """Reading ``cells``: mean over valid rows and channels of (log1p(pred cos_i) - log1p(y cos_i))^2."""
    pred, y = np.asarray(pred, float), np.asarray(y, float)
    c = np.clip(np.asarray(cos_i, float), 0.0, None)[:, None]
    e = (np.log1p(np.clip(pred, 0, None) * c) - np.log1p(np.clip(y, 0, None) * c)) ** 2
    if valid is not None:
        e = e[np.asarray(valid, bool)]
    return float(np.mean(e))


def direction_grid(n_theta_i=45, n_phi_i=90, n_theta_o=45):
    """Reading ``low_sin`` sample set: cell-centre grid of theta_i in (0, pi/2), phi_i in (0, 2 pi),
    theta_o in (0, pi/2) with phi_o = 0. Returns ``wo, wi`` (N, 3) and the weights sin(theta_i) (N,)."""
    ti = (np.arange(n_theta_i) + 0.5) / n_theta_i * (np.pi / 2)
    pi_ = (np.arange(n_phi_i) + 0.5) / n_phi_i * (2 * np.pi)
    to = (np.arange(n_theta_o) + 0.5) / n_theta_o * (np.pi / 2)
    TI, PI, TO = np.meshgrid(ti, pi_, to, indexing="ij")
    TI, PI, TO = TI.ravel(), PI.ravel(), TO.ravel()
    wi = np.stack([np.sin(TI) * np.cos(PI), np.sin(TI) * np.sin(PI), np.cos(TI)], -1)
    wo = np.stack([np.sin(TO), np.zeros_like(TO), np.cos(TO)], -1)
    return wo, wi, np.sin(TI)


def e2_weighted(pred, y, cos_i, w):
    """Reading ``low_sin``: sum_n w_n mean_c (log1p(pred cos_i) - log1p(y cos_i))^2 / sum_n w_n."""
    c = np.clip(np.asarray(cos_i, float), 0.0, None)[:, None]
    e = (np.log1p(np.clip(pred, 0, None) * c) - np.log1p(np.clip(y, 0, None) * c)) ** 2
    w = np.asarray(w, float)
    return float(np.sum(w[:, None] * e) / (np.sum(w) * e.shape[1]))


def best_scale(metric, p, wo, wi, y, key="ks", scales=np.geomspace(0.05, 20.0, 121), d_norm=1.0):
    """The factor s on ``p[key]`` (ks or kd) that minimizes ``metric(pred, y)`` over a log grid, and
    the metric there. A published fit evaluated with its own model form and metric on (a close
    reconstruction of) its own data should need s ~ 1; a missing 1/pi in D would show as s ~ 1/pi."""
    best = (np.inf, 1.0)
    for s in scales:
        q = dict(p)
        q[key] = [s * v for v in p[key]]
        v = metric(low_cooktorrance(q, wo, wi, d_norm=d_norm), y)
        if v < best[0]:
            best = (v, float(s))
    return best[1], best[0]
