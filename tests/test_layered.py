"""Layered materials: Plastic, Layered (incl. stacks and absorption), CoatedConductor, Blend.

1. Sampling (float64, 2**17 samples per case): chi-square goodness of fit of the continuous samples
   against ``pdf(wo, wi) / (1 - P_delta)`` on a (cos theta, phi) grid of the upper hemisphere, with
   an "invalid sample" bin; for smooth coats the fraction of delta samples against the discrete
   lobe probability (binomial z-test) and ``weight * pdf == delta_albedo`` for them; returned
   ``weight == eval |cos| / pdf`` and ``pdf == pdf(wo, wi)`` at the continuous samples;
   ``int pdf d omega`` == fraction of valid continuous samples.
2. Energy <= 1 (MC, + 5 standard errors) over a parameter grid (white bases, several eta, alpha,
   incidences); reciprocity of ``eval``.
3. Limits: coat eta = 1 is the base alone; a smooth lossless coat on a white Lambertian base
   (Plastic, internal_reflection=True) has albedo 1; the closed-form albedo under a smooth coat
   with the Fresnel terms of the independent numpy reference (numpy_ref); a thick absorbing coat leaves only
   the coat's reflection.
4. Gradients w.r.t. every parameter leaf against central finite differences (float64) for
   Plastic and CoatedConductor.
5. float32 and float64: finite values and gradients, including grazing and normal incidence.
"""

from __future__ import annotations

import functools
import math
import os
import sys
import zlib

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import catalogue as C  # noqa: E402
import chi2 as c2  # noqa: E402
import numpy_ref as R  # noqa: E402

from matfit.models import Blend, CoatedConductor, Lambert, Layered, Plastic  # noqa: E402
from matfit.models import RoughConductor, RoughDielectric, SmoothDielectric  # noqa: E402


@pytest.fixture(autouse=True)
def _x64():
    jax.config.update("jax_enable_x64", True)


RHO = C.RGB
SIGMA = (0.1, 0.5, 1.5)
GOLD_ETA, GOLD_K, CU_ETA, CU_K = C.GOLD_ETA, C.GOLD_K, C.CU_ETA, C.CU_K
arr = C.arr


# ------------------------------------------------------------------------------------------------
# Models. Every builder keeps the leaf shapes fixed (3 channels everywhere, scalar alpha / eta /
# thickness), so that the jitted calls below compile once per model *structure* and are reused
# across parameter values, tests and dtypes' shapes.
# ------------------------------------------------------------------------------------------------
ZERO3 = (0.0, 0.0, 0.0)
WHITE = (1.0, 1.0, 1.0)


def plastic(rho=RHO, alpha=0.0, eta=1.5, ir=True, t=np.float64):
    return Plastic(arr(rho, t), alpha=0.0 if alpha == 0 else arr(alpha, t), eta=arr(eta, t), internal_reflection=ir)


def coat(alpha, eta, t=np.float64):
    return SmoothDielectric(arr(eta, t)) if alpha == 0 else RoughDielectric(arr(alpha, t), arr(eta, t))


def lambert(rho=RHO, t=np.float64):
    return Lambert(arr(rho, t))


def conductor(alpha=0.3, eta=CU_ETA, k=CU_K, t=np.float64):
    return RoughConductor(arr(alpha, t), arr(eta, t), arr(k, t))


def layered(c_alpha, c_eta, base, thickness=0.0, sigma=ZERO3, t=np.float64):
    return Layered(coat(c_alpha, c_eta, t), base, thickness=arr(thickness, t), sigma_a=arr(sigma, t))


def coated(alpha_b=0.25, eta_b=GOLD_ETA, k_b=GOLD_K, alpha_c=0.0, eta_c=1.5, thickness=0.2, sigma=SIGMA, t=np.float64):
    return CoatedConductor(arr(alpha_b, t), arr(eta_b, t), arr(k_b, t), 0.0 if alpha_c == 0 else arr(alpha_c, t),
                           arr(eta_c, t), thickness=arr(thickness, t), sigma_a=arr(sigma, t))


def stack2(rho=RHO, eta1=1.3, eta2=1.2, a1=0.3, a2=0.5, t=np.float64):
    inner = layered(a2, eta2, lambert(rho, t), 0.2, SIGMA, t)
    return layered(a1, eta1, inner, 0.1, SIGMA[::-1], t)


def blend_rough(rho=RHO, w=0.35, cond=(GOLD_ETA, GOLD_K), t=np.float64):
    return Blend(plastic(rho, 0.3, 1.5, True, t), conductor(0.3, cond[0], cond[1], t), arr(w, t))


def blend_smooth(rho=RHO, rho_b=(0.3, 0.6, 0.9), w=0.4, t=np.float64):
    return Blend(plastic(rho, 0.0, 1.5, True, t), lambert(rho_b, t), arr(w, t))


