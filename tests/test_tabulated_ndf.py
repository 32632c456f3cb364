"""The tabulated distribution (matfit.microfacet.TabulatedNDF), its model (TabulatedMicrofacet) and
the extraction of a distribution from retro-reflection (matfit.microfacet.extract_ndf, ndf_start).

References are independent of the code under test: numpy_ref's GGX and Beckmann (D, Lambda, G1,
the GGX conductor albedo), a brute-force 2-D quadrature of the projected area, the analytic
1 - ln 2 of the white furnace, the chi-square machinery of tests/chi2.py, central differences, and
synthetic tables made by RoughConductor (the model the extraction inverts) or from the formulas.
"""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import chi2 as c2  # noqa: E402
import numpy_ref as R  # noqa: E402

from matfit import Table  # noqa: E402
from matfit.errors import ParameterError  # noqa: E402
from matfit.microfacet import (GGX, TabulatedNDF, back_facing_area, extract_ndf, interpolate_ndf,  # noqa: E402
                               ndf_grid, ndf_start, projected_mass)
from matfit.models import RoughConductor, TabulatedMicrofacet  # noqa: E402

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
TOOL = SHARED / "tools" / "merl_surrogate.py"
WEIGHTS = SHARED / "data" / "merl_nbrdf" / "weights.npz"

ETA, K = np.array([0.2, 0.9, 1.5]), np.array([3.0, 2.5, 1.8])


def ggx_d(theta, alpha):
    """GGX's D at angle theta from the normal, written out in numpy (the reference of the table
    tests): alpha^2 / (pi (alpha^2 cos^2 + sin^2)^2), finite at pi/2."""
    theta, alpha = np.asarray(theta, np.float64), np.asarray(alpha, np.float64)
    return alpha ** 2 / (np.pi * (alpha ** 2 * np.cos(theta) ** 2 + np.sin(theta) ** 2) ** 2)


def _dirs(theta, phi=0.0):
    theta = np.asarray(theta, np.float64)
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi) + 0 * theta, np.cos(theta)], -1)


def ref_table(kind, alpha, dtype=np.float64, n=256):
    """A TabulatedNDF of numpy_ref's D (not matfit's) on the default nodes."""
    theta = ndf_grid(n)
    m = _dirs(theta)
    m[-1] = [1.0, 0.0, 1e-9]  # the horizon node: D's limit m_z -> 0+
    return TabulatedNDF(theta.astype(dtype), R.Dist(kind, alpha).D(m).astype(dtype))


@eqx.filter_jit
def _eval(model, wo, wi):
    return model.eval(wo, wi)


@eqx.filter_jit
def _pdf_sample(model, wo, wi, u):
    return model.pdf(wo, wi), model.sample(wo, u)


@eqx.filter_jit
def _albedo(model, wo, mc=False):
    if mc:
        return model.albedo(wo, method="mc", n=1 << 15)
    return model.albedo(wo, n=256)


def model_of(ndf, dtype=np.float64, masking="separable", eta=ETA, k=K):
    return TabulatedMicrofacet(ndf, jnp.asarray(eta, dtype), jnp.asarray(k, dtype), masking)


# ------------------------------------------------------------------------------------------------
# The distribution: D and G1 of a tabulated GGX / Beckmann against numpy_ref
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("kind, alpha, d_tol, g_tol", [("ggx", 0.05, 1e-3, 1e-4), ("ggx", 0.3, 1e-4, 1e-5),
                                                       ("ggx", 1.0, 1e-6, 1e-6), ("beckmann", 0.3, 5e-3, 1e-4)])
@pytest.mark.check
def test_tabulated_ggx_matches_reference(kind, alpha, d_tol, g_tol, x64, rng):
    ref = R.Dist(kind, alpha)
    tab = ref_table(kind, alpha)
    m = R.random_normals_near_z(rng, 2000, alpha, alpha, 3.0)
    d_ref, d_tab = ref.D(m), np.asarray(tab.D(jnp.asarray(m)))
    sel = d_ref > 1e-4 * d_ref.max()
    assert np.max(np.abs(d_tab[sel] / d_ref[sel] - 1)) < d_tol
    assert float(tab.alpha_x) == pytest.approx(alpha, rel=d_tol)  # 1 / sqrt(pi D(0)), after normalization
    v = R.random_directions(rng, 2000, "upper", 1e-4)
    n = np.array([0.0, 0.0, 1.0])
    g_ref, g_tab = ref.G1(v, n), np.asarray(tab.G1(jnp.asarray(v), jnp.asarray(n)))
    assert np.max(np.abs(g_tab - g_ref)) < g_tol
    # Lambda itself where it is not tiny, down to grazing (mu = 1e-4)
    lam_ref, lam_tab = ref.Lambda(v), np.asarray(tab.Lambda(jnp.asarray(v)))
    big = lam_ref > 1e-2
    assert np.max(np.abs(lam_tab[big] / lam_ref[big] - 1)) < 5e-3


