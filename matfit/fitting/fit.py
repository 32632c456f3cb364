"""Gradient fitting of a model family to a table: problem -> solver -> uncertainty.

:func:`fit` builds the problem (the family's parametrization, the loss's residuals, the table's
arrays), takes the compiled solver of its configuration (:mod:`._solver`, a method of
:data:`~matfit.fitting.methods.METHODS`), starts it from the data-driven guess and the screened
starts (:mod:`._starts`), and turns the solution into a :class:`FitResult` with Gauss-Newton or
sandwich uncertainties (:func:`covariance`) and diagnostics. :func:`fit_arrays` (and
:func:`fit_batch` over it) does the same for a stack of small tables in one vectorized call.

The table's directions are fixed during a fit; the solver is compiled once per (family,
channels, method, loss, table shape) and reused for every table of that shape and every start.
"""

from __future__ import annotations

import functools
import time

import jax
import jax.numpy as jnp
import numpy as np

from ..cache import loop_jit
from ..errors import ParameterError
from ..fast import supports_soa
from ..parallel import device_count, pad_to_power_of_two
from ..table import Table
from . import _solver as solvers
from ._memory import check_memory, memory_estimate
from ._problem import Problem
from ._result import BatchFit, FitError, FitResult
from ._residuals import split_rows, table_arrays
from ._starts import (SCREEN_PER_START, compiled_helpers, fit_starts, guesses_from_arrays, initial_guess,
                      initial_guesses, screened_starts)
from .diagnostics import diagnose
from .lm import group_map
from .losses import DEFAULT_LOSS, prepare_targets
from .methods import DEFAULT_METHOD, METHODS, get_method
from .families import DEFAULT_FAMILY, reduced_family
from .params import check_solver_options

__all__ = ["fit", "fit_batch", "fit_arrays", "FitResult", "FitError", "BatchFit", "initial_guess", "initial_guesses",
           "guesses_from_arrays", "fit_starts", "memory_estimate", "SCREEN_PER_START", "REFIT_SIGMAS", "refit_line", "SUSPECT_FACTOR",
           "REFIT_STARTS", "REFIT_MIN_BATCH", "NOISE_FLOOR", "noise_level", "covariance", "SANDWICH_MAX", "LEVERAGE_MAX",
           "CHANNEL_RHO_REFIT", "EXACT_FIT", "channel_correlation"]


#: A batch's tables whose residual variance ``q`` ends more than this many of its standard
#: deviations above the batch's noise level (``q / level > 1 + REFIT_SIGMAS sqrt(2 / dof)``, the
#: spread of a chi^2 per degree of freedom) are solved again from more starts (:func:`fit_arrays`).
REFIT_SIGMAS = 4.0
#: Tables still above this multiple of the noise level after the refit are ``suspect``.
SUSPECT_FACTOR = 10.0
#: Starts of a refit: the data-driven one and the best screened candidates.
REFIT_STARTS = 8
#: Without the table's sigma, a single fit whose residuals move together across the colour
#: channels (mean pairwise correlation over the rows above this) is solved again from as many
#: other starts (:func:`channel_correlation`): independent noise per channel leaves them uncorrelated.
CHANNEL_RHO_REFIT = 0.8
#: Residual RMS, relative to the values' RMS, at or below which a fit counts as exact (its
#: residuals are rounding error: no channel correlation is read from them).
EXACT_FIT = 1e-5
#: Fewest tables from which the batch's median residual variance is taken as the noise level.
REFIT_MIN_BATCH = 16
#: The lowest noise level, as a relative residual RMS: below it ends are rounding error.
NOISE_FLOOR = 1e-5
#: Tables of at most this many residuals (held whole as a Jacobian) get sandwich standard errors
#: without sigma (:func:`covariance`); larger ones the Gauss-Newton form.
SANDWICH_MAX = 200_000
#: The largest leverage of one residual in the sandwich (a row that alone fixes a parameter).
LEVERAGE_MAX = 0.9


