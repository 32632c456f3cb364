"""Gradient fitting of a model family to a table: optimistix and jaxopt solvers, multi-start,
Gauss-Newton uncertainties, and batched fits.

The table's directions are fixed during a fit; the solver is compiled once per (family,
channels, method, loss, table shape) and reused for every table of the same shape and every
start (starts are solved together, vectorized with ``vmap``).
"""

from __future__ import annotations

import functools
import os
import time
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np

from .._math import Vec3
from ..errors import MatfitError, ParameterError
from ..fast import SoAPairs, eval_channel, supports_soa
from ..parallel import device_count, shard_batch
from ..table import Table
from .diagnostics import diagnose
from .lm import GRAM_BLOCK, widen, column_groups, lm_fd
from .losses import check_loss, prepare_targets, residuals_from_targets
from .methods import DEFAULT_METHOD, METHODS, get_method
from .params import Parametrization, check_solver_options


class FitError(MatfitError):
    """A fit cannot be done as asked (degenerate table, all starts failed, ...)."""


@dataclass
class FitResult:
    """The outcome of :func:`fit`.

    Attributes
    ----------
    family, method, loss : str
    params : dict of numpy arrays, every parameter (free and fixed), per-channel ones (C,)
    labels : names of the free parameters, in the order of ``values``, ``stderr``, ``cov``
    values, stderr : (p,) free parameter values and standard errors (Gauss-Newton)
    cov, corr : (p, p) covariance and correlation of the free parameters
    objective : 0.5 * sum of squared residuals at the optimum
    rss, n_residuals, dof : residual sum of squares, number of residuals used, n - p
    steps : solver iterations of the best start;  converged : whether it met its tolerances
    wall_time : seconds for the whole call;  start_objectives : objective reached by each start
    model : the fitted matfit model
    warnings : diagnostics of the optimum (list of str; see :mod:`matfit.fitting.diagnostics`):
        not converged, not identifiable (those standard errors are ``inf``), at a bound,
        outliers, poor fit, multiple optima.  ``ok`` is ``converged and not warnings``.
    info : notes on how the fit was computed (list of str), e.g. that a family has no
        channel-split kernel and ``lm_fd`` solved it on ``(N, C)`` residuals, or that a large
        table's starts were compared on its subset; not warnings.
    """

    family: str
    method: str
    loss: str
    params: dict
    labels: list
    values: np.ndarray
    stderr: np.ndarray
    cov: np.ndarray
    corr: np.ndarray
    objective: float
    rss: float
    n_residuals: int
    dof: int
    steps: int
    converged: bool
    wall_time: float
    start_objectives: np.ndarray
    model: object = field(repr=False)
    z: np.ndarray = field(repr=False, default=None)
    warnings: list = field(default_factory=list)
    info: list = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """Converged and no diagnostic warning (see :mod:`matfit.fitting.diagnostics`)."""
        return bool(self.converged) and not self.warnings

    def summary(self) -> str:
        lines = [f"{self.family} fit ({self.method}, {self.loss}): objective {self.objective:.6g}, "
                 f"{self.steps} steps, converged={self.converged}, {self.wall_time:.2f} s"]
        for lab, v, s in zip(self.labels, self.values, self.stderr):
            lines.append(f"  {lab:14s} = {v:.6g} +- {s:.2g}")
        lines += [f"  WARNING {w}" for w in self.warnings]
        lines += [f"  note: {w}" for w in self.info]
        return "\n".join(lines)


# --------------------------------------------------------------------------------------------
def prepared_residual_fn(par, loss, robust, scale):
    """``(prepare, fn)``: ``prepare(arrays)`` turns a table's ``(wo, wi, values, weight)`` into
    ``(wo, wi, target, factor)`` once (:func:`~matfit.fitting.losses.prepare_targets`: the loss's
    transform of the data and the residual weights), and ``fn(z, prepared)`` are the residuals at
    ``z`` -- inside a solver's loop only the model's part is recomputed. ``fn`` returns them as
    ``(N, C)``, the layout the model writes: flattening them inside the same
    compiled function made XLA rewrite the model's loop into a slower one (``docs/performance.md``)."""

    def prepare(arrays):
        wo, wi, values, weight = arrays
        return (wo, wi) + tuple(prepare_targets(values, weight, wi[..., 2], loss))

    def fn(z, prepared):
        wo, wi, target, factor = prepared
        pred = par.model(z).eval(wo, wi)
        return residuals_from_targets(pred, target, factor, wi[..., 2], loss, robust, scale)

    # jitted: a solver calls fn many times (trial step, Jacobian columns, extrapolation), and a
    # jitted fn is traced once per argument shape instead of once per call site
    return prepare, jax.jit(fn)


def split_residual_fn(par, loss, robust, scale):
    """``(prepare, fn)`` like :func:`prepared_residual_fn`, channel-split for :func:`lm_fd`.

    ``prepare`` lays the table out once as :class:`~matfit.fast.SoAPairs` (component arrays,
    half vector, Fresnel cosine: everything that depends only on the directions) and the
    prepared targets as ``(C, n)``, padded to a multiple of :data:`~matfit.fitting.lm.GRAM_BLOCK`
    rows (padding rows: normal incidence, weight 0, residual 0). ``fn(z, prepared)`` returns one
    residual array ``(n,)`` per channel, each the single-output kernel of
    :func:`matfit.fast.eval_channel`: on a full MERL table faster than the ``(N, C)`` layout
    (figures in ``docs/performance.md``). Only for models :func:`matfit.fast.supports_soa` accepts.
    """

    def prepare(arrays):
        wo, wi, values, weight = arrays
        pad = (-wo.shape[0]) % GRAM_BLOCK
        up = jnp.zeros((pad, 3), wo.dtype).at[:, 2].set(1)
        wo, wi = jnp.concatenate([wo, up]), jnp.concatenate([wi, up])
        values, weight = (jnp.concatenate([a, jnp.zeros((pad,) + a.shape[1:], a.dtype)]) for a in (values, weight))
        target, factor = prepare_targets(values, weight, wi[:, 2], loss)
        o, i = Vec3.from_array(wo), Vec3.from_array(wi)
        return SoAPairs.from_directions(o, i, wo.shape[0]), target.T, factor.T

    def fn(z, prepared):
        pairs, target, factor = prepared
        model = par.model(z)
        return tuple(
            residuals_from_targets(eval_channel(model, pairs, c)[:, None], target[c][:, None], factor[c][:, None],
                                   pairs.wi.z, loss, robust, scale)[:, 0]
            for c in range(target.shape[0]))

    return prepare, jax.jit(fn)  # traced once per argument shape (see prepared_residual_fn)