@pytest.mark.parametrize("grid", ["sqrt", "uniform"])
def test_cell_lookup_matches_numpy_interpolation(grid, x64, rng):
    """D at random angles and exactly at the nodes (where rounding decides the cell) equals the
    numpy interpolation of the same table, on the default grid (cell computed) and on any other
    (cell searched)."""
    theta = ndf_grid(200) if grid == "sqrt" else np.linspace(0.0, np.pi / 2, 150)
    d = ggx_d(theta, 0.2) + 0.2 * np.exp(-((theta - 0.9) / 0.05) ** 2)
    d[40:43] = 0.0  # linear cells beside the log-linear ones
    tab = TabulatedNDF(theta, d)
    assert tab.sqrt_grid == (grid == "sqrt")
    tq = np.concatenate([rng.uniform(0, np.pi / 2, 3000), theta[:-1], np.nextafter(theta[1:-1], 0)])
    m = _dirs(tq, rng.uniform(0, 2 * np.pi, tq.size))
    got = np.asarray(tab.D(jnp.asarray(m)))
    ref = interpolate_ndf(theta, np.asarray(tab.d_nodes), tq)
    np.testing.assert_allclose(got, ref, rtol=1e-9, atol=1e-12 * ref.max())


def test_back_facing_area_against_brute_force_quadrature():
    """B(mu) (closed-form azimuthal integral) against a 2-D midpoint rule of max(0, -v.m) D, for a
    distribution with two lobes and a zero node (the linear cells)."""
    theta = ndf_grid(64)
    d = 0.7 * ggx_d(theta, 0.2) + 0.3 * ggx_d(theta, 0.8)
    d[20:24] = 0.0
    d /= projected_mass(theta, d)
    mus = np.array([1.0, 0.8, 0.4, 0.1, 0.0])
    b = back_facing_area(theta, d, mus)
    nt, nphi = 3000, 720
    tm = (np.arange(nt) + 0.5) * (np.pi / 2) / nt
    ph = (np.arange(nphi) + 0.5) * 2 * np.pi / nphi
    T, P = np.meshgrid(tm, ph, indexing="ij")
    m = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1)
    dm = interpolate_ndf(theta, d, T)
    dw = np.sin(T) * (np.pi / 2 / nt) * (2 * np.pi / nphi)
    for mu, bb in zip(mus, b):
        v = np.array([math.sqrt(1 - mu * mu), 0.0, mu])
        ref = np.sum(np.maximum(0, -(m @ v)) * dm * dw)
        assert bb == pytest.approx(ref, rel=2e-3, abs=1e-6)
        # the projected area mu + B is the integral of max(0, v.m) D
        assert mu + bb == pytest.approx(np.sum(np.maximum(0, m @ v) * dm * dw), rel=2e-3)
    assert b[0] == 0.0


def test_normalization_and_dcos_pdf_integrate_to_one(x64):
    """int D cos d omega = 1 (a fine quadrature of the interpolated table), for a scaled input."""
    theta = ndf_grid(100)
    tab = TabulatedNDF(theta, 7.0 * ggx_d(theta, 0.1))
    wi, w = R.upper_hemisphere_rule(200)
    # Gauss-Legendre in theta on every cell of the table (the interpolant is smooth inside a cell)
    x, gw = np.polynomial.legendre.leggauss(8)
    a, b = theta[:-1, None], theta[1:, None]
    t = a + (b - a) * 0.5 * (x + 1)
    dq = interpolate_ndf(theta, np.asarray(tab.d_nodes), t)
    assert np.sum(0.5 * (b - a) * gw * dq * np.cos(t) * np.sin(t)) * 2 * np.pi == pytest.approx(1.0, abs=1e-9)
    p = np.asarray(eqx.filter_jit(lambda t, m: t.pdf_dcos(m))(tab, jnp.asarray(wi)))
    assert float(np.sum(p * w)) == pytest.approx(1.0, abs=3e-3)  # a coarse rule on a narrow lobe


