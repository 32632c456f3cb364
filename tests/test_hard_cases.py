# WORK IN PROGRESS (issue #7), deliberately not collected by pytest (the name does not match
# test_*.py): the hard-case matrix written at the end of a session and not yet verified green.
# Its xfail marks for two bugs (conductor Fresnel slightly negative at eta = 1, k = 0 in float32;
# SmoothDielectric at eta = 1 reflecting at grazing in float32) are stale: both were fixed in
# matfit/fresnel.py and matfit/_math.py. Before renaming it to test_hard_cases.py: remove those
# marks, run it, and cut its runtime (8.5 min on 2 cores, mostly compiling rough-coat models).
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
from hypothesis import given, settings
from hypothesis import strategies as st

jax.config.update("jax_enable_x64", True)

from matfit.errors import ParameterError  # noqa: E402
from matfit.models import (  # noqa: E402
    CoatedConductor,
    Lambert,
    Plastic,
    RoughConductor,
    RoughDielectric,
    SmoothConductor,
    SmoothDielectric,
)

COS_EPS = 1e-7
ETA_PASS = 1e-5
WEIGHT_BOUND = 1e3
DTYPES = {"f32": np.float32, "f64": np.float64}

# --------------------------------------------------------------------------------------------
# Inputs
# --------------------------------------------------------------------------------------------
Z_REFL = [0.0, 1e-7, -1e-7, 1e-4, 0.5, 1.0, -0.5]
Z_DIEL = [0.0, 1e-7, -1e-7, 1e-4, -1e-4, 0.5, -0.5, 0.9, -0.9, 1.0, -1.0]
ONE_M = 1.0 - 2.0**-24
U_CORNERS = [(a, b, c) for a in (0.0, ONE_M) for b in (0.0, ONE_M) for c in (0.0, ONE_M)]
U_EXTRA = [(0.5, 0.5, 0.5), (0.3, 0.7, 0.1), (0.9, 0.2, 0.6), (0.02, 0.98, 0.4)]

GOLD_ETA = (0.143, 0.374, 1.442)
GOLD_K = (3.983, 2.385, 1.603)
ALPHAS = [0.0, 1e-8, 1e-4, 1e-3, 1.0, 2.0]
ALPHAS_BP = [0.0, 1e-8, 1e-4, 1e-3, 1.0]
ETAS = [1.0, 1 + 1e-6, 1 - 1e-6, 1.0001, 0.5, 4.0, 1.5]
COND = [(GOLD_ETA, GOLD_K), ((1.0,) * 3, (0.0,) * 3), ((0.2,) * 3, (50.0,) * 3), ((1.5, 0.5, 3.0), (0.0, 50.0, 1.0))]


def unit(z, phi):
    z = np.asarray(z, np.float64)
    s = np.sqrt(np.maximum(0.0, 1 - z * z))
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], -1)


def pairs(zs):
    """Direction pairs: every (z_o, z_i) with wi at azimuth pi (plane of incidence, mirror) and
    pi/3, plus wo = wi and wo = -wi for every z_o."""
    wo, wi = [], []
    for zo in zs:
        for zi in zs:
            for phi in (np.pi, np.pi / 3):
                wo.append(unit(zo, 0.0))
                wi.append(unit(zi, phi))
        a = unit(zo, 0.3)
        wo += [a, a]
        wi += [a, -a]
    return np.array(wo), np.array(wi)


def sample_inputs(zs):
    wo, u = [], []
    for zo in zs:
        for uu in U_CORNERS + U_EXTRA:
            wo.append(unit(zo, 0.2))
            u.append(uu)
    return np.array(wo), np.array(u)


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
    return dict(f=f, p=p, gm=gm, gwo=gwo, gwi=gwi, swi=swi, sw=sw, sp=sp)


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