def objective_fn(prepare, fn):
    """``objective(zs, arrays)``: ``0.5 |r|^2`` for a stack of ``z`` on raw table arrays (prepared
    once per call), from the pair of :func:`prepared_residual_fn`."""

    def objective(zs, arrays):
        prepared = prepare(arrays)
        r = jax.vmap(lambda z: fn(z, prepared))(zs)
        return 0.5 * jnp.sum(r * r, axis=tuple(range(1, r.ndim)))

    return objective


def _residual_fn(par, loss, robust, scale):
    """Flat residuals ``fn(z, (wo, wi, values, weight))`` (the data prepared at every call)."""
    prepare, fn = prepared_residual_fn(par, loss, robust, scale)
    return lambda z, arrays: fn(z, prepare(arrays)).reshape(-1)


def _split_rows(arrays):
    """Rows split over every device (:mod:`matfit.parallel`; a no-op on one device). Padding rows
    copy the last row with weight 0, so they add nothing to the residuals."""
    nd = device_count()
    pad = (-arrays[0].shape[0]) % nd
    if nd == 1:
        return arrays
    if pad:
        wo, wi, v = (jnp.concatenate([a, jnp.repeat(a[-1:], pad, axis=0)]) for a in arrays[:3])
        arrays = (wo, wi, v, jnp.concatenate([arrays[3], jnp.zeros((pad,) + arrays[3].shape[1:], arrays[3].dtype)]))
    return shard_batch(arrays)[0]


def _by_channel(fn):
    """The flat residuals of ``fn`` as (N, C), the layout :func:`lm_fd` works on."""
    return lambda z, arrays: fn(z, arrays).reshape(arrays[2].shape)


def _solve_one(fn, method, z0, arrays, max_steps, rtol, atol, groups=None, wide=False, extrapolate=False):
    """One start solved by the registered ``method`` (:data:`matfit.fitting.methods.METHODS`)."""
    return METHODS[method].solve(fn, z0, arrays, max_steps, rtol, atol, groups, wide, extrapolate)


def _half_sq(r):
    """``0.5 |r|^2`` of residuals in any of the layouts (one array, or one per channel)."""
    return 0.5 * sum(jnp.sum(x * x) for x in (r if isinstance(r, (tuple, list)) else (r,)))


#: Rows of the subsample a large table's ``lm_fd`` fit is first solved on (see :func:`_solver`).
COARSE_ROWS = 32768


def _coarse_rows(arrays):
    """A fixed random subset of :data:`COARSE_ROWS` rows of a table's arrays, in table order; None
    for tables of fewer than ``4 * COARSE_ROWS`` rows."""
    n = arrays[0].shape[0]
    if n < 4 * COARSE_ROWS:
        return None
    idx = np.sort(np.random.default_rng(0).choice(n, COARSE_ROWS, replace=False))
    return tuple(a[idx] for a in arrays)


@functools.lru_cache(maxsize=64)
def _solver(family, channels, fixed_items, tied, method, loss, robust, scale, max_steps, rtol, atol, split=False):
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
    par = Parametrization(family, channels, dict(fixed_items), tied)
    prepare, fn = prepared_residual_fn(par, loss, robust, scale)  # fn: (N, C) residuals
    flat = lambda z, a: fn(z, a).reshape(-1)  # noqa: E731  (the optimistix and jaxopt solvers)
    channelled = METHODS[method].residuals == "channels"
    solve_prepare, solve_fn = prepare, (fn if channelled else flat)
    split = split and method == "lm_fd" and supports_soa(par.model(jnp.zeros(par.size)))
    if split:
        solve_prepare, solve_fn = split_residual_fn(par, loss, robust, scale)
    groups = column_groups(par)
    objective = objective_fn(prepare, fn)

    def solve_all(z0s, arrays, wide=False):
        """``(prepared, z, obj, steps, ok, best, res, sub)``: every start's solution, objective on
        the whole table, steps and convergence; the best start's index and, for ``lm_fd``, its
        :class:`~matfit.fitting.lm.LMResult` (else None); ``sub`` the starts' subset objectives
        and solutions of a large table (else None)."""
        prepared = solve_prepare(arrays)  # once, outside the solver's loop
        sub = _coarse_rows(arrays) if method == "lm_fd" else None
        if sub is not None:
            coarse = solve_prepare(sub)
            cz, cF, csteps, cok = jax.lax.map(
                lambda z0: lm_fd(solve_fn, z0, coarse, *groups, max_steps=max_steps, rtol=rtol, atol=atol)[:4], z0s)
            good = jnp.isfinite(cF) & jnp.all(jnp.isfinite(cz), axis=1)
            best = jnp.argmin(jnp.where(good, cF, jnp.inf))
            # the whole table from the best subset solution; the line minimum after steps that
            # beat the model (lm._extrapolated) saves full-table iterations of large-residual fits
            zb, steps, ok, res = _solve_one(solve_fn, method, cz[best], prepared, max_steps, rtol, atol, groups, wide,
                                            extrapolate=True)
            others = jax.lax.map(lambda z: _half_sq(solve_fn(z, prepared)), cz) if z0s.shape[0] > 1 else res.F[None]
            z = cz.at[best].set(zb)
            obj = others.at[best].set(res.F)
            return prepared, z, obj, csteps.at[best].set(steps), cok.at[best].set(ok), best, res, (cF, cz)
        if z0s.shape[0] == 1:  # one start: no vmap, which would batch the model's loops
            z, steps, ok, res = jax.tree_util.tree_map(
                lambda x: x[None], _solve_one(solve_fn, method, z0s[0], prepared, max_steps, rtol, atol, groups, wide))
        else:
            z, steps, ok, res = jax.vmap(
                lambda z0: _solve_one(solve_fn, method, z0, prepared, max_steps, rtol, atol, groups, wide))(z0s)
        obj = res.F if method == "lm_fd" else objective(z, arrays)  # lm_fd: 0.5 |r|^2 at z, known
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
        if method != "lm_fd":
            J = widen(jax.jacfwd(flat)(zb, prepared))  # float64 only when x64 is on (no truncation warning)
            return z, obj, steps, ok, best, flat(zb, prepared), J.T @ J, sub
        r = jnp.stack(res.r, axis=-1) if split else res.r
        return z, obj, steps, ok, best, r[:n].reshape(-1), res.A, sub

    return par, jax.jit(run), jax.jit(run_full), jax.jit(objective)