# ------------------------------------------------------------------------------------------------
# The model: agreement with RoughConductor, reciprocity, dtypes, gradients
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("masking", ["separable", "height_correlated"])
def test_model_matches_numpy_conductor_and_is_reciprocal(masking, x64, rng):
    model = model_of(ref_table("ggx", 0.3), masking=masking)
    wo, wi = R.random_directions(rng, 500, "upper", 0.01), R.random_directions(rng, 500, "upper", 0.01)
    f = np.asarray(_eval(model, jnp.asarray(wo), jnp.asarray(wi)))
    ref = R.conductor_eval(wo, wi, R.Dist("ggx", 0.3), ETA, K, masking)
    np.testing.assert_allclose(f, ref, rtol=5e-4)
    f2 = np.asarray(_eval(model, jnp.asarray(wi), jnp.asarray(wo)))
    assert np.max(np.abs(f - f2) / np.maximum(np.abs(f), 1e-300)) < 1e-10
    # below the horizon: zero
    assert np.all(np.asarray(_eval(model, jnp.asarray(wo), jnp.asarray(wi * [1, 1, -1]))) == 0)


def test_float32(rng):
    f32 = np.float32
    model = model_of(ref_table("ggx", 0.2, f32), f32)
    wo, wi = R.random_directions(rng, 300, "upper", 0.01), R.random_directions(rng, 300, "upper", 0.01)
    u = rng.random((300, 3))
    wo32, wi32 = jnp.asarray(wo, f32), jnp.asarray(wi, f32)
    p, smp = _pdf_sample(model, wo32, wi32, jnp.asarray(u, f32))
    out = [np.asarray(a) for a in (_eval(model, wo32, wi32), p, *smp)]
    assert all(a.dtype == np.float32 and np.all(np.isfinite(a)) for a in out)
    ref = R.conductor_eval(wo, wi, R.Dist("ggx", 0.2), ETA, K)
    np.testing.assert_allclose(out[0], ref, rtol=2e-3, atol=1e-6 * ref.max())


def _central(fn, x, h=1e-6):
    g = np.zeros_like(x)
    for i in range(x.size):
        e = np.zeros_like(x)
        e.flat[i] = h
        g.flat[i] = (fn(x + e) - fn(x - e)) / (2 * h)
    return g


def test_gradients_eta_k_match_finite_differences(x64, rng):
    ndf = ref_table("ggx", 0.35)
    wo, wi = (jnp.asarray(R.random_directions(rng, 40, "upper", 0.05)) for _ in range(2))

    @jax.jit
    def loss(eta, k):
        return TabulatedMicrofacet(ndf, eta, k).eval(wo, wi).sum()

    ge, gk = jax.grad(loss, argnums=(0, 1))(jnp.asarray(ETA), jnp.asarray(K))
    fe = _central(lambda e: float(loss(jnp.asarray(e), jnp.asarray(K))), ETA.copy())
    fk = _central(lambda k: float(loss(jnp.asarray(ETA), jnp.asarray(k))), K.copy())
    np.testing.assert_allclose(np.asarray(ge), fe, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(gk), fk, rtol=1e-6)


# ------------------------------------------------------------------------------------------------
# Sampling: chi-square, pdf integral, weights; energy
# ------------------------------------------------------------------------------------------------
N_SAMPLES = 1 << 16
SAMPLING_CASES = [(0.3, 30.0), (0.02, 60.0), (1.0, 85.0)]


