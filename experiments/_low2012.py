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

import sys
from pathlib import Path

import numpy as np

# numpy_ref (the repository's numpy references) holds the one implementation of the model
_ROOT = str(Path(__file__).resolve().parents[1])
if _ROOT not in sys.path:
    sys.path.insert(0, _ROOT)

from numpy_ref.published import LowCookTorrance, fresnel_cook, read_fit_file  # noqa: E402

__all__ = ["parse_low_fits", "low_cooktorrance", "e2_cells", "direction_grid",
           "e2_weighted", "best_scale"]

#: kept for tests/test_low2012.py: the Cook-Torrance Fresnel of numpy_ref.published
_cook_fresnel = fresnel_cook


def parse_low_fits(path):
    """``{material: {"kd": [3], "ks": [3], "m": float, "eta": float}}`` from ``low_cooktorrance_E2.fit``
    (parsed by numpy_ref.published.read_fit_file; a malformed line raises its PublishedFitError, a
    ValueError naming the file, line and field)."""
    out = {}
    for name, mdl in read_fit_file(path).items():
        if not isinstance(mdl, LowCookTorrance):
            raise ValueError(f"{mdl.origin}: not an Aggregate(Lambertian, LowCookTorrance) fit")
        out[name] = {"kd": mdl.kd.tolist(), "ks": mdl.ks.tolist(), "m": mdl.m, "eta": mdl.eta}
    return out


def low_cooktorrance(p, wo, wi, d_norm=1.0):
    """Löw 2012 Cook-Torrance BRDF (N, 3) in 1/sr for directions ``wo``, ``wi`` (N, 3), local frame.

    ``p``: a :func:`parse_low_fits` entry. Evaluated by numpy_ref.published.LowCookTorrance.
    ``d_norm`` multiplies D, hence the specular term (1 = the published form; 1/pi = a normalized
    Beckmann, for the sensitivity check only). Zero below either horizon.
    """
    mdl = LowCookTorrance(p["kd"], p["ks"], p["m"], p["eta"])
    wo, wi = np.asarray(wo, float), np.asarray(wi, float)
    return mdl.diffuse(wo, wi) + d_norm * mdl.specular(wo, wi)


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
