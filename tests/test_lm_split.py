"""Channel-split residuals for lm_fd (one single-output kernel per colour channel), the blocked
Gram reductions, and the solver's step cap.

Checked against the (N, C) path they replace (same residuals, same normal equations), against
numpy's X X^T, and against a one-parameter problem whose Gauss-Newton step is known in closed form.
"""

from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from matfit.fitting import Problem
from matfit.fitting._solver import compiled_solver
from matfit.fitting._residuals import prepared_residual_fn, split_residual_fn, table_arrays
from matfit.fitting.fit import initial_guess
from matfit.fitting.lm import GRAM_BLOCK, _gram, _moments, _spd_solve, column_groups, jacobian, lm_fd, normal_equations
from matfit.fitting.params import Parametrization

from test_fit_lm_fd import _table


@pytest.mark.check
@pytest.mark.parametrize("m, n", [(4, 3 * GRAM_BLOCK), (3, 1000)])  # blocked, and the plain fallback
def test_gram_equals_numpy(m, n, x64):
    X = np.random.default_rng(0).normal(size=(m, n))
    G = np.asarray(_gram([jnp.asarray(x) for x in X]))
    np.testing.assert_allclose(G, X @ X.T, rtol=1e-12)


@pytest.mark.parametrize("as_list", [True, False])  # small tables (elementwise sums), large (the dot)
def test_moments_equal_numpy(as_list, x64):
    rng = np.random.default_rng(1)
    K, r = rng.normal(size=(4, 50, 3)), rng.normal(size=(50, 3))
    Kj = [jnp.asarray(k) for k in K] if as_list else jnp.asarray(K)
    M, v = (np.asarray(x) for x in _moments(Kj, jnp.asarray(r)))
    for c in range(3):
        np.testing.assert_allclose(M[c], K[:, :, c] @ K[:, :, c].T, rtol=1e-12)
        np.testing.assert_allclose(v[c], K[:, :, c] @ r[:, c], rtol=1e-12)
    # ... and under vmap (fit_batch), where the elementwise form replaces XLA's batched tiny dots
    Kb = [jnp.asarray(np.stack([k, 2 * k])) for k in K] if as_list else jnp.asarray(np.stack([K, 2 * K]))
    Mb, vb = jax.vmap(_moments)(Kb, jnp.asarray(np.stack([r, r])))
    np.testing.assert_allclose(np.asarray(Mb[1]), 4 * M, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(vb[1]), 2 * v, rtol=1e-12)


@pytest.mark.parametrize("central", [False, True])
def test_small_and_large_table_normal_equations_agree(central, x64, monkeypatch):
    """The one-by-one evaluation of small tables and the vmapped one of large tables give the same
    normal equations (the threshold moved so that one table takes both paths)."""
    import matfit.fitting.lm as lm

    t = _table(n=96)
    par = Parametrization("conductor", 3)
    groups = column_groups(par)
    z = jnp.asarray(np.random.default_rng(4).normal(0, 0.5, par.size))
    prep, fn = prepared_residual_fn(par, "e2", None, 1.0)
    args = prep(table_arrays(t, jnp.float64))
    small = normal_equations(fn, z, args, *groups, central=central, wide=True)
    monkeypatch.setattr(lm, "SMALL_TABLE", 0)
    large = normal_equations(fn, z, args, *groups, central=central, wide=True)
    tol = 1e-9 if central else 1e-6  # the two programs round differently; a forward step (~1e-8) amplifies it
    for a, b in zip(small, large):
        b = np.asarray(b)
        np.testing.assert_allclose(np.asarray(a), b, rtol=tol, atol=tol * 1e-3 * np.abs(b).max())


@pytest.mark.check
@pytest.mark.parametrize("family, loss", [("conductor", "e2"), ("lambert", "l2"), ("conductor_beckmann", "cosine")])
def test_split_residuals_equal_interleaved(family, loss, x64):
    t = _table(n=700)  # pads to 1024 rows: two Gram blocks
    par = Parametrization(family, 3)
    z = jnp.asarray(np.random.default_rng(2).normal(0, 0.5, par.size))
    arrays = table_arrays(t, jnp.float64)
    prep, fn = prepared_residual_fn(par, loss, None, 1.0)
    sprep, sfn = split_residual_fn(par, loss, None, 1.0)
    r = np.asarray(fn(z, prep(arrays)))
    rs = np.stack([np.asarray(x) for x in sfn(z, sprep(arrays))], axis=-1)
    assert rs.shape == (2 * GRAM_BLOCK, 3)
    np.testing.assert_allclose(rs[:700], r, rtol=1e-12, atol=1e-15)
    assert np.all(rs[700:] == 0)  # padding rows add nothing