# Known library failures: (structure, dtype, check) -> reason. Filled from the runs.
XFAIL: dict[tuple[str, str, str], str] = {}
_NEG_F = "fresnel_conductor(mu, eta=1, k=0) is slightly negative in float32 (-5.6e-8), so eval/weight < 0"
for _d in ("f32", "f64"):
    for _n in ("rough_conductor_ggx", "rough_conductor_beckmann", "rough_conductor_blinn_phong"):
        XFAIL[(_n, _d, "finite_values")] = _NEG_F
    for _n in ("rough_dielectric_ggx", "rough_dielectric_beckmann"):
        XFAIL[(_n, _d, "finite_grads")] = "RoughDielectric eta=1 with wi = -wo: NaN grad of eval w.r.t. wo, wi"
        XFAIL[(_n, _d, "tir")] = "RoughDielectric eta=1 with wi = -wo: NaN grad of eval w.r.t. wo, wi"
    for _n in ("plastic_smooth", "plastic_rough"):
        XFAIL[(_n, _d, "finite_grads")] = "Plastic: non-finite grad of eval at horizon/special pairs"
    XFAIL[("smooth_dielectric", _d, "passthrough")] = "SmoothDielectric eta=1 at mu=1e-4 reflects (F=1, refract TIR by rounding)"
for _n in ("rough_conductor_ggx", "rough_conductor_beckmann", "rough_conductor_blinn_phong", "coated_conductor_rough_coat"):
    XFAIL[(_n, "f32", "finite_grads")] = "float32 non-finite grad of eval w.r.t. wo on grazing pairs"


def matrix(check, names=None):
    out = []
    for name in names or STRUCTURES:
        for dtn in DTYPES:
            reason = XFAIL.get((name, dtn, check))
            marks = [pytest.mark.xfail(strict=True, reason=f"library bug: {reason}")] if reason else []
            out.append(pytest.param(name, dtn, marks=marks, id=f"{name}-{dtn}"))
    return out


# --------------------------------------------------------------------------------------------
# Finite everywhere
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name,dtn", matrix("finite_values"))
def test_finite_values(name, dtn):
    out, inp = results(name, dtn)
    for key in ("f", "p", "swi", "sw", "sp"):
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
MAX_WEIGHTS: dict[tuple[str, str], float] = {}


@pytest.mark.parametrize("name,dtn", matrix("sampling"))
def test_sampling_valid_or_flagged(name, dtn):
    out, inp = results(name, dtn)
    sw, sp, swi = out["sw"], out["sp"], out["swi"]
    invalid = sp == 0
    bad = invalid[..., None] & (sw != 0)
    assert not bad.any(), _where_bad(bad, inp["cases"], "pdf == 0 but weight != 0")
    MAX_WEIGHTS[(name, dtn)] = float(sw.max())
    print(f"max sample weight {name} {dtn}: {sw.max():.6g}")
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
        # pdf returned by sample matches model.pdf (continuous models, continuous samples).
        pass


def test_zz_report_max_weights(capsys):
    """Prints the largest sample weight seen per model (collected by the sampling tests)."""
    with capsys.disabled():
        for (name, dtn), w in sorted(MAX_WEIGHTS.items()):
            print(f"\n  max weight {name:36s} {dtn}: {w:.6g}", end="")
        print()


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
    rng = np.random.default_rng(0)
    n_bf = 0
    for c, (case, f, p) in enumerate(zip(inp["cases"], out["f"], out["p"])):
        eta = case[1]
        bf = _backfacing(inp["wo"], inp["wi"], eta)
        n_bf += bf.sum()
        assert (f[bf] == 0).all(), f"case {case}: eval != 0 on back-facing microfacets"
        assert (p[bf] == 0).all(), f"case {case}: pdf != 0 on back-facing microfacets"
    assert n_bf > 0
    del rng


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
# Property tests (hypothesis): one compiled function per family, parameters traced
# --------------------------------------------------------------------------------------------
SPECIAL_Z = [0.0, 1e-7, -1e-7, 1e-4, -1e-4, 1.0, -1.0, 1e-3]
NP = 6  # direction pairs per example


def z_values():
    return st.one_of(st.sampled_from(SPECIAL_Z), st.floats(-1.0, 1.0))


dirs = st.tuples(st.lists(z_values(), min_size=NP, max_size=NP), st.lists(z_values(), min_size=NP, max_size=NP),
                 st.lists(st.floats(0, 2 * np.pi), min_size=NP, max_size=NP))
u_st = st.lists(st.tuples(*[st.one_of(st.sampled_from([0.0, ONE_M]), st.floats(0.0, ONE_M))] * 3),
                min_size=NP, max_size=NP)
