"""The per-iteration objective of every start of a fit (what a report's loss plot shows).

``fit`` solves all its starts in one compiled, vectorized call and keeps only where each ended;
:func:`loss_history` re-runs the same problem one start at a time on a solver that reports its
iterates.
"""

from __future__ import annotations

import jax
import numpy as np

from ..errors import ParameterError
from ._problem import Problem
from ._residuals import table_arrays
from ._starts import fit_starts
from .losses import DEFAULT_LOSS
from .methods import METHODS

__all__ = ["loss_history"]


def loss_history(table, family, loss=DEFAULT_LOSS, method="lm", starts=4, seed=0, max_steps=256, rtol=1e-8, atol=1e-10,
                 robust=None, robust_scale=1.0, fixed=None, tied=(), init=None, dtype=None):
    """Per-iteration objective of every start of a :func:`matfit.fitting.fit` call.

    Re-runs the same optimistix solver (same family, loss, starting points, tolerances and step
    limit as ``fit`` with these arguments) one start at a time with a ``verbose`` callback that
    records, at every solver step, ``0.5 * sum(r**2)`` at the last accepted iterate: each curve is
    non-increasing (a rejected Levenberg-Marquardt trial step repeats the previous value) and ends
    at that start's final objective.

    Parameters
    ----------
    table : matfit.Table
    family, loss, method, starts, seed, max_steps, rtol, atol, robust, robust_scale, fixed, tied, init, dtype
        As for :func:`matfit.fitting.fit` (``method`` one of ``"lm"``, ``"gn"``, ``"dogleg"``).

    Returns
    -------
    list of numpy arrays
        One array per start: the objective after each solver step (entry 0: at the starting point).

    Examples
    --------
    >>> import numpy as np
    >>> from matfit import Table
    >>> rng = np.random.default_rng(0)
    >>> wo = np.tile([0.0, 0.0, 1.0], (40, 1)); wi = rng.normal(size=(40, 3)); wi[:, 2] = abs(wi[:, 2])
    >>> wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    >>> t = Table(wo=wo, wi=wi, values=np.full((40, 1), 0.3 / np.pi), channels="mono")
    >>> from matfit.fitting import loss_history
    >>> h = loss_history(t, "lambert", starts=2)  # start 0 (data-driven) is exact here; start 1 is perturbed
    >>> bool(h[1][0] > 1e-4 and h[1][-1] < 1e-8 and np.all(np.diff(h[1]) <= 0))
    True
    """
    traced = sorted(n for n, m in METHODS.items() if m.solver.traces)
    if method not in traced:
        raise ParameterError(f"loss_history: method must be one of {traced} (solvers that take a "
                             f"verbose callback), got {method!r}")
    problem = Problem.of(family, table.n_channels, fixed, tied, loss, robust, robust_scale)
    par = problem.par
    prepare, fn_nc = problem.residuals
    arrays = table_arrays(table, dtype)
    # the starts fit() runs (init replaces entries of the data-driven guess of start 0)
    z0s = fit_starts(table, par, starts, seed, jax.jit(problem.objective), arrays, init)
    prepared = prepare(arrays)
    solver = METHODS[method].build(rtol, atol, max_steps)
    record = []

    @jax.jit
    def solve(z0, args):
        return solver.trace(lambda z, a: fn_nc(z, a).reshape(-1), z0, args,
                            lambda n, v: record.append((n, v)))

    out = []
    for z0 in z0s:
        record.clear()
        final = float(solve(z0, prepared))
        jax.effects_barrier()
        vals = [v for n, v in sorted(record) if n > 0]
        out.append(np.asarray(vals + [final], float))
    return out