def covariance(gram, rss, dof, known_sigma, jac=None, res=None):
    r"""The covariance of least-squares parameters, in the parameters of ``gram`` and ``jac``.

    With the data's own sigma, :math:`B = (J^T J)^{-1}`. Without it, and given the Jacobian and the
    residuals, the sandwich (HC3, MacKinnon & White 1985) :math:`B\, J^T \mathrm{diag}(u^2) J\, B`,
    :math:`u_i = r_i / (1 - h_i)`, :math:`h_i = J_i B J_i^T` (each row's leverage, capped at
    :data:`LEVERAGE_MAX`): right whether the noise is the same on every residual or grows with the
    value, where :math:`\hat\sigma^2 B` (:math:`\hat\sigma^2` = ``rss / dof``, used without ``jac``)
    is off by the ratio of the peak's noise to the mean (4-8x on 1 % multiplicative noise; coverage
    in ``docs/fitting.md``).

    Parameters
    ----------
    gram : array_like (p, p), or (B, p, p) without ``jac``
        :math:`J^T J`.
    rss, dof : float, int, or (B,)
        The residual sum of squares; residuals less parameters.
    known_sigma : bool
        The residuals are in units of the data's sigma.
    jac, res : array_like (n, p), (n,), optional
        The Jacobian of the residuals and the residuals.

    Returns
    -------
    numpy.ndarray (p, p)

    Examples
    --------
    >>> import numpy as np
    >>> from matfit.fitting import covariance
    >>> x = np.linspace(1, 2, 200); J = np.stack([np.ones_like(x), x], 1)  # a line's two coefficients
    >>> r = 0.01 * x * np.random.default_rng(0).standard_normal(200)        # noise that grows with x
    >>> gn, hc = (np.sqrt(np.diag(covariance(J.T @ J, r @ r, 198, False, *a))) for a in ((), (J, r)))
    >>> bool(hc[1] > gn[1])
    True
    """
    bread = np.linalg.pinv(np.asarray(gram, float), hermitian=True)
    if known_sigma:
        return bread
    if jac is None:  # also a stack of tables: gram (B, p, p), rss and dof (B,)
        return (np.asarray(rss, float) / np.maximum(dof, 1))[..., None, None] * bread
    h = np.einsum("ij,jk,ik->i", jac, bread, jac)
    u = res / (1 - np.clip(h, 0, LEVERAGE_MAX))
    meat = jac * u[:, None]
    return bread @ (meat.T @ meat) @ bread


@functools.lru_cache(maxsize=32)
def _jacobian_program(problem):
    """A jitted ``(z, arrays, moves) -> Jacobian (n, p)`` of the flat residuals (of a problem without robust loss) in
    the natural parameters: grouped differences (:func:`~matfit.fitting.lm.column_groups`, one
    vmapped evaluation of the model) in ``theta``, a step of ``sqrt(eps) max(1, |theta|)`` towards
    the inside of each range (central, ``eps^(1/3)``, in float32), divided by the change of
    ``theta`` it made (a secant: finite at a bound). ``moves`` (p,) bool: where ``d theta / d z``
    is nonzero; a coordinate whose sigmoid is saturated in floating point gets a zero column, as
    the chain rule gave. Faster to compile than ``jax.jacfwd``, and as accurate
    (``docs/performance.md``)."""
    par = problem.par
    prepare, fn = problem.residuals
    seeds, owner = problem.groups
    lower, upper = par.lower_upper()
    bounded = np.isfinite(upper)  # sigmoid coordinates; the others are lower + exp(z)

    def jac(z, arrays, moves):
        prepared = prepare(arrays)
        central = z.dtype == jnp.float32
        eps = jnp.finfo(z.dtype).eps
        th = par.theta_vector(z)
        a = (eps ** (1 / 3) if central else jnp.sqrt(eps)) * jnp.maximum(1, jnp.abs(th))
        if central:  # theta -+ a, both inside the range
            c = jnp.clip(th, lower + 1.5 * a, jnp.where(bounded, upper - 1.5 * a, jnp.inf))
            z_lo, z_hi = par.z_vector(c - a), par.z_vector(c + a)
        else:  # theta, and theta + a towards the inside of the range
            inward = jnp.where(bounded & (th > (lower + upper) / 2), -1.0, 1.0)
            z_lo, z_hi = z, par.z_vector(th + inward * a)
        z_lo, z_hi = z_lo.astype(z.dtype), z_hi.astype(z.dtype)
        step = jnp.where(moves, par.theta_vector(z_hi) - par.theta_vector(z_lo), jnp.inf)
        base = None if central else fn(z, prepared)

        def diff(s):
            plus = fn(jnp.where(s > 0, z_hi, z), prepared)
            return plus - (fn(jnp.where(s > 0, z_lo, z), prepared) if central else base)

        sd = jnp.asarray(seeds, z.dtype)
        K = jax.vmap(diff)(sd)
        E = group_map(sd, jnp.asarray(owner, z.dtype), step, False)  # 1 / step: step is the whole difference
        return jnp.einsum("gnc,cgp->ncp", K, E).reshape(-1, par.size)

    return jax.jit(jac)


