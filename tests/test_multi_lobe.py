"""MultiLobe (a Lambertian base plus weighted microfacet lobes) and the families composed of it.

    f(wo, wi) = albedo / pi + sum_j w_j F_j(wo.h) D_j(h) G2_j(wo, wi, h) / (4 cos_o cos_i),

F_j Schlick (f0), exact dielectric (eta), exact conductor (eta + i k) or a thin film; sampled by one-sample MIS
over the cosine hemisphere and the lobes, with probabilities proportional to mean(albedo) and to
mean(w_j (F_j(1) + (1 - F_j(1)) / 21)).

1. eval and pdf against the independent numpy reference (numpy_ref: distributions, Smith masking,
   complex-index Fresnel), three lobes of every distribution and Fresnel kind, anisotropy, both
   masking forms; one Schlick lobe equals DiffuseSpecular, one conductor lobe RoughConductor.
2. Helmholtz reciprocity.
3. Energy: directional albedo (the library's quadrature and MC) against a numpy quadrature of the
   reference, and <= 1 when albedo + sum of weights <= 1.
4. Sampling: weight == f cos / pdf, returned pdf == pdf(wo, wi), chi-square of the samples against
   pdf (tests/chi2.py) on a sphere grid, the valid fraction against int pdf.
5. Gradients against central finite differences (float64), finite float32 values and gradients.
6. The fast path: eval_soa (one kernel per channel) equals eval.
7. Families: composed ones (parameters, ordering, mixture weights, equality, errors), the
   existing families unchanged, the data-driven start, and fits: lobes2 recovers a synthetic
   two-lobe RGB table, a family declared in a few lines fits its own model's table.
8. Bad input raises ParameterError naming the problem.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import catalogue as C  # noqa: E402
import numpy_ref as R  # noqa: E402
import test_sampling as S  # noqa: E402
from catalogue import unit  # noqa: E402

from matfit import Table  # noqa: E402
from matfit.errors import ParameterError  # noqa: E402
from matfit.fast import eval_soa, soa_pairs, supports_soa  # noqa: E402
from matfit.fitting import (FAMILIES, METAL_ETA_RANGE, METAL_K_RANGE, Lobe, Param, Parametrization, TruthMap, compose_family, fit,  # noqa: E402
                            initial_guess)
from matfit.models import DiffuseSpecular, MultiLobe, RoughConductor, SpecularLobe  # noqa: E402

ALB = (0.5, 0.3, 0.15)


def j(x, dt=np.float64):
    return jnp.asarray(np.asarray(x, dt))


# ------------------------------------------------------------------------------------------------
# Cases and the reference
# ------------------------------------------------------------------------------------------------
# a lobe: (distribution, alpha, alpha_y, fresnel, weight, fresnel parameters, masking)
LOBE_CASES = {
    "three-kinds": (ALB, [
        ("ggx", 0.08, None, "schlick", (0.9, 0.9, 0.9), {"f0": 0.04}, "separable"),
        ("beckmann", 0.3, None, "dielectric", 0.05, {"eta": 1.6}, "separable"),
        ("blinn_phong", 0.6, None, "conductor", (0.02, 0.03, 0.05), {"eta": C.GOLD_ETA, "k": C.GOLD_K}, "separable"),
    ]),
    "aniso-hc": ((0.2, 0.6, 0.1), [
        ("ggx", 0.1, 0.3, "schlick", 0.5, {"f0": (0.04, 0.5, 0.9)}, "height_correlated"),
        ("ggx", 0.5, None, "conductor", 0.4, {"eta": C.CU_ETA, "k": C.CU_K}, "height_correlated"),
    ]),
    # a clear coat over an iridescent lobe: a 350 nm film of index 1.8 on glass
    "film": ((0.1, 0.05, 0.2), [
        ("ggx", 0.05, None, "dielectric", 1.0, {"eta": 1.5}, "separable"),
        ("beckmann", 0.3, 0.15, "thin_film", 0.8, {"thickness": 350.0, "film_eta": 1.8, "eta": 1.4}, "height_correlated"),
    ]),
    "metal-two-scales": (0.0, [
        ("ggx", 0.05, None, "conductor", 0.7, {"eta": C.GOLD_ETA, "k": C.GOLD_K}, "separable"),
        ("beckmann", 0.4, None, "conductor", 0.3, {"eta": C.GOLD_ETA, "k": C.GOLD_K}, "separable"),
    ]),
}


def build(case, dt=np.float64, sampling="visible"):
    alb, lobes = LOBE_CASES[case]
    out = []
    for dist, a, ay, fres, w, fp, mk in lobes:
        out.append(SpecularLobe(j(a, dt), fres, j(w, dt), distribution=dist, masking=mk,
                                alpha_y=None if ay is None else j(ay, dt), sampling=sampling,
                                **{k: j(v, dt) for k, v in fp.items()}))
    return MultiLobe(j(alb, dt), out)


def ref_fresnel(cos, fres, fp):
    if fres == "schlick":
        return R.fresnel_schlick(cos[..., None], np.atleast_1d(fp["f0"]))
    if fres == "dielectric":
        return R.fresnel_dielectric(cos[..., None], np.atleast_1d(fp["eta"]))
    if fres == "thin_film":
        return R.thin_film_rgb(cos, fp["thickness"], fp["film_eta"], fp["eta"])
    return R.fresnel_conductor(cos[..., None], np.atleast_1d(fp["eta"]), np.atleast_1d(fp["k"]))


def ref_normal_reflectance(fres, fp):
    if fres == "schlick":
        return np.atleast_1d(fp["f0"])
    if fres == "thin_film":
        return R.thin_film_rgb(1.0, fp["thickness"], fp["film_eta"], fp["eta"])
    return R.fresnel_complex(1.0, np.atleast_1d(fp["eta"]) + 1j * np.atleast_1d(fp.get("k", 0.0)))


def ref_eval(wo, wi, case):
    alb, lobes = LOBE_CASES[case]
    f = R.lambert_eval(wo, wi, alb)
    for dist, a, ay, fres, w, fp, mk in lobes:
        ok, h, lobe = R.reflection_lobe(wo, wi, R.Dist(dist, a, ay), mk)
        F = ref_fresnel(np.clip(np.sum(wo * h, -1), 0, 1), fres, fp)
        f = f + np.where(ok[..., None], lobe[..., None] * np.atleast_1d(w) * F, 0.0)
    return f


def ref_probabilities(case):
    alb, lobes = LOBE_CASES[case]
    w = [np.mean(alb)]
    for _, _, _, fres, wt, fp, _ in lobes:
        r0 = ref_normal_reflectance(fres, fp)
        w.append(np.mean(np.atleast_1d(wt) * (r0 + (1 - r0) / 21)))
    w = np.array(w)
    return w / w.sum()


def ref_pdf(wo, wi, case, sampling="visible"):
    p = ref_probabilities(case)
    out = p[0] * R.lambert_pdf(wo, wi)
    for pj, (dist, a, ay, *_) in zip(p[1:], LOBE_CASES[case][1]):
        out = out + pj * R.conductor_pdf(wo, wi, R.Dist(dist, a, ay), sampling)
    return out


def pairs_for(rng, n=300):
    """Random pairs (some grazing, some below the horizon) and pairs near every lobe's peak."""
    wo = np.concatenate([R.random_directions(rng, n, "upper", 0.02), R.random_directions(rng, 20, "lower")])
    wi = np.concatenate([R.random_directions(rng, n, "upper", 0.02), R.random_directions(rng, 20, "upper")])
    m = R.random_normals_near_z(rng, 150, 0.1, 0.1, spread=2.0)
    wo2 = R.random_directions(rng, 150, "upper", 0.2)
    wi2 = 2 * np.sum(wo2 * m, -1, keepdims=True) * m - wo2
    keep = wi2[:, 2] > 0.02
    return np.concatenate([wo, wo2[keep], [[0, 0, 1.0]]]), np.concatenate([wi, wi2[keep], [[0, 0, 1.0]]])


