"""The compiled multi-start solver of one fit configuration: problem (residuals of a family under
a loss) -> registered solver (:data:`~matfit.fitting.methods.METHODS`) -> solution with what the
uncertainty needs (residuals and ``J^T J`` at the best start). Cached, so that new tables of the
same shape and new parameter values never compile again."""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from ..cache import LOOP_COMPILER_OPTIONS, loop_jit, persistent_jit
from ..fast import supports_soa
from .lm import half_sq, widen
from .methods import METHODS

__all__ = ["COARSE_ROWS", "coarse_rows", "compiled_solver", "batched_run"]


#: Rows of the subsample a large table's ``lm_fd`` fit is first solved on (see :func:`compiled_solver`).
COARSE_ROWS = 32768


def coarse_rows(arrays):
    """A fixed random subset of :data:`COARSE_ROWS` rows of a table's arrays, in table order; None
    for tables of fewer than ``4 * COARSE_ROWS`` rows."""
    n = arrays[0].shape[0]
    if n < 4 * COARSE_ROWS:
        return None
    idx = np.sort(np.random.default_rng(0).choice(n, COARSE_ROWS, replace=False))
    return tuple(a[idx] for a in arrays)


@functools.lru_cache(maxsize=64)
def compiled_solver(problem, method, max_steps, rtol, atol, split=False):
    """Compiled multi-start solver for one configuration (cached: no recompilation).

    Returns ``(par, run, run_full, objective)``. ``run(z0s, arrays) -> (z, objective, steps,
    converged)`` for a stack of starts; ``run_full`` also returns the best start's index, its
    residuals (flat), ``J^T J`` (summed in float64 when x64 is on) and, for a large table, the
    starts' objectives and solutions on its subset (else those of the whole table), for
    covariances and diagnostics.

    ``split``: ``lm_fd`` solves on channel-split residuals (:func:`split_residual_fn`) when the
    family's model supports them; single fits only (batched fits vmap the ``(N, C)`` form).
    ``lm_fd`` on a table of at least ``4 * COARSE_ROWS`` rows (a full MERL table) first solves
    every start on a fixed random subset of :data:`COARSE_ROWS` rows, one start after another
    (``lax.map``: under ``vmap`` every start would iterate until the slowest converged), and
    then solves the whole table from the best of them only: the subsample's iterations cost a
    small fraction of the whole table's, and from there the full solve takes a few, to the same
    stopping tests. The other starts' objectives on the whole table are evaluated at their
    subset solutions, so several starts cost little more than one."""
    par = problem.par
    solver = METHODS[method].build(rtol, atol)
    prepare, fn = problem.residuals  # fn: (N, C) residuals
    flat = lambda z, a: fn(z, a).reshape(-1)  # noqa: E731  (solvers of flat residuals)
    channelled = solver.residuals == "channels"
    solve_prepare, solve_fn = prepare, (fn if channelled else flat)
    split = split and channelled and supports_soa(par.model(jnp.zeros(par.size)))
    if split:
        solve_prepare, solve_fn = problem.split_residuals
    groups = problem.groups
    objective = problem.objective

    def solve_all(z0s, arrays, wide=False):
        """``(prepared, z, obj, steps, ok, best, res, sub)``: every start's solution, objective on
        the whole table, steps and convergence; the best start's index and, for ``lm_fd``, its
        :class:`~matfit.fitting.lm.LMResult` (else None); ``sub`` the starts' subset objectives
        and solutions of a large table (else None)."""
        prepared = solve_prepare(arrays)  # once, outside the solver's loop
        sub = coarse_rows(arrays) if solver.normal_equations else None
        if sub is not None:
            coarse = solve_prepare(sub)
            # each start alone (lax.map, not vmap): the solver's large-residual aids (the secant
            # model, the line extrapolation) cost nothing per member there
            subs = jax.lax.map(lambda z0: solver.solve(solve_fn, z0, coarse, max_steps, groups, large_residual=True)
                               .lm._replace(r=None), z0s)
            cz, cF, csteps, cok = subs[:4]
            good = jnp.isfinite(cF) & jnp.all(jnp.isfinite(cz), axis=1)
            best = jnp.argmin(jnp.where(good, cF, jnp.inf))
            # the whole table from the best subset solution, with its damping and secant model;
            # the secant model and the line minimum after steps that beat the model save
            # full-table iterations of large-residual fits (lm.LevenbergMarquardtFD)
            warm = jax.tree_util.tree_map(lambda x: x[best], subs)
            zb, steps, ok, res = solver.solve(solve_fn, cz[best], prepared, max_steps, groups, wide, large_residual=True,
                                              warm=warm)
            others = jax.lax.map(lambda z: half_sq(solve_fn(z, prepared)), cz) if z0s.shape[0] > 1 else res.F[None]
            z = cz.at[best].set(zb)
            obj = others.at[best].set(res.F)
            return prepared, z, obj, csteps.at[best].set(steps), cok.at[best].set(ok), best, res, (cF, cz)
        if z0s.shape[0] == 1:  # one start: no vmap, which would batch the model's loops
            z, steps, ok, res = jax.tree_util.tree_map(
                lambda x: x[None], tuple(solver.solve(solve_fn, z0s[0], prepared, max_steps, groups, wide)))
        else:
            z, steps, ok, res = jax.vmap(lambda z0: tuple(solver.solve(solve_fn, z0, prepared, max_steps, groups, wide)))(z0s)
        obj = res.F if solver.normal_equations else objective(z, arrays)  # 0.5 |r|^2 at z, known
        good = jnp.isfinite(obj) & jnp.all(jnp.isfinite(z), axis=1)
        best = jnp.argmin(jnp.where(good, obj, jnp.inf))
        res = None if res is None else jax.tree_util.tree_map(lambda x: x[best], res)
        return prepared, z, obj, steps, ok, best, res, None

    def run(z0s, arrays):
        return solve_all(z0s, arrays)[1:5]

    def run_full(z0s, arrays):
        # lm_fd sums its moments in float64 (x64 on) for the J^T J returned with the solution
        prepared, z, obj, steps, ok, best, res, sub = solve_all(z0s, arrays, wide=True)
        zb = z[best]
        n = arrays[0].shape[0]
        if not solver.normal_equations:
            J = widen(jax.jacfwd(flat)(zb, prepared))  # float64 only when x64 is on (no truncation warning)
            return z, obj, steps, ok, best, flat(zb, prepared), J.T @ J, sub
        r = jnp.stack(res.r, axis=-1) if split else res.r
        return z, obj, steps, ok, best, r[:n].reshape(-1), res.A, sub

    # traced once per machine, not per process (matfit.cache): a solver takes longer to trace
    # than its compiled program takes to load
    key = dataclasses.astuple(problem) + (method, max_steps, rtol, atol, split)
    # loop_jit: the solver loops run over the whole table (matfit.cache.LOOP_COMPILER_OPTIONS)
    return (par, loop_jit(run), persistent_jit(jax.jit(run_full), ("run_full",) + key, LOOP_COMPILER_OPTIONS),
            persistent_jit(jax.jit(objective), ("objective",) + key))


@functools.lru_cache(maxsize=16)
def batched_run(run):
    return loop_jit(jax.vmap(run))
