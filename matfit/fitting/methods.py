r"""The registry of least-squares methods: one place that ``fit``, ``fit_batch``, the CLI's
``--method`` choices and the docs read.

Each :class:`Method` names its solver and the library it comes from; every method serves every
family and loss, single and batched fits. :data:`DEFAULT_METHOD` is the fastest correct one, ``"lm_fd"``: Levenberg-Marquardt on
the normal equations with a grouped finite-difference Jacobian (:mod:`matfit.fitting.lm`). It
streams ``J^T J`` and ``J^T r`` through the model's evaluations and never materializes the
``N x p`` Jacobian that the optimistix and jaxopt solvers build (which, for a full MERL table,
needs gigabytes). The others stay for comparison and for problems where an exact Jacobian or a
quasi-Newton method is wanted.

Every method builds a solver (:class:`AbstractSolver`, an equinox module) whose options are its
fields, ``Method.build(rtol, atol, max_steps)``. A solver declares what it needs and gives
(``residuals``, ``normal_equations``, ``traces``) and solves with one signature,
:meth:`AbstractSolver.solve`, returning a :class:`~matfit.fitting.lm.Solution`.
What fits do with a solver depends on those declarations, never on the method's name.

Examples
--------
>>> from matfit.fitting import METHODS, DEFAULT_METHOD
>>> DEFAULT_METHOD, METHODS[DEFAULT_METHOD].backend
('lm_fd', 'matfit')
>>> sorted(METHODS)[:3]
['bfgs', 'dogleg', 'gn']
"""

from __future__ import annotations

import abc
from dataclasses import dataclass, field
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp

from ..errors import ParameterError
from .lm import LevenbergMarquardtFD, Solution

__all__ = ["Method", "METHODS", "DEFAULT_METHOD", "get_method", "AbstractSolver", "Solution", "LMFDSolver",
           "OptimistixLeastSquares", "OptimistixBFGS", "JaxoptLBFGS", "JaxoptLM"]


def _objective(fn):
    def obj(z, args):
        r = fn(z, args)
        return 0.5 * jnp.sum(r * r)

    return obj


class AbstractSolver(eqx.Module):
    """A least-squares solver of the registry, built with its tolerances.

    Subclasses are final and declare:

    - ``residuals``: ``"flat"`` (one vector) or ``"channels"`` (``(N, C)`` or one array per
      colour channel, for a grouped Jacobian);
    - ``normal_equations``: the solver returns ``F = 0.5 |r|^2``, ``J^T J`` and the residuals at
      its solution (:class:`~matfit.fitting.lm.LMResult`), so that fits need not evaluate them
      again, and it is cheap enough to solve a large table's subsample first;
    - ``traces``: :meth:`trace` records the objective at every step.

    Parameters
    ----------
    rtol, atol : float
        Relative and absolute stopping tolerances.
    max_steps : int, default 256
        Most iterations.

    Examples
    --------
    >>> from matfit.fitting.methods import METHODS
    >>> s = METHODS["lm_fd"].build(1e-8, 1e-10)
    >>> s.residuals, s.normal_equations, s.traces
    ('channels', True, False)
    """

    rtol: float = eqx.field(static=True)
    atol: float = eqx.field(static=True)
    max_steps: int = eqx.field(default=256, static=True)
    residuals: ClassVar[str] = "flat"
    normal_equations: ClassVar[bool] = False
    traces: ClassVar[bool] = False

    @abc.abstractmethod
    def solve(self, fn, z0, args, groups=None, warm=None) -> Solution:
        """Minimize ``0.5 |fn(z, args)|^2`` from ``z0`` in at most ``max_steps`` steps.

        ``fn(z, args)`` gives the residuals in the layout of ``residuals``; ``groups`` is the
        ``(seeds, owner)`` of :func:`~matfit.fitting.lm.column_groups` and ``warm`` a subset's
        :class:`~matfit.fitting.lm.Solution` (``lm_fd``'s; others ignore both).
        """

    def trace(self, fn, z0, args, record) -> jax.Array:
        """Solve flat residuals as :meth:`solve` does, calling ``record(step, objective)`` from the
        compiled loop at every step (the objective at the last accepted iterate); returns the final
        objective.
        """
        raise ParameterError(f"{type(self).__name__} does not report its iterates")


