"""Multi-start: start 0 is the data-driven guess, the others are the screened candidates with the
lowest objective (matfit.fitting.fit.fit_starts), the same in fit() and fit_batch()."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from data_synth import geometry
from matfit import Table
from matfit.fitting import Parametrization, fit_batch
from matfit.fitting._starts import candidates
from matfit.fitting.fit import SCREEN_PER_START, fit_starts, initial_guess, residual_fn
from matfit.models import RoughConductor


@pytest.fixture(scope="module")
def table():
    wo, wi, ok, _ = geometry.merl_grid(6, 8, 8)
    wo, wi = np.asarray(wo)[ok], np.asarray(wi)[ok]
    f = np.asarray(RoughConductor(0.25, [0.3, 1.2, 2.5], [3.0, 5.0, 2.0]).eval(wo, wi))
    return Table(wo=wo, wi=wi, values=f * (1 + 0.01 * np.random.default_rng(0).normal(size=f.shape)))


def _objective(par, table):
    fn = residual_fn(par, "l2", None, 1.0)
    a = table.as_jax(jnp.float64)
    arrays = (a.wo, a.wi, a.values, a.weight)

    def one(z):  # written out here: sum of squared residuals, one candidate at a time
        r = np.asarray(fn(z, arrays))
        return 0.5 * float(np.sum(r * r)) if np.all(np.isfinite(r)) else np.inf

    return one, arrays


def test_starts_are_guess_then_best_candidates(table, x64):
    par = Parametrization("conductor", 3)
    one, arrays = _objective(par, table)
    fn = residual_fn(par, "l2", None, 1.0)
    obj = jax.jit(jax.vmap(lambda z, a: 0.5 * jnp.sum(fn(z, a) ** 2), in_axes=(0, None)))
    n = 4
    z0s = np.asarray(fit_starts(table, par, n, 7, obj, arrays))
    assert z0s.shape == (n, par.size)
    guess = np.asarray(par.z_from_theta(initial_guess(table, par)))
    np.testing.assert_allclose(z0s[0], guess)
    cand = np.asarray(candidates(par, jnp.asarray(guess)[None], n - 1, 7))[0]
    assert cand.shape == (SCREEN_PER_START * (n - 1), par.size)
    values = np.array([one(c) for c in cand])
    best = cand[np.argsort(values)[: n - 1]]
    np.testing.assert_allclose(z0s[1:], best, rtol=1e-12)
    # half the candidates spread over the parameter box: every bounded parameter's range is visited
    theta = np.array([np.asarray(par.theta_vector(jnp.asarray(c))) for c in cand[len(cand) - len(cand) // 2:]])
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