# ------------------------------------------------------------------------------------------------
# 1. eval and pdf vs the reference; special cases equal the single-lobe models
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("case", [pytest.param(c, marks=pytest.mark.check if c == "metal-two-scales" else ())
                                  for c in LOBE_CASES])
def test_eval_and_pdf_match_reference(case, x64, rng):
    wo, wi = pairs_for(rng)
    model = build(case)
    f = np.asarray(model.eval(j(wo), j(wi)))
    ref = ref_eval(wo, wi, case)
    assert f.shape == ref.shape == (len(wo), 3)
    R.assert_rel(f, ref, 1e-9, 1e-300, "eval", wo=wo, wi=wi)
    below = (wo[:, 2] <= 0) | (wi[:, 2] <= 0)
    assert below.sum() >= 20 and np.all(f[below] == 0)
    # the lobes matter: near the peaks the value is far above the diffuse level
    assert np.median(f[-100:].max(-1) - np.max(LOBE_CASES[case][0]) / np.pi) > 0.05
    p = np.asarray(model.pdf(j(wo), j(wi)))
    R.assert_rel(p, ref_pdf(wo, wi, case), 1e-9, 1e-300, "pdf", wo=wo, wi=wi)
    assert np.all(p[below] == 0) and np.all(p[~below] > 0)
    np.testing.assert_allclose([float(x) for x in model.probabilities()], ref_probabilities(case), rtol=1e-12)


def test_one_lobe_is_diffuse_specular_or_rough_conductor(x64, rng):
    wo, wi = pairs_for(rng, 100)
    for kind in ("ggx", "beckmann"):
        ds = DiffuseSpecular(j(ALB), j((0.04, 0.3, 0.7)), j(0.2), distribution=kind)
        ml = MultiLobe(j(ALB), [SpecularLobe(j(0.2), f0=j((0.04, 0.3, 0.7)), distribution=kind)])
        np.testing.assert_allclose(ml.eval(j(wo), j(wi)), ds.eval(j(wo), j(wi)), rtol=1e-12, atol=1e-300)
        rc = RoughConductor(j(0.2), j(C.GOLD_ETA), j(C.GOLD_K), distribution=kind)
        sl = SpecularLobe(j(0.2), "conductor", eta=j(C.GOLD_ETA), k=j(C.GOLD_K), distribution=kind)
        np.testing.assert_allclose(sl.eval(j(wo), j(wi)), rc.eval(j(wo), j(wi)), rtol=1e-12, atol=1e-300)
        np.testing.assert_allclose(sl.pdf(j(wo), j(wi)), rc.pdf(j(wo), j(wi)), rtol=1e-12, atol=1e-300)