class LMFDSolver(AbstractSolver):
    """``lm_fd``: :class:`~matfit.fitting.lm.LevenbergMarquardtFD` (its options described at
    :func:`~matfit.fitting.lm.lm_fd`).

    Parameters
    ----------
    wide : bool, default False
        ``lm_fd``'s ``wide``: the normal equations summed in float64.
    large_residual : bool, default False
        ``lm_fd``'s ``extrapolate`` and ``secant`` both on (for single large fits).

    Examples
    --------
    >>> import numpy as np, jax.numpy as jnp
    >>> from matfit.fitting.methods import LMFDSolver
    >>> sol = LMFDSolver(1e-8, 1e-10, 50).solve(lambda z, a: (z - a)[None, :], jnp.zeros(2), jnp.ones(2),
    ...                                     (np.eye(2), np.ones((1, 2))))
    >>> [round(float(v), 6) for v in sol.z], bool(sol.converged)
    ([1.0, 1.0], True)
    """

    wide: bool = eqx.field(default=False, static=True)
    large_residual: bool = eqx.field(default=False, static=True)
    residuals: ClassVar[str] = "channels"
    normal_equations: ClassVar[bool] = True

    def solve(self, fn, z0, args, groups=None, warm=None) -> Solution:
        solver = LevenbergMarquardtFD(self.rtol, self.atol, self.max_steps, wide=self.wide,
                                      extrapolate=self.large_residual, secant=self.large_residual)
        return solver.minimise(fn, z0, args, *groups, warm=warm)


_OPTX_LS = {"lm": "LevenbergMarquardt", "gn": "GaussNewton", "dogleg": "Dogleg"}


class OptimistixLeastSquares(AbstractSolver):
    """An optimistix least-squares solver (forward-mode Jacobian, ``N x p`` in memory).

    Parameters
    ----------
    kind : {"lm", "gn", "dogleg"}
        ``optimistix.LevenbergMarquardt``, ``GaussNewton`` or ``Dogleg``.

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.fitting.methods import OptimistixLeastSquares
    >>> sol = OptimistixLeastSquares(1e-8, 1e-10, 50, "dogleg").solve(lambda z, a: z - a, jnp.zeros(1), jnp.ones(1))
    >>> round(float(sol.z[0]), 6)
    1.0
    """

    kind: str = eqx.field(default="lm", static=True)
    traces: ClassVar[bool] = True

    def _solver(self, **kw):
        import optimistix as optx

        return getattr(optx, _OPTX_LS[self.kind])(rtol=self.rtol, atol=self.atol, **kw)

    def solve(self, fn, z0, args, groups=None, warm=None) -> Solution:
        import optimistix as optx

        sol = optx.least_squares(fn, self._solver(), z0, args=args, max_steps=self.max_steps, throw=False)
        return Solution(sol.value, sol.stats["num_steps"], sol.result == optx.RESULTS.successful)

    def trace(self, fn, z0, args, record) -> jax.Array:
        import optimistix as optx

        def verbose(**kw):
            # kw values are (label, traced value); step 0 has no accepted iterate yet.
            jax.debug.callback(lambda n, v: record(int(n), float(v)), kw["num_steps"][1],
                               kw["loss_last_accepted_step"][1])

        sol = optx.least_squares(fn, self._solver(verbose=verbose), z0, args=args, max_steps=self.max_steps, throw=False)
        r = fn(sol.value, args)
        return 0.5 * jnp.sum(r * r)


class OptimistixBFGS(AbstractSolver):
    """optimistix BFGS on ``0.5 |r|^2``.

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.fitting.methods import OptimistixBFGS
    >>> sol = OptimistixBFGS(1e-8, 1e-10, 50).solve(lambda z, a: z[0] - a, jnp.zeros(1), jnp.array([1.0, 3.0]))
    >>> round(float(sol.z[0]), 5)  # the minimum of 0.5 |r|^2: the mean
    2.0
    """

    def solve(self, fn, z0, args, groups=None, warm=None) -> Solution:
        import optimistix as optx

        sol = optx.minimise(_objective(fn), optx.BFGS(rtol=self.rtol, atol=self.atol), z0, args=args,
                            max_steps=self.max_steps, throw=False)
        return Solution(sol.value, sol.stats["num_steps"], sol.result == optx.RESULTS.successful)


class JaxoptLBFGS(AbstractSolver):
    """jaxopt L-BFGS on ``0.5 |r|^2`` (its ``tol`` is ``atol``).

    Examples
    --------
    >>> import numpy as np, jax.numpy as jnp
    >>> from matfit.fitting.methods import JaxoptLBFGS
    >>> x = jnp.linspace(0.0, 1.0, 5)  # a line through five points: intercept 1, slope 2
    >>> sol = JaxoptLBFGS(1e-8, 1e-8, 50).solve(lambda z, x: z[0] + z[1] * x - (1 + 2 * x), jnp.zeros(2), x)
    >>> np.round(np.asarray(sol.z), 5).tolist()
    [1.0, 2.0]
    """

    def solve(self, fn, z0, args, groups=None, warm=None) -> Solution:
        import jaxopt

        res = jaxopt.LBFGS(fun=_objective(fn), maxiter=self.max_steps, tol=self.atol).run(z0, args)
        return Solution(res.params, res.state.iter_num, res.state.error <= self.atol)