@pytest.mark.parametrize("alpha, deg", SAMPLING_CASES)
def test_sampling_chi2_and_pdf_integral(alpha, deg):
    """sample() follows pdf() (Pearson chi-square in the stretched half-vector space, with the
    invalid-sample bin), the pdf integrates to the valid fraction, weight = f cos / pdf."""
    f32 = np.float32
    model = model_of(ref_table("ggx", alpha, f32), f32)
    wo64 = _dirs(math.radians(deg), 0.3)
    wo = jnp.broadcast_to(jnp.asarray(wo64, f32), (N_SAMPLES, 3))
    rng = np.random.default_rng(int(deg * 1000 + alpha * 1e4))
    u = jnp.asarray(rng.random((N_SAMPLES, 3)), f32)
    sample = jax.jit(lambda w, uu: model.sample(w, uu))
    pdf = jax.jit(lambda w, v: model.pdf(w, v))
    ev = jax.jit(lambda w, v: model.eval(w, v))
    wi, weight, p = (np.asarray(a, np.float64) for a in sample(wo, u))
    valid = p > 0
    assert np.all(np.isfinite(weight)) and np.all(weight[~valid] == 0)
    p_re = np.asarray(pdf(wo, jnp.asarray(wi, f32)), np.float64)
    np.testing.assert_allclose(p[valid], p_re[valid], rtol=1e-4)
    f_re = np.asarray(ev(wo, jnp.asarray(wi, f32)), np.float64)[valid]
    np.testing.assert_allclose(weight[valid], f_re * np.abs(wi[valid, 2:3]) / p_re[valid, None], rtol=1e-4)

    def pdf_np(w):
        w = np.asarray(w, np.float64).reshape(-1, 3)
        out = np.zeros(len(w))
        for s in range(0, len(w), N_SAMPLES):
            blk = w[s:s + N_SAMPLES]
            pad = np.concatenate([blk, np.tile([[0.0, 0.0, 1.0]], (N_SAMPLES - len(blk), 1))])
            out[s:s + len(blk)] = np.asarray(pdf(wo, jnp.asarray(pad, f32)), np.float64)[:len(blk)]
        return out

    g = c2.SlopeGrid(alpha, alpha, 16, 32)

    def dens(t, ph):
        m, j = g.to_m(t, ph)
        wim, jr = c2.wi_from_m_reflect(wo64, m)
        ok = wim[:, 2] > 0
        v = np.zeros(len(t))
        v[ok] = pdf_np(wim[ok]) * (j * jr)[ok]
        return v

    P, unresolved = c2.cell_probabilities(dens, g.xedges, g.yedges, n_samples=N_SAMPLES)
    t, ph = g.from_m(c2.half_vector_reflect(wo64, wi[valid]))
    H, _, _ = np.histogram2d(t, ph, [g.xedges, g.yedges])
    integral = float(P.sum())
    res = c2.chi2_test(np.concatenate([H.ravel(), [np.sum(~valid)]]),
                       N_SAMPLES * np.concatenate([P.ravel(), [max(0.0, 1 - integral)]]))
    assert res.pvalue > 0.01 / len(SAMPLING_CASES), res.summary(8)
    sig = math.sqrt(max(valid.mean() * (1 - valid.mean()), 1 / N_SAMPLES) / N_SAMPLES)
    assert integral <= 1 + 1e-3 + unresolved
    assert abs(integral - valid.mean()) <= 0.01 * integral + 5 * sig + unresolved


def test_white_furnace(x64):
    """With F ~ 1 (k = 1e4) the albedo is <= 1; at alpha = 1, normal incidence, it is 1 - ln 2
    (Smith separable); elsewhere it is numpy_ref's GGX conductor albedo (quadrature), and the MC
    albedo (the mean sample weight) agrees with it."""
    degs = np.array([0.0, 30.0, 85.0])
    wo = jnp.asarray(_dirs(np.radians(degs)))
    for alpha in (1.0, 0.1):
        model = model_of(ref_table("ggx", alpha), eta=[1.0], k=[1e4])
        e = np.asarray(_albedo(model, wo))[:, 0]
        mc = np.asarray(_albedo(model, wo, True))[:, 0]
        if alpha == 1.0:
            assert e[0] == pytest.approx(1 - math.log(2), abs=1e-4)
        for deg, ei, mci in zip(degs, e, mc):
            ref = R.ggx_conductor_albedo(math.cos(math.radians(deg)), alpha, "separable", n=256)
            assert ei <= 1.0 and ei == pytest.approx(ref, abs=2e-3)
            assert mci <= 1.0 + 0.01 and mci == pytest.approx(ei, abs=0.02)


