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
from .lm import Solution, half_sq, widen
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
    """Compiled multi-start solver of one problem (cached: no recompilation).

    Returns ``(solve, objective)``: ``solve(z0s, arrays)`` solves a stack of starts and returns a
    multi-start :class:`~matfit.fitting.lm.Solution` (every start's ``z``, ``steps``,
    ``converged`` and objective ``F`` on the whole table; the ``best`` start's flat residuals
    ``r`` and ``J^T J`` ``A``, summed in float64 when x64 is on; for a large table ``sub``, the
    starts' objectives and solutions on its subset); ``objective(zs, arrays)`` is the problem's
    ``0.5 |r|^2`` of a stack of ``z``.

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
    registered = METHODS[method]
    normal_equations = registered.solver.normal_equations
    # lm_fd sums its moments in float64 (x64 on) for the J^T J returned with the solution; a large
    # table's subset solves (each start alone, under lax.map, not vmap) use the large-residual aids
    # (the secant model, the line extrapolation), and so does its whole-table solve
    solver = registered.build(rtol, atol, max_steps, **({"wide": True} if normal_equations else {}))
    if normal_equations:
        coarse_solver = registered.build(rtol, atol, max_steps, large_residual=True)
        whole_solver = registered.build(rtol, atol, max_steps, wide=True, large_residual=True)
    prepare, fn = problem.residuals  # fn: (N, C) residuals
    flat = lambda z, a: fn(z, a).reshape(-1)  # noqa: E731  (solvers of flat residuals)
    channelled = solver.residuals == "channels"
    solve_prepare, solve_fn = prepare, (fn if channelled else flat)
    split = split and channelled and supports_soa(par.model(jnp.zeros(par.size)))
    if split:
        solve_prepare, solve_fn = problem.split_residuals
    groups = problem.groups
    objective = problem.objective

    def solve(z0s, arrays):
        prepared = solve_prepare(arrays)  # once, outside the solver's loop
        n = arrays[0].shape[0]
        sub = coarse_rows(arrays) if normal_equations else None
        if sub is not None:
            coarse = solve_prepare(sub)
            subs = jax.lax.map(lambda z0: coarse_solver.solve(solve_fn, z0, coarse, groups)._replace(r=None), z0s)
            good = jnp.isfinite(subs.F) & jnp.all(jnp.isfinite(subs.z), axis=1)
            best = jnp.argmin(jnp.where(good, subs.F, jnp.inf))
            # the whole table from the best subset solution, with its damping and secant model;
            # the secant model and the line minimum after steps that beat the model save
            # full-table iterations of large-residual fits (lm.LevenbergMarquardtFD)
            warm = jax.tree_util.tree_map(lambda x: x[best], subs)
            res = whole_solver.solve(solve_fn, subs.z[best], prepared, groups, warm=warm)
            others = jax.lax.map(lambda z: half_sq(solve_fn(z, prepared)), subs.z) if z0s.shape[0] > 1 else res.F[None]
            r = jnp.stack(res.r, axis=-1) if split else res.r
            return Solution(subs.z.at[best].set(res.z), subs.steps.at[best].set(res.steps),
                            subs.converged.at[best].set(res.converged), F=others.at[best].set(res.F), A=res.A,
                            r=r[:n].reshape(-1), best=best, sub=(subs.F, subs.z))
        if z0s.shape[0] == 1:  # one start: no vmap, which would batch the model's loops
            ends = jax.tree_util.tree_map(lambda x: x[None], solver.solve(solve_fn, z0s[0], prepared, groups))
        else:
            ends = jax.vmap(lambda z0: solver.solve(solve_fn, z0, prepared, groups))(z0s)
        obj = ends.F if normal_equations else objective(ends.z, arrays)  # 0.5 |r|^2 at z, known
        good = jnp.isfinite(obj) & jnp.all(jnp.isfinite(ends.z), axis=1)
        best = jnp.argmin(jnp.where(good, obj, jnp.inf))
        zb = ends.z[best]
        if normal_equations:
            r = jnp.stack(ends.r, axis=-1)[best] if split else ends.r[best]
            r, A = r[:n].reshape(-1), ends.A[best]
        else:
            J = widen(jax.jacfwd(flat)(zb, prepared))  # float64 only when x64 is on (no truncation warning)
            r, A = flat(zb, prepared), J.T @ J
        return Solution(ends.z, ends.steps, ends.converged, F=obj, A=A, r=r, best=best)

    # traced once per machine, not per process (matfit.cache): a solver takes longer to trace
    # than its compiled program takes to load
    key = dataclasses.astuple(problem) + (method, max_steps, rtol, atol, split)
    # loop_jit: the solver loops run over the whole table (matfit.cache.LOOP_COMPILER_OPTIONS)
    return (persistent_jit(jax.jit(solve), ("run_full",) + key, LOOP_COMPILER_OPTIONS),
            persistent_jit(jax.jit(objective), ("objective",) + key))


@functools.lru_cache(maxsize=16)
def batched_run(run):
    return loop_jit(jax.vmap(run))