@pytest.mark.parametrize("central", [False, True])
def test_split_normal_equations_equal_interleaved(central, x64):
    t = _table(n=700)
    par = Parametrization("conductor", 3)
    groups = column_groups(par)
    z = jnp.asarray(np.random.default_rng(3).normal(0, 0.5, par.size))
    arrays = table_arrays(t, jnp.float64)
    prep, fn = prepared_residual_fn(par, "e2", None, 1.0)
    sprep, sfn = split_residual_fn(par, "e2", None, 1.0)
    F, A, g, _ = normal_equations(fn, z, prep(arrays), *groups, central=central)
    Fs, As, gs, rs = normal_equations(sfn, z, sprep(arrays), *groups, central=central)
    assert isinstance(rs, tuple) and len(rs) == 3
    np.testing.assert_allclose(float(Fs), float(F), rtol=1e-12)
    # The two layouts round differently; forward differences (h ~ 1e-8) turn that into ~1e-8.
    tol = 1e-9 if central else 1e-6
    np.testing.assert_allclose(np.asarray(As), np.asarray(A), rtol=tol, atol=tol * 1e-3 * np.abs(A).max())
    # g = J^T r sums ~2000 such entries: a component 600x smaller than the largest (here
    # 0.005 of 3.0) keeps only the rounding of the largest, ~3e-12 of it with central differences.
    np.testing.assert_allclose(np.asarray(gs), np.asarray(g), rtol=tol, atol=tol * 1e-2 * np.abs(g).max())
    # The covariance Jacobian stacks the channels back to (n, C, p).
    r_j, J = jacobian(sfn, z, sprep(arrays), *groups, central=central)
    assert r_j.shape == (2 * GRAM_BLOCK, 3) and J.shape == (2 * GRAM_BLOCK, 3, par.size)
    np.testing.assert_allclose(np.einsum("ncp,ncq->pq", J, J), np.asarray(As), rtol=tol, atol=tol * 1e-3 * np.abs(A).max())


def test_split_solver_reaches_interleaved_solution(x64):
    """fit's single-table solver (channel-split) and the (N, C) solver fit_batch uses end at the
    same objective from the same start."""
    t = _table(n=600, noise=0.01)
    par = Parametrization("conductor", 3)
    arrays = table_arrays(t, jnp.float64)
    z0 = jnp.asarray(par.z_from_theta(initial_guess(t, par)))[None]
    out = {}
    for split in (False, True):
        solve, _ = compiled_solver(Problem.of("conductor", 3, loss="e2"), "lm_fd", 128, 1e-10, 1e-12, split)
        sol = solve(z0, arrays)
        assert bool(sol.converged[0])
        out[split] = float(sol.F[0])
    assert abs(out[True] - out[False]) <= 1e-9 * out[False]


def _saturating(z, args):
    """r = sigmoid(z) - 1.2: the optimum lies beyond sigmoid's range (z -> inf)."""
    return (jax.nn.sigmoid(z[0]) - 1.2) * jnp.ones((4, 1))


@pytest.mark.parametrize("cap", [3.0, 1.0])
def test_step_cap(cap, x64):
    seeds, owner = np.ones((1, 1)), np.ones((1, 1))
    z0 = jnp.array([0.0])
    # Unlimited, the first Gauss-Newton step from z = 0 is (1.2 - 0.5) / sigmoid'(0) = 0.7 / 0.25 = 2.8.
    z_free = lm_fd(_saturating, z0, None, seeds, owner, max_steps=1, max_step=np.inf, tau=1e-12).z
    assert float(z_free[0]) == pytest.approx(2.8, rel=1e-6)
    z1 = lm_fd(_saturating, z0, None, seeds, owner, max_steps=1, max_step=cap, tau=1e-12).z
    assert float(z1[0]) == pytest.approx(min(cap, 2.8), rel=1e-6)
    # Many capped steps still make progress towards the bound, at most `cap` per step.
    res = lm_fd(_saturating, z0, None, seeds, owner, max_steps=5, max_step=cap)
    z5, steps = res.z, res.steps
    assert 0 < float(z5[0]) <= 5 * cap + 1e-9 and int(steps) == 5