def refit_line(dof):
    """The residual variance, in units of the noise level, above which a table is refitted.

    Parameters
    ----------
    dof : array_like
        Degrees of freedom (residuals less free parameters).

    Returns
    -------
    numpy.ndarray
        ``1 + REFIT_SIGMAS * sqrt(2 / dof)``.
    """
    return 1 + REFIT_SIGMAS * np.sqrt(2 / np.maximum(np.asarray(dof, float), 1))


def channel_correlation(r):
    """Mean pairwise correlation over the rows of the residuals of different colour channels.

    Independent noise per channel leaves it near 0 (figures in ``docs/fitting.md``); a fit that
    missed the table's shape (a false minimum) leaves the same misfit in every channel. Rows whose
    residuals are all zero (masked) are left out.

    Parameters
    ----------
    r : array_like (N, C)
        Residuals, one column per channel.

    Returns
    -------
    float
        The mean of the ``C (C - 1) / 2`` correlations; NaN for one channel, fewer than 3 rows or a
        channel without spread.

    Examples
    --------
    >>> import numpy as np
    >>> from matfit.fitting import channel_correlation
    >>> shape = np.sin(np.linspace(0, 3, 24))[:, None]
    >>> round(channel_correlation(shape * [1.0, 2.0, 0.5]), 3)  # one misfit in every channel
    1.0
    """
    r = np.asarray(r, float)
    r = r[np.any(r != 0, axis=1)]
    C = r.shape[1] if r.ndim == 2 else 1
    if C < 2 or r.shape[0] < 3:
        return float("nan")
    d = r - r.mean(axis=0)
    sd = np.sqrt(np.sum(d * d, axis=0))
    if not np.all(sd > 0):
        return float("nan")
    c = (d.T @ d) / np.outer(sd, sd)
    return float(np.mean(c[np.triu_indices(C, 1)]))


def noise_level(q, known_sigma, scale=1.0):
    """The level a batch's ends are judged against (:func:`fit_arrays`, :func:`matfit.maps.fit_map`).

    Parameters
    ----------
    q : array_like
        Each table's residual variance, ``2 F / (n - p)``.
    known_sigma : bool
        The residuals are weighted by the data's own sigma: the level is 1.
    scale : float
        The mean squared value in the residuals' space (1 for relative residuals): the level is
        floored at ``NOISE_FLOOR**2 * scale``, so that noise-free tables ending at rounding error
        are not refitted for it.

    Returns
    -------
    float
        1 with known sigma; else the median of the finite ``q``, floored, over at least
        :data:`REFIT_MIN_BATCH` tables; NaN (no level) for fewer tables or none finite.
    """
    if known_sigma:
        return 1.0
    q = np.asarray(q, float)
    ok = q[np.isfinite(q)]
    if q.size < REFIT_MIN_BATCH or not ok.size:
        return float("nan")
    return max(float(np.median(ok)), NOISE_FLOOR**2 * scale)