class JaxoptLM(AbstractSolver):
    """jaxopt Levenberg-Marquardt, stopped by Madsen and Nielsen's tests: a step shorter than
    ``rtol`` relative to ``z`` (jaxopt's ``xtol``) or a gradient's largest entry below ``atol``
    (``gtol``). Converged when a test ended the loop before ``max_steps`` (jaxopt's default test,
    a gradient norm below its own ``tol`` of 1e-3, would ignore both tolerances).

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.fitting.methods import JaxoptLM
    >>> fn = lambda z, a: z - a  # two steps meet the tests: converged only with max_steps > 2
    >>> [bool(JaxoptLM(1e-8, 1e-10, n).solve(fn, jnp.zeros(1), jnp.ones(1)).converged) for n in (2, 50)]
    [False, True]
    """

    def solve(self, fn, z0, args, groups=None, warm=None) -> Solution:
        import jaxopt

        res = jaxopt.LevenbergMarquardt(residual_fun=fn, maxiter=self.max_steps, xtol=self.rtol, gtol=self.atol,
                                        stop_criterion="madsen-nielsen").run(z0, args)
        return Solution(res.params, res.state.iter_num, res.state.iter_num < self.max_steps)


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
    solver : type
        The :class:`AbstractSolver` subclass.
    options : dict
        Keyword arguments of the solver beyond the tolerances.

    Every method serves every family and loss, and batched fits (under ``vmap``):
    ``tests/test_methods_families.py`` fits two families with each.

    Examples
    --------
    >>> from matfit.fitting.methods import get_method
    >>> get_method("lm").backend, get_method("lm_fd").residuals
    ('optimistix', 'channels')
    """

    name: str
    backend: str
    description: str
    solver: type
    options: dict = field(default_factory=dict)

    @property
    def residuals(self) -> str:
        """The residual layout the solver takes (:attr:`AbstractSolver.residuals`)."""
        return self.solver.residuals

    def build(self, rtol, atol, max_steps=256, **options) -> AbstractSolver:
        """The solver with tolerances ``rtol``, ``atol``, at most ``max_steps`` steps and its
        ``options`` (``lm_fd``'s ``wide``, ``large_residual``; other solvers take none)."""
        return self.solver(float(rtol), float(atol), int(max_steps), **self.options, **options)


#: The methods, the default first.
METHODS = {
    m.name: m for m in (
        Method("lm_fd", "matfit", "Levenberg-Marquardt, grouped finite-difference Jacobian, streamed normal "
               "equations (default; bounded memory on any table)", LMFDSolver),
        Method("lm", "optimistix", "optimistix Levenberg-Marquardt (forward-mode Jacobian, N x p in memory)",
               OptimistixLeastSquares, {"kind": "lm"}),
        Method("gn", "optimistix", "optimistix Gauss-Newton", OptimistixLeastSquares, {"kind": "gn"}),
        Method("dogleg", "optimistix", "optimistix Dogleg trust region", OptimistixLeastSquares, {"kind": "dogleg"}),
        Method("bfgs", "optimistix", "optimistix BFGS on 0.5 |r|^2", OptimistixBFGS),
        Method("lbfgs", "jaxopt", "jaxopt L-BFGS on 0.5 |r|^2", JaxoptLBFGS),
        Method("jaxopt_lm", "jaxopt", "jaxopt Levenberg-Marquardt", JaxoptLM),
    )
}

#: The method every fitting entry point uses unless told otherwise.
DEFAULT_METHOD = "lm_fd"


def get_method(name, where="fit") -> Method:
    """The registered :class:`Method` called ``name``.

    Parameters
    ----------
    name : str
        A key of :data:`METHODS`.
    where : str, default "fit"
        The caller, named in errors.

    Returns
    -------
    Method

    Raises
    ------
    matfit.ParameterError
        Naming the choices, when there is no such method.
    """
    m = METHODS.get(name) if isinstance(name, str) else None
    if m is None:
        raise ParameterError(f"{where}: method must be one of {list(METHODS)}, got {name!r}")
    return m