# --------------------------------------------------------------------------------------------


def initial_guess(table: Table, par: Parametrization):
    """Data-driven starting values: diffuse floor, specular peak height and width.

    The floor is the 10th percentile of the valid values (times pi: a Lambertian albedo); the
    peak is the row of largest ``f cos(theta_i)``; the width is the largest half-vector angle
    among rows above half the peak's excess over the floor, turned into a GGX alpha through
    ``D(theta_h)/D(0) = 1/2  <=>  tan(theta_h) = alpha * sqrt(sqrt(2) - 1)``. For the rough
    conductor families the width is then refined from the lobe's shape and ``eta``, ``k`` per
    channel come from the Fresnel curve read off the table
    (:func:`matfit.fitting._conductor_guess.conductor_guess`).

    Returns
    -------
    dict
        Parameter name -> value (scalar or per channel), every one strictly inside its bounds.

    Examples
    --------
    >>> import numpy as np
    >>> from matfit import Table
    >>> from matfit.fitting import Parametrization, initial_guess
    >>> wo = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]]); wi = wo[::-1].copy()
    >>> g = initial_guess(Table(wo=wo, wi=wi, values=np.full((2, 3), 0.2)), Parametrization("lambert", 3))
    >>> np.round(g["albedo"], 3).tolist()
    [0.628, 0.628, 0.628]
    """
    return {k: v[0] for k, v in initial_guesses([table], par).items()}


def _percentile10(v, valid):
    """``np.percentile(v[b][valid[b]], 10, axis=0)`` for every b at once (linear interpolation)."""
    if v.shape[0] == 1:  # one (large) table: numpy's partition, not a sort of every row
        return np.percentile(v[0] if valid[0].all() else v[0][valid[0]], 10, axis=0)[None]
    n = valid.sum(axis=1)  # (B,)
    srt = np.sort(np.where(valid[..., None], v, np.inf), axis=1)  # invalid rows last
    pos = 0.1 * (n - 1)
    lo = np.floor(pos).astype(int)
    hi = np.minimum(lo + 1, n - 1)
    a = np.take_along_axis(srt, lo[:, None, None], axis=1)[:, 0]
    b = np.take_along_axis(srt, hi[:, None, None], axis=1)[:, 0]
    return a + (pos - lo)[:, None] * (b - a)


def initial_guesses(tables, par: Parametrization):
    """:func:`initial_guess` for many tables of one shape at once (vectorized over the tables;
    a texel map's guesses are a few array operations, not a loop over the texels).

    Returns
    -------
    dict
        Parameter name -> array with a leading table axis ``(B,)`` or ``(B, C)``.

    Examples
    --------
    >>> import numpy as np
    >>> from matfit import Table
    >>> from matfit.fitting import Parametrization, initial_guesses
    >>> wo = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]]); wi = wo[::-1].copy()
    >>> tables = [Table(wo=wo, wi=wi, values=np.full((2, 3), a)) for a in (0.1, 0.2)]
    >>> initial_guesses(tables, Parametrization("lambert", 3))["albedo"].shape
    (2, 3)
    """
    stack = (lambda xs: np.asarray(xs[0])[None]) if len(tables) == 1 else np.stack  # one table: no copy
    V = stack([np.asarray(t.values, float) for t in tables])
    M = stack([np.asarray(t.valid, bool) for t in tables])
    WO = stack([np.asarray(t.wo, float) for t in tables])
    WI = stack([np.asarray(t.wi, float) for t in tables])
    return guesses_from_arrays(WO, WI, V, M, par, one=len(tables) == 1)