# ------------------------------------------------------------------------------------------------
# Hard cases: grazing, narrow tables, bad input
# ------------------------------------------------------------------------------------------------
def test_grazing_and_narrow(x64):
    for alpha in (0.005, 0.3):
        model = model_of(ref_table("ggx", alpha))
        mus = np.array([0.0, 1e-8, 1e-5, 1e-3])
        g = _dirs(np.arccos(mus))
        wo, wi = jnp.asarray(g), jnp.asarray(g * [-1, 1, 1])
        p, (wi_s, w_s, p_s) = _pdf_sample(model, wo, wi, jnp.full((4, 3), 0.5))
        f, p = np.asarray(_eval(model, wo, wi)), np.asarray(p)
        assert np.all(np.isfinite(f)) and np.all(np.isfinite(p))
        horizon = mus <= 1e-7  # COS_EPS
        assert np.all(f[horizon] == 0) and np.all(p[horizon] == 0) and np.all(f[~horizon] > 0)
        assert np.all(np.isfinite(np.asarray(w_s))) and np.all(np.isfinite(np.asarray(p_s)))
        ndf = model.ndf
        assert float(ndf.G1(jnp.array([1.0, 0.0, 0.0]), jnp.array([0.0, 0.0, 1.0]))) == 0.0
        assert np.isfinite(float(ndf.Lambda(jnp.array([1.0, 0.0, 0.0]))))
    # a narrow table keeps its peak and its normalization
    tab = ref_table("ggx", 0.005)
    assert float(tab.d_nodes[0]) == pytest.approx(1 / (math.pi * 0.005 ** 2), rel=5e-3)
    assert float(tab.alpha_x) == pytest.approx(0.005, rel=3e-3)
    assert projected_mass(ndf_grid(256), np.asarray(tab.d_nodes)) == pytest.approx(1.0, abs=1e-12)
    m = R.random_normals_near_z(np.random.default_rng(3), 2000, 0.005, 0.005, 3.0)
    d_ref = R.Dist("ggx", 0.005).D(m)
    sel = d_ref > 1e-3 * d_ref.max()
    assert np.max(np.abs(np.asarray(tab.D(jnp.asarray(m)))[sel] / d_ref[sel] - 1)) < 0.02


def test_bad_input():
    t = ndf_grid(16)
    d = ggx_d(t, 0.3)
    with pytest.raises(ParameterError, match="d must be >= 0"):
        TabulatedNDF(t, -d)
    with pytest.raises(ParameterError, match="increase strictly"):
        TabulatedNDF(t[::-1], d)
    with pytest.raises(ParameterError, match="positive projected area"):
        TabulatedNDF(t, 0 * d)
    with pytest.raises(ParameterError, match="1-D arrays"):
        TabulatedNDF(t, d[:-1])
    with pytest.raises(ParameterError, match="concrete"):
        jax.jit(lambda dd: TabulatedNDF(t, dd).d_nodes)(d)
    with pytest.raises(ParameterError, match="must be a matfit.microfacet.TabulatedNDF"):
        TabulatedMicrofacet(GGX(0.3), 1.0, 2.0)
    with pytest.raises(ParameterError, match="masking"):
        TabulatedMicrofacet(TabulatedNDF(t, d), 1.0, 2.0, masking="v-groove")
    with pytest.raises(ParameterError, match="eta"):
        TabulatedMicrofacet(TabulatedNDF(t, d), -1.0, 2.0)
    # an in-plane specular sweep has no backscattering rows: the extraction says so
    th = np.linspace(0.1, 1.2, 20)
    table = Table(wo=_dirs(th), wi=_dirs(th) * [-1, 1, 1], values=np.ones((20, 1)), channels="mono")
    with pytest.raises(ParameterError, match="near backscattering"):
        extract_ndf(table)
    with pytest.raises(ParameterError, match="masking"):
        extract_ndf(table, masking="exact")
    with pytest.raises(ParameterError, match="matfit.Table"):
        ndf_start(np.ones((3, 3)))


# ------------------------------------------------------------------------------------------------
# Extraction
# ------------------------------------------------------------------------------------------------
def retro_table(model, n_h=90, tds=(0.5, 1.5), n_pd=6):
    """Rows near backscattering on MERL's theta_h grid (theta_d 0.5 and 1.5 deg, phi_h = 0)."""
    th = ((np.arange(n_h) + 0.5) / n_h) ** 2 * (np.pi / 2)
    td, pd, th = np.meshgrid(np.radians(tds), (np.arange(n_pd) + 0.5) / n_pd * np.pi, th, indexing="ij")
    d = np.stack([np.sin(td) * np.cos(pd), np.sin(td) * np.sin(pd), np.cos(td)], -1).reshape(-1, 3)
    c, s = np.cos(th).ravel(), np.sin(th).ravel()
    w1 = np.stack([c * d[:, 0] + s * d[:, 2], d[:, 1], -s * d[:, 0] + c * d[:, 2]], -1)  # rotated about y
    h = np.stack([s, 0 * s, c], -1)
    w2 = 2 * np.sum(w1 * h, 1, keepdims=True) * h - w1
    ok = (w1[:, 2] > 0) & (w2[:, 2] > 0)
    wo, wi = w1[ok], w2[ok]
    return Table(wo=wo, wi=wi, values=np.asarray(_eval(model, jnp.asarray(wo), jnp.asarray(wi))))