def fit(table, model=None, method=DEFAULT_METHOD, loss=None, robust=None, robust_scale=1.0, fixed=None, tied=(),
        starts=4, init=None, max_steps=256, rtol=1e-8, atol=1e-10, seed=0, dtype=None) -> FitResult:
    """Fit a model family to a table by nonlinear least squares.

    Parameters
    ----------
    table : matfit.Table
    model : str, optional
        Family name: ``"lambert"``, ``"conductor"``, ``"plastic"``, ``"lobes2"``, ... (see
        :data:`matfit.fitting.FAMILIES`). None: the family whose render looks most like the
        measurement, among candidates the data call for (:func:`~matfit.fitting.choose_family`;
        the result's ``choice`` says why).
    method : str
        A method of :data:`matfit.fitting.methods.METHODS`. Default ``"lm_fd"``:
        Levenberg-Marquardt on the normal equations with a grouped finite-difference Jacobian
        (:mod:`matfit.fitting.lm`), the fastest on every table size and bounded in memory;
        ``"lm"``, ``"gn"``, ``"dogleg"``, ``"bfgs"`` (optimistix), ``"lbfgs"``, ``"jaxopt_lm"``
        (jaxopt).
    loss, robust, robust_scale
        See :mod:`matfit.fitting.losses`; ``loss`` defaults to ``"l2"`` for a named family, to
        :data:`~matfit.fitting.CHOICE_LOSS` when the family is chosen.
    fixed, tied : optional
        Parameters held at given values; per-channel parameters shared by all channels.
    starts : int
        The data-driven guess plus the ``starts - 1`` best screened candidates
        (:func:`fit_starts`). With the table's own sigma (``l2``, no robust loss) an end whose
        reduced chi-square lies above :func:`refit_line` is solved again from
        ``max(REFIT_STARTS, 2 * starts)`` other starts and the lower end kept (``info`` says so).
    init : dict, optional
        Starting values replacing the data-driven guess.

    Returns
    -------
    FitResult
        The fit (examples: :class:`FitResult`, ``docs/examples.md``).
    """
    t0 = time.perf_counter()
    if not isinstance(table, Table):
        raise ParameterError(f"fit: table must be a matfit.Table, got {type(table).__name__}")
    if model is None:  # matfit.fitting.fit (in _choose) chooses the family; this one fits a named one
        raise ParameterError("fit: name the family (model=...), or call matfit.fitting.fit to choose it")
    loss = DEFAULT_LOSS if loss is None else loss
    get_method(method, "fit")
    check_solver_options("fit", starts=starts, max_steps=max_steps, rtol=rtol, atol=atol, robust_scale=robust_scale,
                         dtype=dtype)
    C = table.n_channels
    problem = Problem.of(model, C, fixed, tied, loss, robust, robust_scale)
    problem.par.check_theta("fit: init", {} if init is None else init)
    par = problem.par
    solve, objective = solvers.compiled_solver(problem, method, int(max_steps), float(rtol), float(atol), device_count() == 1)
    w_eff = table.effective_weight()
    n_res = int(np.count_nonzero(w_eff))
    if n_res <= par.size:
        raise FitError(f"fit: the table has {n_res} usable residuals for {par.size} free parameters "
                       f"({', '.join(par.labels)}): at least {par.size + 1} are needed")
    check_memory("fit", int(np.count_nonzero(np.any(w_eff > 0, axis=1))), C, len(problem.groups[0]), dtype)
    arrays = table_arrays(table, dtype, weight=w_eff)
    n_rows = arrays[2].size
    rows = split_rows(arrays)
    # a large table's candidate starts are screened on its subset (24 candidates on a full MERL
    # table would otherwise evaluate 24 copies of its residuals at once)
    screen = solvers.coarse_rows(rows) if METHODS[method].solver.normal_equations else None
    z0s = fit_starts(table, par, starts, seed, objective, rows if screen is None else screen, init)
    # the best start's residuals and J^T J come with the solution (Gauss-Newton covariance below)
    sol = solve(z0s, rows)
    obj = np.asarray(sol.F)
    known = table.sigma is not None and loss == "l2" and robust is None
    chi2 = 2 * float(np.nanmin(obj)) / max(n_res - par.size, 1)
    line = float(refit_line(n_res - par.size))
    info = []
    rho = float("nan")
    if not known and sol.sub is None and C > 1 and chi2 > 0:
        rb = np.asarray(sol.r)[:n_rows]
        # an exact fit's residuals are rounding error, whose pattern says nothing
        if np.sqrt(np.mean(np.square(rb, dtype=float))) > EXACT_FIT * float(np.sqrt(np.mean(np.square(np.asarray(arrays[2]), dtype=float)))):
            rho = channel_correlation(rb.reshape(-1, C))
    if sol.sub is None and ((known and not chi2 <= line) or rho > CHANNEL_RHO_REFIT):
        # with the table's own sigma the end is judged against the noise: far above it, a false
        # minimum is likely; without it, residuals that move together across the channels (a
        # shape the fit missed, not independent noise) say the same. More starts (other seeds)
        # are solved and the lower end is kept (tables small enough to be solved whole from
        # every start: a large one's starts end on its subset)
        # without sigma as many starts again (the program compiled for them): a measured table
        # that no family describes to its noise correlates too, and pays only a second solve
        n2 = max(REFIT_STARTS, 2 * starts) if known else starts
        again = solve(fit_starts(table, par, n2, seed + 1, objective, rows if screen is None else screen, init), rows)
        obj2 = np.asarray(again.F)
        kept = bool(np.nanmin(obj2) < np.nanmin(obj))
        if kept:
            sol, obj = again, obj2
        why = (f"the first end's reduced chi-square {chi2:.4g} was above {line:.4g} (the noise's line for the "
               "table's sigma)" if known else
               f"the first end's residuals moved together across the colour channels (mean correlation {rho:.3g} "
               f"> {CHANNEL_RHO_REFIT:g}; independent noise leaves them uncorrelated)")
        info.append(f"{why}: refitted from {n2} more start{'s' if n2 > 1 else ''}, " + ("a lower end found" if kept else "no lower end found"))
    z, sub = np.asarray(sol.z), sol.sub
    good = np.isfinite(obj) & np.all(np.isfinite(z), axis=1)
    if not good.any():
        raise FitError("fit: every start ended with non-finite parameters or objective")
    best = int(sol.best)
    zb = z[best]
    steps, ok = np.asarray(sol.steps), np.asarray(sol.converged)
    # Uncertainty: Gauss-Newton covariance in the natural parameters (chain rule through the
    # element-wise transform), scaled by the residual variance unless the table carries sigma.
    r_best = np.asarray(sol.r)[:n_rows]
    post = compiled_helpers(par)["post"](zb, z, zb if sub is None else sub[1])
    dtheta = np.asarray(post["dtheta"])
    inv_d = 1 / np.where(dtheta != 0, dtheta, np.inf)
    At = np.asarray(sol.A, float) * np.outer(inv_d, inv_d)  # J^T J in the natural parameters
    rss = float(2 * obj[best])
    dof = n_res - par.size
    jac = None
    if not known and robust is None and sub is None and n_rows <= SANDWICH_MAX:
        # the noise's size per residual is unknown (it may grow with the value): the sandwich,
        # from the Jacobian at the solution and the solver's residuals there (same flat layout)
        jac = np.asarray(_jacobian_program(problem)(jnp.asarray(zb), arrays, dtheta != 0), float)
    cov = covariance(At, rss, dof, known, *(() if jac is None else (jac, r_best.astype(float))))
    se = np.sqrt(np.clip(np.diag(cov), 0, None))
    # each fitted value's variance from the parameters' (diagnostics: the noise scale of small values)
    fit_var = None if jac is None else np.einsum("ij,jk,ik->i", jac, cov, jac)
    values = np.asarray(post["values"])
    lower, upper = par.lower_upper()
    data_scale = float(_weighted_rms(arrays[2], arrays[3]))
    if METHODS[method].residuals == "channels" and device_count() == 1 and not supports_soa(post["model"]):
        info.append(f"{method}: the {model!r} family's model has no channel-split kernel; solved on (N, C) residuals")
    start_kw = dict(start_values=np.asarray(post["starts"]), start_objectives=obj)
    if sub is not None:  # a large table: the starts are compared where they ended on its subset
        sub_values = np.asarray(post["sub_starts"])
        start_kw = dict(start_values=sub_values, start_objectives=np.asarray(sub[0]), start_reference=sub_values[best],
                        start_stderr=se * np.sqrt(n_rows / (solvers.COARSE_ROWS * C)))
        info.append(f"the {len(table)}-row table was first solved on a random {solvers.COARSE_ROWS}-row subset from "
                    f"{starts} start(s); the whole table from the best of them")
    notes, unident = diagnose(
        labels=par.labels, values=values, stderr=se, lower=lower, upper=upper, gram=At, residuals=r_best,
        converged=bool(ok[best]), steps=int(steps[best]), max_steps=int(max_steps),
        known_sigma=known, dof=n_res - par.size,
        data_scale=data_scale, best=best, scale=_value_scale(arrays, loss, robust),
        physical=par.physical_bounds(), fit_var=fit_var, **start_kw)
    se = np.where(np.isin(par.labels, unident), np.inf, se)
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(se, se)
    theta = post["theta"]
    reduced = reduced_family(par.family.name, theta)
    if reduced is not None:
        info.append(f"this family reduces to a smaller one: {par.family.name} -> {reduced[0]} ({reduced[1]})")
    return FitResult(
        family=model, method=method, loss=loss,
        params={k: np.asarray(v) for k, v in theta.items()},
        labels=par.labels, values=values, stderr=se, cov=cov, corr=corr,
        objective=float(obj[best]), rss=rss, n_residuals=n_res, dof=dof, steps=int(steps[best]),
        converged=bool(ok[best]), wall_time=time.perf_counter() - t0, start_objectives=obj,
        model=post["model"], z=np.asarray(zb), warnings=notes, info=info,
        reduces_to=None if reduced is None else reduced[0],
    )


