"""Multi-start: start 0 is the data-driven guess, the others are the screened candidates with the
lowest objective (matfit.fitting.fit.fit_starts), the same in fit() and fit_batch(); one candidate
is the guess with the widths of the distribution extracted from the retro-reflection
(matfit.fitting._starts.ndf_widths, Dupuy et al. 2015)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from data_synth import geometry
from matfit import Table
from matfit.fitting import Parametrization, fit, fit_batch
import matfit.fitting._starts as starts_module
from matfit.fitting._starts import candidates, initial_guesses, ndf_widths
from matfit.fitting._residuals import residual_fn
from matfit.fitting.fit import SCREEN_PER_START, fit_starts, initial_guess
from matfit.models import Plastic, RoughConductor


ALPHA, ETA, K = 0.25, [0.3, 1.2, 2.5], [3.0, 5.0, 2.0]


def _conductor_table(grid, alpha=ALPHA, seed=0):
    wo, wi, ok, _ = geometry.merl_grid(*grid)
    wo, wi = np.asarray(wo)[ok], np.asarray(wi)[ok]
    f = np.asarray(RoughConductor(alpha, ETA, K).eval(wo, wi))
    return Table(wo=wo, wi=wi, values=f * (1 + 0.01 * np.random.default_rng(seed).normal(size=f.shape)))


@pytest.fixture(scope="module")
def table():
    """A coarse MERL-like grid: its first theta_d cell (5.6 deg) is too far from backscattering
    for the extraction (no ndf candidate)."""
    return _conductor_table((6, 8, 8))


@pytest.fixture(scope="module")
def retro_table():
    """A grid with retro-reflection cells (theta_d 1.875 deg), the extraction's input."""
    return _conductor_table((24, 24, 8))


def _objective(par, table):
    fn = residual_fn(par, "l2", None, 1.0)
    a = table.as_jax(jnp.float64)
    arrays = (a.wo, a.wi, a.values, a.weight)

    def one(z):  # written out here: sum of squared residuals, one candidate at a time
        r = np.asarray(fn(z, arrays))
        return 0.5 * float(np.sum(r * r)) if np.all(np.isfinite(r)) else np.inf

    return one, arrays


