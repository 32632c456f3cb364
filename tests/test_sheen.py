"""Sheen: the Charlie sheen lobe (Estevez & Kulla 2017) over a base, the base scaled by the
extension's albedo scaling.

1. eval against a numpy transcription of the paper's formulas (D, the fitted Lambda, V) with the
   albedo scaling computed here by quadrature (not read from matfit's table).
2. The sheen's directional albedo (the table) against a numpy quadrature; the white furnace:
   a white sheen over a white Lambertian base reflects at most everything.
3. Helmholtz reciprocity.
4. Sampling: weight == f cos / pdf, chi-square of the samples against pdf (tests/chi2.py), the
   valid fraction against int pdf.
5. Gradients against central finite differences (float64); float32 finite at the hard pairs.
6. Bad input raises ParameterError naming the problem.
"""

from __future__ import annotations

import math
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

from matfit.errors import ParameterError  # noqa: E402
from matfit.models import Lambert, RoughConductor, Sheen, sheen_albedo  # noqa: E402

# Estevez & Kulla's L(x) fits at alpha = 1 and 0 (the paper's table; KHR_materials_sheen)
FITS = {"a": (21.5473, 25.3245), "b": (3.82987, 3.32435), "c": (0.19823, 0.16801), "d": (-1.97760, -1.27393),
        "e": (-4.32054, -4.85967)}


def ref_lambda(mu, r):
    t = (1 - r) ** 2
    k = {n: lo + (hi - lo) * t for n, (lo, hi) in FITS.items()}

    def L(x):
        return k["a"] / (1 + k["b"] * np.maximum(x, 1e-6) ** k["c"]) + k["d"] * x + k["e"]

    return np.where(mu < 0.5, np.exp(L(np.minimum(mu, 0.5))), np.exp(2 * L(0.5) - L(1 - mu)))


def ref_sheen(wo, wi, r):
    """The white sheen lobe D V (1/sr), 0 below the horizon."""
    h = wo + wi
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    sin2 = np.clip(1 - h[..., 2] ** 2, 0, 1)
    D = (2 + 1 / r) * sin2 ** (0.5 / r) / (2 * np.pi)
    mo, mi = wo[..., 2], wi[..., 2]
    ok = (mo > 1e-7) & (mi > 1e-7)
    with np.errstate(all="ignore"):
        V = 1 / ((1 + ref_lambda(np.clip(mo, 0, 1), r) + ref_lambda(np.clip(mi, 0, 1), r)) * 4 * mo * mi)
    return np.where(ok, D * V, 0.0)


def ref_albedo(mu, r, n=128):
    wi, w = R.upper_hemisphere_rule(n)
    wi = wi.reshape(-1, 3)
    wo = np.broadcast_to(unit(mu, 0.0), wi.shape)
    return float(np.sum(ref_sheen(wo, wi, r) * wi[:, 2] * w.ravel()))


def j(x, dt=np.float64):
    return jnp.asarray(np.asarray(x, dt))


BASE = (0.4, 0.2, 0.1)
COLOR = (0.9, 0.5, 0.6)


def test_sheen_albedo_matches_quadrature(x64, rng):
    mus = np.concatenate([[1.0, 0.5, 0.1, 0.02], rng.uniform(0.05, 1, 6)])
    rs = np.concatenate([[0.3, 1.0, 0.05, 0.6], rng.uniform(0.05, 1, 6)])
    got = np.asarray(sheen_albedo(j(mus), j(rs)))
    ref = np.array([ref_albedo(m, r) for m, r in zip(mus, rs)])
    np.testing.assert_allclose(got, ref, rtol=5e-3, atol=2e-3)
    assert ref.max() < 1 and ref[2] > ref[0]  # a sheen reflects more at grazing light