def fit_batch(tables, model=DEFAULT_FAMILY, method=DEFAULT_METHOD, loss=DEFAULT_LOSS, fixed=None, tied=(), starts=1, max_steps=128,
              rtol=1e-8, atol=1e-10, dtype=None):
    """Fit many tables of the same shape (e.g. texels), each from its own data-driven starts, in
    one compiled program (:func:`fit_arrays`).

    Parameters
    ----------
    tables : sequence of matfit.Table
        Tables of one shape (rows and channels).
    model, method, loss, fixed, tied, starts, max_steps, rtol, atol, dtype
        As for :func:`fit`.

    Returns
    -------
    values : numpy.ndarray (B, p)
        Natural parameter values per table.
    objective : numpy.ndarray (B,)
        ``0.5 * sum`` of squared residuals per table.
    labels : list of str
        Names of the free parameters.
    """
    if isinstance(tables, Table) or not hasattr(tables, "__len__"):
        raise ParameterError(f"fit_batch: tables must be a sequence of matfit.Table, got {type(tables).__name__}")
    if len(tables) == 0:
        raise ParameterError("fit_batch: no tables given")
    for i, t in enumerate(tables):
        if not isinstance(t, Table):
            raise ParameterError(f"fit_batch: table {i} must be a matfit.Table, got {type(t).__name__}")
    get_method(method, "fit_batch")
    check_solver_options("fit_batch", starts=starts, max_steps=max_steps, rtol=rtol, atol=atol, dtype=dtype)
    t0 = tables[0]
    Problem.of(model, t0.n_channels, fixed, tied, loss)  # checked before the tables are stacked
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