# ------------------------------------------------------------------------------------------------
# 2. reciprocity
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("case", list(LOBE_CASES))
def test_reciprocity(case, x64, rng):
    wo, wi = C.random_pairs(rng, 200, 0.01, "both")
    model = build(case)
    f1, f2 = np.asarray(model.eval(j(wo), j(wi))), np.asarray(model.eval(j(wi), j(wo)))
    assert np.count_nonzero(f1.max(-1)) > 30
    assert R.rel_err(f1, f2, 1e-300).max() <= 1e-12


# ------------------------------------------------------------------------------------------------
# 3. energy
# ------------------------------------------------------------------------------------------------
def ref_albedo(mu, case, n=160):
    wi, wts = R.upper_hemisphere_rule(n)
    wi = wi.reshape(-1, 3)
    wo = np.broadcast_to(unit(mu, 0.4), wi.shape)
    return np.sum(ref_eval(wo, wi, case) * (wi[:, 2] * wts.ravel())[:, None], axis=0)


@eqx.filter_jit
def _albedo(model, wo, method, n, key):
    return model.albedo(wo, method=method, n=n, key=key)


def test_albedo_and_energy_bound(x64):
    # weights with albedo + sum w <= 1 in every channel, lobes wide enough for the quadratures
    LOBE_CASES["energy"] = ((0.4, 0.3, 0.2), [
        ("ggx", 0.15, None, "schlick", (0.3, 0.4, 0.5), {"f0": 1.0}, "separable"),  # F = 1: the bound is tight
        ("beckmann", 0.5, None, "conductor", (0.3, 0.3, 0.3), {"eta": C.GOLD_ETA, "k": C.GOLD_K}, "height_correlated"),
    ])
    try:
        model = build("energy")
        for mu in (1.0, 0.5, 0.1):
            wo = j(unit(mu, 0.4))
            e_q = np.asarray(_albedo(model, wo, "quadrature", 128, None))
            e_mc = np.asarray(_albedo(model, wo, "mc", 2**17, jax.random.PRNGKey(1)))
            e_ref = ref_albedo(mu, "energy")
            np.testing.assert_allclose(e_q, e_ref, rtol=2e-3)
            np.testing.assert_allclose(e_mc, e_ref, rtol=1e-2)
            assert np.all(e_ref <= 1.0) and np.all(e_q <= 1.0 + 1e-6)
            assert np.all(e_ref >= np.array((0.4, 0.3, 0.2)) - 1e-9)  # the base is not shadowed
        # the sum is additive: the lobes' albedos add to the base's
        lobes_only = [np.asarray(_albedo(lb, j(unit(0.5, 0.4)), "quadrature", 128, None)) for lb in model.lobes]
        np.testing.assert_allclose(np.asarray(_albedo(model, j(unit(0.5, 0.4)), "quadrature", 128, None)),
                                   np.array((0.4, 0.3, 0.2)) + sum(lobes_only), rtol=1e-10)
    finally:
        del LOBE_CASES["energy"]


# ------------------------------------------------------------------------------------------------
# 4. sampling
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class LobesCase(S.Case):
    """A MultiLobe case of tests/test_sampling.py's machinery (S.run_case): the chi-square cells
    are those of the narrowest lobe's slope space (``alpha``, ``alpha_y``), in which the diffuse
    base and the wider lobes fill the outer cells; everything in float32."""

    name: str = "three-kinds"

    @property
    def id(self):
        return f"multilobe-{self.name}-{self.deg:g}deg"

    def make(self):
        return build(self.name, np.float32)


SAMPLE_CASES = [LobesCase("conductor", "slope", alpha=0.08, deg=45.0, name="three-kinds"),
                LobesCase("conductor", "slope", alpha=0.1, alpha_y=0.3, deg=72.5, phi=0.7, name="aniso-hc"),
                LobesCase("conductor", "slope", alpha=0.05, deg=25.0, name="metal-two-scales"),
                LobesCase("conductor", "slope", alpha=0.05, deg=60.0, name="film")]


@pytest.mark.parametrize("case", SAMPLE_CASES, ids=[c.id for c in SAMPLE_CASES])
def test_sampling_matches_pdf(case):
    r = S.run_case(case)
    S.check_sampled(r, len(SAMPLE_CASES))
    # the density of the samples is the mixture of the numpy reference (float32 directions)
    wo = case.wo().astype(np.float64)
    u = np.random.default_rng(7).random((S.CHUNK, 3), dtype=np.float32)
    wi, _, p, *_ = S.sample_all(case.make(), case.wo(), u)
    ok = p > 0
    ref = ref_pdf(np.broadcast_to(wo, wi[ok].shape), wi[ok] / np.linalg.norm(wi[ok], axis=-1, keepdims=True), case.name)
    err = R.rel_err(p[ok], ref, 1e-30)
    assert np.quantile(err, 0.999) < 1e-3 and err.max() < 2e-2, (np.quantile(err, 0.999), err.max())