@pytest.mark.parametrize("dist", ["ggx", "beckmann"])
@pytest.mark.parametrize("masking", ["separable", "height_correlated"])
def test_extraction_recovers_ggx_and_beckmann(dist, masking, x64):
    """Within 2 % in alpha (1 % for the widths the grid resolves well), the right distribution,
    one lobe, and F(0) per channel within 2 %."""
    f0 = R.fresnel_conductor(1.0, ETA, K)
    for alpha in (0.02, 0.1, 0.5):
        table = retro_table(RoughConductor(alpha, jnp.asarray(ETA), jnp.asarray(K), distribution=dist, masking=masking))
        s = ndf_start(table, masking=masking)
        got = s["alpha_ggx"] if dist == "ggx" else s["alpha_beckmann"]
        assert got == pytest.approx(alpha, rel=0.02 if alpha < 0.05 else 0.01), s
        assert s["distribution"] == dist and s["lobes"] == 1 and s["converged"]
        assert s["anisotropy"] is None  # every row at phi_h = 0
        np.testing.assert_allclose(s["f0"], f0, rtol=0.02)
        # the paper's moment conversion of the matching distribution
        mom = s["alpha_ggx_moment"] if dist == "ggx" else s["alpha_beckmann_moment"]
        assert mom == pytest.approx(alpha, rel=0.1)


def test_extraction_narrow_and_wide(x64):
    """The limits of MERL's theta_h grid: a very narrow lobe (alpha = 0.005: its first cells are
    0.003 and 0.025 deg) within 5 %, a very wide one (alpha = 1.5, its tail cut at 85 deg) within 1 %."""
    for alpha, rel in ((0.005, 0.05), (1.5, 0.01)):
        s = ndf_start(retro_table(RoughConductor(alpha, jnp.asarray(ETA), jnp.asarray(K))))
        assert s["alpha"] == pytest.approx(alpha, rel=rel) and s["lobes"] == 1


@pytest.mark.check
def test_extraction_power_iteration_and_two_lobes(x64):
    """Dupuy et al.'s own relation (G2(k, k) = G1(k)) on exact retro-reflection written from the
    formulas, for one GGX lobe and for a mixture of two, whose G1 follows from the linearity of the
    projected area in D: sigma = w sigma_1 + (1 - w) sigma_2, sigma_j = cos (1 + Lambda_j)."""
    t = np.linspace(0.0, np.radians(84.0), 300)
    w = _dirs(t)

    def lam(a):
        return R.Dist("ggx", a).Lambda(w)

    for mix in ((1.0, 0.15, 0.15), (0.6, 0.05, 0.4)):
        s_, a1, a2 = mix
        d = s_ * ggx_d(t, a1) + (1 - s_) * ggx_d(t, a2)
        sigma = np.cos(t) * (s_ * (1 + lam(a1)) + (1 - s_) * (1 + lam(a2)))
        f = 0.8 * d * (np.cos(t) / sigma) / (4 * np.cos(t) ** 2)
        st = ndf_start(Table(wo=w, wi=w, values=f[:, None], channels="mono"), masking="smith_g1")
        assert st["f0"][0] == pytest.approx(0.8, rel=0.01)
        if s_ == 1.0:
            assert st["alpha"] == pytest.approx(0.15, rel=0.01) and st["lobes"] == 1
        else:
            assert st["lobes"] == 2 and st["misfit_ggx"] > 0.05
            two = st["two_lobe"]
            assert two["alpha"][0] == pytest.approx(a1, rel=0.05) and two["alpha"][1] == pytest.approx(a2, rel=0.05)
            assert two["weight"] == pytest.approx(s_, abs=0.03) and two["misfit"] < 0.01
        # the returned table is the distribution itself
        tab = extract_ndf(Table(wo=w, wi=w, values=f[:, None], channels="mono"), masking="smith_g1")
        peak = (s_ / a1 ** 2 + (1 - s_) / a2 ** 2) / np.pi  # D(0) of the mixture
        assert float(tab.d_nodes[0]) == pytest.approx(peak, rel=0.02)