def _value_scale(arrays, loss, robust):
    """The measured values in the residuals' space, ``|target| * factor`` (N * C,): the scale
    of noise proportional to the value (:func:`~matfit.fitting.diagnostics.diagnose`)."""
    if robust is not None:
        return None
    target, factor = prepare_targets(arrays[2], arrays[3], arrays[1][:, 2], loss)
    return np.abs(np.asarray(target) * np.asarray(factor)).reshape(-1)


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


#: ``sqrt(mean(w v^2))`` of a table's values and weights (the data's scale, for the diagnostics'
#: exact-fit threshold), on the device where the arrays already are.
_weighted_rms = jax.jit(lambda v, w: jnp.sqrt(jnp.mean(w * v * v)))


@functools.lru_cache(maxsize=16)
def _batch_programs(solve, par, shared):
    """Jitted ``vmap`` over tables of the data-driven guesses' map to ``z``, of a compiled
    solver's ``solve`` (directions shared or per table) and of the natural values with the
    diagonal of their Jacobian in ``z``."""
    d_ax = None if shared else 0
    to_z = jax.jit(jax.vmap(par.z_from_theta))
    run = loop_jit(jax.vmap(solve, in_axes=(0, (d_ax, d_ax, 0, 0))))
    post = jax.jit(jax.vmap(lambda z: (par.theta_vector(z), jnp.diag(jax.jacfwd(par.theta_vector)(z)))))
    return to_z, run, post