# ------------------------------------------------------------------------------------------------
# 5. gradients
# ------------------------------------------------------------------------------------------------
def test_gradients_match_finite_differences(x64, rng):
    wo, wi = C.random_pairs(rng, 40, 0.2)
    model = build("three-kinds")
    wts = j(rng.random((len(wo), 3)))
    params, static = eqx.partition(model, eqx.is_inexact_array)

    @jax.jit
    def loss(p):
        return jnp.sum(eqx.combine(p, static).eval(j(wo), j(wi)) * wts)

    grads = jax.jit(jax.grad(loss))(params)
    assert len(jax.tree_util.tree_leaves(params)) == 11  # albedo, three (alpha, weight) and f0, eta, eta and k
    assert C.check_leaf_gradients(loss, grads, params, 1e-5) >= 20


def test_float32_finite_at_special_pairs():
    wo, wi = (jnp.asarray(x, jnp.float32) for x in C.special_pairs())
    model = build("three-kinds", np.float32)
    C.check_float32_eval_pdf_finite(model, wo, wi)
    # every special wo, 64 draws each
    wos = jnp.repeat(wo, 64, axis=0)
    u = jnp.asarray(np.random.default_rng(0).random((len(wos), 3)), jnp.float32)
    wi_s, w_s, p_s = eqx.filter_jit(lambda m, a, b: m.sample(a, b))(model, wos, u)
    assert np.all(np.isfinite(np.asarray(wi_s))) and np.all(np.isfinite(np.asarray(w_s))) and np.all(np.asarray(p_s) >= 0)


# ------------------------------------------------------------------------------------------------
# 6. the fast path
# ------------------------------------------------------------------------------------------------
def test_eval_soa_equals_eval(rng):
    wo, wi = C.random_pairs(rng, 257, 0.05)
    model = build("three-kinds", np.float32)
    assert supports_soa(model)
    a = np.asarray(eval_soa(model, soa_pairs(wo.astype(np.float32), wi.astype(np.float32)), stack=True))
    b = np.asarray(model.eval(jnp.asarray(wo, jnp.float32), jnp.asarray(wi, jnp.float32)))
    np.testing.assert_allclose(a, b, rtol=2e-5, atol=1e-7)


# ------------------------------------------------------------------------------------------------
# 7. families
# ------------------------------------------------------------------------------------------------
def _p(name, lo, hi, per_channel=False, doc="", generic=None, physical=(False, False)):
    return Param(name, lo, hi, per_channel, doc, generic, physical)


_ALPHA = _p("alpha", 1e-3, 1.5, False, "GGX width", 0.2)
_METAL = (_p("eta", *METAL_ETA_RANGE, True, "real index", 1.0), _p("k", *METAL_K_RANGE, True, "extinction", 3.0, (True, False)))
#: the families as they were before the composed ones were added (params, doc, constant starts, truth)
EXISTING = {
    "lambert": ((_p("albedo", 0.0, 1.0, True, "diffuse albedo", 0.5, (True, True)),), "Lambertian diffuse", {},
                TruthMap("Lambert")),
    "conductor": ((_ALPHA,) + _METAL, "rough conductor, GGX, separable Smith", {},
                  TruthMap("RoughConductor", {"distribution": (None, "ggx")})),
    "conductor_beckmann": ((_p("alpha", 1e-3, 1.5, False, "Beckmann width", 0.2),) + _METAL,
                           "rough conductor, Beckmann, separable Smith", {},
                           TruthMap("RoughConductor", {"distribution": ("beckmann",)})),
    "dielectric": ((_ALPHA, _p("eta", 1.01, 4.0, False, "relative index", 1.5)),
                   "rough dielectric (reflection and transmission)", {"eta": 1.5},
                   TruthMap("RoughDielectric", {"distribution": (None, "ggx")})),
    "plastic": ((_p("albedo", 0.0, 1.0, True, "base albedo", 0.5, (True, True)), _p("alpha", 1e-3, 1.5, False, "coat GGX width", 0.2),
                 _p("eta", 1.05, 3.0, False, "coat index", 1.5)), "Lambertian base under a rough coat", {"eta": 1.5},
                TruthMap("Plastic")),
    "car_paint": ((_p("alpha_base", 1e-3, 1.5, False, "metal GGX width", 0.2),
                   _p("eta_base", *METAL_ETA_RANGE, True, "metal index", 1.0),
                   _p("k_base", *METAL_K_RANGE, True, "metal extinction", 3.0, (True, False)),
                   _p("alpha_coat", 1e-3, 1.0, False, "coat GGX width", 0.1),
                   _p("eta_coat", 1.05, 2.5, False, "coat index", 1.5)), "rough metal under a rough clear coat", {},
                  TruthMap("CoatedConductor")),
    "diffuse_specular": ((_p("albedo", 0.0, 1.0, True, "diffuse albedo", 0.5, (True, True)),
                          _p("f0", 0.0, 1.0, True, "specular F0 (Schlick)", None, (True, True)),
                          _ALPHA), "Lambertian albedo plus a GGX lobe with Schlick's Fresnel (the texel model of captures)",
                         {}, None),
}