def _saturated_and_linear(z, args):
    """r0 = sigmoid(z0) - 1.2 (saturated at z0 = 6: its Gauss-Newton step is ~80), r1 = z1 - 2."""
    return jnp.stack([jax.nn.sigmoid(z[0]) - 1.2, z[1] - 2.0])[:, None]


def test_capped_coordinate_does_not_freeze_the_others(x64):
    """A step that would move one coordinate beyond the cap holds that coordinate at the cap and
    takes the full Gauss-Newton step in the others (scaling the whole step down would move z1 by
    2 * 3 / 80 = 0.07 instead of 2)."""
    seeds, owner = np.eye(2), np.ones((1, 2))
    z1 = lm_fd(_saturated_and_linear, jnp.array([6.0, 0.0]), None, seeds, owner, max_steps=1, max_step=3.0,
               tau=1e-12).z
    assert float(z1[0]) == pytest.approx(9.0, rel=1e-9)
    assert float(z1[1]) == pytest.approx(2.0, rel=1e-5)


def _exp_decay(z, xy):
    x, y = xy
    return (z[0] * jnp.exp(-z[1] * x) - y)[:, None]


def test_float32_fit_stops_at_its_rounding_floor(x64):
    """At a float32 minimum the trial steps are rejected for rounding: the solver stops at the first
    one whose actual and predicted changes are within the tolerance (MINPACK's ftol test), not
    after max_reject of them, and at the float64 minimum to float32 precision."""
    rng = np.random.default_rng(3)
    x = np.linspace(0, 4, 2000)
    y = 2.0 * np.exp(-1.3 * x) + 0.01 * rng.standard_normal(x.size)
    seeds, owner = np.eye(2), np.ones((1, 2))
    out = {}
    for dt in (jnp.float32, jnp.float64):
        args = (jnp.asarray(x, dt), jnp.asarray(y, dt))
        out[dt] = lm_fd(_exp_decay, jnp.array([1.0, 0.5], dt), args, seeds, owner, max_steps=100, max_reject=12)
    res = out[jnp.float32]
    z, F, steps, ok, evals = res.z, res.F, res.steps, res.converged, res.evals
    per_jac = 2 * 2  # central differences in float32, two groups
    rejected = int(evals) - (1 + per_jac) - int(steps) * (1 + per_jac)
    assert bool(ok) and int(steps) < 100
    assert rejected <= 1, f"{rejected} rejected trial steps"
    F64 = float(out[jnp.float64].F)
    assert abs(float(F) - F64) <= 1e-5 * F64
    np.testing.assert_allclose(np.asarray(z), np.asarray(out[jnp.float64].z), rtol=1e-3)


@pytest.mark.parametrize("dt", [jnp.float32, jnp.float64])
def test_rejected_step_below_the_resolution_of_z_stops(dt, x64):
    """scipy's xtol test on a rejected step: after rejections (MINPACK's test no longer applies)
    a trial step shorter than max(rtol, 4 eps) (max(rtol, 4 eps) + |z|) ends the loop, a longer
    one does not."""
    from matfit.fitting.lm import LevenbergMarquardtFD

    term = LevenbergMarquardtFD(1e-8, 1e-10)._stops
    z = jnp.array([2.0, -1.0], dt)
    tol = max(1e-8, 4 * float(jnp.finfo(dt).eps))
    s = SimpleNamespace(z=z, F=jnp.asarray(10.0, dt), rejects=jnp.asarray(3))
    F_new, pred, rho, g = jnp.asarray(10.5, dt), jnp.asarray(1.0, dt), jnp.asarray(-0.5, dt), jnp.ones(2, dt)

    def stops(step):
        delta = jnp.array([step, 0.0], dt)
        return bool(term(s, delta, F_new, s.F, pred, rho, jnp.asarray(False), g, jnp.asarray(4)))

    length = tol * (tol + float(jnp.linalg.norm(z)))
    assert stops(0.5 * length)
    assert not stops(4 * length)