@pytest.mark.parametrize("which", ["table", "retro_table"])
def test_starts_are_guess_then_best_candidates(which, request, x64):
    table = request.getfixturevalue(which)
    par = Parametrization("conductor", 3)
    one, arrays = _objective(par, table)
    fn = residual_fn(par, "l2", None, 1.0)
    obj = jax.jit(jax.vmap(lambda z, a: 0.5 * jnp.sum(fn(z, a) ** 2), in_axes=(0, None)))
    n = 4
    z0s = np.asarray(fit_starts(table, par, n, 7, obj, arrays))
    assert z0s.shape == (n, par.size)
    guess = np.asarray(par.z_from_theta(initial_guess(table, par)))
    np.testing.assert_allclose(z0s[0], guess)
    # the extracted widths' start is one more candidate, in a slot that is always there (unused: never picked)
    widths = ndf_widths(table)
    assert (widths is None) == (which == "table")
    extra = None
    if widths is not None:
        g = {k: v[0] for k, v in initial_guesses([table], par, widths=widths).items()}
        extra = np.asarray(par.z_from_theta(g))[None, None]
    cand = np.asarray(candidates(par, jnp.asarray(guess)[None], n - 1, 7, extra))[0]
    assert cand.shape == (SCREEN_PER_START * (n - 1) + 1, par.size)
    plain = np.asarray(candidates(par, jnp.asarray(guess)[None], n - 1, 7))[0]
    np.testing.assert_array_equal(cand[:-1], plain[:-1])
    np.testing.assert_array_equal(cand[-1], guess if extra is None else extra[0, 0])
    values = np.array([one(c) for c in cand])
    if extra is None:
        values[-1] = np.inf
    best = cand[np.argsort(values)[: n - 1]]
    np.testing.assert_allclose(z0s[1:], best, rtol=1e-12)
    # half the candidates spread over the parameter box: every bounded parameter's range is visited
    theta = np.array([np.asarray(par.theta_vector(jnp.asarray(c))) for c in cand[(len(cand) - 1) // 2:-1]])  # the spread half (before the extra slot)
    lo, hi = par.lower_upper()
    assert np.all(theta.min(0) < lo + 0.35 * (hi - lo)) and np.all(theta.max(0) > lo + 0.65 * (hi - lo))


def test_fit_batch_starts_include_the_guess(table, x64):
    """Extra screened starts never make fit_batch worse than one start (start 0 is the guess)."""
    v1, o1, _ = fit_batch([table], model="conductor", starts=1, max_steps=40)
    v3, o3, _ = fit_batch([table], model="conductor", starts=3, max_steps=40)
    assert o3[0] <= o1[0] * (1 + 1e-9)


def test_percentile10_matches_numpy():
    from matfit.fitting._starts import percentile10

    rng = np.random.default_rng(3)
    v = rng.random((7, 50, 3))
    valid = rng.random((7, 50)) < 0.6
    valid[0] = False
    valid[0, 4] = True  # one valid row
    got = percentile10(v, valid)
    ref = np.stack([np.percentile(v[b][valid[b]], 10, axis=0) for b in range(7)])
    np.testing.assert_allclose(got, ref, rtol=1e-14)


@pytest.mark.check
@pytest.mark.parametrize("family", ["conductor", "plastic", "car_paint"])
def test_initial_guesses_batch_equals_one_by_one(table, family):
    from matfit.fitting.fit import initial_guesses

    rng = np.random.default_rng(4)
    tables = []
    for i in range(5):
        valid = rng.random(len(table)) < 0.8 if i else np.ones(len(table), bool)
        tables.append(Table(wo=table.wo, wi=table.wi, values=table.values * rng.uniform(0.5, 2.0, 3), valid=valid))
    par = Parametrization(family, 3)
    batch = initial_guesses(tables, par)
    for i, t in enumerate(tables):
        one = initial_guess(t, par)
        assert set(one) == set(batch)
        for k in one:
            np.testing.assert_allclose(batch[k][i], one[k], rtol=1e-12)


# ------------------------------------------------------------------------------------------------
# The data-driven microfacet start (ndf_widths)
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("alpha", [0.08, 0.25])
def test_ndf_widths_recover_the_width_of_the_table(alpha, x64):
    """The extracted GGX width of a GGX conductor table is its alpha (within 3 %), where the
    half-width guess is only a rough estimate."""
    w = ndf_widths(_conductor_table((24, 24, 8), alpha))
    assert w["alpha"] == pytest.approx(alpha, rel=0.03)
    assert w["alpha_base"] == w["alpha_coat"] == w["alpha"]  # one lobe


def test_ndf_widths_bad_tables_give_none(table, x64):
    assert ndf_widths(table) is None  # no rows near backscattering
    black = Table(wo=table.wo, wi=table.wi, values=np.zeros_like(table.values))
    assert ndf_widths(black) is None


def test_ndf_candidate_only_where_the_family_reads_widths(retro_table, x64, monkeypatch):
    """The candidate carries the extracted width for a family with a width (its start differs
    from the guess only there, for plastic); a family without one (lambert) keeps the plain pool."""
    seen = []
    real = starts_module.candidates

    def spy(par, base, n_extra, seed, extra=None):
        seen.append(extra)
        return real(par, base, n_extra, seed, extra)

    monkeypatch.setattr(starts_module, "candidates", spy)
    for family, expect in (("plastic", True), ("lambert", False)):
        par = Parametrization(family, 3)
        fn = residual_fn(par, "l2", None, 1.0)
        obj = jax.jit(jax.vmap(lambda z, a: 0.5 * jnp.sum(fn(z, a) ** 2), in_axes=(0, None)))
        _, arrays = _objective(par, retro_table)
        seen.clear()
        fit_starts(retro_table, par, 3, 0, obj, arrays)
        assert (seen[0] is not None) == expect
        if expect:
            theta = np.asarray(par.theta_vector(jnp.asarray(seen[0][0, 0])))
            guess = np.asarray(par.theta_vector(par.z_from_theta(initial_guess(retro_table, par))))
            i = par.labels.index("alpha")
            differs = np.flatnonzero(~np.isclose(theta, guess, rtol=1e-9))
            assert differs.tolist() == [i]
            g = initial_guess(retro_table, par)
            w = ndf_widths(retro_table, np.asarray(g["albedo"]) / np.pi)
            assert theta[i] == pytest.approx(w["alpha"], rel=1e-9)
    # switched off: no candidate
    monkeypatch.setattr(starts_module, "NDF_CANDIDATE", False)
    seen.clear()
    par = Parametrization("plastic", 3)
    fn = residual_fn(par, "l2", None, 1.0)
    obj = jax.jit(jax.vmap(lambda z, a: 0.5 * jnp.sum(fn(z, a) ** 2), in_axes=(0, None)))
    fit_starts(retro_table, par, 3, 0, obj, _objective(par, retro_table)[1])
    assert seen == [None]


def test_fit_with_the_ndf_candidate_compiles_once(x64):
    """Two plastic fits of tables of one shape with retro-reflection rows (so the candidate is
    built): the second compiles nothing. (Plastic: the conductor families' refinement compiles
    per table whatever the starts, see _conductor_guess.)"""
    from test_compile_count import count_compilations

    wo, wi, ok, _ = geometry.merl_grid(24, 24, 8)
    wo, wi = np.asarray(wo)[ok], np.asarray(wi)[ok]
    t1, t2 = (Table(wo=wo, wi=wi, values=np.asarray(Plastic([0.5, 0.3, 0.2], a, 1.5).eval(wo, wi))) for a in (0.1, 0.3))
    assert ndf_widths(t1) is not None and ndf_widths(t2) is not None
    r1 = fit(t1, model="plastic", starts=3, max_steps=24)
    with count_compilations() as seen:
        r2 = fit(t2, model="plastic", starts=3, max_steps=24)
    assert seen == [], f"recompiled: {seen}"
    assert float(r1.params["alpha"]) == pytest.approx(0.1, rel=0.05)
    assert float(r2.params["alpha"]) == pytest.approx(0.3, rel=0.05)


def test_widths_entries_are_checked(table):
    from matfit.errors import ParameterError

    with pytest.raises(ParameterError, match="widths entry 'eta'"):
        initial_guesses([table], Parametrization("conductor", 3), widths={"eta": 1.0})


@pytest.mark.parametrize("family", ["conductor", "plastic"])
def test_guess_from_shared_features_equals_a_fresh_guess(family, retro_table):
    """fit_starts computes a table's features once for its two guesses (the generic one and the
    one with the extracted widths): each equals the guess computed from scratch, and the family's
    refinement (the conductor's, in place) leaves the shared features unchanged."""
    from matfit.fitting.fit import guesses_from_arrays
    from matfit.fitting._starts import table_features

    par = Parametrization(family, 3)
    arrays = tuple(np.asarray(a, float)[None] for a in (retro_table.wo, retro_table.wi, retro_table.values))
    M = np.asarray(retro_table.valid)[None]
    feats = table_features(*arrays, M)
    before = {k: v.copy() for k, v in feats.items()}
    for widths in (None, {"alpha": 0.1, "alpha_base": 0.3, "alpha_coat": 0.1}):
        shared = guesses_from_arrays(*arrays, M, par, widths=widths, features=feats)
        fresh = guesses_from_arrays(*arrays, M, par, widths=widths)
        assert shared.keys() == fresh.keys()
        for k in fresh:
            np.testing.assert_array_equal(shared[k], fresh[k])
    for k in before:
        np.testing.assert_array_equal(feats[k], before[k])
    assert feats["alpha"].shape == (1,) and feats["floor"].shape == feats["r0"].shape == (1, 3)
