"""Statistical tests of every model's importance sampling (see tests/chi2.py for the machinery).

1. Chi-square goodness of fit of ``sample(wo, u)`` against ``pdf(wo, wi)``:
   * "sphere" cases: cells in (cos theta, phi) over the whole sphere (lobes of alpha >= 0.3);
   * "slope" cases: cells in the stretched space of the (generalised) half vector, one grid per
     region (reflection / transmission), so that lobes down to alpha = 1e-3 are resolved.
   Both include an "invalid sample" bin (pdf == 0) whose expected count is 1 - int(pdf), so the
   rejected fraction is tested too. Significance: 0.01 / (number of chi-square tests) (Bonferroni).
2. Weight / pdf consistency of the returned samples with ``eval`` and ``pdf``.
3. int pdf d omega (quadrature) == fraction of valid samples, within 1 %.
4. Directional albedo <= 1 (mc and quadrature), the albedo == mean sample weight, and the
   single-scattering energy loss of GGX at alpha = 1 against an independent quadrature and the
   analytic value 1 - ln 2 at normal incidence.
5. Delta models.

Everything runs in float32 (inputs and parameters are explicit float32 arrays, so the tests give the
same results whether or not another test switched x64 on). Random numbers come from fixed seeds.
"""

from __future__ import annotations

import functools
import math
import os
import sys
import zlib
from dataclasses import dataclass
from typing import Optional

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import catalogue as C  # noqa: E402
import chi2 as c2  # noqa: E402
import numpy_ref as R  # noqa: E402

from matfit import microfacet as mf  # noqa: E402
from matfit.models import Lambert, RoughConductor, RoughDielectric, SmoothConductor, SmoothDielectric  # noqa: E402

F32 = np.float32
CHUNK = 1 << 15
N_SAMPLES = 4 * CHUNK  # 131072  # fixed batch size of pdf evaluations in the quadrature (no recompilation)

COMBOS = [("ggx", "visible"), ("ggx", "dcos"), ("beckmann", "visible"), ("beckmann", "dcos"), ("blinn_phong", "dcos")]
ALPHAS = [1e-3, 0.05, 0.3, 1.0]
INCS = [0.0, 30.0, 60.0, 89.0]
ETAS = list(C.DIELECTRIC_ETAS)
ANISO = (0.1, 0.4)
COND_ETA = (0.2, 0.9, 1.5)  # a 3-channel conductor (C = 3)
COND_K = (3.0, 2.5, 1.8)
#: a conductor with one nearly white channel (k = 10) and one with k = 0
METAL_ETA, METAL_K = np.array([0.2, 1.0, 1.5]), np.array([3.0, 10.0, 0.0])


def f32(x):
    return C.arr(x, F32)


# ------------------------------------------------------------------------------------------------
# Cases
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Case:
    model: str  # lambert | conductor | dielectric
    space: str  # sphere | slope
    dist: str = "ggx"
    sampling: str = "visible"
    alpha: float = 0.3
    alpha_y: Optional[float] = None
    deg: float = 0.0
    eta: float = 1.5
    inside: bool = False
    masking: str = "separable"
    phi: float = 0.3  # azimuth of wo

    @property
    def id(self):
        if self.model == "lambert":
            return f"lambert-{self.space}-{self.deg:g}deg"
        a = f"{self.alpha:g}" if self.alpha_y in (None, self.alpha) else f"{self.alpha:g}x{self.alpha_y:g}"
        s = f"{self.model}-{self.space}-{self.dist}-{self.sampling}-a{a}-{self.deg:g}deg-{self.masking[:3]}"
        if self.model == "dielectric":
            s += f"-eta{self.eta:g}-{'in' if self.inside else 'out'}"
        return s

    @property
    def lobe(self):
        return C.Lobe(self.dist, self.masking, self.alpha, self.alpha_y, self.sampling)

    def make(self):
        if self.model == "lambert":
            return Lambert(f32(C.RGB))
        if self.model == "conductor":
            return C.rough_conductor(self.lobe, COND_ETA, COND_K, F32)
        return C.rough_dielectric(self.lobe, self.eta, F32)

    def wo(self):
        w = C.from_degrees(self.deg, self.phi, self.inside)
        return (w / np.linalg.norm(w)).astype(F32)

    @property
    def alphas(self):
        return self.alpha, self.alpha if self.alpha_y is None else self.alpha_y

    @property
    def etap_t(self):
        """Relative index for transmission: eta from outside, 1/eta from inside."""
        return 1.0 / self.eta if self.inside else self.eta