# name -> (builder(dtype), delta info). Delta info says how the discrete lobe probability is
# computed independently: (kind, eta, rho, selection probability); kind "plastic":
# F / (F + (1 - F) mean(rho)), kind "layered": F.
MODELS = {
    "plastic-smooth-ir": (lambda t: plastic(RHO, 0.0, 1.5, True, t), ("plastic", 1.5, RHO, 1.0)),
    "plastic-smooth-noir": (lambda t: plastic(RHO, 0.0, 1.7, False, t), ("plastic", 1.7, RHO, 1.0)),
    "plastic-rough-ir": (lambda t: plastic(RHO, 0.3, 1.5, True, t), None),
    "plastic-rough-noir": (lambda t: plastic(RHO, 0.4, 1.4, False, t), None),
    "layered-smooth-lambert-abs": (lambda t: layered(0.0, 1.5, lambert(RHO, t), 0.3, SIGMA, t), ("layered", 1.5, None, 1.0)),
    "layered-rough-lambert-abs": (lambda t: layered(0.3, 1.5, lambert(RHO, t), 0.3, SIGMA, t), None),
    "layered-smooth-conductor": (lambda t: layered(0.0, 1.4, conductor(t=t), t=t), ("layered", 1.4, None, 1.0)),
    "layered-rough-conductor-abs": (lambda t: layered(0.4, 1.5, conductor(t=t), 0.2, SIGMA, t), None),
    "stack2-rough": (lambda t: stack2(t=t), None),
    "coated-conductor-smooth": (lambda t: coated(alpha_c=0.0, t=t), ("layered", 1.5, None, 1.0)),
    "coated-conductor-rough": (lambda t: coated(alpha_c=0.3, t=t), None),
    "blend-roughplastic-conductor": (lambda t: blend_rough(t=t), None),
    # A Blend of a smooth-coated Plastic (a delta lobe, but not is_delta): the Plastic is chosen
    # with probability 1 - w = 0.6 and its delta lobe must keep its discrete probability.
}
MODEL_IDS = list(MODELS)


def make(name, dtype=np.float64):
    return MODELS[name][0](dtype)


def wo_deg(deg, phi=0.3):
    return C.from_degrees(deg, phi)


def p_delta_ref(name, wo):
    info = MODELS[name][1]
    if info is None:
        return 0.0
    kind, eta, rho, sel = info
    F = float(R.fresnel_dielectric(wo[2], eta))
    if kind == "layered":
        return sel * F
    return sel * F / (F + (1 - F) * float(np.mean(rho)))


# ------------------------------------------------------------------------------------------------
# Jitted calls, fixed shapes (CHUNK rows): one compilation per model structure and dtype.
# ------------------------------------------------------------------------------------------------
CHUNK = 1 << 15


# the rough coat's transmittance table appears several times per call: compilation dominates
FAST_COMPILE = C.FAST_COMPILE


@eqx.filter_jit(compiler_options=FAST_COMPILE)
def _sample(model, wo, u):
    return model.sample(wo, u)


@eqx.filter_jit(compiler_options=FAST_COMPILE)
def _evalpdf(model, wo, wi):
    return model.eval(wo, wi), model.pdf(wo, wi)


def _pad(x, n=CHUNK):
    x = np.asarray(x, np.float64).reshape(-1, 3)
    m = len(x)
    return np.concatenate([x, np.tile([[0.0, 0.0, 1.0]], (n - m, 1))]) if m < n else x


def sample_batched(model, wo, u, dtype=np.float64):
    """sample() at rows (wo, u) (n, 3), n a multiple of CHUNK, and pdf(), eval() at the samples:
    (wi, weight, pdf, pdf(wo, wi), eval(wo, wi)) as numpy float64."""
    wo = np.broadcast_to(np.asarray(wo, np.float64), u.shape)
    outs = []
    for s in range(0, len(u), CHUNK):
        wo_b = arr(wo[s:s + CHUNK], dtype)
        wi, w, p = _sample(model, wo_b, arr(u[s:s + CHUNK], dtype))
        f, p_re = _evalpdf(model, wo_b, wi)
        outs.append((wi, w, p, p_re, f))
    return [np.concatenate([np.asarray(o[i], np.float64) for o in outs]) for i in range(5)]


def evalpdf_batched(model, wo, wi, dtype=np.float64):
    """(eval, pdf) at rows (wo, wi) of any length (broadcast), in padded CHUNK blocks."""
    wo, wi = np.broadcast_arrays(np.asarray(wo, np.float64).reshape(-1, 3), np.asarray(wi, np.float64).reshape(-1, 3))
    n = len(wi)
    fs, ps = [], []
    for s in range(0, n, CHUNK):
        m = len(wi[s:s + CHUNK])
        f, p = _evalpdf(model, arr(_pad(wo[s:s + CHUNK]), dtype), arr(_pad(wi[s:s + CHUNK]), dtype))
        fs.append(np.asarray(f, np.float64)[:m])
        ps.append(np.asarray(p, np.float64)[:m])
    return np.concatenate(fs), np.concatenate(ps)


def _seed(*parts):
    return zlib.crc32("|".join(map(str, parts)).encode())


def _upper_quadrature(n=64):
    """Gauss-Legendre in cos(theta) x midpoint in phi over the upper hemisphere: (wi, weight * cos)."""
    wi, w = R.upper_hemisphere_rule(n)
    return wi.reshape(-1, 3), (w * wi[..., 2]).ravel()


QUAD = _upper_quadrature()


def quad_albedo(model, wos):
    """Directional albedo (reflection models): quadrature of the continuous part + delta_albedo."""
    wi, wts = QUAD
    out = []
    for wo in np.asarray(wos, np.float64).reshape(-1, 3):
        f, _ = evalpdf_batched(model, wo[None], wi)
        out.append(np.sum(f * wts[:, None], 0))
    return np.array(out) + np.asarray(model.delta_albedo(arr(wos)), np.float64)