@pytest.mark.parametrize("dt, tol", [(jnp.float64, 1e-10), (jnp.float32, 2e-3)])
def test_spd_solve_matches_numpy_under_vmap(dt, tol, x64):
    """The unrolled Cholesky solve of lm_fd's steps against numpy's LU solve, for a batch of
    symmetric positive definite 7 x 7 systems (condition numbers up to ~1e4)."""
    rng = np.random.default_rng(5)
    J = rng.standard_normal((64, 20, 7)) * np.geomspace(1, 1e-2, 7)
    B = np.einsum("bni,bnj->bij", J, J) + 1e-3 * np.eye(7)
    b = rng.standard_normal((64, 7))
    x = np.asarray(jax.vmap(_spd_solve)(jnp.asarray(B, dt), jnp.asarray(b, dt)))
    ref = np.linalg.solve(B, b[..., None])[..., 0]
    assert np.max(np.abs(x - ref) / np.abs(ref).max(axis=1, keepdims=True)) < tol


def _exp_objective(t, y):
    """0.5 |z0 exp(z1 t) - y|^2 and its analytic gradient (numpy): the reference minimum."""

    def F_and_grad(z):
        e = np.exp(z[1] * t)
        r = z[0] * e - y
        return 0.5 * r @ r, np.array([r @ e, r @ (z[0] * t * e)])

    return F_and_grad


def test_secant_model_converges_where_gauss_newton_crawls(x64):
    """A large-residual fit (an exponential against a curve it cannot follow): Gauss-Newton
    converges only linearly there and the objective's stopping test ends it above the minimum;
    with the secant model of the dropped second-order term (NL2SOL) the solver reaches the minimum
    in fewer steps. The minimum is found independently: scipy's BFGS on the analytic gradient."""
    from scipy.optimize import minimize

    t = np.linspace(0.0, 1.0, 40)
    y = np.exp(0.5 * t) + 20.0 * np.sin(5.0 * t)
    fn = lambda z, t: (z[0] * jnp.exp(z[1] * t) - y)[:, None]  # noqa: E731
    z0 = jnp.array([1.0, 0.0])
    gn = lm_fd(fn, z0, jnp.asarray(t), np.eye(2), np.ones((1, 2)), max_steps=500)
    sec = lm_fd(fn, z0, jnp.asarray(t), np.eye(2), np.ones((1, 2)), max_steps=500, secant=True)
    assert bool(gn.converged) and bool(sec.converged)

    ref = minimize(_exp_objective(t, y), np.asarray(sec.z), jac=True, method="BFGS", options=dict(gtol=1e-9))
    F_min = min(float(ref.fun), float(sec.F), float(gn.F))
    assert float(sec.F) - F_min <= 1e-10 * F_min
    assert float(gn.F) - F_min > 10 * (float(sec.F) - F_min)
    assert int(sec.steps) < int(gn.steps)
    np.testing.assert_allclose(np.asarray(sec.z), ref.x, rtol=1e-5)


def test_warm_start_from_a_subset_keeps_the_minimum_and_saves_steps(x64):
    """fit's whole-table solve starts from its subset solution with the subset's damping and
    secant model (scaled by the ratio of the J^T J traces): on the large-residual exponential fit
    it reaches the same minimum as a cold start (checked against scipy's BFGS on the analytic
    gradient), in fewer steps."""
    from scipy.optimize import minimize

    t = np.linspace(0.0, 1.0, 400)
    y = np.exp(0.5 * t) + 20.0 * np.sin(5.0 * t)
    fn = lambda z, a: (z[0] * jnp.exp(z[1] * a[0]) - a[1])[:, None]  # noqa: E731
    full, sub = (jnp.asarray(t), jnp.asarray(y)), (jnp.asarray(t[::8]), jnp.asarray(y[::8]))
    groups = (np.eye(2), np.ones((1, 2)))
    first = lm_fd(fn, jnp.array([1.0, 0.0]), sub, *groups, max_steps=500, secant=True)
    cold = lm_fd(fn, first.z, full, *groups, max_steps=500, secant=True)
    warm = lm_fd(fn, first.z, full, *groups, max_steps=500, secant=True, warm=first)
    assert bool(cold.converged) and bool(warm.converged)

    ref = minimize(_exp_objective(t, y), np.asarray(warm.z), jac=True, method="BFGS", options=dict(gtol=1e-9))
    F_min = min(float(ref.fun), float(warm.F), float(cold.F))
    assert float(warm.F) - F_min <= 1e-10 * F_min
    assert int(warm.steps) < int(cold.steps)