def fit_arrays(wo, wi, values, weight=None, *, model=DEFAULT_FAMILY, method=DEFAULT_METHOD, loss=DEFAULT_LOSS, fixed=None,
               tied=(), starts=1, max_steps=128, rtol=1e-8, atol=1e-10, dtype=None, valid=None, known_sigma=False,
               uncertainty=True, refit=True, init=None, level=None, where="fit_arrays") -> BatchFit:
    r"""Fit one family to a stack of B small tables given as arrays, in one vectorized call.

    The core of :func:`fit_batch` and :func:`matfit.maps.fit_map`: every table gets its own
    data-driven start (:func:`guesses_from_arrays`; ``starts - 1`` screened candidates more) and
    its own solve, all in one compiled program; new values of the same shapes reuse it.

    False minima: each table's end is compared with the noise level, :math:`q = 2 F / (n - p)`
    (the residual variance; ``chi^2 / dof`` with ``known_sigma``) against the level
    :math:`\hat q` (1 with ``known_sigma``, else the batch's median of ``q``: tables of one
    capture share their noise; with fewer than :data:`REFIT_MIN_BATCH` tables and no known
    sigma there is no level). Tables above :func:`refit_line` times the level are solved
    again from :data:`REFIT_STARTS` screened starts (and ``init``) and keep the better end;
    those still above :data:`SUSPECT_FACTOR` times it are ``suspect`` in the result.

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
        Compute standard errors (from the ``J^T J`` the solver returns).
    refit : bool, default True
        Solve tables that end far above the noise level again from more starts (above).
    init : array_like, (B, k, p), optional
        More candidate starts per table, natural values in the order of the labels (e.g. a map's
        neighbouring solutions; NaN: none), screened with the random candidates (of the first
        solve when ``starts > 1``, and of a refit).
    level : float, optional
        The noise level to compare the ends with (default: the batch's, :func:`noise_level`).

    Returns
    -------
    BatchFit
        One row per table (an example: ``docs/examples.md``).
    """
    wo, wi, values = _check_stack(where, wo, wi, values, weight, valid)
    B, N, C = values.shape
    problem = Problem.of(model, C, fixed, tied, loss)
    check_solver_options(where, starts=starts, max_steps=max_steps, rtol=rtol, atol=atol, dtype=dtype)
    get_method(method, where)
    par = problem.par
    solve, objective = solvers.compiled_solver(problem, method, int(max_steps), float(rtol), float(atol))
    check_memory(where, B * N, C, len(problem.groups[0]) * starts, dtype)
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
    to_z, run, post = _batch_programs(solve, par, shared)
    dirs = (jnp.asarray(wo, dt), jnp.asarray(wi, dt)) if shared else (jnp.asarray(WO, dt), jnp.asarray(WI, dt))
    arrays = dirs + (jnp.asarray(values, dt), jnp.asarray(w, dt))
    base = np.asarray(to_z({k: jnp.asarray(v, float) for k, v in guess.items()})).astype(np.dtype(dt))
    n_res = np.count_nonzero(w, axis=(1, 2))
    dof = np.maximum(n_res - par.size, 1)
    full = lambda sel: (jnp.asarray(WO[sel], dt), jnp.asarray(WI[sel], dt)) + tuple(a[sel] for a in arrays[2:])  # noqa: E731
    init_z = None if init is None else _init_z(par, to_z, init, base)
    z0 = screened_starts(objective, par, base, starts, 0, full(slice(None)), batched=True, extra=init_z) \
        if starts > 1 else jnp.asarray(base[:, None, :])
    zb, objective_b, steps_b, ok_b, A = _solve_stack(run, z0, arrays)
    q = 2 * objective_b.astype(float) / dof
    if level is None:
        scale = 1.0 if loss == "relative" else float(np.median(np.sum(w * values**2, axis=(1, 2)) / np.maximum(n_res, 1)))
        level = noise_level(q, known_sigma, scale)
    redo = np.flatnonzero(~(q <= refit_line(dof) * level)) if refit and np.isfinite(level) else np.array([], int)
    if redo.size:
        sel = pad_to_power_of_two(redo)  # refits of nearby counts share one compiled program
        extra = None if init_z is None else init_z[sel]
        z1 = screened_starts(objective, par, base[sel], REFIT_STARTS, 1, full(sel), batched=True, extra=extra)
        sub = (dirs if shared else tuple(d[sel] for d in dirs)) + tuple(a[sel] for a in arrays[2:])
        zr, obj_r, steps_r, ok_r, A_r = _solve_stack(run, z1, sub)
        n = redo.size
        better = np.flatnonzero(obj_r[:n] < objective_b[redo])
        t = redo[better]
        zb, A = np.array(zb), np.array(A)
        zb[t], objective_b[t], steps_b[t], ok_b[t], A[t] = (zr[better], obj_r[better], steps_r[better] + steps_b[t],
                                                            ok_r[better], A_r[better])
        q = 2 * objective_b.astype(float) / dof
    suspect = q > SUSPECT_FACTOR * level if np.isfinite(level) else np.zeros(B, bool)
    refitted = np.zeros(B, bool)
    refitted[redo] = True
    vals, dtheta = (np.asarray(a) for a in post(jnp.asarray(zb)))
    se = np.full(vals.shape, np.nan)
    if uncertainty:
        inv_d = 1 / np.where(dtheta != 0, dtheta, np.inf)
        At = np.asarray(A, float) * inv_d[:, :, None] * inv_d[:, None, :]
        cov = covariance(At, 2 * objective_b.astype(float), dof, known_sigma)
        se = np.sqrt(np.clip(np.diagonal(cov, axis1=1, axis2=2), 0, None))
    return BatchFit(labels=par.labels, values=vals, stderr=se, objective=objective_b, steps=steps_b,
                    converged=ok_b.astype(bool), n_residuals=n_res, suspect=suspect, noise_level=level,
                    refitted=refitted)