MC_DEGS = (0.0, 20.0, 40.0, 60.0, 75.0, 85.0, 89.0, 89.9)
N_MC = CHUNK // len(MC_DEGS)


def mc_albedo(model, key):
    """MC directional albedo (mean sample weight; all these models only reflect) at MC_DEGS, one
    CHUNK call: N_MC samples per angle. Returns (E, standard error), each (len(MC_DEGS), C)."""
    wo = np.repeat(np.stack([wo_deg(d) for d in MC_DEGS]), N_MC, 0)
    u = np.random.default_rng(key).random((CHUNK, 3))
    wi, w, p, _, _ = sample_batched(model, wo, u)
    assert np.all(wi[p > 0, 2] > 0), "a layered model transmitted"
    w = w.reshape(len(MC_DEGS), N_MC, -1)
    return w.mean(1), w.std(1) / math.sqrt(N_MC)


class HemiGrid(c2.SphereGrid):
    """(cos theta, phi) cells of the upper hemisphere only."""

    @property
    def xedges(self):
        return np.linspace(0.0, 1.0, self.n_cos + 1)


# ------------------------------------------------------------------------------------------------
# 1. Sampling
# ------------------------------------------------------------------------------------------------
SAMPLING_DEGS = (0.0, 45.0, 80.0)
N_SAMPLES = 4 * CHUNK
SAMPLING_CASES = [(m, d) for m in MODEL_IDS for d in SAMPLING_DEGS]
N_TESTS = len(SAMPLING_CASES)
P_MIN = 0.01 / N_TESTS  # Bonferroni over the chi-square (and binomial) tests
Z_MAX = float(stats.norm.isf(P_MIN / 2))


@functools.lru_cache(maxsize=None)
def run_sampling(name, deg):
    jax.config.update("jax_enable_x64", True)
    model = make(name)
    wo = wo_deg(deg)
    n = N_SAMPLES
    u = np.random.default_rng(_seed(name, deg)).random((n, 3))
    wi, w, p, p_re, ev = sample_batched(model, wo, u)
    r = {"n": n}
    finite = np.isfinite(wi).all(-1) & np.isfinite(w).all(-1) & np.isfinite(p)
    r["bad"] = int(np.sum(~finite) + np.sum((p <= 0) & (np.abs(w).max(-1) != 0)) + np.sum(p < 0))
    valid = finite & (p > 0)
    mirror = wo * np.array([-1.0, -1.0, 1.0])
    is_delta = valid & (np.abs(wi - mirror).max(-1) < 1e-12)
    r["p_delta_ref"] = pd = p_delta_ref(name, wo)
    r["n_delta"] = k = int(np.sum(is_delta))
    r["z_delta"] = (k - n * pd) / math.sqrt(max(n * pd * (1 - pd), 1e-12))
    delta_alb = np.asarray(model.delta_albedo(arr(wo)))
    if k:
        r["delta_pdf_err"] = float(np.max(np.abs(p[is_delta] - pd)))
        r["delta_energy_err"] = float(np.max(np.abs(w[is_delta] * p[is_delta, None] - delta_alb[None])))
        r["delta_example"] = (f"returned pdf={p[is_delta][0]:.6g} (ref {pd:.6g}), weight={w[is_delta][0]}, "
                              f"weight*pdf should be delta_albedo={delta_alb}")
    else:
        r["delta_pdf_err"] = r["delta_energy_err"] = 0.0
        r["delta_example"] = f"no delta sample; delta_albedo={delta_alb}"
    cont = ~is_delta
    vc = valid & cont
    sel = vc & (p_re > 0)
    r["n_pdf_zero"] = int(np.sum(vc & ~(p_re > 0)))
    rel = lambda a, b: np.abs(a - b) / np.maximum(np.abs(b), 1e-300)  # noqa: E731
    e_pdf = rel(p[sel], p_re[sel])
    w_ref = ev[sel] * np.abs(wi[sel, 2:3]) / p_re[sel, None]
    e_w = rel(w[sel], w_ref).max(-1)
    r["pdf_err"] = float(e_pdf.max()) if e_pdf.size else 0.0
    r["w_err"] = float(e_w.max()) if e_w.size else 0.0
    if e_w.size:
        j = int(np.argmax(e_w))
        r["w_example"] = f"wi={wi[sel][j]} weight={w[sel][j]} eval|cos|/pdf={w_ref[j]}"
    # chi-square of the continuous samples against pdf / (1 - P_delta)
    g = HemiGrid(24, 48)
    P, un = c2.cell_probabilities(lambda x, y: evalpdf_batched(model, wo[None], g.to_dir(x, y))[1],
                                  g.xedges, g.yedges, n_samples=n)
    integral = float(P.sum())
    n_c = int(np.sum(cont))
    x, y = g.from_dir(wi[vc])
    H, _, _ = np.histogram2d(x, y, [g.xedges, g.yedges])
    obs = np.concatenate([H.ravel(), [np.sum(cont & ~valid) + np.sum(vc & (wi[:, 2] < 0))]])
    scale = 1.0 / max(1.0 - pd, 1e-300)
    exp = n_c * np.concatenate([P.ravel() * scale, [max(0.0, 1.0 - integral * scale)]])

    def label(i):
        return g.describe(*divmod(i, g.n_phi)) if i < P.size else "invalid samples"
    r["chi2"] = c2.chi2_test(obs, exp, label)
    r["integral"] = integral
    r["unresolved"] = un
    r["frac_valid_cont"] = float(np.sum(vc)) / n
    return r


