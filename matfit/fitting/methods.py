r"""The registry of least-squares methods: one place that ``fit``, ``fit_batch``, the CLI's
``--method`` choices and the docs read.

Each :class:`Method` names its solver, the library it comes from, the families and losses it
serves (``None``: all of them) and whether batched fits (:func:`~matfit.fitting.fit_batch`) can
use it. :data:`DEFAULT_METHOD` is the fastest correct one, ``"lm_fd"``: Levenberg-Marquardt on
the normal equations with a grouped finite-difference Jacobian (:mod:`matfit.fitting.lm`). It
streams ``J^T J`` and ``J^T r`` through the model's evaluations and never materializes the
``N x p`` Jacobian that the optimistix and jaxopt solvers build (which, for a full MERL table,
needs gigabytes). The others stay for comparison and for problems where an exact Jacobian or a
quasi-Newton method is wanted.

Every solver has the same signature,
``solve(fn, z0, args, max_steps, rtol, atol, groups, wide, extrapolate) -> (z, steps, converged, res)``,
where ``fn(z, args)`` are the residuals (flat for the optimistix and jaxopt solvers; ``(N, C)``
or channel-split for ``lm_fd``), ``groups`` the column groups of
:func:`~matfit.fitting.lm.column_groups` and ``res`` the :class:`~matfit.fitting.lm.LMResult`
of ``lm_fd`` (None for the others).

Examples
--------
>>> from matfit.fitting import METHODS, DEFAULT_METHOD
>>> DEFAULT_METHOD, METHODS[DEFAULT_METHOD].backend
('lm_fd', 'matfit')
>>> sorted(m for m in METHODS if METHODS[m].batched)[:3]
['bfgs', 'dogleg', 'gn']
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import jax.numpy as jnp

from ..errors import ParameterError
from .lm import lm_fd

__all__ = ["Method", "METHODS", "DEFAULT_METHOD", "get_method"]


@dataclass(frozen=True)
class Method:
    """One least-squares method of the registry.

    Parameters
    ----------
    name : str
        The key of :data:`METHODS` (``fit(..., method=name)``, ``matfit fit --method name``).
    backend : str
        Where the solver comes from: ``"matfit"``, ``"optimistix"`` or ``"jaxopt"``.
    description : str
        One line for the CLI's help and the docs.
    solve : callable
        The solver (signature in the module docstring).
    residuals : {"flat", "channels"}
        The residual layout the solver takes: one flat vector, or ``(N, C)`` / channel-split
        arrays (``lm_fd``, whose grouped Jacobian needs the channels apart).
    batched : bool
        Usable by :func:`~matfit.fitting.fit_batch` (under ``vmap``).
    families, losses : tuple of str or None
        What it serves (None: every family, every loss).

    Examples
    --------
    >>> from matfit.fitting.methods import get_method
    >>> get_method("lm").serves("plastic", "e2")
    True
    """

    name: str
    backend: str
    description: str
    solve: Callable
    residuals: str = "flat"
    batched: bool = True
    families: tuple | None = None
    losses: tuple | None = None

    def serves(self, family: str, loss: str) -> bool:
        """True when the method fits ``family`` under ``loss``."""
        return (self.families is None or family in self.families) and (self.losses is None or loss in self.losses)


def _objective(fn):
    def obj(z, args):
        r = fn(z, args)
        return 0.5 * jnp.sum(r * r)

    return obj


def _lm_fd(fn, z0, args, max_steps, rtol, atol, groups, wide, extrapolate):
    res = lm_fd(fn, z0, args, *groups, max_steps=max_steps, rtol=rtol, atol=atol, wide=wide, extrapolate=extrapolate)
    return res.z, res.steps, res.converged, res


def _optimistix_ls(kind):
    def solve(fn, z0, args, max_steps, rtol, atol, groups, wide, extrapolate):
        import optimistix as optx

        solver = {"lm": optx.LevenbergMarquardt, "gn": optx.GaussNewton, "dogleg": optx.Dogleg}[kind](rtol=rtol, atol=atol)
        sol = optx.least_squares(fn, solver, z0, args=args, max_steps=max_steps, throw=False)
        return sol.value, sol.stats["num_steps"], sol.result == optx.RESULTS.successful, None

    return solve


def _bfgs(fn, z0, args, max_steps, rtol, atol, groups, wide, extrapolate):
    import optimistix as optx

    sol = optx.minimise(_objective(fn), optx.BFGS(rtol=rtol, atol=atol), z0, args=args, max_steps=max_steps, throw=False)
    return sol.value, sol.stats["num_steps"], sol.result == optx.RESULTS.successful, None


def _lbfgs(fn, z0, args, max_steps, rtol, atol, groups, wide, extrapolate):
    import jaxopt

    res = jaxopt.LBFGS(fun=_objective(fn), maxiter=max_steps, tol=atol).run(z0, args)
    return res.params, res.state.iter_num, res.state.error <= atol, None


def _jaxopt_lm(fn, z0, args, max_steps, rtol, atol, groups, wide, extrapolate):
    import jaxopt

    res = jaxopt.LevenbergMarquardt(residual_fun=fn, maxiter=max_steps, xtol=rtol, gtol=atol).run(z0, args)
    return res.params, res.state.iter_num, res.state.error <= atol, None


#: The methods, the default first.
METHODS = {
    m.name: m for m in (
        Method("lm_fd", "matfit", "Levenberg-Marquardt, grouped finite-difference Jacobian, streamed normal "
               "equations (default; bounded memory on any table)", _lm_fd, residuals="channels"),
        Method("lm", "optimistix", "optimistix Levenberg-Marquardt (forward-mode Jacobian, N x p in memory)",
               _optimistix_ls("lm")),
        Method("gn", "optimistix", "optimistix Gauss-Newton", _optimistix_ls("gn")),
        Method("dogleg", "optimistix", "optimistix Dogleg trust region", _optimistix_ls("dogleg")),
        Method("bfgs", "optimistix", "optimistix BFGS on 0.5 |r|^2", _bfgs),
        Method("lbfgs", "jaxopt", "jaxopt L-BFGS on 0.5 |r|^2", _lbfgs),
        Method("jaxopt_lm", "jaxopt", "jaxopt Levenberg-Marquardt", _jaxopt_lm),
    )
}

#: The method every fitting entry point uses unless told otherwise.
DEFAULT_METHOD = "lm_fd"


def get_method(name, where="fit", family=None, loss=None) -> Method:
    """The registered :class:`Method` called ``name``; a :class:`~matfit.ParameterError` naming
    the choices when there is none, or when it does not serve ``family`` / ``loss``.

    Examples
    --------
    >>> from matfit.fitting.methods import get_method
    >>> get_method("lm_fd").residuals
    'channels'
    """
    m = METHODS.get(name) if isinstance(name, str) else None
    if m is None:
        raise ParameterError(f"{where}: method must be one of {list(METHODS)}, got {name!r}")
    if family is not None and loss is not None and not m.serves(family, loss):
        raise ParameterError(f"{where}: method {name!r} does not fit the {family!r} family with loss {loss!r}; "
                             f"use one of {[k for k, v in METHODS.items() if v.serves(family, loss)]}")
    return m