def test_existing_families_unchanged():
    names = list(FAMILIES)
    assert names[:len(EXISTING)] == list(EXISTING)  # the new ones come after, none renamed
    for name, (params, doc, starts, truth) in EXISTING.items():
        fam = FAMILIES[name]
        assert (fam.name, fam.params, fam.doc, dict(fam.starts), fam.truth) == (name, params, doc, starts, truth), name
    assert FAMILIES["conductor"].refine is not None and FAMILIES["lambert"].refine is None
    vals = {"albedo": j(0.5), "alpha": j(0.2), "eta": j(1.5), "k": j(2.0), "f0": j(0.04)}
    assert type(FAMILIES["diffuse_specular"].build(vals, 1)).__name__ == "DiffuseSpecular"
    assert type(FAMILIES["conductor"].build(vals, 1)).__name__ == "RoughConductor"


@pytest.mark.check
def test_composed_families_layout():
    assert [p.name for p in FAMILIES["lobes3"].params] == [
        "albedo", "alpha_1", "ks_1", "f0", "ratio_2", "ks_2", "ratio_3", "ks_3"]
    assert [p.name for p in FAMILIES["metal2"].params] == ["alpha_1", "eta", "k", "ratio_2", "mix_2"]
    per = {p.name: p.per_channel for p in FAMILIES["lobes2"].params}
    assert per == {"albedo": True, "alpha_1": False, "ks_1": True, "f0": False, "ratio_2": False, "ks_2": True}
    # distinct generic widths (narrow, medium, wide), ordered through ratios > 1
    spec = FAMILIES["lobes3"].build
    start = FAMILIES["lobes3"].generic_start({})
    widths = [float(a) for a in spec.widths(start)]
    assert widths[0] < widths[1] < widths[2] and widths[2] / widths[0] > 10
    assert FAMILIES["lobes3"].params[4].lower == 1.0  # ratio_2 > 1: the lobes cannot swap
    # mixture weights sum to 1
    w = FAMILIES["metal2"].build.lobe_weights({"mix_2": jnp.asarray(0.3)})
    assert abs(float(w[0]) + float(w[1]) - 1) < 1e-12 and abs(float(w[1]) - 0.3) < 1e-7
    fam3 = compose_family("m3", [Lobe(fresnel="conductor")] * 3, base=None, weights="mixture", share=("eta", "k"))
    w = fam3.build.lobe_weights({"mix_2": jnp.asarray(0.5), "mix_3": jnp.asarray(0.2)})
    np.testing.assert_allclose([float(x) for x in w], [0.4, 0.4, 0.2], rtol=1e-6)
    # declared alike: equal and hashable (the compiled fits are cached by family)
    a = compose_family("x", ["ggx", Lobe("beckmann", "dielectric")], tied=("ks_1",), fixed={"eta_2": 1.5})
    b = compose_family("x", [Lobe("ggx"), Lobe("beckmann", "dielectric")], tied=("ks_1",), fixed={"eta_2": 1.5})
    assert a == b and hash(a) == hash(b) and a != compose_family("x", ["ggx", "beckmann"])
    assert [p.name for p in a.params] == ["albedo", "alpha_1", "ks_1", "f0_1", "ratio_2", "ks_2"]
    assert not a.params[2].per_channel
    m = a.build(Parametrization(a, 3).full({"albedo": 0.5, "alpha_1": 0.1, "ks_1": 0.8, "f0_1": 0.04, "ratio_2": 3.0,
                                            "ks_2": 0.2}), 3)
    assert float(m.lobes[1].eta[0]) == 1.5 and abs(float(m.lobes[1].alpha) - 0.3) < 1e-6
    c = compose_family("y", ["ggx", "ggx"], bounds={"alpha_1": (0.01, 0.5)}, ordered=False)
    assert [(p.name, p.lower, p.upper) for p in c.params][1] == ("alpha_1", 0.01, 0.5)
    assert "alpha_2" in [p.name for p in c.params]


@pytest.mark.parametrize("kwargs, match", [
    (dict(lobes=[]), "non-empty list"),
    (dict(lobes=["phong"]), "distribution must be one of"),
    (dict(lobes=["ggx"], base="oren_nayar"), "base must be"),
    (dict(lobes=["ggx"], weights="sum"), "weights must be one of"),
    (dict(lobes=["ggx", Lobe(fresnel="dielectric")], share=("eta", "f0")), "share 'eta'"),
    (dict(lobes=[Lobe(fresnel="dielectric"), Lobe(fresnel="conductor")], share=("eta",)), "same Fresnel term"),
    (dict(lobes=["ggx"], fixed={"alpha": 0.1}), "fixed names 'alpha'"),
    (dict(lobes=["ggx"], fixed={"alpha_1": 3.0}), r"compose_family: fixed alpha_1=3.0 is outside its range \[0.001, 1.5\]"),
    (dict(lobes=["ggx"], bounds={"ks_1": (1.0, 0.5)}), "lower < upper"),
    (dict(lobes=["ggx"], fixed={"alpha_1": (0.1, 0.2)}), r"fixed alpha_1=\(0.1, 0.2\): expected a scalar"),
    (dict(lobes=["ggx"], starts={"ks_1": -0.5}), r"starts ks_1=-0.5 is outside its range \[0.0, 1.0\]"),
    (dict(lobes=["ggx", "ggx"], share=("f0",), fixed={"f0": float("nan")}), "fixed f0=nan: expected finite values"),
    (dict(lobes=["ggx"], tied="ks_1"), "tied must be a sequence"),
    (dict(lobes=["ggx"], tied=("albedos",)), "tied names 'albedos'"),
])
def test_compose_family_errors(kwargs, match):
    with pytest.raises(ParameterError, match=match):
        compose_family("bad", **kwargs)


