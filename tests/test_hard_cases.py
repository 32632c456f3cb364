"""Hard-case matrix (robustness issue): grazing angles, extreme roughness and index, special
geometries, sampler corner inputs and parameters at their bounds, for every model in float32 and
float64.

Every model *structure* (class, distribution, isotropic/anisotropic, smooth/rough coat) and dtype
is compiled once: all parameter cases are stacked into one batched module and ``jax.vmap``-ed over,
and all direction pairs / sampler inputs of a case form one array. The per-case function returns
eval, pdf, sample and ``jax.grad`` of ``sum(eval)`` w.r.t. the parameters, ``wo`` and ``wi``.
The results are cached per (structure, dtype) and inspected by several small tests.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

import catalogue as C
from catalogue import ONE_M, Z_DIEL, Z_REFL, pairs, sample_inputs, unit
from matfit.errors import ParameterError
from matfit.models import Blend, CoatedConductor, Lambert, Plastic, RoughConductor, RoughDielectric
from matfit.models import SmoothConductor, SmoothDielectric
from numpy_ref import COS_EPS

# The inputs are the catalogue's hard cases (tests/catalogue.py): the direction sets Z_REFL /
# Z_DIEL (pairs of them) and the sampler's corners, roughness and index values at and near their
# limits, extreme conductors.
ETA_PASS = 1e-5
WEIGHT_BOUND = 1e3
DTYPES = {"f32": np.float32, "f64": np.float64}
ALPHAS, ALPHAS_BP, ETAS, COND = C.ALPHAS_HARD, C.ALPHAS_HARD_BP, C.ETAS_HARD, C.CONDUCTORS_HARD
GOLD_ETA, GOLD_K = C.GOLD_ETA, C.GOLD_K


# --------------------------------------------------------------------------------------------
# Model structures: name -> (list of per-case constructors' args, builder, direction z set)
# --------------------------------------------------------------------------------------------
def _rc(dist):
    # alpha_y is always an array (isotropic cases pass alpha_y = alpha), so the isotropic and
    # anisotropic cases share one compiled function; the alpha_y=None path is exercised by the
    # property tests.
    def build(dt, p):
        (a, ay), (eta, k) = p
        return RoughConductor(dt(a), np.asarray(eta, dt), np.asarray(k, dt), distribution=dist,
                              alpha_y=dt(a if ay is None else ay))

    al = [(a, None) for a in (ALPHAS_BP if dist == "blinn_phong" else ALPHAS)]
    al += [(0.0, 0.5), (0.5, 0.0)] + ([(1e-8, 2.0)] if dist != "blinn_phong" else [(1e-8, 1.0)])
    cases = [(a, c) for a in al for c in COND]
    return cases, build, Z_REFL


def _rd(dist):
    def build(dt, p):
        (a, ay), eta = p
        return RoughDielectric(dt(a), dt(eta), distribution=dist, alpha_y=dt(a if ay is None else ay))

    al = [(a, None) for a in ALPHAS] + [(0.0, 0.5), (0.5, 0.0)]
    return [(a, e) for a in al for e in ETAS], build, Z_DIEL


def _lambert():
    def build(dt, p):
        return Lambert(np.asarray(p, dt))

    return [(0.0,) * 3, (1.0,) * 3, (0.0, 0.5, 1.0)], build, Z_REFL


def _sc():
    def build(dt, p):
        return SmoothConductor(np.asarray(p[0], dt), np.asarray(p[1], dt))

    return COND, build, Z_REFL


def _sd():
    def build(dt, p):
        return SmoothDielectric(dt(p))

    return ETAS, build, Z_DIEL


def _plastic(rough):
    def build(dt, p):
        alb, a, eta = p
        return Plastic(np.asarray(alb, dt), dt(a), dt(eta))

    alphas = [1e-8, 1e-4, 1e-3, 1.0, 2.0] if rough else [0.0]
    albs = [(0.0,) * 3, (1.0,) * 3, (0.0, 0.5, 1.0)]
    etas = [1.0, 1.0001, 1.5, 4.0] if rough else [1.0, 1 + 1e-6, 1.0001, 1.5, 0.5, 4.0]
    return [(alb, a, e) for alb in albs for a in alphas for e in etas], build, Z_REFL


def _coated():
    def build(dt, p):
        ab, (eta, k), ac, d = p
        return CoatedConductor(dt(ab), np.asarray(eta, dt), np.asarray(k, dt), alpha_coat=dt(ac),
                               eta_coat=dt(1.5), thickness=dt(d), sigma_a=np.asarray((0.0, 0.5, 1.0), dt))

    cases = [(ab, c, ac, d) for ab in (0.0, 1e-4, 0.3, 2.0) for c in (COND[0], COND[2], COND[1])
             for ac in (1e-8, 0.2, 1.0) for d in (0.0, 100.0)]
    return cases, build, Z_REFL


STRUCTURES = {
    "lambert": _lambert,
    "rough_conductor_ggx": functools.partial(_rc, "ggx"),
    "rough_conductor_beckmann": functools.partial(_rc, "beckmann"),
    "rough_conductor_blinn_phong": functools.partial(_rc, "blinn_phong"),
    "rough_dielectric_ggx": functools.partial(_rd, "ggx"),
    "rough_dielectric_beckmann": functools.partial(_rd, "beckmann"),
    "smooth_conductor": _sc,
    "smooth_dielectric": _sd,
    "plastic_smooth": functools.partial(_plastic, False),
    "plastic_rough": functools.partial(_plastic, True),
    "coated_conductor_rough_coat": _coated,
}
REFLECTION_ONLY = {n for n in STRUCTURES if not n.startswith(("rough_dielectric", "smooth_dielectric"))}
DELTA = {"smooth_conductor", "smooth_dielectric"}


def _one(model, wo, wi, swo, u):
    def total(m, a, b):
        return jnp.sum(m.eval(a, b))

    f = model.eval(wo, wi)
    p = model.pdf(wo, wi)
    gm, gwo, gwi = jax.grad(total, argnums=(0, 1, 2))(model, wo, wi)
    swi, sw, sp = model.sample(swo, u)
    sp_check = model.pdf(swo, swi)
    return dict(f=f, p=p, gm=gm, gwo=gwo, gwi=gwi, swi=swi, sw=sw, sp=sp, sp_check=sp_check)


_run = jax.jit(jax.vmap(_one, in_axes=(0, None, None, None, None)))


@functools.lru_cache(maxsize=None)
def results(name, dtn):
    dt = DTYPES[dtn]
    cases, build, zs = STRUCTURES[name]()
    models = [build(dt, c) for c in cases]
    batched = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *models)
    wo, wi = pairs(zs)
    swo, u = sample_inputs(zs)
    out = _run(batched, jnp.asarray(wo, dt), jnp.asarray(wi, dt), jnp.asarray(swo, dt), jnp.asarray(u, dt))
    out = jax.tree_util.tree_map(np.asarray, out)
    out["gm_leaves"] = jax.tree_util.tree_leaves(out.pop("gm"))
    inputs = dict(wo=wo.astype(dt), wi=wi.astype(dt), swo=swo.astype(dt), u=u.astype(dt), cases=cases,
                  models=models)
    return out, inputs


def _where_bad(bad, cases, what):
    idx = np.argwhere(bad)
    rows = [f"case {cases[i[0]]} index {tuple(i[1:])}" for i in idx[:5]]
    return f"{what}: {len(idx)} bad entries, e.g. " + "; ".join(rows)


def matrix(check, names=None):
    return [pytest.param(name, dtn, id=f"{name}-{dtn}") for name in names or STRUCTURES for dtn in DTYPES]


# --------------------------------------------------------------------------------------------
# Finite everywhere
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name,dtn", matrix("finite_values"))
def test_finite_values(name, dtn):
    out, inp = results(name, dtn)
    for key in ("f", "p", "swi", "sw", "sp", "sp_check"):
        bad = ~np.isfinite(out[key])
        assert not bad.any(), _where_bad(bad, inp["cases"], key)
    for key in ("f", "p", "sw", "sp"):
        bad = out[key] < 0
        assert not bad.any(), _where_bad(bad, inp["cases"], f"{key} < 0")


@pytest.mark.parametrize("name,dtn", matrix("finite_grads"))
def test_finite_gradients(name, dtn):
    out, inp = results(name, dtn)
    for key in ("gwo", "gwi"):
        bad = ~np.isfinite(out[key])
        assert not bad.any(), _where_bad(bad, inp["cases"], f"d sum(eval) / d {key[1:]}")
    for j, leaf in enumerate(out["gm_leaves"]):
        bad = ~np.isfinite(leaf)
        assert not bad.any(), _where_bad(bad, inp["cases"], f"d sum(eval) / d param leaf {j}")


# --------------------------------------------------------------------------------------------
# Sampling: valid (pdf > 0) or flagged invalid (pdf == 0 and weight == 0); bounded weights
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name,dtn", matrix("sampling"))
def test_sampling_valid_or_flagged(name, dtn):
    out, inp = results(name, dtn)
    sw, sp, swi = out["sw"], out["sp"], out["swi"]
    invalid = sp == 0
    bad = invalid[..., None] & (sw != 0)
    assert not bad.any(), _where_bad(bad, inp["cases"], "pdf == 0 but weight != 0")
    bad = sw >= WEIGHT_BOUND
    assert not bad.any(), _where_bad(bad, inp["cases"], f"weight >= {WEIGHT_BOUND}")
    # Valid samples are unit vectors; grazing wo (|z| <= COS_EPS) is always invalid.
    norm = np.linalg.norm(swi.astype(np.float64), axis=-1)
    tol = 1e-5 if dtn == "f32" else 1e-10
    bad = ~invalid & (np.abs(norm - 1) > tol)
    assert not bad.any(), _where_bad(bad, inp["cases"], "valid sample wi not unit")
    zo = inp["swo"][:, 2]
    bad = (np.abs(zo) <= inp["swo"].dtype.type(COS_EPS))[None] & ~invalid
    assert not bad.any(), _where_bad(bad, inp["cases"], "grazing wo gives a valid sample")
    if name in REFLECTION_ONLY:
        bad = ~invalid & (swi[..., 2] <= inp["swo"].dtype.type(COS_EPS))
        assert not bad.any(), _where_bad(bad, inp["cases"], "reflection-only sample below horizon is valid")
    if name not in DELTA:
        # the pdf returned by sample is model.pdf of the sampled direction, except for discrete
        # samples: Plastic's smooth-coat Dirac lobe and RoughDielectric's index-matched pass-through
        ok = ~invalid
        if name == "plastic_smooth":
            mirror = inp["swo"] * np.array([-1, -1, 1], inp["swo"].dtype)
            ok &= ~np.all(np.abs(swi - mirror[None]) <= 1e-6, axis=-1)
        if name.startswith("rough_diel"):
            ok &= np.array([abs(c[1] - 1) >= ETA_PASS for c in inp["cases"]])[:, None]
        assert np.isfinite(out["sp_check"]).all()
        rel = np.abs(out["sp_check"][ok] - sp[ok]) / np.maximum(sp[ok], 1e-30)
        tol = 2e-2 if dtn == "f32" else 1e-6
        assert np.mean(rel > tol) < 0.01, f"sample pdf != pdf(wo, wi) on {np.mean(rel > tol):.1%} of valid samples"


# --------------------------------------------------------------------------------------------
# Exact zeros
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name,dtn", matrix("horizon_zero", sorted(REFLECTION_ONLY)))
def test_reflection_only_zero_at_or_below_horizon(name, dtn):
    out, inp = results(name, dtn)
    eps = inp["wo"].dtype.type(COS_EPS)
    off = (inp["wo"][:, 2] <= eps) | (inp["wi"][:, 2] <= eps)
    assert off.any()
    bad = off[None, :, None] & (out["f"] != 0)
    assert not bad.any(), _where_bad(bad, inp["cases"], "eval != 0 at/below horizon")
    bad = off[None] & (out["p"] != 0)
    assert not bad.any(), _where_bad(bad, inp["cases"], "pdf != 0 at/below horizon")
    # wo = -wi always has one direction at or below the horizon (or both on it).
    anti = np.all(inp["wo"] == -inp["wi"], axis=-1)
    assert (out["f"][:, anti] == 0).all()


@pytest.mark.parametrize("name,dtn", matrix("delta_zero", sorted(DELTA)))
def test_delta_models_eval_pdf_zero(name, dtn):
    out, _ = results(name, dtn)
    assert (out["f"] == 0).all() and (out["p"] == 0).all()
    for leaf in out["gm_leaves"] + [out["gwo"], out["gwi"]]:
        assert (leaf == 0).all()


@pytest.mark.parametrize("name,dtn", matrix("dielectric_horizon", [n for n in STRUCTURES if n.startswith("rough_diel")]))
def test_rough_dielectric_zero_on_horizon(name, dtn):
    out, inp = results(name, dtn)
    eps = inp["wo"].dtype.type(COS_EPS)
    off = (np.abs(inp["wo"][:, 2]) <= eps) | (np.abs(inp["wi"][:, 2]) <= eps)
    assert not (off[None, :, None] & (out["f"] != 0)).any()
    assert not (off[None] & (out["p"] != 0)).any()


def _backfacing(wo, wi, eta):
    """float64 mask of pairs whose generalized half vector is back-facing for wo or wi (margin 1e-3)."""
    wo, wi = wo.astype(np.float64), wi.astype(np.float64)
    co, ci = wo[:, 2], wi[:, 2]
    etap = np.where(co * ci > 0, 1.0, np.where(co > 0, eta, 1 / eta))
    m = etap[:, None] * wi + wo
    n = np.linalg.norm(m, axis=-1, keepdims=True)
    m = m / np.where(n > 0, n, 1)
    m = np.where(m[:, 2:3] < 0, -m, m)
    wom, wim = np.sum(wo * m, -1), np.sum(wi * m, -1)
    return (n[:, 0] > 1e-3) & (np.abs(co) > 1e-3) & (np.abs(ci) > 1e-3) & ((wom * co < -1e-3) | (wim * ci < -1e-3))


@pytest.mark.parametrize("name,dtn", matrix("backfacing", [n for n in STRUCTURES if n.startswith("rough_diel")]))
def test_rough_dielectric_backfacing_microfacets_zero(name, dtn):
    out, inp = results(name, dtn)
    n_bf = 0
    for c, (case, f, p) in enumerate(zip(inp["cases"], out["f"], out["p"])):
        eta = case[1]
        bf = _backfacing(inp["wo"], inp["wi"], eta)
        n_bf += bf.sum()
        assert (f[bf] == 0).all(), f"case {case}: eval != 0 on back-facing microfacets"
        assert (p[bf] == 0).all(), f"case {case}: pdf != 0 on back-facing microfacets"
    assert n_bf > 0


@pytest.mark.parametrize("name,dtn", matrix("passthrough", [n for n in STRUCTURES if n.startswith("rough_diel")]))
def test_rough_dielectric_index_matched_passthrough(name, dtn):
    out, inp = results(name, dtn)
    eps = inp["swo"].dtype.type(COS_EPS)
    for c, case in enumerate(inp["cases"]):
        eta = case[1]
        if abs(eta - 1) >= ETA_PASS:
            continue
        assert (out["f"][c] == 0).all(), f"case {case}: eval != 0 for an index-matched interface"
        assert (out["p"][c] == 0).all()
        ok = np.abs(inp["swo"][:, 2]) > eps
        assert (out["swi"][c][ok] == -inp["swo"][ok]).all(), f"case {case}: sample wi != -wo"
        assert (out["sw"][c][ok] == 1).all() and (out["sp"][c][ok] == 1).all()
        assert (out["sw"][c][~ok] == 0).all() and (out["sp"][c][~ok] == 0).all()


@pytest.mark.parametrize("name,dtn", matrix("passthrough", ["smooth_dielectric"]))
def test_smooth_dielectric_index_matched_passthrough(name, dtn):
    """eta = 1: no reflection (F = 0), straight transmission with weight 1."""
    out, inp = results(name, dtn)
    eps = inp["swo"].dtype.type(COS_EPS)
    c = inp["cases"].index(1.0)
    ok = np.abs(inp["swo"][:, 2]) > eps
    sw, sp, swi = out["sw"][c][ok, 0], out["sp"][c][ok], out["swi"][c][ok]
    tol = 1e-6 if dtn == "f32" else 1e-12
    bad = (np.abs(sw - 1) > tol) | (np.abs(sp - 1) > tol) | np.any(np.abs(swi + inp["swo"][ok]) > tol, -1)
    assert not bad.any(), (
        f"eta=1: {bad.sum()} samples not straight through, e.g. wo={inp['swo'][ok][bad][:2]}, "
        f"wi={swi[bad][:2]}, weight={sw[bad][:2]}, pdf={sp[bad][:2]}"
    )


@pytest.mark.check
@pytest.mark.parametrize("name,dtn", matrix("tir", ["smooth_dielectric"]))
def test_smooth_dielectric_total_internal_reflection(name, dtn):
    """From inside (wo_z < 0) beyond the critical angle nothing is transmitted."""
    out, inp = results(name, dtn)
    zo = inp["swo"][:, 2].astype(np.float64)
    for c, eta in enumerate(inp["cases"]):
        # inside, wo relative index 1/eta; TIR when sin^2 / (1/eta)^2 > 1 (margin).
        tir = (zo < -COS_EPS * 2) & ((1 - zo**2) * eta**2 > 1 + 1e-3)
        if not tir.any():
            continue
        assert (out["swi"][c][tir, 2] < 0).all(), f"eta={eta}: transmission beyond the critical angle"
        assert (out["sp"][c][tir] == 1).all() and (out["sw"][c][tir] == 1).all()


@pytest.mark.parametrize("name,dtn", matrix("tir", [n for n in STRUCTURES if n.startswith("rough_diel")]))
def test_rough_dielectric_tir_finite_and_reflection_zero_when_matched(name, dtn):
    out, inp = results(name, dtn)
    zo, zi = inp["wo"][:, 2].astype(np.float64), inp["wi"][:, 2].astype(np.float64)
    trans_in = (zo < -1e-3) & (zi > 1e-3)
    assert np.isfinite(out["f"][:, trans_in]).all() and np.isfinite(out["p"][:, trans_in]).all()
    assert np.isfinite(out["gwo"][:, trans_in]).all() and np.isfinite(out["gwi"][:, trans_in]).all()


# --------------------------------------------------------------------------------------------
# Parameter errors
# --------------------------------------------------------------------------------------------
@pytest.mark.check
@pytest.mark.parametrize("kw", [dict(alpha=2.0), dict(alpha=1.0001), dict(alpha=0.5, alpha_y=2.0)])
def test_blinn_phong_alpha_above_one_raises(kw):
    a = kw.pop("alpha")
    with pytest.raises(ParameterError):
        RoughConductor(a, 1.0, 1.0, distribution="blinn_phong", **kw)
    with pytest.raises(ParameterError):
        RoughDielectric(a, 1.5, distribution="blinn_phong", **kw)


def test_blinn_phong_alpha_one_allowed():
    RoughConductor(1.0, 1.0, 1.0, distribution="blinn_phong")




# --------------------------------------------------------------------------------------------
# alpha -> 0: the rough models approach the smooth ones
# --------------------------------------------------------------------------------------------
#: documented in docs/robustness.md: at alpha <= ALPHA_SMOOTH the rough models' directional
#: reflectance is within SMOOTH_TOL of the smooth model's (theta_o <= 80 deg).
ALPHA_SMOOTH = 1e-3
SMOOTH_TOL = 1e-3
#: Plastic's diffuse part through a rough coat uses the tabulated transmittance (see the test)
PLASTIC_TABLE_TOL = 1e-2


@functools.partial(jax.jit, static_argnames="n")  # one program per model type, not one per primitive
def _reflected_fraction(model, wo, n=4096):
    """Mean importance-sampling weight of the samples reflected to the upper side (per channel)."""
    u = jax.random.uniform(jax.random.PRNGKey(1), (n, 3), wo.dtype)

    def one(w):
        wi, wt, _ = model.sample(jnp.broadcast_to(w, (n, 3)), u)
        up = (wi[:, 2] > 0)[:, None]
        return jnp.mean(jnp.where(up, wt, 0), axis=0)

    return jax.vmap(one)(wo)


assert max(C.ALPHA_NEAR_ZERO) == ALPHA_SMOOTH


@pytest.mark.parametrize("alpha", C.ALPHA_NEAR_ZERO)
def test_rough_approaches_smooth(alpha, x64):
    wo = jnp.asarray(unit(np.cos(np.radians([0.0, 30.0, 60.0, 80.0])), 0.4))
    pairs_ = [
        (RoughConductor(alpha, np.array(GOLD_ETA), np.array(GOLD_K)), SmoothConductor(np.array(GOLD_ETA), np.array(GOLD_K))),
        (RoughDielectric(alpha, 1.5), SmoothDielectric(1.5)),
    ]
    for rough, smooth in pairs_:
        er, es = (np.asarray(_reflected_fraction(m, wo)) for m in (rough, smooth))
        np.testing.assert_allclose(er, es, atol=SMOOTH_TOL, err_msg=f"{type(rough).__name__} alpha={alpha}")
    # Plastic: the diffuse part (through the coat's transmittance) away from the mirror direction
    # is deterministic; the whole albedo agrees within the Monte Carlo error of both estimates.
    alb = np.array([0.2, 0.5, 0.9])
    rough, smooth = Plastic(alb, alpha if alpha > 0 else 1e-8, 1.5), Plastic(alb, 0.0, 1.5)
    o, i = (jnp.asarray(x) for x in pairs([0.2, 0.5, 0.9, 1.0]))
    mirror = np.asarray(jnp.sum(i * jnp.stack([-o[:, 0], -o[:, 1], o[:, 2]], -1), -1)) > np.cos(0.6)
    fr, fs = np.asarray(rough.eval(o, i))[~mirror], np.asarray(smooth.eval(o, i))[~mirror]
    assert (fs > 0).any()
    # the rough coat's transmittance is a 24-node table interpolated linearly (models/_coat.py):
    # measured 0.45 % from the exact 1 - F of the smooth coat
    np.testing.assert_allclose(fr, fs, rtol=PLASTIC_TABLE_TOL, atol=1e-12)
    n = 16384
    er, es = (np.asarray(_reflected_fraction(m, wo, n)) for m in (rough, smooth))
    np.testing.assert_allclose(er, es, atol=5 * 0.5 / np.sqrt(n))


# --------------------------------------------------------------------------------------------
# Property tests (hypothesis): one compiled function per model, parameters traced
# --------------------------------------------------------------------------------------------
SPECIAL_Z = [0.0, 1e-7, -1e-7, 1e-4, -1e-4, 1.0, -1.0, 1e-3]
NP = 6  # direction pairs per example
N_EX = 300  # examples per model
N_MC = 256  # samples for the energy check of one direction
PROP = settings(max_examples=N_EX, deadline=None, derandomize=True)


def z_values():
    return st.one_of(st.sampled_from(SPECIAL_Z), st.floats(-1.0, 1.0))


dirs = st.tuples(st.lists(z_values(), min_size=NP, max_size=NP), st.lists(z_values(), min_size=NP, max_size=NP),
                 st.lists(st.floats(0, 2 * np.pi), min_size=NP, max_size=NP))
u_st = st.lists(st.tuples(*[st.one_of(st.sampled_from([0.0, ONE_M]), st.floats(0.0, ONE_M))] * 3),
                min_size=NP, max_size=NP)
alpha_st = st.one_of(st.sampled_from(C.ALPHAS_HARD), st.floats(0.0, 2.0))
eta_st = st.one_of(st.sampled_from(C.ETA_NEAR_ONE + (0.5, 4.0)), st.floats(0.2, 5.0))
unit_st = st.floats(0.0, 1.0)
rgb = st.lists(unit_st, min_size=3, max_size=3)
cond_eta = st.lists(st.floats(0.05, 5.0), min_size=3, max_size=3)
cond_k = st.lists(st.one_of(st.just(0.0), st.just(50.0), st.floats(0.0, 50.0)), min_size=3, max_size=3)
HDT = np.float32


def _dirs(d):
    zo, zi, phi = (np.asarray(x) for x in d)
    return jnp.asarray(unit(zo, 0.0), HDT), jnp.asarray(unit(zi, phi), HDT)


def _prop(model, wo, wi, u, key):
    def total(m, a, b):
        return jnp.sum(m.eval(a, b))

    f, fr = model.eval(wo, wi), model.eval(wi, wo)
    p = model.pdf(wo, wi)
    g = jax.grad(total, argnums=(0, 1, 2))(model, wo, wi)
    swi, sw, sp = model.sample(wo, u)
    e = sw * model.energy_factor(wo, swi)[..., None]
    # energy of the first non-grazing direction by importance sampling (N_MC samples)
    w0 = jnp.where(jnp.abs(wo[:, 2:3]) > 1e-3, wo, jnp.asarray([0.0, 0.6, 0.8], wo.dtype))[0]
    uu = jax.random.uniform(key, (N_MC, 3), wo.dtype, maxval=ONE_M)
    wb = jnp.broadcast_to(w0, (N_MC, 3))
    mwi, mw, _ = model.sample(wb, uu)
    me = mw * model.energy_factor(wb, mwi)[..., None]
    return f, fr, p, g, swi, sw, sp, e, me


_prop_jit = jax.jit(_prop)
_KEY = jax.random.PRNGKey(7)


def _check_prop(model, wo, wi, u, reciprocal=True, per_sample_energy=False, energy_bound=1.0):
    out = _prop_jit(model, wo, wi, jnp.asarray(u, HDT), _KEY)
    f, fr, p, g, swi, sw, sp, e, me = jax.tree_util.tree_map(np.asarray, out)
    for x in (f, fr, p, swi, sw, sp, me, *jax.tree_util.tree_leaves(g)):
        assert np.isfinite(x).all()
    assert (f >= 0).all() and (p >= 0).all() and (sp >= 0).all() and (sw >= 0).all()
    assert ((sp > 0)[..., None] | (sw == 0)).all(), "weight != 0 on an invalid sample"
    if reciprocal:
        # float32: relative 2e-3, and 1e-6 1/sr absolute for values that are float32 rounding of
        # near-zero reflectances (e.g. F ~ (eta - 1)^2 at eta = 0.99999 at grazing: 5.3e-8 vs 5.5e-8)
        np.testing.assert_allclose(f, fr, rtol=2e-3, atol=1e-6)
    if per_sample_energy:
        # visible-normal sampling: every sample's energy weight is G2/G1 * (F or 1-F)/(lobe prob) <= 1
        assert (e <= 1 + 1e-3).all(), e.max()
    # directional albedo <= 1 (Monte Carlo: mean + 5 standard errors)
    mean, se = me.mean(0), me.std(0) / np.sqrt(N_MC)
    assert (mean - 5 * se <= energy_bound + 1e-3).all(), (mean, se)


@PROP
@given(albedo=rgb, d=dirs, u=u_st)
def test_property_lambert(albedo, d, u):
    _check_prop(Lambert(np.asarray(albedo, HDT)), *_dirs(d), u, per_sample_energy=True)


@PROP
@given(alpha=alpha_st, eta=cond_eta, k=cond_k, d=dirs, u=u_st)
@example(alpha=0.0, eta=[1.0, 1.0, 1.0], k=[0.0, 0.0, 1.5393532296991593e-35], d=([0.0] * NP, [0.0] * NP, [0.0] * NP),
         u=[(0.0, 0.0, 0.0)] * NP)  # found by hypothesis: a tiny k, whose 1/k^2 overflowed a Fresnel gradient
def test_property_rough_conductor(alpha, eta, k, d, u):
    m = RoughConductor(HDT(alpha), np.asarray(eta, HDT), np.asarray(k, HDT))
    _check_prop(m, *_dirs(d), u, per_sample_energy=True)


@PROP
@given(alpha=alpha_st, ay=alpha_st, eta=cond_eta, k=cond_k, d=dirs, u=u_st)
def test_property_rough_conductor_beckmann_anisotropic(alpha, ay, eta, k, d, u):
    m = RoughConductor(HDT(alpha), np.asarray(eta, HDT), np.asarray(k, HDT), distribution="beckmann", alpha_y=HDT(ay))
    _check_prop(m, *_dirs(d), u, per_sample_energy=True)


@PROP
@given(alpha=alpha_st, eta=eta_st, d=dirs, u=u_st)
def test_property_rough_dielectric(alpha, eta, d, u):
    m = RoughDielectric(HDT(alpha), HDT(eta))
    _check_prop(m, *_dirs(d), u, reciprocal=False, per_sample_energy=True)


@PROP
@given(eta=cond_eta, k=cond_k, d=dirs, u=u_st)
def test_property_smooth_conductor(eta, k, d, u):
    _check_prop(SmoothConductor(np.asarray(eta, HDT), np.asarray(k, HDT)), *_dirs(d), u, per_sample_energy=True)


@PROP
@given(eta=eta_st, d=dirs, u=u_st)
def test_property_smooth_dielectric(eta, d, u):
    _check_prop(SmoothDielectric(HDT(eta)), *_dirs(d), u, reciprocal=False, per_sample_energy=True)


@PROP
@given(albedo=rgb, eta=st.one_of(st.sampled_from([1.0, 1 + 1e-6, 1.0001, 4.0]), st.floats(1.0, 4.0)), d=dirs, u=u_st)
@example(albedo=[0.0, 0.0, 0.0], eta=1.0, d=([0.0] * NP, [0.0] * (NP - 1) + [1.175494351e-38], [0.0] * NP),
         u=[(0.0, 0.0, 0.0)] * NP)  # found by hypothesis: a grazing wo and a wi one float32 normal above the horizon
def test_property_plastic_smooth(albedo, eta, d, u):
    _check_prop(Plastic(np.asarray(albedo, HDT), 0.0, HDT(eta)), *_dirs(d), u)


@PROP
@given(albedo=rgb, alpha=st.one_of(st.sampled_from([1e-8, 1e-4, 2.0]), st.floats(1e-6, 2.0)),
       eta=st.one_of(st.sampled_from([1.0, 1.0001, 4.0]), st.floats(1.0, 3.0)), d=dirs, u=u_st)
@example(albedo=[0.0, 0.0, 0.0], alpha=0.5, eta=1.0, d=([0.0] * NP, [0.0] * (NP - 1) + [1.175494351e-38], [0.0] * NP),
         u=[(0.0, 0.0, 0.0)] * NP)  # found by hypothesis: a grazing wo and a wi one float32 normal above the horizon
def test_property_plastic_rough(albedo, alpha, eta, d, u):
    _check_prop(Plastic(np.asarray(albedo, HDT), HDT(alpha), HDT(eta)), *_dirs(d), u)


@PROP
@given(alpha=st.one_of(st.sampled_from([1e-4, 1.0]), st.floats(1e-4, 1.0)), eta=cond_eta, k=cond_k,
       alpha_coat=st.one_of(st.sampled_from([1e-8, 1.0]), st.floats(1e-6, 1.0)),
       eta_coat=st.one_of(st.sampled_from([1.0, 2.5]), st.floats(1.0, 2.5)),
       thickness=st.one_of(st.sampled_from([0.0, 100.0]), st.floats(0.0, 100.0)),
       sigma_a=rgb, d=dirs, u=u_st)
def test_property_coated_conductor(alpha, eta, k, alpha_coat, eta_coat, thickness, sigma_a, d, u):
    m = CoatedConductor(HDT(alpha), np.asarray(eta, HDT), np.asarray(k, HDT), alpha_coat=HDT(alpha_coat),
                        eta_coat=HDT(eta_coat), thickness=HDT(thickness), sigma_a=np.asarray(sigma_a, HDT))
    _check_prop(m, *_dirs(d), u)


@PROP
@given(weight=st.one_of(st.sampled_from([0.0, 1.0]), unit_st), albedo=rgb, alpha=alpha_st, eta=cond_eta, k=cond_k,
       d=dirs, u=u_st)
@example(weight=0.0, albedo=[0.0, 0.0, 0.0], alpha=0.0, eta=[1.0, 1.0, 1.0], k=[0.0, 0.0, 1e-30],
         d=([0.0] * NP, [0.0] * NP, [0.0] * NP), u=[(0.0, 0.0, 0.0)] * NP)  # as in test_property_rough_conductor
def test_property_blend(weight, albedo, alpha, eta, k, d, u):
    m = Blend(Lambert(np.asarray(albedo, HDT)), RoughConductor(HDT(alpha), np.asarray(eta, HDT), np.asarray(k, HDT)),
              HDT(weight))
    _check_prop(m, *_dirs(d), u)


# --------------------------------------------------------------------------------------------
# The fast path (matfit.fast: cosine-only isotropic lobes) on the same hard cases
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("dtn", list(DTYPES))
@pytest.mark.parametrize("dist", ["ggx", "beckmann", "blinn_phong"])
def test_fast_path_hard_cases(dist, dtn):
    from matfit.fast import eval_soa, soa_pairs

    dt = DTYPES[dtn]
    z = np.array(Z_REFL)
    zo, zi = (a.ravel() for a in np.meshgrid(z, z))
    wo = unit(zo, 0.3 + 0 * zo)
    wi = unit(zi, 2.5 + 0 * zi)
    wi = np.concatenate([wi, wo])  # and the mirror pairs (h on the normal)
    wo = np.concatenate([wo, unit(zo, 0.3 + np.pi + 0 * zo)])
    pairs = soa_pairs(wo, wi, dtype=dt)
    grad = jax.jit(jax.grad(lambda mm, p: sum(jnp.sum(c) for c in eval_soa(mm, p))))  # one compile per structure
    general = jax.jit(lambda mm, a, b: mm.eval(a, b))
    wo_j, wi_j = jnp.asarray(wo, dt), jnp.asarray(wi, dt)
    for alpha in (ALPHAS_BP if dist == "blinn_phong" else ALPHAS):
        for eta, k in COND:
            m = RoughConductor(jnp.asarray(alpha, dt), jnp.asarray(eta, dt), jnp.asarray(k, dt), dist)
            blend = Blend(Lambert(jnp.asarray([0.5, 0.4, 0.3], dt)), m, jnp.asarray(0.6, dt))
            for model in (m, blend):
                f = np.asarray(eval_soa(model, pairs, stack=True))
                ref = np.asarray(general(model, wo_j, wi_j))
                case = f"{type(model).__name__} {dist} alpha={alpha} eta={eta} k={k}"
                assert np.all(np.isfinite(f)) and np.all(f >= 0), case
                tol = 1e-12 if dt == np.float64 else 3e-5
                np.testing.assert_allclose(f, ref, rtol=tol, atol=tol * 1e-3 * max(np.max(np.abs(ref)), 1e-30),
                                           err_msg=case)
                for leaf in jax.tree_util.tree_leaves(grad(model, pairs)):
                    assert np.all(np.isfinite(np.asarray(leaf))), f"gradient: {case}"