CASE_IDS = [f"{m}-{d:g}deg" for m, d in SAMPLING_CASES]


@pytest.mark.parametrize("name,deg", SAMPLING_CASES, ids=CASE_IDS)
def test_sampling_chi2(name, deg):
    r = run_sampling(name, deg)
    assert r["chi2"].pvalue > P_MIN, (
        f"{name} at {deg} deg: continuous samples do not follow pdf/(1-P_delta) (threshold {P_MIN:.2g}); "
        f"int pdf = {r['integral']:.5f}, valid continuous fraction = {r['frac_valid_cont']:.5f}\n"
        + r["chi2"].summary(8))


@pytest.mark.parametrize("name,deg", SAMPLING_CASES, ids=CASE_IDS)
def test_sampling_delta_fraction(name, deg):
    r = run_sampling(name, deg)
    msg = (f"{name} at {deg} deg: {r['n_delta']} delta samples of {r['n']}, expected P_delta = "
           f"{r['p_delta_ref']:.6f} (z = {r['z_delta']:.2f}); {r['delta_example']}")
    assert abs(r["z_delta"]) < Z_MAX, msg
    assert r["delta_pdf_err"] < 1e-9, msg
    assert r["delta_energy_err"] < 1e-9, msg


@pytest.mark.parametrize("name,deg", SAMPLING_CASES, ids=CASE_IDS)
def test_sampling_weight_consistency(name, deg):
    r = run_sampling(name, deg)
    assert r["bad"] == 0, f"{name} {deg}: {r['bad']} samples non-finite or pdf == 0 with weight != 0"
    assert r["n_pdf_zero"] == 0, f"{name} {deg}: {r['n_pdf_zero']} valid samples where pdf(wo, wi) == 0"
    assert r["pdf_err"] < 1e-7 and r["w_err"] < 1e-7, (
        f"{name} {deg}: max rel. err. pdf {r['pdf_err']:.2e}, weight {r['w_err']:.2e}; {r.get('w_example', '')}")


@pytest.mark.parametrize("name,deg", SAMPLING_CASES, ids=CASE_IDS)
def test_sampling_pdf_integral(name, deg):
    r = run_sampling(name, deg)
    f, n = r["frac_valid_cont"], r["n"]
    tol = 5 * math.sqrt(max(f * (1 - f), 1 / n) / n) + 2e-3 * f + r["unresolved"]
    assert abs(r["integral"] - f) <= tol, (
        f"{name} {deg}: int pdf d omega = {r['integral']:.5f}, fraction of valid continuous samples {f:.5f} "
        f"(tol {tol:.2g})")


# ------------------------------------------------------------------------------------------------
# 2. Energy and reciprocity
# ------------------------------------------------------------------------------------------------
MIRRORLIKE = (WHITE, (1e4, 1e4, 1e4))  # conductor with F ~ 1


def _energy_grid():
    """White / lossless bases over eta and alpha (same structures as MODELS: no new compilation)."""
    g = []
    for eta in (1.1, 1.5, 2.5):
        for ir in (True, False):
            g.append((f"plastic-smooth-ir{ir}-eta{eta}", lambda eta=eta, ir=ir: plastic(WHITE, 0.0, eta, ir)))
            for a in (0.05, 0.3, 1.0):
                g.append((f"plastic-rough-ir{ir}-eta{eta}-a{a}", lambda eta=eta, ir=ir, a=a: plastic(WHITE, a, eta, ir)))
        for a in (0.0, 0.05, 0.3, 1.0):
            g.append((f"layered-lambert-eta{eta}-a{a}", lambda eta=eta, a=a: layered(a, eta, lambert(WHITE))))
            g.append((f"layered-mirrorlike-eta{eta}-a{a}",
                      lambda eta=eta, a=a: layered(a, eta, conductor(0.3, *MIRRORLIKE))))
            g.append((f"coated-gold-eta{eta}-a{a}", lambda eta=eta, a=a: coated(0.1, alpha_c=a, eta_c=eta, thickness=0.0)))
        g.append((f"stack2-white-eta{eta}", lambda eta=eta: stack2(WHITE, eta1=eta, a1=0.2, a2=0.6)))
    for w in (0.0, 0.5, 1.0):
        g.append((f"blend-rough-white-w{w}", lambda w=w: blend_rough(WHITE, w, MIRRORLIKE)))
    return g


ENERGY_GRID = _energy_grid()


@pytest.mark.parametrize("label,factory", ENERGY_GRID, ids=[lab for lab, _ in ENERGY_GRID])
def test_energy_le_1(label, factory):
    e, se = mc_albedo(factory(), _seed("energy", label))
    assert np.all(np.isfinite(e))
    lim = 1.0 + 5 * se + 1e-3
    bad = np.argwhere(e > lim)
    assert bad.size == 0, (f"{label}: MC albedo > 1 at "
                           + ", ".join(f"{MC_DEGS[i]} deg ch{c}: {e[i, c]:.5f} (SE {se[i, c]:.1e})" for i, c in bad))