alpha_st = st.one_of(st.sampled_from([0.0, 1e-8, 1e-4, 1e-3, 1.0, 2.0]), st.floats(0.0, 2.0))
eta_st = st.one_of(st.sampled_from([1.0, 1 + 1e-6, 1 - 1e-6, 1.0001, 0.5, 4.0]), st.floats(0.2, 5.0))
unit_st = st.floats(0.0, 1.0)
HDT = np.float32


def _dirs(d):
    zo, zi, phi = (np.asarray(x) for x in d)
    wo = unit(zo, 0.0)
    wi = unit(zi, phi)
    return jnp.asarray(wo, HDT), jnp.asarray(wi, HDT)


def _prop(model, wo, wi, u):
    def total(m, a, b):
        return jnp.sum(m.eval(a, b))

    f, fr = model.eval(wo, wi), model.eval(wi, wo)
    p = model.pdf(wo, wi)
    g = jax.grad(total, argnums=(0, 1, 2))(model, wo, wi)
    swi, sw, sp = model.sample(wo, u)
    e = sw * model.energy_factor(wo, swi)[..., None]
    return f, fr, p, g, swi, sw, sp, e


_prop_jit = jax.jit(_prop)


def _check_prop(model, wo, wi, u, reciprocal=True, per_sample_energy=False):
    f, fr, p, g, swi, sw, sp, e = jax.tree_util.tree_map(np.asarray, _prop_jit(model, wo, wi, jnp.asarray(u, HDT)))
    for x in (f, fr, p, swi, sw, sp, *jax.tree_util.tree_leaves(g)):
        assert np.isfinite(x).all()
    assert (f >= 0).all() and (p >= 0).all() and (sp >= 0).all()
    assert ((sp > 0)[..., None] | (sw == 0)).all()
    if reciprocal:
        np.testing.assert_allclose(f, fr, rtol=2e-3, atol=1e-30)
    if per_sample_energy:
        # visible-normal sampling: every sample's energy weight is G2/G1 * (F or 1-F)/(lobe prob) <= 1
        assert (e <= 1 + 1e-3).all(), e.max()


@settings(max_examples=200, deadline=None)
@given(albedo=st.lists(unit_st, min_size=3, max_size=3), d=dirs, u=u_st)
def test_property_lambert(albedo, d, u):
    wo, wi = _dirs(d)
    _check_prop(Lambert(np.asarray(albedo, HDT)), wo, wi, u, per_sample_energy=True)


@settings(max_examples=200, deadline=None)
@given(alpha=alpha_st, eta=st.lists(st.floats(0.05, 5.0), min_size=3, max_size=3),
       k=st.lists(st.one_of(st.just(0.0), st.just(50.0), st.floats(0.0, 50.0)), min_size=3, max_size=3), d=dirs, u=u_st)
def test_property_rough_conductor(alpha, eta, k, d, u):
    wo, wi = _dirs(d)
    m = RoughConductor(HDT(alpha), np.asarray(eta, HDT), np.asarray(k, HDT))
    _check_prop(m, wo, wi, u, per_sample_energy=True)


@settings(max_examples=200, deadline=None)
@given(alpha=alpha_st, eta=eta_st, d=dirs, u=u_st)
def test_property_rough_dielectric(alpha, eta, d, u):
    wo, wi = _dirs(d)
    m = RoughDielectric(HDT(alpha), HDT(eta))
    _check_prop(m, wo, wi, u, reciprocal=False, per_sample_energy=True)


@pytest.mark.xfail(strict=True, reason="library bug: Plastic rough: non-finite grad/value found by hypothesis")
@settings(max_examples=200, deadline=None)
@given(albedo=st.lists(unit_st, min_size=3, max_size=3), alpha=st.one_of(st.sampled_from([1e-8, 1e-4, 2.0]), st.floats(1e-6, 2.0)),
       eta=st.one_of(st.sampled_from([1.0, 1.0001, 4.0]), st.floats(1.0, 3.0)), d=dirs, u=u_st)
def test_property_plastic_rough(albedo, alpha, eta, d, u):
    wo, wi = _dirs(d)
    m = Plastic(np.asarray(albedo, HDT), HDT(alpha), HDT(eta))
    _check_prop(m, wo, wi, u)
