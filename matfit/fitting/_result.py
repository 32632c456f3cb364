"""The results of fits: :class:`FitResult` (one table), :class:`BatchFit` (a stack of tables)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import MatfitError

__all__ = ["FitError", "FitResult", "BatchFit"]


class FitError(MatfitError):
    """A fit cannot be done as asked (degenerate table, all starts failed, too little memory, ...).

    Parameters
    ----------
    message : str
        What went wrong, naming the table's property or the option at fault.

    Examples
    --------
    >>> from matfit import Table
    >>> from matfit.fitting import FitError, fit
    >>> t = Table(wo=[[0.0, 0.0, 1.0]], wi=[[0.0, 0.0, 1.0]], values=[[0.1, 0.1, 0.1]])
    >>> try:
    ...     fit(t, model="conductor")
    ... except FitError as e:
    ...     print(str(e)[:36])
    fit: the table has 3 usable residual
    """


@dataclass
class FitResult:
    """The outcome of :func:`~matfit.fitting.fit`.

    Attributes
    ----------
    family, method, loss : str
        What was fitted, by which method, under which loss.
    params : dict of numpy.ndarray
        Every parameter (free and fixed); per-channel ones have shape (C,).
    labels : list of str
        Names of the free parameters, in the order of ``values``, ``stderr``, ``cov``.
    values, stderr : numpy.ndarray (p,)
        Free parameter values and their Gauss-Newton standard errors.
    cov, corr : numpy.ndarray (p, p)
        Covariance and correlation of the free parameters.
    objective, rss : float
        ``0.5 * sum`` of squared residuals at the optimum, and the residual sum of squares.
    n_residuals, dof : int
        Number of residuals used, and ``n - p``.
    steps : int
        Solver iterations of the best start.
    converged : bool
        Whether the best start met its tolerances.
    wall_time : float
        Seconds for the whole call.
    start_objectives : numpy.ndarray
        Objective reached by each start.
    model : AbstractBSDF
        The fitted matfit model.
    z : numpy.ndarray (p,)
        The solution in the unconstrained space.
    warnings : list of str
        Diagnostics of the optimum (:mod:`matfit.fitting.diagnostics`): not converged, not
        identifiable (those standard errors are ``inf``), at a bound, outliers, poor fit,
        multiple optima. ``ok`` is ``converged and not warnings``.
    info : list of str
        Notes on how the fit was computed, e.g. that a family has no channel-split kernel and
        ``lm_fd`` solved it on ``(N, C)`` residuals, or that a large table's starts were compared
        on its subset; not warnings.
    choice : matfit.fitting.Choice or None
        How the family was chosen, when none was named (:func:`~matfit.fitting.choose_family`).
    appearance : matfit.appearance.AppearanceDiff or None
        The fit's image differences from the measurement, when it was judged by them.
    reduces_to : str or None
        The smaller family this fit is, where a term ended unused (a lobe of zero weight:
        :func:`~matfit.fitting.reduced_family`); model choice counts its parameters.

    Examples
    --------
    >>> import numpy as np
    >>> from matfit import Table
    >>> from matfit.fitting import fit
    >>> wo = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, 0.6, 0.8]]); wi = wo[[1, 2, 0]]
    >>> r = fit(Table(wo=wo, wi=wi, values=np.full((3, 3), 0.1)), model="lambert", starts=1)
    >>> r.labels, round(float(r.values[0]), 4), r.converged
    (['albedo[0]', 'albedo[1]', 'albedo[2]'], 0.3142, True)
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
    choice: object = field(repr=False, default=None)
    appearance: object = field(repr=False, default=None)
    reduces_to: str = None

    @property
    def ok(self) -> bool:
        """Converged and no diagnostic warning (see :mod:`matfit.fitting.diagnostics`)."""
        return bool(self.converged) and not self.warnings

    def summary(self) -> str:
        """A few lines: family, method, loss, objective, steps, convergence and wall time, then every
        free parameter with its standard error, the warnings and the notes.
        """
        lines = [f"{self.family} fit ({self.method}, {self.loss}): objective {self.objective:.6g}, "
                 f"{self.steps} steps, converged={self.converged}, {self.wall_time:.2f} s"]
        for lab, v, s in zip(self.labels, self.values, self.stderr):
            lines.append(f"  {lab:14s} = {v:.6g} +- {s:.2g}")
        lines += [f"  WARNING {w}" for w in self.warnings]
        lines += [f"  note: {w}" for w in self.info]
        return "\n".join(lines)


@dataclass(frozen=True)
class BatchFit:
    """Per-table results of :func:`~matfit.fitting.fit_arrays` (leading axis: the tables).

    Attributes
    ----------
    labels : list of str
        Names of the free parameters.
    values : numpy.ndarray (B, p)
        Natural parameter values, in the order of ``labels``.
    stderr : numpy.ndarray (B, p)
        Gauss-Newton standard errors (NaN when not computed).
    objective : numpy.ndarray (B,)
        ``0.5 * sum`` of squared residuals.
    steps : numpy.ndarray (B,)
        Solver iterations.
    converged : numpy.ndarray (B,) of bool
        Whether each table's solve met its tolerances.
    n_residuals : numpy.ndarray (B,)
        Residuals with a nonzero weight.
    suspect : numpy.ndarray (B,) of bool
        Tables whose end stays above ``SUSPECT_FACTOR`` times the noise level after the refit:
        a false minimum or a model that does not describe them (all False without a level).
    noise_level : float
        The residual variance the ends are compared with (1 with known sigma; NaN: none).
    refitted : numpy.ndarray (B,) of bool
        Tables solved again from more starts.

    Examples
    --------
    >>> import numpy as np
    >>> from matfit.fitting import fit_arrays
    >>> wo = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, 0.6, 0.8]]); wi = wo[[1, 2, 0]]
    >>> b = fit_arrays(wo, wi, np.full((2, 3, 3), 0.1), model="lambert")
    >>> b.values.shape, b.n_residuals.tolist()
    ((2, 3), [9, 9])
    """

    labels: list
    values: np.ndarray
    stderr: np.ndarray
    objective: np.ndarray
    steps: np.ndarray
    converged: np.ndarray
    n_residuals: np.ndarray
    suspect: np.ndarray = None
    noise_level: float = float("nan")
    refitted: np.ndarray = None