def _rand_pairs(seed, n, mu_min=0.01):
    rng = np.random.default_rng(seed)
    mu = rng.uniform(mu_min, 1.0, (2, n))
    phi = rng.uniform(0, 2 * np.pi, (2, n))
    s = np.sqrt(1 - mu**2)
    d = np.stack([s * np.cos(phi), s * np.sin(phi), mu], -1)
    return d[0], d[1]


@pytest.mark.parametrize("name", MODEL_IDS)
def test_reciprocity(name):
    model = make(name)
    a, b = _rand_pairs(_seed("recip", name), 8192)
    f1, _ = evalpdf_batched(model, a, b)
    f2, _ = evalpdf_batched(model, b, a)
    err = np.abs(f1 - f2) / np.maximum(np.maximum(np.abs(f1), np.abs(f2)), 1e-300)
    j = int(np.argmax(err.max(-1)))
    assert np.all(np.isfinite(f1)) and np.any(f1 > 0)
    assert err.max() < 1e-9, (f"{name}: f(wo,wi) != f(wi,wo): max rel. err {err.max():.2e} at wo={a[j]}, "
                              f"wi={b[j]}: {f1[j]} vs {f2[j]}")


# ------------------------------------------------------------------------------------------------
# 3. Limits
# ------------------------------------------------------------------------------------------------
BASES = {"lambert": lambda: lambert(RHO), "conductor": lambda: conductor()}
ALB_DEGS = (0.0, 20.0, 45.0, 60.0, 75.0, 85.0, 89.0)