MASKING = {  # one masking form per (distribution, sampling): both forms for GGX and Beckmann
    ("ggx", "visible"): "height_correlated", ("ggx", "dcos"): "separable",
    ("beckmann", "visible"): "separable", ("beckmann", "dcos"): "height_correlated",
    ("blinn_phong", "dcos"): "separable",
}


def _cases():
    """~180 cases. The number of jit compilations is bounded by using one model structure per
    (class, distribution, sampling): alpha_y is always passed explicitly (= alpha when isotropic;
    alpha_y=None is compared with it in test_alpha_y_none) and the masking form is tied to the
    (distribution, sampling) combination. Parameter grids are covered in Latin-square fashion:
    every (combination, alpha, incidence) for the conductor; for the dielectric every
    (combination, alpha, incidence) on one of the two sides, with eta cycling through ETAS."""
    cases = [Case("lambert", "sphere", deg=d) for d in INCS]
    for ci, (dist, smp) in enumerate(COMBOS):
        mk = MASKING[dist, smp]
        for ia, a in enumerate(ALPHAS):
            for ii, d in enumerate(INCS):
                # every (alpha, incidence) pair for GGX visible sampling, half of them otherwise
                if (dist, smp) == ("ggx", "visible") or (ia + ii + ci) % 2 == 0:
                    cases.append(Case("conductor", "slope", dist, smp, a, a, deg=d, masking=mk))
        for ia, a in enumerate((0.3, 1.0)):
            d = (30.0, 89.0)[(ia + ci) % 2]
            cases.append(Case("conductor", "sphere", dist, smp, a, a, deg=d, masking=mk))
        for side in (False, True):
            for ia, a in enumerate(ALPHAS):
                for ii, d in enumerate(INCS):
                    if (ia + ii + ci + side) % 2:
                        continue
                    eta = ETAS[(ia + ii // 2 + ci + side) % 4]
                    cases.append(Case("dielectric", "slope", dist, smp, a, a, deg=d, eta=eta, inside=side,
                                      masking=mk))
            for ie, eta in enumerate((1.5, 3.0, 0.67)):
                if (ie + ci + side) % 3 == 2:
                    continue
                a = (0.3, 1.0)[(ie + ci + side) % 2]
                d = INCS[(ie + ci + 2 * side) % 4]
                cases.append(Case("dielectric", "sphere", dist, smp, a, a, deg=d, eta=eta, inside=side,
                                  masking=mk))
        if dist != "blinn_phong":
            for d in INCS:
                cases.append(Case("conductor", "slope", dist, smp, ANISO[0], ANISO[1], deg=d, phi=0.7,
                                  masking=mk))
            for side in (False, True):
                d = INCS[(ci + 2 * side) % 4]
                cases.append(Case("dielectric", "slope", dist, smp, ANISO[0], ANISO[1], deg=d, phi=0.7,
                                  eta=ETAS[(ci + side) % 4], inside=side, masking=mk))
    return cases


CASES = _cases()
N_CHI2 = len(CASES)
P_MIN = 0.01 / N_CHI2  # Bonferroni


# ------------------------------------------------------------------------------------------------
# Jitted model calls (parameters are dynamic leaves: one compilation per model structure)
# ------------------------------------------------------------------------------------------------
@eqx.filter_jit
def _sample_all(model, wo, u):
    """sample() and, at the sampled directions, pdf(), eval() and the energy factor."""
    wi, weight, pdf = model.sample(wo, u)
    return wi, weight, pdf, model.pdf(wo, wi), model.eval(wo, wi), model.energy_factor(wo, wi)


@eqx.filter_jit
def _pdf(model, wo, wi):
    return model.pdf(wo, wi)


def sample_all(model, wo, u):
    """_sample_all in fixed-size chunks (one compilation per model structure), as float64 numpy."""
    wob = jnp.broadcast_to(f32(wo), (CHUNK, 3))
    outs = [_sample_all(model, wob, f32(u[s:s + CHUNK])) for s in range(0, len(u), CHUNK)]
    return [np.concatenate([np.asarray(o[i], np.float64) for o in outs]) for i in range(6)]


def pdf_batched(model, wo, wi):
    """Library pdf at float64 directions wi (n, 3) for one wo, in fixed-size float32 chunks."""
    wi = np.asarray(wi, np.float64).reshape(-1, 3)
    n = len(wi)
    out = np.empty(n)
    wob = jnp.broadcast_to(f32(wo), (CHUNK, 3))
    for s in range(0, n, CHUNK):
        blk = wi[s:s + CHUNK]
        m = len(blk)
        if m < CHUNK:
            blk = np.concatenate([blk, np.tile([[0.0, 0.0, 1.0]], (CHUNK - m, 1))])
        out[s:s + m] = np.asarray(_pdf(model, wob, f32(blk)), np.float64)[:m]
    return out


def _seed(*parts):
    return zlib.crc32("|".join(map(str, parts)).encode())


# ------------------------------------------------------------------------------------------------
# One case: sample, bin, integrate, compare
# ------------------------------------------------------------------------------------------------
@dataclass
class CaseResult:
    chi2: c2.Chi2Result
    integral: float  # int pdf d omega (quadrature)
    unresolved: float  # quadrature error estimate of the integral
    frac_valid: float
    n: int
    bad_invalid: int  # samples with pdf == 0 but weight != 0, or non-finite output
    pdf_relerr: float  # quantiles of |pdf_sample - pdf(wo, wi)| / pdf(wo, wi)
    pdf_relerr_max: float
    w_relerr: float  # same for weight vs eval |cos| / pdf
    w_relerr_max: float
    worst_sample: str
    mean_energy: np.ndarray  # mean of weight * energy_factor (MC albedo), per channel
    se_energy: np.ndarray


def _relerr(a, b):
    return np.abs(a - b) / np.maximum(np.abs(b), 1e-30)


@functools.lru_cache(maxsize=None)
def run_case(case: Case) -> CaseResult:
    model = case.make()
    wo = case.wo()
    wo64 = wo.astype(np.float64)
    n = N_SAMPLES
    rng = np.random.default_rng(_seed(case.id))
    u = rng.random((n, 3), dtype=F32)
    wi, w, p, p_re, ev, en = sample_all(model, wo, u)

    finite = np.isfinite(wi).all(-1) & np.isfinite(w).all(-1) & np.isfinite(p)
    valid = finite & (p > 0)
    bad_invalid = int(np.sum(~finite) + np.sum((p == 0) & (np.abs(w).max(-1) != 0)) + np.sum(p < 0))

    # -- 2. consistency of the returned weight and pdf
    sel = valid & (p_re > 0)
    e_pdf = _relerr(p[sel], p_re[sel])
    w_ref = ev[sel] * np.abs(wi[sel, 2:3]) / p_re[sel, None]
    e_w = _relerr(w[sel], w_ref).max(-1)
    nope = valid & ~(p_re > 0)  # sampled with pdf > 0 where pdf(wo, wi) says 0
    worst = ""
    if np.any(sel):
        k = np.argmax(e_w)
        j = np.flatnonzero(sel)[k]
        worst = (f"worst weight: wi={wi[j]}, weight={w[j]}, eval*cos/pdf={w_ref[k]}, "
                 f"pdf_sample={p[j]:.6g}, pdf={p_re[j]:.6g}")
    if np.any(nope):
        j = np.flatnonzero(nope)[0]
        worst += f"; {np.sum(nope)} samples with pdf_sample > 0 but pdf(wo, wi) == 0, e.g. wi={wi[j]} pdf={p[j]}"
    q = (lambda e: float(np.quantile(e, 0.999)) if len(e) else 0.0)
    mx = (lambda e: float(e.max()) if len(e) else 0.0)

    energy = np.where(valid[:, None], w * en[:, None], 0.0)

    # -- 1./3. chi-square and integral
    labels, obs, exp_p = [], [], []
    unresolved = 0.0
    if case.space == "sphere":
        g = c2.SphereGrid(24, 48)
        P, unresolved = c2.cell_probabilities(lambda x, y: pdf_batched(model, wo64, g.to_dir(x, y)),
                                              g.xedges, g.yedges, n_samples=n)
        x, y = g.from_dir(wi[valid])
        H, _, _ = np.histogram2d(x, y, [g.xedges, g.yedges])
        obs.append(H.ravel())
        exp_p.append(P.ravel())
        labels.append((g, "", g.n_cos * g.n_phi))
    else:
        ax, ay = case.alphas
        g = c2.SlopeGrid(ax, ay, 20, 40)
        regions = ["reflection"] + (["transmission"] if case.model == "dielectric" else [])
        side = np.sign(wo64[2])
        refl_s = wi[:, 2] * wo64[2] > 0
        for reg in regions:
            if reg == "reflection":
                def dens(t, ph):
                    m, j = g.to_m(t, ph)
                    wi_m, jr = c2.wi_from_m_reflect(wo64, m)
                    ok = wi_m[:, 2] * side > 0
                    v = np.zeros(len(t))
                    v[ok] = pdf_batched(model, wo64, wi_m[ok]) * (j * jr)[ok]
                    return v
                m_s = c2.half_vector_reflect(wo64, wi[valid & refl_s])
            else:
                etap = case.etap_t

                def dens(t, ph):
                    m, j = g.to_m(t, ph)
                    wi_m, jt, okr = c2.wi_from_m_refract(wo64, m, etap)
                    ok = okr & (wi_m[:, 2] * side < 0) & (np.sum(wo64 * m, -1) * side > 0)
                    v = np.zeros(len(t))
                    v[ok] = pdf_batched(model, wo64, wi_m[ok]) * (j * jt)[ok]
                    return v
                m_s = c2.half_vector_refract(wo64, wi[valid & ~refl_s], etap)
            P, un = c2.cell_probabilities(dens, g.xedges, g.yedges, n_samples=n)
            unresolved += un
            t, ph = g.from_m(m_s)
            H, _, _ = np.histogram2d(t, ph, [g.xedges, g.yedges])
            obs.append(H.ravel())
            exp_p.append(P.ravel())
            labels.append((g, f"{reg}: ", g.n_t * g.n_phi))
    integral = float(sum(e.sum() for e in exp_p))
    obs.append([np.sum(~valid)])
    exp_p.append([max(0.0, 1.0 - integral)])

    def label(k):
        for grid, prefix, size in labels:
            if k < size:
                return prefix + grid.describe(*divmod(k, grid.yedges.size - 1))
            k -= size
        return "invalid samples (pdf == 0)"
    res = c2.chi2_test(np.concatenate(obs), n * np.concatenate(exp_p), label)
    return CaseResult(
        chi2=res, integral=integral, unresolved=unresolved, frac_valid=float(np.mean(valid)), n=n,
        bad_invalid=bad_invalid, pdf_relerr=q(e_pdf), pdf_relerr_max=mx(e_pdf), w_relerr=q(e_w),
        w_relerr_max=mx(e_w), worst_sample=worst, mean_energy=energy.mean(0),
        se_energy=energy.std(0) / math.sqrt(n))


CASE_IDS = [c.id for c in CASES]


# ------------------------------------------------------------------------------------------------
# 1. chi-square goodness of fit
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("case", CASES, ids=CASE_IDS)
def test_chi2(case):
    r = run_case(case)
    assert r.chi2.pvalue > P_MIN, (
        f"{case.id}: sample() does not follow pdf() (Bonferroni threshold {P_MIN:.2g}, {N_CHI2} tests); "
        f"int pdf = {r.integral:.5f}, valid fraction = {r.frac_valid:.5f}\n" + r.chi2.summary(8))


# ------------------------------------------------------------------------------------------------
# 2. weight == eval |cos| / pdf and returned pdf == pdf(wo, wi); invalid samples are zero
# ------------------------------------------------------------------------------------------------
W_RTOL = 1e-4


def check_sampled(r, n_cases):
    """The sampling checks of a model file's own cases (:func:`run_case`'s result ``r``, one of
    ``n_cases`` chi^2 tests): weight == f cos / pdf and the returned pdf == pdf(wo, wi), invalid
    samples 0; the valid fraction equals int pdf (lobe samples below the horizon are the invalid
    ones); the samples follow the pdf (chi^2, Bonferroni over the cases)."""
    assert r.bad_invalid == 0 and "pdf(wo, wi) == 0" not in r.worst_sample, r.worst_sample
    assert r.pdf_relerr < W_RTOL and r.w_relerr < W_RTOL, r.worst_sample
    assert r.pdf_relerr_max < 1e-2 and r.w_relerr_max < 1e-2, r.worst_sample
    sig = math.sqrt(max(r.frac_valid * (1 - r.frac_valid), 1.0 / r.n) / r.n)
    assert r.integral <= 1 + 1e-3 + r.unresolved
    assert abs(r.integral - r.frac_valid) <= 0.01 * r.integral + 5 * sig + r.unresolved
    assert r.chi2.pvalue > 0.01 / n_cases, r.chi2.summary(8)


@pytest.mark.parametrize("case", CASES, ids=CASE_IDS)
def test_weight_consistency(case):
    r = run_case(case)
    assert r.bad_invalid == 0, f"{case.id}: {r.bad_invalid} samples non-finite or with pdf == 0 but weight != 0"
    msg = (f"{case.id}: 99.9% quantile / max rel. error: pdf {r.pdf_relerr:.2e} / {r.pdf_relerr_max:.2e}, "
           f"weight {r.w_relerr:.2e} / {r.w_relerr_max:.2e}; {r.worst_sample}")
    assert "pdf(wo, wi) == 0" not in r.worst_sample, msg
    assert r.pdf_relerr < W_RTOL and r.w_relerr < W_RTOL, msg
    assert r.pdf_relerr_max < 1e-2 and r.w_relerr_max < 1e-2, msg


# ------------------------------------------------------------------------------------------------
# 3. the pdf integrates to the fraction of valid samples (1 when nothing is rejected)
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("case", CASES, ids=CASE_IDS)
def test_pdf_integral(case):
    r = run_case(case)
    sig = math.sqrt(max(r.frac_valid * (1 - r.frac_valid), 1.0 / r.n) / r.n)
    tol = 0.01 * max(r.frac_valid, r.integral) + 5 * sig + r.unresolved
    assert r.integral <= 1.0 + 1e-3 + r.unresolved, f"{case.id}: int pdf = {r.integral:.5f} > 1"
    assert abs(r.integral - r.frac_valid) <= tol, (
        f"{case.id}: int pdf d omega = {r.integral:.5f} but {r.frac_valid:.5f} of the samples are valid "
        f"(tolerance {tol:.4f})")


# ------------------------------------------------------------------------------------------------
# 4a. the MC albedo of every case (mean of weight * energy factor) is <= 1
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("case", CASES, ids=CASE_IDS)
def test_sampled_albedo_le_1(case):
    r = run_case(case)
    lim = 1.0 + 5 * r.se_energy + 1e-4
    if case.dist == "blinn_phong" and case.alpha > 0.3:
        # Documented model limitation (docs/models.md, "Blinn-Phong energy"): Beckmann's Lambda
        # standing in for Blinn-Phong's own Smith Lambda under-masks at grazing incidence for
        # alpha > 0.3; with F = 1 the albedo reaches 1.31 at alpha = 1, 89 deg. Hold that bound.
        lim = 1.35 + 5 * r.se_energy
    assert np.all(r.mean_energy <= lim), (
        f"{case.id}: mean sample weight (MC directional albedo) {r.mean_energy} > 1 (+5 SE = {lim})")


# ------------------------------------------------------------------------------------------------
# The independent float64 reference: numpy_ref.ggx_conductor_albedo (quadrature), checked here
# ------------------------------------------------------------------------------------------------
ggx_albedo_ref = R.ggx_conductor_albedo


# Blender Cycles, src/scene/shader.tables, table_ggx_E (albedo of the height-correlated Smith GGX
# conductor with F = 1, tabulated by MC; row j: mu = j/31, column i: alpha = (i/31)^2).
CYCLES_GGX_E = [  # (mu, alpha, E)
    (1.0, 1.0, 0.306853),
    (16 / 31, 1.0, 0.443841),
    (8 / 31, 1.0, 0.591195),
    (1.0, (15 / 31) ** 2, 0.926694),
    (16 / 31, (20 / 31) ** 2, 0.746651),
]


def test_reference_quadrature_matches_literature():
    """Our independent quadrature reproduces the analytic 1 - ln 2 (alpha = 1, normal incidence:
    D = 1/pi, Lambda(wo) = 0, G1(wi) = 2 mu / (1 + mu), for both Smith forms) and Cycles' table."""
    for form in ("separable", "height_correlated"):
        assert ggx_albedo_ref(1.0, 1.0, form) == pytest.approx(1 - math.log(2), abs=1e-6)
    for mu, a, e in CYCLES_GGX_E:
        assert ggx_albedo_ref(mu, a, "height_correlated", n=256) == pytest.approx(e, abs=2e-5)


# ------------------------------------------------------------------------------------------------
# 4b. GGX single-scattering energy loss at alpha = 1 (matfit's microfacet functions and model)
# ------------------------------------------------------------------------------------------------
@eqx.filter_jit
def _d_g2(d, wo, wi, h, form):
    return d.D(h), d.G2(wo, wi, h, form)


@pytest.mark.parametrize("form", ["separable", "height_correlated"])
def test_ggx_energy_loss_alpha1(form):
    wi, wts = R.upper_hemisphere_rule(128)
    wi, wts = wi.reshape(-1, 3), wts.ravel()
    d = mf.GGX(f32(1.0))
    for deg in (0.0, 45.0, 80.0):
        mu_o = math.cos(math.radians(deg))
        wo = np.array([math.sin(math.radians(deg)), 0.0, mu_o])
        h = (wi + wo) / np.linalg.norm(wi + wo, axis=-1, keepdims=True)
        wo_b = f32(np.broadcast_to(wo, wi.shape))
        Dv, G2 = (np.asarray(v, np.float64) for v in _d_g2(d, wo_b, f32(wi), f32(h), form))
        e_lib = float(np.sum(Dv * G2 / (4 * mu_o) * wts))
        e_ref = ggx_albedo_ref(mu_o, 1.0, form)
        assert e_lib == pytest.approx(e_ref, rel=2e-4), (deg, e_lib, e_ref)
        assert e_ref < 0.7  # more than 30 % of the energy is lost by single scattering at alpha = 1
    assert ggx_albedo_ref(1.0, 1.0, form) == pytest.approx(1 - math.log(2), abs=1e-6)


@eqx.filter_jit
def _albedo(model, wo, method, n, key):
    return model.albedo(wo, method=method, n=n, key=key)


def test_rough_conductor_albedo_vs_reference():
    """RoughConductor GGX albedo (quadrature and MC) against the independent quadrature, with the
    exact conductor Fresnel (3 channels, one of them nearly white), alpha = 1
    (height-correlated masking; the separable form is checked through the microfacet functions
    in test_ggx_energy_loss_alpha1)."""
    form = "height_correlated"
    eta, k = METAL_ETA, METAL_K
    degs = np.array([0.0, 45.0, 80.0])
    wo = C.from_degrees(degs)
    for alpha in (1.0,):
        model = RoughConductor(f32(alpha), f32(eta), f32(k), distribution="ggx", masking=form, alpha_y=f32(alpha))
        eq = np.asarray(_albedo(model, f32(wo), "quadrature", 128, None), np.float64)
        emc = np.asarray(_albedo(model, f32(wo), "mc", 1 << 15, jax.random.PRNGKey(7)), np.float64)
        for i, deg in enumerate(degs):
            ref = ggx_albedo_ref(math.cos(math.radians(deg)), alpha, form, eta, k)
            assert np.allclose(eq[i], ref, rtol=2e-3, atol=2e-4), (alpha, deg, eq[i], ref)
            assert np.allclose(emc[i], ref, rtol=0, atol=1.5e-2), (alpha, deg, emc[i], ref)
            if alpha == 1.0:
                assert np.all(ref < 0.75)


# ------------------------------------------------------------------------------------------------
# 4c. model.albedo(method="mc" | "quadrature") <= 1 over a parameter grid (vmapped over parameters)
# ------------------------------------------------------------------------------------------------
def _wos(degs, inside=False):
    return C.from_degrees(degs, 0.4, inside)


@eqx.filter_jit
def _albedo_grid(models, wo, method, n, key):
    return eqx.filter_vmap(lambda m: m.albedo(wo, method=method, n=n, key=key))(models)


GRID_DEGS = [0.0, 30.0, 60.0, 85.0]


LAMBERT_GRID = np.array([[1.0, 0.5, 0.0], [0.9, 0.2, 0.7]])


def _albedo_models():
    a = np.array([0.05, 0.3, 1.0])
    out = {"lambert": (Lambert(f32(LAMBERT_GRID)), False)}
    A, E = np.meshgrid(a, [0.5, 2.0], indexing="ij")
    A, E = A.ravel(), E.ravel()
    out["conductor"] = (RoughConductor(f32(A), f32(np.stack([E, 0.2 * E, 1.0 + 0 * E], -1)),
                                       f32(np.stack([0 * E, 3.0 + 0 * E, 20.0 + 0 * E], -1)),
                                       distribution="ggx", masking="height_correlated", alpha_y=f32(A)), False)
    A, E = np.meshgrid([0.3, 1.0], [1.5, 3.0, 0.67], indexing="ij")
    A, E = A.ravel(), E.ravel()
    out["dielectric"] = (RoughDielectric(f32(A), f32(E), distribution="ggx", masking="height_correlated",
                                         alpha_y=f32(A)), True)
    return out


@pytest.mark.parametrize("name", ["lambert", "conductor", "dielectric"])
def test_model_albedo_le_1(name):
    model, two_sided = _albedo_models()[name]
    sides = (False, True) if two_sided else (False,)
    for inside in sides:
        wo = f32(_wos(GRID_DEGS, inside))
        eq = np.asarray(_albedo_grid(model, wo, "quadrature", 64, None), np.float64)
        emc = np.asarray(_albedo_grid(model, wo, "mc", 1 << 14, jax.random.PRNGKey(3)), np.float64)
        assert np.all(np.isfinite(eq)) and np.all(np.isfinite(emc))
        assert np.all(eq <= 1 + 2e-3), f"{name} inside={inside}: quadrature albedo max {eq.max()}"
        # MC: weights are bounded by ~1 for these models, so 2^14 samples give SE < ~4e-3
        assert np.all(emc <= 1 + 2e-2), f"{name} inside={inside}: MC albedo max {emc.max()}"
        if name == "lambert":
            alb = LAMBERT_GRID[:, None, :]
            assert np.allclose(eq, alb, atol=1e-3) and np.allclose(emc, alb, atol=1e-6)
        else:
            # quadrature (lobes >= 0.3 wide are resolved by the 64-point rule) vs MC
            sel = np.asarray(model.alpha) >= 0.3
            assert np.allclose(eq[sel], emc[sel], atol=2.5e-2), np.abs(eq[sel] - emc[sel]).max()


# ------------------------------------------------------------------------------------------------
# 5. delta models
# ------------------------------------------------------------------------------------------------
@eqx.filter_jit
def _delta_all(model, wo, u, wr):
    wi, weight, pdf = model.sample(wo, u)
    return wi, weight, pdf, model.eval(wo, wi), model.pdf(wo, wi), model.eval(wo, wr), model.pdf(wo, wr)


N_DELTA = 1 << 15


@pytest.mark.parametrize("inside", [False, True], ids=["outside", "inside"])
def test_smooth_conductor(inside):
    eta, k = METAL_ETA, METAL_K
    model = SmoothConductor(f32(eta), f32(k))
    rng = np.random.default_rng(_seed("smooth_conductor", inside))
    degs = np.array(INCS + [45.0, 75.0])
    wo = _wos(degs, inside)
    wob = np.repeat(wo, 64, axis=0)
    u = rng.random((len(wob), 3), dtype=F32)
    wi, w, p, ev, pd, ev2, pd2 = (np.asarray(a, np.float64) for a in
                                  _delta_all(model, f32(wob), f32(u), f32(R.random_directions(rng, len(wob), "both"))))
    assert np.all(ev == 0) and np.all(pd == 0) and np.all(ev2 == 0) and np.all(pd2 == 0)
    if inside:  # one-sided: nothing is reflected from below
        assert np.all(w == 0) and np.all(p == 0)
        return
    assert np.allclose(wi, wob * np.array([-1, -1, 1]), atol=2e-6)
    F = R.fresnel_conductor(wob[:, 2:3], eta, k)
    assert np.allclose(w, F, rtol=1e-4, atol=1e-6), np.abs(w - F).max()
    assert np.allclose(p, 1.0)


@pytest.mark.check
@pytest.mark.parametrize("eta", ETAS)
@pytest.mark.parametrize("inside", [False, True], ids=["outside", "inside"])
def test_smooth_dielectric(eta, inside):
    model = SmoothDielectric(f32(eta))
    rng = np.random.default_rng(_seed("smooth_dielectric", eta, inside))
    degs = INCS + [45.0, 75.0]
    n = N_DELTA
    etap = 1 / eta if inside else eta
    for deg in degs:
        wo = _wos([deg], inside)[0]
        wob = np.broadcast_to(wo, (n, 3))
        u = rng.random((n, 3), dtype=F32)
        wi, w, p, ev, pd, ev2, pd2 = (np.asarray(a, np.float64) for a in
                                      _delta_all(model, f32(wob), f32(u), f32(R.random_directions(rng, n, "both"))))
        assert np.all(ev == 0) and np.all(pd == 0) and np.all(ev2 == 0) and np.all(pd2 == 0)
        assert np.all(np.isfinite(wi)) and np.all(np.isfinite(w)) and np.all(p > 0)
        assert np.allclose(np.linalg.norm(wi, axis=-1), 1, atol=1e-5)
        F = float(R.fresnel_dielectric(wo[2], eta))
        refl = wi[:, 2] * wo[2] > 0
        frac = refl.mean()
        sig = math.sqrt(max(F * (1 - F), 1e-12) / n)
        what = f"eta={eta} inside={inside} deg={deg}"
        # 5 sigma: 96 (eta, side, angle) binomial tests
        assert abs(frac - F) <= 5 * sig + 1e-6, f"{what}: reflected fraction {frac:.5f} vs Fresnel {F:.5f}"
        if refl.any():
            assert np.allclose(wi[refl], wo * np.array([-1, -1, 1]), atol=2e-6), what
            assert np.allclose(w[refl], 1.0, rtol=1e-5), what
            assert np.allclose(p[refl], F, rtol=1e-4, atol=1e-7), what
        t = ~refl
        if t.any():
            # Snell: sin(theta_t) = sin(theta_o) / etap, in the plane of incidence, opposite azimuth
            sin_o = math.hypot(wo[0], wo[1])
            sin_t = np.hypot(wi[t, 0], wi[t, 1])
            assert np.allclose(sin_t, sin_o / etap, atol=2e-6), what
            if sin_o > 0:
                assert np.allclose(wi[t, :2] / sin_t[:, None], -wo[:2] / sin_o, atol=1e-5), what
            assert np.allclose(wi[t, 2], -np.sign(wo[2]) * np.sqrt(1 - (sin_o / etap) ** 2), atol=2e-6), what
            assert np.allclose(w[t], 1 / etap**2, rtol=1e-5), what
            assert np.allclose(p[t], 1 - F, rtol=1e-4, atol=1e-7), what
        if math.sin(math.radians(deg)) > etap:
            assert refl.all(), f"{what}: total internal reflection expected"


# ------------------------------------------------------------------------------------------------
# alpha_y=None (isotropic) is the same model as alpha_y = alpha (the chi-square cases use the latter)
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("cls", ["dielectric"])
def test_alpha_y_none(cls):
    rng = np.random.default_rng(_seed("alpha_y_none", cls))
    n = 512
    u = f32(rng.random((n, 3), dtype=F32))
    wo = _wos(rng.uniform(0, 85, n), inside=False) * np.where(rng.random(n) < 0.5, 1, -1)[:, None]
    for a in (0.05, 0.5):
        mk = functools.partial(RoughConductor, f32(a), f32(COND_ETA), f32(COND_K)) if cls == "conductor" else \
            functools.partial(RoughDielectric, f32(a), f32(1.5))
        m0, m1 = mk(alpha_y=None), mk(alpha_y=f32(a))
        r0 = _sample_all(m0, f32(wo), u)
        r1 = _sample_all(m1, f32(wo), u)
        for x0, x1 in zip(r0, r1):
            assert np.allclose(np.asarray(x0), np.asarray(x1), rtol=1e-5, atol=1e-6)
