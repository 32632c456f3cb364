"""The grouped-difference Levenberg-Marquardt solver (fit(..., method="lm_fd")).

Checks against independent machinery: the grouped Jacobian against forward-mode AD, the final
loss against scipy.optimize.least_squares on the same residuals, and fit_batch against fit.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from testdata import random_pairs
from matfit import Table
from matfit.fitting import fit, fit_batch, initial_guess
from matfit.fitting._residuals import by_channel, residual_fn, table_arrays
from matfit.fitting.lm import column_groups, jacobian
from matfit.fitting.params import Parametrization
from matfit.models import RoughConductor


def _table(n=96, seed=0, params=(0.3, [0.2, 0.9, 1.4], [3.6, 2.5, 1.9]), noise=0.02):
    rng = np.random.default_rng(seed)
    wo, wi = random_pairs(rng, n)
    a, e, k = params
    f = np.asarray(RoughConductor(a, jnp.asarray(e, float), jnp.asarray(k, float)).eval(jnp.asarray(wo), jnp.asarray(wi)))
    return Table(wo=wo, wi=wi, values=f * (1 + noise * rng.standard_normal(f.shape)), channels="rgb")


@pytest.mark.check
def test_column_groups_structure():
    par = Parametrization("conductor", 3, tied=("k",))
    seeds, owner = column_groups(par)
    assert par.labels == ["alpha", "eta[0]", "eta[1]", "eta[2]", "k"]
    np.testing.assert_array_equal(seeds, [[1, 0, 0, 0, 0], [0, 1, 1, 1, 0], [0, 0, 0, 0, 1]])
    np.testing.assert_array_equal(owner[:, 1:4], np.eye(3))  # eta[c] acts on channel c only
    assert np.all(owner[:, [0, 4]] == 1)  # shared and tied parameters act on every channel


@pytest.mark.parametrize("family", ["conductor"])  # plastic: same grouping, a minute to compile
def test_grouped_jacobian_matches_forward_mode(family, x64):
    t = _table(n=24)
    par = Parametrization(family, 3)
    fn = by_channel(residual_fn(par, "e2", None, 1.0))
    arrays = table_arrays(t, jnp.float64)
    z = jnp.asarray(np.random.default_rng(1).normal(0, 0.5, par.size))
    r, J = jacobian(fn, z, arrays, *column_groups(par), central=True)
    J_ad = jax.jacfwd(fn)(z, arrays)  # (N, C, p), every column by AD
    np.testing.assert_allclose(np.asarray(r), np.asarray(fn(z, arrays)))
    scale = np.max(np.abs(J_ad))
    np.testing.assert_allclose(np.asarray(J), np.asarray(J_ad), atol=1e-6 * scale, rtol=1e-5)


def test_lm_fd_reaches_scipy_loss(x64):
    from scipy.optimize import least_squares

    # 0.5 % noise keeps the minimum inside the bounds: with 2 % on 96 rows the red eta runs to
    # its lower bound, where both solvers creep along the flat tail of the bound's sigmoid and
    # stop wherever a step's decrease falls below tolerance (1e-10 to 1e-7 of the loss apart,
    # depending on the Jacobian's last bits).
    t = _table(noise=0.005)
    # Tolerances as tight as scipy's here: with the default rtol = 1e-8 lm_fd stops like
    # least_squares(ftol=1e-8) does, once a step lowers the objective by less than 1e-8 of it.
    r = fit(t, model="conductor", method="lm_fd", starts=1, dtype=jnp.float64, rtol=1e-12, atol=1e-14)
    par = Parametrization("conductor", 3)
    fn = jax.jit(residual_fn(par, "l2", None, 1.0))
    arrays = table_arrays(t, jnp.float64)
    z0 = np.asarray(par.z_from_theta(initial_guess(t, par)))
    ref = least_squares(lambda z: np.asarray(fn(jnp.asarray(z), arrays)), z0, xtol=1e-12, ftol=1e-12, gtol=1e-12)
    assert r.converged
    assert abs(r.objective - ref.cost) <= 1e-10 * ref.cost
    # And it recovers the generating parameters within the noise.
    np.testing.assert_allclose(r.params["alpha"], 0.3, rtol=0.05)


def test_fit_batch_lm_fd_equals_single_fits(x64):
    tables = [_table(n=48, seed=s, params=(0.2 + 0.1 * s, [0.3, 0.8, 1.5], [3.0, 2.0, 1.5])) for s in range(2)]
    values, obj, labels = fit_batch(tables, model="conductor", method="lm_fd", max_steps=64)
    for i, t in enumerate(tables):
        r = fit(t, model="conductor", method="lm_fd", starts=1, max_steps=64)
        assert abs(obj[i] - r.objective) <= 1e-8 * r.objective + 1e-14
        np.testing.assert_allclose(values[i], r.values, rtol=1e-5, atol=1e-8)


def test_large_table_multi_start_solves_the_best_subset_start_in_full(x64, monkeypatch):
    """With several starts a large table's starts are solved on its subset one after another and
    only the best of them on the whole table: the result is no worse than a one-start fit from
    the data-driven guess, every start's objective on the whole table is finite and at least the
    best's, and the result says how it was computed."""
    import importlib

    fm = importlib.import_module("matfit.fitting._solver")  # where the subset size and the solver cache live
    t = _table(n=4 * 2048 + 500, seed=4, noise=0.01)
    monkeypatch.setattr(fm, "COARSE_ROWS", 2048)
    fm.compiled_solver.cache_clear()
    multi = fit(t, model="conductor", method="lm_fd", loss="l2", starts=3)
    one = fit(t, model="conductor", method="lm_fd", loss="l2", starts=1)
    fm.compiled_solver.cache_clear()
    objs = np.asarray(multi.start_objectives)
    assert objs.shape == (3,) and np.all(np.isfinite(objs))
    # Both stop by the default rtol = 1e-8 (a last step that changed the objective by less than
    # 1e-8 of it), so equal minima agree to far better than that but not to the last bits; a
    # worse local minimum is percents higher.
    assert multi.objective == objs.min() <= one.objective * (1 + 1e-10)
    assert any("subset" in note for note in multi.info)
    assert abs(float(multi.params["alpha"]) - 0.3) < 0.01


def test_large_table_subset_start_reaches_the_plain_minimum(x64, monkeypatch):
    """A table of >= 4 * COARSE_ROWS rows is solved on a random subset first, then in full (with
    the line-minimum extrapolation): it must end at the minimum the plain full-table solve finds,
    with the truth recovered."""
    import importlib

    fm = importlib.import_module("matfit.fitting._solver")  # where the subset size and the solver cache live

    t = _table(n=4 * 2048 + 500, seed=3, noise=0.01)
    monkeypatch.setattr(fm, "COARSE_ROWS", 2048)
    fm.compiled_solver.cache_clear()
    coarse = fit(t, model="conductor", method="lm_fd", loss="l2", starts=1)
    monkeypatch.setattr(fm, "COARSE_ROWS", 10**9)  # no subset: the plain solve
    fm.compiled_solver.cache_clear()
    plain = fit(t, model="conductor", method="lm_fd", loss="l2", starts=1)
    fm.compiled_solver.cache_clear()
    assert coarse.converged and plain.converged
    assert abs(coarse.objective - plain.objective) <= 1e-7 * plain.objective
    np.testing.assert_allclose(coarse.values, plain.values, rtol=1e-3, atol=1e-4)
    assert abs(float(coarse.params["alpha"]) - 0.3) < 0.01