@pytest.mark.parametrize("coat_kind", ["smooth", "rough"])
@pytest.mark.parametrize("base", list(BASES))
def test_limit_eta1_is_base(coat_kind, base):
    """Index-matched coat (eta = 1, no absorption) is the base alone: eval, pdf, albedo (cos >= 0.05;
    see test_limit_eta1_is_base_grazing), and sampling (MC albedo)."""
    b = BASES[base]()
    lay = layered(0.0 if coat_kind == "smooth" else 0.3, 1.0, b)
    wo, wi = _rand_pairs(_seed("eta1", coat_kind, base), 4096, 0.05)
    fl, pl = evalpdf_batched(lay, wo, wi)
    fb, pb = evalpdf_batched(b, wo, wi)
    np.testing.assert_allclose(fl, fb, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(pl, pb, rtol=1e-9, atol=1e-12)
    wos = np.stack([wo_deg(d) for d in (0.0, 40.0, 70.0)])
    # rough coat: an index-matched coat passes everything (T = 1 at every table node)
    np.testing.assert_allclose(quad_albedo(lay, wos), quad_albedo(b, wos), rtol=1e-9 if coat_kind == "smooth" else 1e-6,
                               atol=1e-12)
    assert np.all(np.asarray(lay.delta_albedo(arr(wos))) == 0)


@pytest.mark.parametrize("coat_kind", ["smooth", "rough"])
def test_limit_eta1_is_base_grazing(coat_kind):
    """The same limit within 3 degrees of grazing (cos theta_o in [0.01, 0.05])."""
    b = lambert(RHO)
    lay = layered(0.0 if coat_kind == "smooth" else 0.3, 1.0, b)
    wo, wi = _rand_pairs(_seed("eta1g", coat_kind), 256, 0.3)
    mu = np.linspace(0.01, 0.05, 256)
    wo = np.stack([np.sqrt(1 - mu**2), np.zeros_like(mu), mu], -1)
    fl, _ = evalpdf_batched(lay, wo, wi)
    fb, _ = evalpdf_batched(b, wo, wi)
    err = np.abs(fl / fb - 1).max(-1)
    j = int(np.argmax(err))
    assert err.max() < 1e-6, (f"{coat_kind} coat, eta = 1: |Layered/base - 1| up to {err.max():.3g} near grazing, "
                              f"e.g. cos_o = {mu[j]:.4f}: {fl[j]} vs {fb[j]}")


@pytest.mark.parametrize("eta", [1.2, 1.5, 2.0])
def test_limit_white_plastic_albedo_1(eta):
    m = plastic(WHITE, 0.0, eta, True)
    wos = np.stack([wo_deg(d) for d in ALB_DEGS])
    e = quad_albedo(m, wos)
    np.testing.assert_allclose(e, 1.0, atol=2e-5, err_msg=f"white Plastic, smooth coat eta={eta}: albedo != 1 "
                                                           f"at {ALB_DEGS} deg")
    emc, se = mc_albedo(m, _seed("white", eta))
    assert np.all(np.abs(emc - 1) <= 5 * se + 1e-6), f"MC albedo at {MC_DEGS} deg: {emc[:, 0]} (SE {se[:, 0]})"


@pytest.mark.parametrize("eta", [1.3, 1.5, 1.9])
def test_limit_smooth_coat_closed_form(eta):
    """E = F + (1-F) rho (1-Fi)/(1-rho Fi) (Plastic, internal reflection); F + (1-F) rho (1-Fe)
    (Plastic without: T T rho/pi); F + (1-F) rho (1-Fi) (Layered over Lambert: T T rho/(pi eta^2))."""
    F_e = R.fresnel_dielectric_average(eta)
    F_i = R.fresnel_dielectric_average(1 / eta)
    assert abs((1 - F_i) - (1 - F_e) / eta**2) < 1e-9  # self-check of the reference
    wos = np.stack([wo_deg(d) for d in ALB_DEGS])
    F = R.fresnel_dielectric(wos[:, 2], eta)[:, None]
    for rho in ((0.05, 0.5, 0.95), (0.2, 0.8, 1.0)):
        rho = np.array(rho)
        refs = {
            "plastic-ir": (plastic(rho, 0.0, eta, True), F + (1 - F) * rho * (1 - F_i) / (1 - rho * F_i)),
            "plastic-noir": (plastic(rho, 0.0, eta, False), F + (1 - F) * rho * (1 - F_e)),
            "layered": (layered(0.0, eta, lambert(rho)), F + (1 - F) * rho * (1 - F_i)),
        }
        for k, (m, ref) in refs.items():
            np.testing.assert_allclose(quad_albedo(m, wos), ref, atol=2e-5, rtol=0,
                                       err_msg=f"{k}, eta={eta}, rho={rho}: albedo vs closed form (rows {ALB_DEGS} deg)")


@pytest.mark.parametrize("base", list(BASES))
def test_limit_thick_absorbing_smooth(base):
    wos = np.stack([wo_deg(d) for d in ALB_DEGS])
    F = np.broadcast_to(R.fresnel_dielectric(wos[:, 2], 1.5)[:, None], (len(wos), 3))
    lay = layered(0.0, 1.5, BASES[base](), thickness=60.0, sigma=(1.0, 2.0, 0.5))
    np.testing.assert_allclose(quad_albedo(lay, wos), F, atol=1e-9)
    cc = coated(0.2, alpha_c=0.0, eta_c=1.5, thickness=60.0, sigma=(1.0, 2.0, 0.5))
    np.testing.assert_allclose(quad_albedo(cc, wos), F, atol=1e-9)


@pytest.mark.parametrize("base", list(BASES))
def test_limit_thick_absorbing_rough(base):
    """Thick absorbing rough coat: the albedo of the coat's reflection lobe alone
    (int f_coat cos over the upper hemisphere), by quadrature and by sampling."""
    c = coat(0.3, 1.5)
    lay = layered(0.3, 1.5, BASES[base](), thickness=60.0, sigma=(1.0, 2.0, 0.5))
    cc = coated(0.2, alpha_c=0.3, eta_c=1.5, thickness=60.0, sigma=(1.0, 2.0, 0.5))
    wos = np.stack([wo_deg(d) for d in (0.0, 30.0, 60.0, 75.0)])
    ref = quad_albedo(c, wos)[:, :1]
    np.testing.assert_allclose(quad_albedo(lay, wos), np.broadcast_to(ref, (len(wos), 3)), rtol=1e-9)
    np.testing.assert_allclose(quad_albedo(cc, wos), np.broadcast_to(ref, (len(wos), 3)), rtol=1e-9)
    # sanity of the reference: the coat's own reflection, a fraction of its full albedo
    assert np.all((ref > 0.03) & (ref < 0.2)), ref
    # sampling converges to the same (angles up to 75 deg)
    emc, se = mc_albedo(lay, _seed("thick", base))
    ref_mc = quad_albedo(c, np.stack([wo_deg(d) for d in MC_DEGS[:5]]))[:, :1]
    assert np.all(np.abs(emc[:5] - ref_mc) < 5 * se[:5] + 2e-4), (emc[:5, 0], se[:5, 0], ref_mc[:, 0])


# ------------------------------------------------------------------------------------------------
# 4. Gradients vs central finite differences (float64), and finite float32/float64 gradients
# ------------------------------------------------------------------------------------------------
NG = 128
GRAD_PAIRS = np.array([
    [wo_deg(0.0), wo_deg(30.0, phi=2.0)],
    [wo_deg(35.0), wo_deg(35.0, phi=0.3 + np.pi)],  # close to the specular pair
    [wo_deg(50.0, phi=1.0), wo_deg(70.0, phi=-1.5)],
    [wo_deg(75.0), wo_deg(20.0, phi=2.5)],
    [wo_deg(10.0), wo_deg(60.0, phi=0.1)],
])
K = len(GRAD_PAIRS)
WF = np.linspace(0.5, 1.5, 3 * K).reshape(K, 3)  # weights of eval in the objective
WP = np.linspace(0.2, 0.6, K)  # weights of pdf


def _objective(model, wo, wi, wf, wp):
    return jnp.sum(model.eval(wo, wi) * wf) + jnp.sum(model.pdf(wo, wi) * wp)


@eqx.filter_jit(compiler_options=FAST_COMPILE)
def _grad_leaves(model, wo, wi, wf, wp):
    params, static = eqx.partition(model, eqx.is_inexact_array)
    return jax.grad(lambda p: _objective(eqx.combine(p, static), wo, wi, wf, wp))(params)


def _obj_np(model, n=K):
    f, p = evalpdf_batched(model, GRAD_PAIRS[:n, 0], GRAD_PAIRS[:n, 1])
    return float(np.sum(f * WF[:n]) + np.sum(p * WP[:n]))


def _padded_pairs(wo, wi, wf, wp, dtype=np.float64):
    m = len(wo)
    return (arr(_pad(wo, NG), dtype), arr(_pad(wi, NG), dtype),
            arr(np.concatenate([wf, np.zeros((NG - m, 3))]), dtype), arr(np.concatenate([wp, np.zeros(NG - m)]), dtype))


def _fd_check(label, grads, x0, rebuild):
    """Compare grads (list of arrays, one per entry of x0) with central differences of _obj_np."""
    fails = []
    for i, (x, g) in enumerate(zip(x0, grads)):
        flat = np.atleast_1d(np.asarray(x, np.float64)).ravel()
        g = np.atleast_1d(np.asarray(g)).ravel()
        assert np.all(np.isfinite(g)), f"{label}: non-finite gradient {i}: {g}"
        for k in range(flat.size):
            h = 1e-6 * max(abs(flat[k]), 1e-2)
            vals = []
            for s in (1, -1):
                y = list(x0)
                z = flat.copy()
                z[k] += s * h
                y[i] = z.reshape(np.shape(x))
                vals.append(_obj_np(rebuild(y)))
            fd = (vals[0] - vals[1]) / (2 * h)
            if abs(g[k] - fd) > 1e-5 * max(abs(fd), abs(g[k])) + 1e-8:
                fails.append(f"param {i}[{k}] = {flat[k]:.4g}: grad {g[k]:.8g}, central FD {fd:.8g}")
    return fails


@pytest.mark.parametrize("name", ["plastic-smooth-ir", "plastic-rough-ir"])
def test_gradients_fd_plastic(name):
    model = make(name)
    params, static = eqx.partition(model, eqx.is_inexact_array)
    leaves, treedef = jax.tree_util.tree_flatten(params)
    paths = [jax.tree_util.keystr(p) for p, _ in jax.tree_util.tree_flatten_with_path(params)[0]]
    assert len(leaves) == (3 if "rough" in name else 2), paths  # reflectance, eta (, alpha)
    g = _grad_leaves(model, *_padded_pairs(GRAD_PAIRS[:, 0], GRAD_PAIRS[:, 1], WF, WP))
    g_leaves = jax.tree_util.tree_leaves(g)

    def rebuild(xs):
        return eqx.combine(jax.tree_util.tree_unflatten(treedef, [arr(x) for x in xs]), static)
    fails = _fd_check(name, g_leaves, [np.asarray(x) for x in leaves], rebuild)
    assert not fails, f"{name} (leaves {paths}):\n  " + "\n  ".join(fails)


CC_NAMES = ["alpha_base", "eta_base", "k_base", "alpha_coat", "eta_coat", "thickness", "sigma_a"]


def _cc_args(smooth):
    x = [np.array(0.3), np.array(GOLD_ETA), np.array(GOLD_K), np.array(0.25), np.array(1.5), np.array(0.2),
         np.array(SIGMA)]
    return x[:3] + x[4:] if smooth else x


def _cc_build(xs, smooth, dtype=np.float64):
    xs = [jnp.asarray(x, dtype) for x in xs]
    if smooth:
        xs = xs[:3] + [0.0] + xs[3:]
    return CoatedConductor(*xs[:5], thickness=xs[5], sigma_a=xs[6])


@functools.partial(jax.jit, static_argnums=0, compiler_options=FAST_COMPILE)
def _grad_cc(smooth, xs, wo, wi, wf, wp):
    return jax.grad(lambda xs: _objective(_cc_build(xs, smooth, xs[0].dtype), wo, wi, wf, wp))(xs)


@pytest.mark.parametrize("smooth", [True, False], ids=["smooth-coat", "rough-coat"])
def test_gradients_fd_coated_conductor(smooth):
    """Gradient w.r.t. every argument of CoatedConductor (eta_coat also enters the base's relative
    index, so this covers every leaf of the resulting Layered)."""
    x0 = _cc_args(smooth)
    g = _grad_cc(smooth, [arr(x) for x in x0], *_padded_pairs(GRAD_PAIRS[:, 0], GRAD_PAIRS[:, 1], WF, WP))
    names = [n for n in CC_NAMES if not (smooth and n == "alpha_coat")]
    fails = _fd_check("CoatedConductor", g, x0, lambda xs: _cc_build(xs, smooth))
    assert not fails, "CoatedConductor " + ("smooth" if smooth else "rough") + f" coat ({names}):\n  " + "\n  ".join(fails)


def _edge_dirs():
    d = [wo_deg(x, phi=p) for x, p in [(0.0, 0.0), (10.0, 1.0), (45.0, 2.0), (80.0, -1.0), (89.0, 0.3), (89.99, 1.2)]]
    d += [np.array([1.0, 0.0, 0.0]), np.array([0.6, 0.8, 1e-7]), np.array([0.6, 0.8, 1e-4]), np.array([0.0, 0.6, -0.8]),
          wo_deg(35.0, 0.3 + np.pi)]
    d = np.array(d)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


EDGE = _edge_dirs()
EDGE_WO = np.repeat(EDGE, len(EDGE), 0)
EDGE_WI = np.tile(EDGE, (len(EDGE), 1))
assert len(EDGE_WO) <= NG


# (rough coat in float32 left out: compiling the gradient through the rough coat's transmittance
# table takes ~100 s of CPU on its own)
EDGE_GRAD_CASES = [(True, np.float32), (True, np.float64), (False, np.float64)]


@pytest.mark.parametrize("smooth,dt", EDGE_GRAD_CASES, ids=["smooth-coat-f32", "smooth-coat-f64", "rough-coat-f64"])
def test_gradients_finite_edges(smooth, dt):
    """Gradients finite at normal, grazing, horizon, below-horizon and specular pairs (both dtypes)."""
    n = len(EDGE_WO)
    pairs = _padded_pairs(EDGE_WO, EDGE_WI, np.ones((n, 3)), np.ones(n), dt)
    g = _grad_cc(smooth, [arr(x, dt) for x in _cc_args(smooth)], *pairs)
    for i, gi in enumerate(g):
        assert gi.dtype == dt and np.all(np.isfinite(np.asarray(gi))), f"CoatedConductor grad {i}: {gi}"
    for name in (["plastic-smooth-ir"] if smooth else ["plastic-rough-ir"]):
        g = _grad_leaves(make(name, dt), *pairs)
        for path, leaf in jax.tree_util.tree_flatten_with_path(g)[0]:
            assert leaf.dtype == dt and np.all(np.isfinite(np.asarray(leaf))), f"{name} {jax.tree_util.keystr(path)}: {leaf}"


# ------------------------------------------------------------------------------------------------
# 5. float32 / float64 values: finite, right dtype, edge directions
# ------------------------------------------------------------------------------------------------
# float32 on a subset of the structures (each float32 structure is a new compilation).
F32_MODELS = ["plastic-smooth-noir", "layered-smooth-lambert-abs", "coated-conductor-rough", "blend-roughplastic-conductor"]
DTYPE_CASES = [(n, np.float64) for n in MODEL_IDS] + [(n, np.float32) for n in F32_MODELS]
# the quick tier: the float32 cases (each a layered structure of its own)
DTYPE_PARAMS = [pytest.param(n, d, id=f"{n}-{np.dtype(d).name}", marks=pytest.mark.check if d == np.float32 else ())
                for n, d in DTYPE_CASES]


@pytest.mark.parametrize("name,dt", DTYPE_PARAMS)
def test_dtypes_finite(name, dt):
    model = make(name, dt)
    f, p = _evalpdf(model, arr(_pad(EDGE_WO), dt), arr(_pad(EDGE_WI), dt))
    assert f.dtype == dt and p.dtype == dt, f"{name}: eval {f.dtype}, pdf {p.dtype} for {np.dtype(dt).name} inputs"
    f, p = np.asarray(f), np.asarray(p)
    assert np.all(np.isfinite(f)) and np.all(np.isfinite(p)), f"{name}: non-finite eval/pdf"
    assert np.all(f >= 0) and np.all(p >= 0)
    assert np.any(f > 0)
    wo = np.repeat(EDGE, CHUNK // len(EDGE) + 1, 0)[:CHUNK]
    u = np.random.default_rng(1).random((CHUNK, 3))
    out = _sample(model, arr(wo, dt), arr(u, dt))
    for x in out:
        assert x.dtype == dt and np.all(np.isfinite(np.asarray(x))), f"{name}: sample output {x.dtype} / non-finite"
    w, pdf = np.asarray(out[1]), np.asarray(out[2])
    assert np.all(w[pdf == 0] == 0) and np.all(w >= 0)


def test_blend_rejects_mixed_delta_component():
    """A smooth-coated Plastic mixes a Dirac lobe with a continuous one: Blend refuses it, and a
    Layered base built on it is refused too (review finding: its delta samples were re-weighted
    as continuous ones)."""
    from matfit.errors import ParameterError

    with pytest.raises(ParameterError, match="Dirac"):
        blend_smooth()
    with pytest.raises(ParameterError, match="Dirac"):
        Layered(RoughDielectric(0.3, 1.5), plastic(RHO, 0.0, 1.5, True, np.float64))


@pytest.mark.parametrize("eta", [1.5, 1.01, 0.7])
def test_refract_into_is_refract_through_the_normal(eta, x64):
    """The layer's inner directions (refract_into, in components for the structure-of-arrays
    eval) equal the general refract through the normal (0, 0, 1), mirrored up, with the same
    total-internal-reflection flags, for arrays and Vec3 alike; and they obey Snell's law."""
    from matfit._math import Vec3, refract, refract_into

    rng = np.random.default_rng(3)
    w = rng.normal(size=(500, 3))
    w[:, 2] = np.abs(w[:, 2]) + 1e-3
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    n = np.tile([0.0, 0.0, 1.0], (500, 1))
    t_ref, ok_ref = refract(jnp.asarray(w), jnp.asarray(n), jnp.asarray(eta))
    t, ok = refract_into(jnp.asarray(w), eta)
    tv, okv = refract_into(Vec3.from_array(jnp.asarray(w)), eta)
    np.testing.assert_array_equal(np.asarray(ok), np.asarray(ok_ref))
    np.testing.assert_array_equal(np.asarray(okv), np.asarray(ok))
    sel = np.asarray(ok)
    assert (sel.all() if eta > 1 else (~sel).any() and sel.any())
    np.testing.assert_allclose(np.asarray(t)[sel], -np.asarray(t_ref)[sel], rtol=1e-12, atol=1e-14)
    np.testing.assert_array_equal(np.asarray(tv.to_array()), np.asarray(t))
    sin_i = np.hypot(w[:, 0], w[:, 1])
    sin_t = np.hypot(np.asarray(t)[:, 0], np.asarray(t)[:, 1])
    np.testing.assert_allclose(sin_t[sel], sin_i[sel] / eta, rtol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(np.asarray(t)[sel], axis=1), 1.0, rtol=1e-12)