def _synthetic(model, rng, n=300, mono=False):
    """A noise-free table of ``model``: half random pairs, half near the mirror direction."""
    def rd(k):
        return R.random_directions(rng, k, "upper", 0.05)

    wo, wi = rd(2 * n), rd(2 * n)
    mir = wo[:n] * np.array([-1, -1, 1]) + rng.normal(scale=0.15, size=(n, 3))
    mir[:, 2] = np.abs(mir[:, 2]) + 0.03
    wi[:n] = mir / np.linalg.norm(mir, axis=1, keepdims=True)
    v = np.asarray(model.eval(j(wo), j(wi)), np.float64)
    return Table(wo=wo, wi=wi, values=v, channels="mono" if mono else "rgb")


LOBES2_TRUTH = {"albedo": (0.5, 0.3, 0.15), "alpha_1": 0.08, "ks_1": (0.9, 0.9, 0.9), "f0": 0.05, "ratio_2": 5.0,
                "ks_2": (0.3, 0.25, 0.2)}


def test_data_driven_start_reads_diffuse_and_lobes(x64, rng):
    fam = FAMILIES["lobes2"]
    truth = {k: j(v) for k, v in LOBES2_TRUTH.items()}
    table = _synthetic(fam.build(truth, 3), rng)
    g = initial_guess(table, Parametrization("lobes2", 3))
    np.testing.assert_allclose(g["albedo"], LOBES2_TRUTH["albedo"], rtol=0.15)
    assert 0.5 < g["alpha_1"] / 0.08 < 2 and g["ratio_2"] > 2
    assert np.all(g["ks_1"] * g["f0"] > 0.5 * 0.9 * 0.05)  # the narrow lobe's height near the mirror
    # metal2's start: a mixture and a conductor index inside the bounds
    gm = initial_guess(table, Parametrization("metal2", 3))
    assert 0 < gm["mix_2"] < 1 and gm["k"].shape == (3,)


def test_fit_lobes2_recovers_a_two_lobe_table(rng):
    fam = FAMILIES["lobes2"]
    table = _synthetic(fam.build({k: j(v, np.float32) for k, v in LOBES2_TRUTH.items()}, 3), rng)
    r = fit(table, model="lobes2", starts=1, dtype=np.float32)
    assert r.converged and not r.info, (r.info, r.warnings)  # solved on the channel-split kernels
    assert type(r.model).__name__ == "MultiLobe"
    for name, v in LOBES2_TRUTH.items():
        np.testing.assert_allclose(r.params[name], v, rtol=2e-3, err_msg=name)
    assert r.objective < 1e-6 * float(np.sum(np.asarray(table.values) ** 2))


def test_a_family_declared_in_a_few_lines_fits(rng):
    # white (one value) narrow GGX highlight with Schlick's F0, a wide Beckmann haze of a glass-like index
    fam = compose_family("gloss_haze", [Lobe("ggx"), Lobe("beckmann", fresnel="dielectric")],
                         tied=("ks_1",), fixed={"eta_2": 1.5})
    truth = {"albedo": 0.35, "alpha_1": 0.06, "ks_1": 0.8, "f0_1": 0.06, "ratio_2": 6.0, "ks_2": 0.4}
    table = _synthetic(fam.build({k: j(v, np.float32)[None] if k in ("albedo", "ks_2") else j(v, np.float32)
                                  for k, v in truth.items()}, 1), rng, mono=True)
    r = fit(table, model=fam, starts=1, dtype=np.float32)
    assert r.converged and not r.info
    for name, v in truth.items():
        np.testing.assert_allclose(r.params[name], v, rtol=3e-3, err_msg=name)


