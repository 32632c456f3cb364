"""The Löw 2012 Cook-Torrance model used to evaluate the published MERL fits (experiments/_low2012.py).

Checked against an evaluation written here from the angles (theta_h, theta_d, theta_i, theta_o) with
Snell's-law Fresnel, against matfit's dielectric Fresnel, and against the normalization that
defines the published form (Beckmann D without 1/pi: the projected integral of D is pi).
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO / "experiments"))

from _low2012 import _cook_fresnel, e2_cells, e2_weighted, low_cooktorrance, parse_low_fits  # noqa: E402

SHARED = REPO.parent / "shared"
FITFILE = SHARED / "data" / "published_fits" / "low_cooktorrance_E2.fit"
P = {"kd": [0.24, 0.05, 0.02], "ks": [0.12, 0.11, 0.10], "m": 0.21, "eta": 1.55}


def _reference_from_angles(p, wo, wi):
    """f from the angles: D(theta_h), V-groove G, Fresnel with Snell's law at cos theta_d = i.h."""
    kd, ks, m, eta = np.asarray(p["kd"]), np.asarray(p["ks"]), p["m"], p["eta"]
    ti, to = np.arccos(wi[:, 2]), np.arccos(wo[:, 2])
    h = (wi + wo) / np.linalg.norm(wi + wo, axis=1, keepdims=True)
    th = np.arccos(np.clip(h[:, 2], -1, 1))
    td = np.arccos(np.clip(np.sum(wi * h, 1), -1, 1))
    D = np.exp(-(np.tan(th) / m) ** 2) / (m ** 2 * np.cos(th) ** 4)
    cd = np.cos(td)
    G = np.minimum(1.0, np.minimum(2 * np.cos(th) * np.cos(ti) / cd, 2 * np.cos(th) * np.cos(to) / cd))
    ct = np.sqrt(1.0 - (np.sin(td) / eta) ** 2)
    rs = (cd - eta * ct) / (cd + eta * ct)
    rp = (eta * cd - ct) / (eta * cd + ct)
    F = 0.5 * (rs ** 2 + rp ** 2)
    return kd / np.pi + ks * (D * G * F / (np.pi * np.cos(ti) * np.cos(to)))[:, None]


def _hemi(rng, n):
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2]) + 1e-3
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_matches_angle_reference(rng):
    wo, wi = _hemi(rng, 2000), _hemi(rng, 2000)
    for p in (P, dict(P, m=0.03, eta=1.2), dict(P, m=0.9, eta=3.5)):
        f = low_cooktorrance(p, wo, wi)
        ref = _reference_from_angles(p, wo, wi)
        np.testing.assert_allclose(f, ref, rtol=1e-9, atol=1e-12)


def test_cook_fresnel_is_dielectric_fresnel(x64):
    from matfit.fresnel import fresnel_dielectric

    c = np.linspace(0.01, 1.0, 200)
    for eta in (1.05, 1.5, 2.4, 6.0):
        np.testing.assert_allclose(_cook_fresnel(eta, c), np.asarray(fresnel_dielectric(c, eta)), rtol=1e-9, atol=1e-12)


@pytest.mark.check
def test_published_D_is_unnormalized_beckmann():
    """Integral of D cos(theta_h) over the hemisphere of normals is pi (a normalized Beckmann gives 1):
    ks D G F / (pi cos cos) then equals the microfacet BRDF of a normalized Beckmann times ks."""
    m = 0.3
    t = np.linspace(0.0, np.pi / 2, 200001)[:-1]
    D = np.exp(-(np.tan(t) / m) ** 2) / (m ** 2 * np.cos(t) ** 4)
    integral = 2 * np.pi * np.trapezoid(D * np.cos(t) * np.sin(t), t)
    assert integral == pytest.approx(np.pi, rel=1e-6)


def test_below_horizon_and_reciprocity(rng):
    wo, wi = _hemi(rng, 500), _hemi(rng, 500)
    np.testing.assert_allclose(low_cooktorrance(P, wo, wi), low_cooktorrance(P, wi, wo), rtol=1e-12)
    below = wi * np.array([1, 1, -1])
    assert np.all(low_cooktorrance(P, wo, below) == 0)


def test_e2_readings():
    y = np.array([[1.0, 2.0, 3.0], [0.5, 0.5, 0.5]])
    f = np.e * (1.0 + y) - 1.0  # log1p(f c) - log1p(y c) = 1 at c = 1 for every entry
    c = np.array([1.0, 1.0])
    assert e2_cells(f, y, c) == pytest.approx(1.0)
    assert e2_weighted(f, y, c, np.array([0.3, 2.0])) == pytest.approx(1.0)
    assert e2_cells(f, y, c, valid=np.array([True, False])) == pytest.approx(1.0)


@pytest.mark.check
@pytest.mark.skipif(not FITFILE.exists(), reason=f"shared data not found: {FITFILE}")
def test_parse_published_fits():
    fits = parse_low_fits(FITFILE)
    n_lines = sum(1 for ln in FITFILE.read_text().splitlines() if ln.strip() and not ln.startswith("#"))
    assert len(fits) == n_lines >= 90
    r = fits["red-plastic"]
    assert len(r["kd"]) == len(r["ks"]) == 3 and r["m"] > 0 and r["eta"] > 1