@pytest.mark.check
def test_eval_matches_reference(x64, rng):
    wo, wi = C.random_pairs(rng, 300, 0.02, "both")
    r = 0.35
    m = Sheen(Lambert(j(BASE)), j(COLOR), j(r))
    f = np.asarray(m.eval(j(wo), j(wi)))
    mo, mi = np.clip(wo[:, 2], 0, 1), np.clip(wi[:, 2], 0, 1)
    E = {mu: ref_albedo(mu, r, 96) for mu in np.unique(np.round(np.concatenate([mo, mi]), 3))}
    e = np.maximum([E[x] for x in np.round(mo, 3)], [E[x] for x in np.round(mi, 3)])
    scale = 1 - max(COLOR) * e
    ref = np.asarray(COLOR) * ref_sheen(wo, wi, r)[:, None] + scale[:, None] * R.lambert_eval(wo, wi, BASE)
    below = (wo[:, 2] <= 0) | (wi[:, 2] <= 0)
    assert below.sum() > 20 and np.all(f[below] == 0)
    # the lobe exactly; the scaling through the albedo table (bilinear) within 2e-3 of quadrature
    np.testing.assert_allclose(f, ref, rtol=3e-3, atol=1e-6)


def test_white_furnace_and_reciprocity(x64, rng):
    white = Sheen(Lambert(1.0), 1.0, 0.4)
    for mu in (1.0, 0.5, 0.1, 0.02):
        e = np.asarray(white.albedo(j(unit(mu, 0.3)), n=128))
        # <= 1 up to the albedo table's interpolation error (the scaling reads the table, the
        # sheen reflects its true albedo): 1e-3 at mu = 0.02
        assert e[0] <= 1.0 + 3e-3, (mu, e)
        assert e[0] >= 0.85  # the scaling takes no more than the sheen gives
    wo, wi = C.random_pairs(rng, 200, 0.01, "both")
    m = Sheen(RoughConductor(0.3, *map(j, (C.GOLD_ETA, C.GOLD_K))), j(COLOR), 0.5)
    f1, f2 = np.asarray(m.eval(j(wo), j(wi))), np.asarray(m.eval(j(wi), j(wo)))
    assert np.count_nonzero(f1.max(-1)) > 30
    assert R.rel_err(f1, f2, 1e-300).max() <= 1e-12


@dataclass(frozen=True)
class SheenCase(S.Case):
    """A Sheen over a Lambertian or rough-conductor base, in tests/test_sampling.py's machinery
    (the sphere grid: both lobes are wide); float32."""

    base: str = "lambert"

    @property
    def id(self):
        return f"sheen-{self.base}-{self.deg:g}deg"

    def make(self):
        base = Lambert(j(BASE, np.float32)) if self.base == "lambert" else RoughConductor(
            j(0.4, np.float32), j(C.GOLD_ETA, np.float32), j(C.GOLD_K, np.float32))
        return Sheen(base, j(COLOR, np.float32), j(0.3, np.float32))


SAMPLE_CASES = [SheenCase("lambert", "sphere", deg=30.0), SheenCase("lambert", "sphere", deg=80.0, base="conductor")]


@pytest.mark.parametrize("case", SAMPLE_CASES, ids=[c.id for c in SAMPLE_CASES])
def test_sampling_matches_pdf(case):
    r = S.run_case(case)
    assert r.bad_invalid == 0, r.worst_sample
    assert r.pdf_relerr < S.W_RTOL and r.w_relerr < S.W_RTOL, r.worst_sample
    sig = math.sqrt(max(r.frac_valid * (1 - r.frac_valid), 1.0 / r.n) / r.n)
    assert r.integral <= 1 + 1e-3 + r.unresolved
    assert abs(r.integral - r.frac_valid) <= 0.01 * r.integral + 5 * sig + r.unresolved
    assert r.chi2.pvalue > 0.01 / len(SAMPLE_CASES), r.chi2.summary(8)


def test_gradients_match_finite_differences(x64, rng):
    wo, wi = C.random_pairs(rng, 40, 0.2)
    model = Sheen(Lambert(j(BASE)), j(COLOR), j(0.35))
    wts = j(rng.random((len(wo), 3)))
    params, static = eqx.partition(model, eqx.is_inexact_array)

    @jax.jit
    def loss(p):
        return jnp.sum(eqx.combine(p, static).eval(j(wo), j(wi)) * wts)

    grads = jax.grad(loss)(params)
    # the scaling is bilinear in the albedo table: its derivative in alpha jumps at grid lines,
    # hence 1e-3 (the lobe's own derivative is exact)
    assert C.check_leaf_gradients(loss, grads, params, 1e-3) == 7  # base albedo, colour, alpha


