"""The results of fits: :class:`FitResult` (one table), :class:`BatchFit` (a stack of tables)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import MatfitError

__all__ = ["FitError", "FitResult", "BatchFit"]


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