@pytest.mark.parametrize("family", ["lobes2", "metal2"])
def test_fit_a_table_larger_than_the_start_subset(family, rng):
    # the data-driven start reads MAX_ROWS rows of a larger table: the fit runs on all of them
    from matfit.fitting._compose import MAX_ROWS

    truth = FAMILIES["lobes2"].build({k: j(v, np.float32) for k, v in LOBES2_TRUTH.items()}, 3)
    table = _synthetic(truth, rng, n=(MAX_ROWS + 1000) // 2)
    assert len(table) > MAX_ROWS
    g = initial_guess(table, Parametrization(family, 3))
    for p in FAMILIES[family].params:  # every start inside its bounds
        assert np.all(np.isfinite(g[p.name])) and np.all((p.lower <= g[p.name]) & (g[p.name] <= p.upper)), p.name
    r = fit(table, model=family, starts=1, max_steps=4, dtype=np.float32)
    assert type(r.model).__name__ == "MultiLobe" and np.isfinite(r.objective)
    # a start read from the table's lobes is better than none: below the objective of zero
    assert r.objective < float(np.sum(np.asarray(table.values) ** 2))


# ------------------------------------------------------------------------------------------------
# 8. model files, reports and the renderer exporters
# ------------------------------------------------------------------------------------------------
def test_model_file_round_trip(x64, rng, tmp_path):
    from matfit.export import load_model, save_model

    wo, wi = pairs_for(rng, 100)
    for case in LOBE_CASES:
        model = build(case)
        save_model(tmp_path / f"{case}.json", model)
        back = load_model(tmp_path / f"{case}.json")
        assert type(back) is MultiLobe and len(back.lobes) == len(model.lobes)
        assert all(type(lb) is SpecularLobe for lb in back.lobes)
        assert [(lb.fresnel, lb.distribution, lb.masking) for lb in back.lobes] == [
            (lb.fresnel, lb.distribution, lb.masking) for lb in model.lobes]
        np.testing.assert_allclose(back.eval(j(wo), j(wi)), model.eval(j(wo), j(wi)), rtol=1e-12, atol=1e-300)
        np.testing.assert_allclose(back.pdf(j(wo), j(wi)), model.pdf(j(wo), j(wi)), rtol=1e-12, atol=1e-300)
    lobe = build("three-kinds").lobes[2]
    save_model(tmp_path / "lobe.json", lobe)
    back = load_model(tmp_path / "lobe.json")
    assert type(back) is SpecularLobe
    np.testing.assert_allclose(back.eval(j(wo), j(wi)), lobe.eval(j(wo), j(wi)), rtol=1e-12, atol=1e-300)


def test_model_file_rejects_a_bad_lobe_list():
    from matfit.errors import DataFormatError
    from matfit.export import describe_model, model_from_description

    d = describe_model(MultiLobe(0.5, [SpecularLobe(0.1, f0=0.04)]))
    d["lobes"] = [d["lobes"][0], 0.5]
    with pytest.raises(DataFormatError, match=r"MultiLobe.lobes: expected a list of models"):
        model_from_description(d)


def test_cli_fit_lobes2_with_report(rng, tmp_path, capsys):
    import json

    from matfit.cli import main
    from matfit.io import save

    table = _synthetic(FAMILIES["lobes2"].build({k: j(v, np.float32) for k, v in LOBES2_TRUTH.items()}, 3), rng, n=40)
    save(tmp_path / "t.npz", table)
    rep = tmp_path / "report"
    rc = main([str(a) for a in ("fit", tmp_path / "t.npz", "--model", "lobes2", "--starts", 1, "--max-steps", 8,
                                "--report", rep, "--save-model", tmp_path / "fit.json")])
    err = capsys.readouterr().err
    assert rc == 0, err
    doc = json.loads((rep / "report.json").read_text())
    assert doc["model"]["type"] == "MultiLobe" and len(doc["model"]["lobes"]) == 2
    assert (rep / "report.md").exists() and (rep / "model.json").exists()
    from matfit.export import load_model
    m = load_model(tmp_path / "fit.json")
    assert type(m) is MultiLobe and m.lobes[0].distribution == "ggx"


_GOLD = (C.GOLD_ETA, C.GOLD_K)
#: MultiLobe models Mitsuba evaluates exactly (conductor and dielectric lobes, GGX, separable masking)
MITSUBA_EXACT = {
    "base-metal-glass": lambda: MultiLobe(j((0.2, 0.15, 0.1), np.float32), [
        SpecularLobe(0.08, "conductor", weight=j((0.3, 0.25, 0.2), np.float32), eta=j(_GOLD[0], np.float32),
                     k=j(_GOLD[1], np.float32)),
        SpecularLobe(0.3, "dielectric", weight=0.2, eta=1.5, alpha_y=0.5)]),
    "metal2": lambda: FAMILIES["metal2"].build({"alpha_1": j(0.05, np.float32), "eta": j(_GOLD[0], np.float32),
                                                "k": j(_GOLD[1], np.float32), "ratio_2": j(6.0, np.float32),
                                                "mix_2": j(0.3, np.float32)}, 3),
}


@pytest.mark.parametrize("name", sorted(MITSUBA_EXACT))
def test_mitsuba_evaluates_an_exported_multilobe_equal(name):
    import test_export as E

    from matfit.export import to_mitsuba, to_mitsuba_xml

    mi = E._mitsuba()
    model = MITSUBA_EXACT[name]()
    r = to_mitsuba(model)
    assert r.exact and r.fidelity is None and r.content["type"] == "blendbsdf"
    wo, wi = E._pairs(300)
    ours = np.asarray(model.eval(jnp.asarray(wo, jnp.float32), jnp.asarray(wi, jnp.float32)))
    assert ours.max() > 0.5 and np.all(ours >= 0)  # the pairs reach the lobes, not only the base
    for bsdf in (mi.load_dict(r.content), mi.load_string(to_mitsuba_xml(model).content)):
        theirs = E._mi_eval(mi, bsdf, wo, wi)
        err = np.abs(ours - theirs) / np.maximum(np.abs(theirs), 1e-6)
        assert np.median(err) <= 1e-5 and err.max() <= 1e-4, (name, np.median(err), err.max())


@pytest.mark.parametrize("target, model, match", [
    # Schlick lobes (lobes1/2/3): no Mitsuba plugin has Schlick's Fresnel with a separate weight
    ("mitsuba", lambda: MultiLobe(j(ALB), [SpecularLobe(0.1, weight=0.9, f0=0.04)]), "MultiLobe has no mapping.*Schlick"),
    ("mitsuba-xml", lambda: MultiLobe(j(ALB), [SpecularLobe(0.1, weight=0.9, f0=0.04)]), "MultiLobe has no mapping"),
    # albedo + weights above 1: the blend's scales would be reflectances above 1
    ("mitsuba", lambda: MultiLobe(0.6, [SpecularLobe(0.1, "conductor", weight=0.6, eta=_GOLD[0], k=_GOLD[1])]),
     "MultiLobe has no mapping.*sum of weights <= 1"),
    # height-correlated masking: Mitsuba's is separable
    ("mitsuba", lambda: MultiLobe(0.1, [SpecularLobe(0.1, "conductor", weight=0.6, eta=_GOLD[0], k=_GOLD[1],
                                                     masking="height_correlated")]), "MultiLobe has no mapping"),
    ("pbrt", lambda: MITSUBA_EXACT["metal2"](), "MultiLobe has no pbrt-v4 material; exports Lambert"),
    ("pbrt", lambda: MultiLobe(j(ALB), [SpecularLobe(0.1, weight=0.9, f0=0.04)]), "MultiLobe has no pbrt-v4 material"),
])
def test_exporters_without_a_multilobe_form_raise(target, model, match):
    from matfit.export import export

    with pytest.raises(ParameterError, match=match) as info:
        export(model(), target)
    assert "Lambert" in str(info.value)  # names what the exporter supports


@pytest.mark.parametrize("target", ["gltf", "mtlx"])
def test_gltf_and_materialx_write_a_fitted_multilobe(target):
    from matfit.export import export

    if target == "mtlx":
        pytest.importorskip("MaterialX")
    model = MultiLobe(j((0.3, 0.2, 0.1), np.float32), [SpecularLobe(0.15, weight=0.8, f0=0.04),
                                                       SpecularLobe(0.5, weight=0.2, f0=0.04)])
    r = export(model, target)
    assert not r.exact and r.fidelity is not None and np.isfinite(r.fidelity.relative_rmse)
    assert r.fidelity.relative_rmse < 0.5 and any("MultiLobe" in n for n in r.notes)
    assert type(r.model).__name__ == "GltfPBR"


# ------------------------------------------------------------------------------------------------
# 9. bad input
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("make, match", [
    (lambda: MultiLobe(0.5, []), "at least one SpecularLobe"),
    (lambda: MultiLobe(0.5, SpecularLobe()), "list or tuple of SpecularLobe"),
    (lambda: MultiLobe(0.5, [RoughConductor(0.2, 1.5, 3.0)]), r"lobes\[0\] must be a SpecularLobe"),
    (lambda: MultiLobe(1.5, [SpecularLobe()]), "parameter 'albedo' must be <= 1.0"),
    (lambda: MultiLobe([0.1, 0.2, 0.3], [SpecularLobe(weight=[1.0, 1.0])]), "colour channels"),
    (lambda: SpecularLobe(fresnel="metal"), "fresnel must be one of"),
    (lambda: Lobe(fresnel="metal"), "Lobe: fresnel must be one of"),
    (lambda: Lobe(masking="smith"), "Lobe: masking must be one of"),
    (lambda: SpecularLobe(fresnel="conductor", eta=0.2), "needs eta and k"),
    (lambda: SpecularLobe(fresnel="conductor", eta=0.2, k=3.0, f0=0.5), "f0 does not apply to a 'conductor' lobe"),
    (lambda: SpecularLobe(fresnel="schlick", eta=1.5), "eta does not apply to a 'schlick' lobe"),
    (lambda: SpecularLobe(f0=1.5), "parameter 'f0' must be <= 1.0"),
    (lambda: SpecularLobe(weight=-0.1), "parameter 'weight' must be >= 0.0"),
    (lambda: SpecularLobe(1.5, distribution="blinn_phong"), r"alpha \(blinn_phong\)"),
])
def test_bad_parameters_raise(make, match):
    with pytest.raises(ParameterError, match=match):
        make()


@pytest.mark.parametrize("family, params, expect", [
    ("lobes3", {"ks_1": 0.3, "ks_2": [0.0, 0.0, 0.0], "ks_3": 0.2, "ratio_2": 3.0, "ratio_3": 2.0}, "lobes2"),
    ("lobes3", {"ks_1": 0.3, "ks_2": 0.1, "ks_3": 0.2, "ratio_2": 1.0002, "ratio_3": 1.0}, "lobes1"),
    ("lobes3", {"ks_1": 0.3, "ks_2": 0.1, "ks_3": 0.2, "ratio_2": 1.5, "ratio_3": 2.0}, None),
    ("lobes2", {"ks_1": [0.3, 0.0, 0.0], "ks_2": 0.1, "ratio_2": 2.0}, None),  # one channel's zero is a colour
    ("lobes1", {"ks_1": 0.0}, None),  # no smaller lobes family: its diffuse base stays
    ("metal2", {"mix_2": 0.0, "ratio_2": 2.0}, "conductor"),
    ("metal2", {"mix_2": 0.4, "ratio_2": 1.0}, "conductor"),
    ("metal2", {"mix_2": 0.4, "ratio_2": 2.0}, None),
    ("plastic", {"albedo": 0.0, "alpha": 0.1, "eta": 1.5}, None),
])
def test_reduced_family(family, params, expect):
    from matfit.fitting import reduced_family

    red = reduced_family(family, params)
    assert (red and red[0]) == expect if expect else red is None