def guesses_from_arrays(WO, WI, V, M, par: Parametrization, one=False):
    """:func:`initial_guesses` of a stack of tables given as arrays: directions ``WO``, ``WI``
    ``(B, N, 3)`` (broadcast views are fine: directions shared by every table cost no copy),
    values ``V`` ``(B, N, C)`` and the valid rows ``M`` ``(B, N)``. ``one``: the stack is a single
    table (its error messages say "the table").

    Examples
    --------
    >>> import numpy as np
    >>> from matfit.fitting import Parametrization, guesses_from_arrays
    >>> wo = np.broadcast_to([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]], (4, 2, 3)); wi = wo[:, ::-1]
    >>> g = guesses_from_arrays(wo, wi, np.full((4, 2, 3), 0.1), np.ones((4, 2), bool), Parametrization("lambert", 3))
    >>> g["albedo"].shape
    (4, 3)
    """
    V = np.asarray(V, float)
    empty = np.flatnonzero(~M.any(axis=1))
    if empty.size:
        raise FitError("the table has no valid rows" if one else f"tables {empty[:10].tolist()} have no valid rows")
    B = V.shape[0]
    rows = np.arange(B)
    floor = _percentile10(V, M)  # (B, C)
    mean = np.einsum("bnc->bn", V) / V.shape[2]  # (einsum: numpy's mean over a short last axis is slower)
    s = WO + WI
    hz = s[..., 2] / np.maximum(np.sqrt(np.einsum("bni,bni->bn", s, s)), 1e-12)  # the half vector's cosine
    excess = np.where(M, mean - np.where(M, mean, np.inf).min(axis=1, keepdims=True), -np.inf)
    emax = excess.max(axis=1, keepdims=True)
    top = M & np.where(emax > 0, excess >= 0.5 * emax, True)
    # the largest theta_h among the top rows: arccos of their smallest cosine
    th = np.arccos(np.clip(np.where(top, hz, np.inf).min(axis=1), -1, 1))
    alpha = np.clip(np.tan(np.minimum(th, 1.3)) / np.sqrt(np.sqrt(2) - 1), 0.02, 0.8)
    ipk = np.argmax(np.where(M, mean * np.abs(WI[..., 2]), -np.inf), axis=1)
    peak = V[rows, ipk] - floor
    co = np.maximum(np.abs(WO[rows, ipk, 2]), 0.05)
    # At the peak (theta_h ~ 0): f ~ F / (4 pi alpha^2 cos^2), so F ~ f 4 pi alpha^2 cos^2.
    r0 = np.clip(peak * (4 * np.pi * alpha**2 * co**2)[:, None], 0.02, 0.9)
    k = 2 * np.sqrt(r0 / (1 - r0))
    ones = np.ones_like(r0)
    guess = {
        "albedo": np.clip(np.pi * floor, 0.01, 0.95),
        "alpha": alpha.copy(), "alpha_base": alpha, "alpha_coat": np.maximum(alpha / 2, 0.02),
        "eta": ones.copy(),
        "k": k.copy(), "eta_base": ones, "k_base": k, "eta_coat": np.full(B, 1.5), "f0": r0,
    }
    # what the family itself knows: constant starts, then its data-driven refinement
    for p in par.family.params:
        if p.name in par.family.starts:
            guess[p.name] = np.full((B, V.shape[2]) if p.per_channel else B, float(par.family.starts[p.name]))
    if par.family.refine is not None:
        par.family.refine(WO, WI, V, M, guess, par.family)
    # Every guess strictly inside its bounds (the bijection saturates at a bound).
    out = {}
    for p in par.free:
        lo, hi = p.lower, p.upper
        span = (hi - lo) if np.isfinite(hi) else 1.0
        # a parameter without a data-driven guess (a user-defined family's) starts mid-range
        g = guess.get(p.name)
        if g is None:
            mid = 0.5 * (lo + hi) if np.isfinite(hi) else lo + 1.0
            g = np.full((B, V.shape[2]) if p.per_channel else B, mid)
        out[p.name] = np.clip(g, lo + 1e-3 * span, hi - 1e-3 * span if np.isfinite(hi) else np.inf)
    return out


#: Candidates screened per extra start (see :func:`_screened_starts`).
SCREEN_PER_START = 8