def test_extraction_anisotropy_hint(x64):
    """Retro-reflection rows over all azimuths of an anisotropic GGX: the widths along x and y."""
    rng = np.random.default_rng(7)
    u, ph = rng.random(6000), rng.random(6000) * 2 * np.pi
    th = u ** 2 * np.pi / 2 * 0.95
    h = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1)
    tangent = np.stack([-np.sin(ph), np.cos(ph), 0 * ph], -1)
    wo = math.cos(0.01) * h + math.sin(0.01) * tangent
    wi = 2 * np.sum(wo * h, 1, keepdims=True) * h - wo
    ok = (wo[:, 2] > 0) & (wi[:, 2] > 0)
    for ax, ay in ((0.15, 0.3), (0.2, 0.2)):
        m = RoughConductor(ax, jnp.asarray(ETA), jnp.asarray(K), alpha_y=ay)
        f = np.asarray(_eval(m, jnp.asarray(wo[ok]), jnp.asarray(wi[ok])))
        an = ndf_start(Table(wo=wo[ok], wi=wi[ok], values=f))["anisotropy"]
        assert an["alpha_x"] == pytest.approx(ax, rel=0.05) and an["alpha_y"] == pytest.approx(ay, rel=0.05)
        assert an["ratio"] == pytest.approx(max(ax, ay) / min(ax, ay), rel=0.05)
        if ax != ay:
            assert an["phi_wide"] == pytest.approx(np.pi / 2, abs=0.05)


# ------------------------------------------------------------------------------------------------
# A MERL surrogate (shared/tools/merl_surrogate.py): a sensible alpha
# ------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def surrogate():
    """The surrogate's retro-reflection cells (MERL's theta_h axis, theta_d indices 0 and 1, every
    phi_d; phi_h = 0 as in a MERL file) as a Table, and its raw values there, per material."""
    if not (TOOL.is_file() and WEIGHTS.is_file()):
        pytest.skip(f"shared data not found at {SHARED} (needs tools/merl_surrogate.py and data/merl_nbrdf/weights.npz)")
    sys.path.insert(0, str(TOOL.parent))
    try:
        import merl_surrogate as ms
    finally:
        sys.path.remove(str(TOOL.parent))
    from matfit.io.merl import cell_centres

    th, td, pd = cell_centres()
    TH, TD, PD = np.meshgrid(th, td[:2], pd, indexing="ij")  # (90, 2, 180)
    wo, wi = ms.half_diff_to_dirs(TH, TD, PD)
    valid = (wo[..., 2] > 0) & (wi[..., 2] > 0)
    out = {}
    for name in ("gold-metallic-paint", "steel"):
        f = ms.network_brdf(name, TH, TD, PD)  # (90, 2, 180, 3), 1/sr
        table = Table(wo=wo[valid], wi=wi[valid], values=f[valid], channels="rgb")
        out[name] = (table, f)
    return out


def _half_width_alpha(f):
    """GGX alpha of the half width of the raw retro-reflection D ~ f cos^2 (theta_d = 0.5 deg,
    luminance, mean over phi_d): tan theta_1/2 = alpha sqrt(sqrt 2 - 1)."""
    from matfit.io.merl import cell_centres

    th = cell_centres()[0]
    d = (f[:, 0] @ [0.2126, 0.7152, 0.0722]).mean(-1) * np.cos(th) ** 2
    i = int(np.argmax(d < d[0] / 2))
    t = th[i - 1] + (d[0] / 2 - d[i - 1]) * (th[i] - th[i - 1]) / (d[i] - d[i - 1])
    return math.tan(t) / math.sqrt(math.sqrt(2) - 1)


def test_merl_surrogate_alpha_is_sensible(surrogate):
    table, f = surrogate["gold-metallic-paint"]
    s = ndf_start(table)
    # one GGX-like lobe: its width is that of the measured peak, within 10 %
    assert s["lobes"] == 1 and s["distribution"] == "ggx" and s["misfit_ggx"] < 0.05
    assert s["alpha"] == pytest.approx(_half_width_alpha(f), rel=0.1)
    assert s["anisotropy"] is None  # MERL is isotropic: every row at phi_h = 0
    assert np.all((s["f0"] > 0) & (s["f0"] < 1))
    # a sharp core over a wide tail: two lobes, the narrow one about as wide as the peak
    table, f = surrogate["steel"]
    s = ndf_start(table)
    assert s["lobes"] == 2
    assert 0.5 < s["two_lobe"]["alpha"][0] / _half_width_alpha(f) < 2.0
    assert 1e-3 < s["alpha"] < 0.05