def _solve_stack(run, z0, arrays):
    """Solve every table from its starts ``z0`` (B, n, p); each table's best end as numpy arrays
    ``(z (B, p), objective, steps, converged, J^T J)``."""
    sol = run(z0, arrays)
    best = np.asarray(sol.best)
    pick = lambda a: np.take_along_axis(np.asarray(a), best.reshape((-1,) + (1,) * (np.ndim(a) - 1)), axis=1)[:, 0]  # noqa: E731
    return pick(sol.z), pick(sol.F), pick(sol.steps), pick(sol.converged), np.asarray(sol.A)


def _init_z(par, to_z, init, base):
    """Natural starting values (B, k, p) to the unconstrained space, kept inside their ranges; a
    start with a NaN (no neighbour) is the table's data-driven one, ``base`` (B, p)."""
    v = np.asarray(init, float)
    if v.ndim != 3 or v.shape[0] != base.shape[0] or v.shape[2] != par.size:
        raise ParameterError(f"fit_arrays: init must be (B, k, p) = ({base.shape[0]}, k, {par.size}) natural values, "
                             f"found shape {v.shape}")
    lo, hi = par.lower_upper()
    span = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    missing = ~np.isfinite(v).all(axis=2)
    # a missing start's values are a placeholder inside the box (replaced by base below)
    v = np.clip(np.where(missing[..., None], lo + span / 2, v), lo + 1e-3 * span, hi - 1e-3 * span)
    B, k, p = v.shape
    z = np.asarray(to_z(par.split(jnp.asarray(v.reshape(B * k, p), float)))).reshape(B, k, p)
    return np.where(missing[..., None], base[:, None, :], z).astype(base.dtype)