def _candidates(par, base, n_extra, seed):
    """``SCREEN_PER_START * n_extra`` candidate starts per table, (B, K, p): half the data-driven
    start plus N(0, 1) steps in the unconstrained space, half spread over the whole parameter box
    (bounded parameters uniform in (2 %, 98 %) of their range, others N(0, 1) in z)."""
    K = SCREEN_PER_START * n_extra
    rng = np.random.default_rng(seed)
    local = rng.normal(0, 1.0, (K - K // 2, par.size))
    u = rng.uniform(0.02, 0.98, (K // 2, par.size))
    bounded = np.isfinite(par.lower_upper()[1])
    spread = np.where(bounded, np.log(u) - np.log1p(-u), rng.normal(0, 1.0, u.shape))
    base = np.asarray(base)
    return np.concatenate([base[:, None, :] + local.astype(base.dtype)[None],
                           np.broadcast_to(spread.astype(base.dtype), (base.shape[0],) + spread.shape)], axis=1)


def fit_starts(table, par, n, seed, objective, arrays, init=None):
    """The ``n`` starts (n, p) that :func:`fit` runs: the data-driven guess (with ``init``'s values
    replacing its entries), then the best screened candidates (:func:`_screened_starts`).
    ``objective(zs, arrays)`` is the fit's objective for a stack of ``z``."""
    g = initial_guess(table, par)
    if init is not None:
        g.update(init)
    base = np.asarray(_compiled(par)["z_from_theta"](g)).astype(arrays[0].dtype)[None]
    return _screened_starts(objective, par, base, n, seed, arrays)[0]


def _screened_starts(objective, par, base, n, seed, arrays, batched=False):
    """Starts per table, (B, n, p): the data-driven start ``base`` (B, p) first, then the ``n - 1``
    candidates of :func:`_candidates` with the lowest objective on the table (one vectorized
    evaluation of the fit's own objective; multi-start without the cost of ``n`` full solves
    from blind perturbations, which for layered and metal families mostly end at a bound)."""
    base = np.asarray(base)
    if n <= 1:
        return jnp.asarray(base[:, None, :])
    cand = _candidates(par, base, n - 1, seed)  # numpy: no eager JAX operations to dispatch
    if batched:
        (c, a), nb = shard_batch((jnp.asarray(cand), arrays))
        obj = np.asarray(batched_run(objective)(c, a)[:nb])
    else:
        obj = np.asarray(objective(jnp.asarray(cand[0]), arrays))[None]
    obj = np.where(np.isfinite(obj), obj, np.inf)
    best = np.argsort(obj, axis=1, kind="stable")[:, : n - 1]
    return jnp.asarray(np.concatenate([base[:, None, :], np.take_along_axis(cand, best[:, :, None], axis=1)], axis=1))


@functools.lru_cache(maxsize=64)
def _compiled(par):
    """Jitted helpers of a (cached) :class:`Parametrization`: ``z_from_theta`` and ``post(zb, z,
    zs)`` -> the natural values of ``zb``, the diagonal of their Jacobian in ``z``, the natural
    values of the starts ``z`` and ``zs``, every parameter's value and the model at ``zb``. One
    compiled call each, instead of dozens of small eagerly dispatched operations per fit."""

    def post(zb, z, zs):
        return {"values": par.theta_vector(zb), "dtheta": jnp.diag(jax.jacfwd(par.theta_vector)(zb)),
                "starts": par.theta_vector(z), "sub_starts": par.theta_vector(zs),
                "theta": par.full(par.theta(zb)), "model": par.model(zb)}

    return {"z_from_theta": jax.jit(par.z_from_theta), "post": jax.jit(post)}


#: Bytes of working memory a fit needs per table row and value, in units of the float size: the
#: table's device copy, its structure-of-arrays layout and prepared targets, and per parameter
#: group one difference column (``lm_fd`` keeps ``J`` compressed and streams ``J^T J``).
_BYTES_PER_ROW = (16, 8, 2)  # (per row, per value, per value and parameter group)


def available_memory():
    """Bytes of memory the system can give this process now (``MemAvailable`` of
    ``/proc/meminfo``, else the physical memory), or None when unknown."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def memory_estimate(rows, channels, groups, dtype=None):
    """Estimated peak working memory (bytes) of :func:`fit` on a table of ``rows`` rows.

    Examples
    --------
    >>> from matfit.fitting.fit import memory_estimate
    >>> round(memory_estimate(1_458_000, 3, 3, "float32") / 2**20)  # a full MERL table, conductor
    323
    """
    size = np.dtype(dtype or jnp.result_type(float)).itemsize
    a, b, c = _BYTES_PER_ROW
    return int(rows * size * (a + channels * (b + c * groups)))


def check_memory(where, rows, channels, groups, dtype=None):
    """Raise :class:`FitError` before allocating when a fit of ``rows`` rows would need more
    memory than the system has available (row count, estimate and availability in the message)."""
    need = memory_estimate(rows, channels, groups, dtype)
    have = available_memory()
    if have is not None and need > have:
        size = lambda b: f"{b / 2**30:.1f} GiB" if b >= 2**30 else f"{b / 2**20:.1f} MiB"  # noqa: E731
        raise FitError(f"{where}: a table of {rows} rows x {channels} channels needs about {size(need)} of working "
                       f"memory ({np.dtype(dtype or jnp.result_type(float)).name}), and {size(have)} are "
                       "available; fit a subsample (Table.subsample or matfit fit --subsample N) or use a machine "
                       "with more memory")


def table_arrays(table, dtype, weight=None):
    """``(wo, wi, values, weight)`` of a table as JAX arrays; given the table's ``weight``
    (:meth:`~matfit.Table.effective_weight`), only the rows with a nonzero weight in some channel
    (the others add nothing to any residual: a MERL table's invalid cells, a quarter of its rows,
    cost neither memory nor time)."""
    if weight is not None:
        w = weight
        keep = np.any(w > 0, axis=1)
        if not keep.all():
            f = (lambda x: jnp.asarray(x[keep], dtype=dtype)) if dtype is not None else (lambda x: jnp.asarray(x[keep]))
            return (f(table.wo), f(table.wi), f(table.values), f(w))
    a = table.as_jax(dtype)
    return (a.wo, a.wi, a.values, a.weight)


def fit(table, model="plastic", method=DEFAULT_METHOD, loss="l2", robust=None, robust_scale=1.0, fixed=None, tied=(),
        starts=4, init=None, max_steps=256, rtol=1e-8, atol=1e-10, seed=0, dtype=None) -> FitResult:
    """Fit a model family to a table by nonlinear least squares.

    Parameters
    ----------
    table : matfit.Table
    model : str
        Family name: ``"lambert"``, ``"conductor"``, ``"conductor_beckmann"``, ``"dielectric"``,
        ``"plastic"``, ``"car_paint"`` (see :data:`matfit.fitting.FAMILIES`).
    method : str
        A method of :data:`matfit.fitting.methods.METHODS`. Default ``"lm_fd"``:
        Levenberg-Marquardt on the normal equations with a grouped finite-difference Jacobian
        (:mod:`matfit.fitting.lm`), the fastest on every table size and bounded in memory;
        ``"lm"``, ``"gn"``, ``"dogleg"``, ``"bfgs"`` (optimistix), ``"lbfgs"``, ``"jaxopt_lm"``
        (jaxopt).
    loss, robust, robust_scale : see :mod:`matfit.fitting.losses`.
    fixed : dict, optional
        Parameters held at given values.  tied : per-channel parameters shared by all channels.
    starts : int
        Number of starts: the data-driven guess plus the ``starts - 1`` best of ``8 (starts - 1)``
        screened candidates (see :func:`fit_starts`).
    init : dict, optional
        Starting values replacing the data-driven guess.

    Returns
    -------
    FitResult

    Examples
    --------
    >>> import numpy as np, jax.numpy as jnp
    >>> from matfit import Table
    >>> from matfit.models import Lambert
    >>> from matfit.fitting import fit
    >>> rng = np.random.default_rng(0)
    >>> wo = np.tile([0.0, 0.0, 1.0], (50, 1)); wi = rng.normal(size=(50, 3)); wi[:, 2] = abs(wi[:, 2])
    >>> wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    >>> t = Table(wo=wo, wi=wi, values=np.full((50, 1), 0.3 / np.pi), channels="mono")
    >>> r = fit(t, model="lambert", starts=1)
    >>> round(float(r.params["albedo"][0]), 4)
    0.3
    """
    t0 = time.perf_counter()
    if not isinstance(table, Table):
        raise ParameterError(f"fit: table must be a matfit.Table, got {type(table).__name__}")
    get_method(method, "fit", model, loss)
    check_loss(loss, robust)
    check_solver_options("fit", starts=starts, max_steps=max_steps, rtol=rtol, atol=atol, robust_scale=robust_scale,
                         dtype=dtype)
    Parametrization(model, table.n_channels, fixed, tied).check_theta("fit: init", {} if init is None else init)
    C = table.n_channels
    fixed_items = _fixed_items(fixed)
    par, _, run_full, objective = _solver(model, C, fixed_items, tuple(tied), method, loss, robust, float(robust_scale),
                                       int(max_steps), float(rtol), float(atol), device_count() == 1)
    w_eff = table.effective_weight()
    n_res = int(np.count_nonzero(w_eff))
    if n_res <= par.size:
        raise FitError(f"fit: the table has {n_res} usable residuals for {par.size} free parameters "
                       f"({', '.join(par.labels)}): at least {par.size + 1} are needed")
    check_memory("fit", int(np.count_nonzero(np.any(w_eff > 0, axis=1))), C, len(column_groups(par)[0]), dtype)
    arrays = table_arrays(table, dtype, weight=w_eff)
    n_rows = arrays[2].size
    rows = _split_rows(arrays)
    # a large table's candidate starts are screened on its subset (24 candidates on a full MERL
    # table would otherwise evaluate 24 copies of its residuals at once)
    screen = _coarse_rows(rows) if method == "lm_fd" else None
    z0s = fit_starts(table, par, starts, seed, objective, rows if screen is None else screen, init)
    # the best start's residuals and J^T J come with the solution (Gauss-Newton covariance below)
    z, obj, steps, ok, best, r_best, A, sub = run_full(z0s, rows)
    obj = np.asarray(obj)
    good = np.isfinite(obj) & np.all(np.isfinite(np.asarray(z)), axis=1)
    if not good.any():
        raise FitError("fit: every start ended with non-finite parameters or objective")
    best = int(best)
    zb = z[best]
    # Uncertainty: Gauss-Newton covariance in the natural parameters (chain rule through the
    # element-wise transform), scaled by the residual variance unless the table carries sigma.
    r_best = np.asarray(r_best)[:n_rows]
    post = _compiled(par)["post"](zb, z, zb if sub is None else sub[1])
    dtheta = np.asarray(post["dtheta"])
    inv_d = 1 / np.where(dtheta != 0, dtheta, np.inf)
    At = np.asarray(A, float) * np.outer(inv_d, inv_d)  # J^T J in the natural parameters
    rss = float(2 * obj[best])
    dof = n_res - par.size
    s2 = 1.0 if (table.sigma is not None and loss == "l2" and robust is None) else rss / max(dof, 1)
    cov = s2 * np.linalg.pinv(At)
    se = np.sqrt(np.clip(np.diag(cov), 0, None))
    values = np.asarray(post["values"])
    lower, upper = par.lower_upper()
    sw = np.sqrt(np.asarray(arrays[3], float))
    data_scale = float(np.sqrt(np.mean((sw * np.asarray(arrays[2], float)) ** 2)))
    info = []
    if method == "lm_fd" and device_count() == 1 and not supports_soa(post["model"]):
        info.append(f"lm_fd: the {model!r} family's model has no channel-split kernel; solved on (N, C) residuals")
    start_kw = dict(start_values=np.asarray(post["starts"]), start_objectives=obj)
    if sub is not None:  # a large table: the starts are compared where they ended on its subset
        sub_values = np.asarray(post["sub_starts"])
        start_kw = dict(start_values=sub_values, start_objectives=np.asarray(sub[0]), start_reference=sub_values[best],
                        start_stderr=se * np.sqrt(n_rows / (COARSE_ROWS * C)))
        info.append(f"the {len(table)}-row table was first solved on a random {COARSE_ROWS}-row subset from "
                    f"{starts} start(s); the whole table from the best of them")
    notes, unident = diagnose(
        labels=par.labels, values=values, stderr=se, lower=lower, upper=upper, gram=At, residuals=r_best,
        converged=bool(np.asarray(ok)[best]), steps=int(np.asarray(steps)[best]), max_steps=int(max_steps),
        known_sigma=table.sigma is not None and loss == "l2" and robust is None, dof=n_res - par.size,
        data_scale=data_scale, best=best, **start_kw)
    se = np.where(np.isin(par.labels, unident), np.inf, se)
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(se, se)
    theta = post["theta"]
    return FitResult(
        family=model, method=method, loss=loss,
        params={k: np.asarray(v) for k, v in theta.items()},
        labels=par.labels, values=values, stderr=se, cov=cov, corr=corr,
        objective=float(obj[best]), rss=rss, n_residuals=n_res, dof=dof, steps=int(np.asarray(steps)[best]),
        converged=bool(np.asarray(ok)[best]), wall_time=time.perf_counter() - t0, start_objectives=obj,
        model=post["model"], z=np.asarray(zb), warnings=notes, info=info,
    )


def fit_batch(tables, model="plastic", method=DEFAULT_METHOD, loss="l2", fixed=None, tied=(), starts=1, max_steps=128,
              rtol=1e-8, atol=1e-10, dtype=None):
    """Fit many tables of the same shape and directions in one vectorized call (e.g. texels).

    Returns ``(values (B, p), objective (B,), labels)``; every table gets its own data-driven
    start (``starts`` per table).
    """
    if isinstance(tables, Table) or not hasattr(tables, "__len__"):
        raise ParameterError(f"fit_batch: tables must be a sequence of matfit.Table, got {type(tables).__name__}")
    if len(tables) == 0:
        raise ParameterError("fit_batch: no tables given")
    for i, t in enumerate(tables):
        if not isinstance(t, Table):
            raise ParameterError(f"fit_batch: table {i} must be a matfit.Table, got {type(t).__name__}")
    if not get_method(method, "fit_batch", model, loss).batched:
        raise ParameterError(f"fit_batch: method {method!r} cannot fit tables in a batch; use one of "
                             f"{[k for k, v in METHODS.items() if v.batched]}")
    check_loss(loss, None)
    check_solver_options("fit_batch", starts=starts, max_steps=max_steps, rtol=rtol, atol=atol, dtype=dtype)
    t0 = tables[0]
    Parametrization(model, t0.n_channels, fixed, tied)
    for i, t in enumerate(tables):
        if len(t) != len(t0) or t.n_channels != t0.n_channels:
            raise ParameterError(f"fit_batch: table {i} has shape ({len(t)}, {t.n_channels}), expected ({len(t0)}, {t0.n_channels})")
    stacked = [np.stack(a) for a in zip(*((t.wo, t.wi, t.values, t.effective_weight()) for t in tables))]
    res = fit_arrays(*stacked, model=model, method=method, loss=loss, fixed=fixed, tied=tied, starts=starts,
                     max_steps=max_steps, rtol=rtol, atol=atol, dtype=dtype, valid=np.stack([t.valid for t in tables]),
                     uncertainty=False, where="fit_batch")
    bad = ~(np.isfinite(res.values).all(axis=1) & np.isfinite(res.objective))
    if bad.any():
        idx = np.flatnonzero(bad)
        raise FitError(f"fit_batch: {idx.size} of {len(tables)} tables ended with non-finite parameters or objective "
                       f"(tables {idx[:10].tolist()}{' ...' if idx.size > 10 else ''}); fit them one by one with fit() "
                       "to see why")
    return res.values, res.objective, res.labels


def _fixed_items(fixed):
    """``fixed`` as a hashable key of the compiled-solver cache (:func:`_solver`)."""
    return tuple(sorted((k, tuple(np.atleast_1d(np.asarray(v, float)).tolist())) for k, v in (fixed or {}).items()))


@dataclass(frozen=True)
class BatchFit:
    """Per-table results of :func:`fit_arrays` (leading axis: the tables)."""

    labels: list
    values: np.ndarray  # (B, p) natural parameter values, in the order of labels
    stderr: np.ndarray  # (B, p) Gauss-Newton standard errors (NaN when not computed)
    objective: np.ndarray  # (B,) 0.5 * sum of squared residuals
    steps: np.ndarray  # (B,) solver iterations
    converged: np.ndarray  # (B,) bool
    n_residuals: np.ndarray  # (B,) residuals with a nonzero weight


def _check_stack(where, wo, wi, values, weight, valid):
    values = np.asarray(values)
    if values.ndim != 3:
        raise ParameterError(f"{where}: values must be (B, N, C), found shape {values.shape}")
    B, N, C = values.shape
    dirs = []
    for name, d in (("wo", wo), ("wi", wi)):
        d = np.asarray(d)
        if d.shape not in ((N, 3), (B, N, 3)):
            raise ParameterError(f"{where}: {name} must be (N, 3) or (B, N, 3) = ({N}, 3) or ({B}, {N}, 3), "
                                 f"found shape {d.shape}")
        if not np.all(np.isfinite(d)):
            raise ParameterError(f"{where}: {name} has non-finite directions")
        dirs.append(d)
    if weight is not None and np.shape(weight) != values.shape:
        raise ParameterError(f"{where}: weight must have the shape of values {values.shape}, found {np.shape(weight)}")
    if valid is not None and np.shape(valid) != (B, N):
        raise ParameterError(f"{where}: valid must be (B, N) = ({B}, {N}), found {np.shape(valid)}")
    return dirs[0], dirs[1], values


@functools.lru_cache(maxsize=16)
def _batch_programs(run_full, par, shared):
    """Jitted ``vmap`` over tables of the data-driven guesses' map to ``z``, of a solver's
    ``run_full`` (directions shared or per table) and of the natural values with the diagonal of
    their Jacobian in ``z``."""
    d_ax = None if shared else 0
    to_z = jax.jit(jax.vmap(par.z_from_theta))
    run = jax.jit(jax.vmap(run_full, in_axes=(0, (d_ax, d_ax, 0, 0))))
    post = jax.jit(jax.vmap(lambda z: (par.theta_vector(z), jnp.diag(jax.jacfwd(par.theta_vector)(z)))))
    return to_z, run, post


def fit_arrays(wo, wi, values, weight=None, *, model="plastic", method=DEFAULT_METHOD, loss="l2", fixed=None,
               tied=(), starts=1, max_steps=128, rtol=1e-8, atol=1e-10, dtype=None, valid=None, known_sigma=False,
               uncertainty=True, where="fit_arrays") -> BatchFit:
    """Fit one family to a stack of B small tables given as arrays, in one vectorized call.

    The core of :func:`fit_batch` and :func:`matfit.maps.fit_map`: every table gets its own
    data-driven start (:func:`guesses_from_arrays`; ``starts - 1`` screened candidates more) and
    its own solve, all in one compiled program; new values of the same shapes reuse it.

    Parameters
    ----------
    wo, wi : array_like, (N, 3) shared by every table, or (B, N, 3)
        Unit directions to the viewer and to the light.
    values : array_like, (B, N, C)
        Measured BSDF values (1/sr, without the cosine).
    weight : array_like, (B, N, C), optional
        Residual weights (``1 / sigma**2`` for known noise); 0 leaves a value out. Default 1.
    model, method, loss, fixed, tied, starts, max_steps, rtol, atol, dtype
        As in :func:`fit`.
    valid : array_like of bool, (B, N), optional
        Rows that may seed the data-driven start (default: rows with a nonzero weight).
    known_sigma : bool
        The weights are ``1 / sigma**2`` of the data's noise: standard errors are not rescaled by
        the residual variance.
    uncertainty : bool
        Compute standard errors (the Gauss-Newton ``J^T J`` the solver returns with its solution).

    Returns
    -------
    BatchFit

    Examples
    --------
    >>> import numpy as np
    >>> from matfit.fitting import fit_arrays
    >>> wo = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, 0.6, 0.8]]); wi = wo[[1, 2, 0]]
    >>> values = np.array([0.1, 0.2])[:, None, None] * np.ones((2, 3, 3))  # two Lambertian tables
    >>> r = fit_arrays(wo, wi, values, model="lambert")
    >>> [round(float(a), 3) for a in r.values[:, 0] / np.pi]
    [0.1, 0.2]
    """
    wo, wi, values = _check_stack(where, wo, wi, values, weight, valid)
    B, N, C = values.shape
    check_loss(loss, None)
    check_solver_options(where, starts=starts, max_steps=max_steps, rtol=rtol, atol=atol, dtype=dtype)
    if not get_method(method, where, model, loss).batched:
        raise ParameterError(f"{where}: method {method!r} cannot fit tables in a batch; use one of "
                             f"{[k for k, v in METHODS.items() if v.batched]}")
    Parametrization(model, C, fixed, tied)
    fixed_items = _fixed_items(fixed)
    par, _, run_full, objective = _solver(model, C, fixed_items, tuple(tied), method, loss, None, 1.0, int(max_steps),
                                          float(rtol), float(atol))
    check_memory(where, B * N, C, len(column_groups(par)[0]) * starts, dtype)
    dt = dtype if dtype is not None else jnp.result_type(float)
    if np.dtype(dt) == np.float64 and not jax.config.jax_enable_x64:
        raise ParameterError(f"{where}: dtype float64 needs JAX's 64-bit mode (jax.config.update('jax_enable_x64', "
                             "True) before any JAX work); use float32 or switch it on")
    w = np.ones(values.shape, values.dtype) if weight is None else np.asarray(weight)
    ok_rows = np.any(w > 0, axis=2)
    if valid is not None:
        ok_rows &= np.asarray(valid, bool)
    shared = wo.ndim == 2 and wi.ndim == 2
    WO = np.broadcast_to(wo, (B, N, 3)) if wo.ndim == 2 else wo
    WI = np.broadcast_to(wi, (B, N, 3)) if wi.ndim == 2 else wi
    guess = guesses_from_arrays(WO, WI, values, ok_rows, par, one=B == 1)
    to_z, run, post = _batch_programs(run_full, par, shared)
    if shared:
        dirs = (jnp.asarray(wo, dt), jnp.asarray(wi, dt))
    else:
        dirs = (jnp.asarray(WO, dt), jnp.asarray(WI, dt))
    arrays = dirs + (jnp.asarray(values, dt), jnp.asarray(w, dt))
    base = np.asarray(to_z({k: jnp.asarray(v, float) for k, v in guess.items()})).astype(np.dtype(dt))
    if starts > 1:
        full = (jnp.asarray(WO, dt), jnp.asarray(WI, dt)) + arrays[2:]
        z0 = _screened_starts(objective, par, base, starts, 0, full, batched=True)
    else:
        z0 = jnp.asarray(base[:, None, :])
    z, obj, steps, ok, best, r, A, _ = run(z0, arrays)
    best = np.asarray(best)
    zb = jnp.take_along_axis(z, jnp.asarray(best)[:, None, None], axis=1)[:, 0]
    vals, dtheta = (np.asarray(a) for a in post(zb))
    pick = lambda a: np.take_along_axis(np.asarray(a), best[:, None], axis=1)[:, 0]  # noqa: E731
    objective_b = pick(obj)
    n_res = np.count_nonzero(w, axis=(1, 2))
    se = np.full(vals.shape, np.nan)
    if uncertainty:
        inv_d = 1 / np.where(dtheta != 0, dtheta, np.inf)
        At = np.asarray(A, float) * inv_d[:, :, None] * inv_d[:, None, :]
        dof = np.maximum(n_res - par.size, 1)
        s2 = np.ones(B) if known_sigma else 2 * objective_b.astype(float) / dof
        cov = s2[:, None, None] * np.linalg.pinv(At, hermitian=True)
        se = np.sqrt(np.clip(np.diagonal(cov, axis1=1, axis2=2), 0, None))
    return BatchFit(labels=par.labels, values=vals, stderr=se, objective=objective_b, steps=pick(steps),
                    converged=pick(ok).astype(bool), n_residuals=n_res)


@functools.lru_cache(maxsize=16)
def batched_run(run):
    return jax.jit(jax.vmap(run))