# ------------------------------------------------------------------------------------------------
# The model file and the renderer exports
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("masking", ["separable", "height_correlated"])
def test_model_file_round_trip(masking, x64, rng, tmp_path):
    """save -> load rebuilds the same model: eval, pdf and sampling equal to rounding, against
    the reference conductor too (the loaded tables are not a copy of something else)."""
    from matfit.export import load_model, save_model

    model = model_of(ref_table("ggx", 0.3), masking=masking)
    save_model(tmp_path / "m.json", model, family="tabulated")
    back = load_model(tmp_path / "m.json")
    assert type(back) is TabulatedMicrofacet and back.masking == masking and back.ndf.sqrt_grid
    wo, wi = R.random_directions(rng, 400, "upper", 0.01), R.random_directions(rng, 400, "upper", 0.01)
    u = jnp.asarray(rng.random((400, 3)))
    f0, f1 = (np.asarray(_eval(m, jnp.asarray(wo), jnp.asarray(wi))) for m in (model, back))
    np.testing.assert_allclose(f1, f0, rtol=1e-12, atol=0)
    (p0, s0), (p1, s1) = (_pdf_sample(m, jnp.asarray(wo), jnp.asarray(wi), u) for m in (model, back))
    np.testing.assert_allclose(np.asarray(p1), np.asarray(p0), rtol=1e-12)
    for a, b in zip(s0, s1):
        np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(f1, R.conductor_eval(wo, wi, R.Dist("ggx", 0.3), ETA, K, masking), rtol=5e-4)


def test_model_file_rejects_a_bad_table(x64, tmp_path):
    import json

    from matfit.errors import DataFormatError
    from matfit.export import load_model, save_model

    save_model(tmp_path / "m.json", model_of(ref_table("ggx", 0.3, n=32)))
    doc = json.loads((tmp_path / "m.json").read_text())
    assert doc["model"]["type"] == "TabulatedMicrofacet" and doc["model"]["ndf"]["type"] == "TabulatedNDF"
    for change, match in ((lambda nd: nd["d"].__setitem__(3, -1.0), "d must be >= 0"),
                          (lambda nd: nd.pop("theta"), "missing \\['theta'\\]"),
                          (lambda nd: nd.__setitem__("n_lambda", 2.5), "n_lambda: expected an integer"),
                          (lambda nd: nd.__setitem__("d", "many"), "expected a list of numbers")):
        bad = json.loads(json.dumps(doc))
        change(bad["model"]["ndf"])
        (tmp_path / "bad.json").write_text(json.dumps(bad))
        with pytest.raises(DataFormatError, match=match):
            load_model(tmp_path / "bad.json")


@pytest.mark.parametrize("kind", ["ggx", "beckmann"])
def test_nearest_analytic_width(kind, x64):
    """A table of numpy_ref's D of one family: that family's width, misfit ~0, the other family
    misfits more."""
    from matfit.microfacet import nearest_analytic

    tab = ref_table(kind, 0.3)
    other = "beckmann" if kind == "ggx" else "ggx"
    near, far = nearest_analytic(tab, kind), nearest_analytic(tab, other)
    assert near["alpha"] == pytest.approx(0.3, rel=2e-3) and near["misfit"] < 5e-3
    assert far["misfit"] > 10 * near["misfit"]
    with pytest.raises(ParameterError, match="distribution must be one of"):
        nearest_analytic(tab, "phong")
    with pytest.raises(ParameterError, match="must be a matfit.microfacet.TabulatedNDF"):
        nearest_analytic(GGX(0.3))


@pytest.mark.parametrize("to", ["mitsuba", "mitsuba-xml", "pbrt"])
def test_renderer_export_names_the_model_and_the_nearest_analytic_fit(to, x64):
    """Mitsuba 3 and pbrt-v4 have no tabulated microfacet distribution: a ParameterError naming
    TabulatedMicrofacet and the nearest analytic conductor (the table's own width), also for a
    tabulated lobe inside a Blend."""
    from matfit.export import export
    from matfit.models import Blend, Lambert

    tab = model_of(ref_table("beckmann", 0.15), masking="height_correlated")
    for model in (tab, Blend(tab, Lambert([0.2, 0.2, 0.2]), 0.5)):
        with pytest.raises(ParameterError) as err:
            export(model, to)
        msg = str(err.value)
        assert "TabulatedMicrofacet" in msg and "RoughConductor(alpha=" in msg
        alpha = float(msg.split("RoughConductor(alpha=")[1].split(",")[0])
        assert alpha == pytest.approx(0.15, rel=5e-3)
        assert "distribution='beckmann'" in msg and "masking='height_correlated'" in msg