def test_float32_finite_at_special_pairs():
    wo, wi = (jnp.asarray(x, jnp.float32) for x in C.special_pairs())
    model = Sheen(Lambert(j(BASE, np.float32)), j(COLOR, np.float32), j(0.3, np.float32))
    C.check_float32_eval_pdf_finite(model, wo, wi)


@pytest.mark.parametrize("args, match", [
    ((Lambert(0.5), 1.2, 0.3), "color"),
    ((Lambert(0.5), 0.5, 0.0), "alpha"),
    ((Lambert(0.5), 0.5, 1.5), "alpha"),
    (("lambert", 0.5, 0.3), "base must be a matfit model"),
    ((Lambert([0.5, 0.4]), [0.5, 0.4, 0.3], 0.3), "channels"),
])
@pytest.mark.check
def test_bad_parameters_raise(args, match):
    with pytest.raises(ParameterError, match=match):
        Sheen(*args)


def test_sheen_family_recovers_a_velvet_and_the_cues_call_for_it(x64, rng):
    from matfit import Table
    from matfit.fitting import appearance_cues, candidates_for, fit

    truth = {"albedo": np.array([0.3, 0.05, 0.1]), "sheen_color": np.array([0.9, 0.4, 0.5]), "sheen_alpha": 0.35}
    model = Sheen(Lambert(j(truth["albedo"])), j(truth["sheen_color"]), j(truth["sheen_alpha"]))
    wo, wi = C.random_pairs(rng, 1500, 0.03)
    v = np.asarray(model.eval(j(wo), j(wi))) * (1 + 0.01 * rng.standard_normal((len(wo), 3)))
    table = Table(wo=wo, wi=wi, values=v)
    cues = appearance_cues(table)
    assert cues["grazing_excess"] and "sheen" in candidates_for(cues), cues
    r = fit(table, model="sheen")
    for name in truth:
        np.testing.assert_allclose(np.ravel(r.params[name]), np.ravel(truth[name]), rtol=0.03, err_msg=name)
    assert r.converged


def test_model_file_round_trip(x64, rng):
    from matfit.export import describe_model, model_from_description

    m = Sheen(RoughConductor(j(0.3), j(C.GOLD_ETA), j(C.GOLD_K)), j(COLOR), j(0.45))
    back = model_from_description(describe_model(m))
    wo, wi = C.random_pairs(rng, 50, 0.05)
    assert type(back) is Sheen and type(back.base) is RoughConductor
    np.testing.assert_allclose(np.asarray(back.eval(j(wo), j(wi))), np.asarray(m.eval(j(wo), j(wi))), rtol=1e-12)


def test_unnormalized_sheen_is_the_extension_formula(x64):
    """normalize=False (the glTF stand-in): the lobe D V undivided and the scaling 1 - max(c) E_bar
    unclamped; equal to the normalized model wherever the lobe's albedo stays below 1."""
    wo, wi = (jnp.asarray(x) for x in C.random_pairs(np.random.default_rng(3), 300, min_cos=0.002))
    for a in (0.3, 1.0):
        np.testing.assert_allclose(Sheen(Lambert(j(BASE)), j(COLOR), a, normalize=False).eval(wo, wi),
                                   Sheen(Lambert(j(BASE)), j(COLOR), a).eval(wo, wi), rtol=1e-12)
    white = Sheen(Lambert(1.0), 1.0, 0.01, normalize=False)
    graze = jnp.array([[0.0, 0.9999, 0.01]]) / jnp.linalg.norm(jnp.array([0.0, 0.9999, 0.01]))
    up = jnp.array([[0.0, 0.0, 1.0]])
    assert float(white.eval(graze, up)[0, 0]) < 0 <= float(Sheen(Lambert(1.0), 1.0, 0.01).eval(graze, up)[0, 0])
    with pytest.raises(ParameterError, match="normalize must be True or False"):
        Sheen(Lambert(1.0), 1.0, 0.3, normalize="yes")
