r"""Model choice: fit several families, compare information criteria and hold-out error.

:func:`compare_models` splits the table at random into a fit part and a hold-out part
(``holdout`` is the hold-out fraction), fits every family to the fit part with :func:`robust_fit`
(two starting points) and reports, per family:

* ``p``: free parameters; ``n``: residuals used by the fit (valid rows x channels);
* ``aic = n log(RSS/n) + 2p`` and ``bic = n log(RSS/n) + p log n``: the Gaussian log-likelihood
  with the variance profiled out, from the fit's residual sum of squares (the fit's own loss and
  weights, so with ``sigma`` in the table they are chi-square residuals);
* ``holdout_rmse``: ``sqrt(mean r^2)`` of the same residuals (same loss, same weights) on the
  hold-out rows; ``holdout_rmse_raw``: plain RMSE of the BRDF values there, in 1/sr.

Recommendation: among the families whose hold-out RMSE is within ``tol`` (default 2 %, relative)
of the best one, the one with the fewest free parameters (ties: the order of ``models``). The
hold-out error decides, not the AIC/BIC, because it does not depend on the Gaussian error model
being right.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import ParameterError
from ..table import Table
from .fit import FitError, fit, initial_guess
from .losses import DEFAULT_LOSS, residuals
from ._problem import Problem
from .families import COMPARE_FAMILIES, get_family

__all__ = ["compare_models", "ModelComparison", "recommend", "robust_fit", "information_criteria", "DEFAULT_TOL"]

#: Relative hold-out tolerance of the recommendation.
DEFAULT_TOL = 0.02


@dataclass
class ModelComparison:
    """The outcome of :func:`compare_models`.

    Attributes
    ----------
    rows : list of dict
        One dict per family, in the order of ``models``: ``model``, ``p``, ``n``, ``rss``,
        ``aic``, ``bic``, ``holdout_rmse``, ``holdout_rmse_raw``, ``objective``, ``converged``,
        ``seconds`` (see the module docstring); a family whose fit failed has only ``model``,
        ``error`` (the message) and ``seconds``.
    recommended, best : str or None
        The family chosen (:func:`recommend`; None when every fit failed) and the one with the
        lowest hold-out RMSE.
    tol : float
        Relative hold-out tolerance of the recommendation.
    n_fit, n_holdout : int
        Rows in the fit part and in the hold-out part of the split.
    results : dict, default {}
        The :class:`~matfit.fitting.FitResult` per family (fitted to the fit part); failed
        families are missing.

    Examples
    --------
    >>> import numpy as np
    >>> from matfit import Table
    >>> from matfit.fitting import compare_models
    >>> wo = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, 0.6, 0.8], [0.8, 0.0, 0.6]])
    >>> table = Table(wo=wo, wi=wo[[1, 2, 3, 0]], values=np.full((4, 3), 0.1))  # a Lambertian table
    >>> cmp = compare_models(table, models=("lambert",), starts=1)
    >>> cmp.recommended, cmp.best, cmp.n_fit, cmp.n_holdout, sorted(cmp.results)
    ('lambert', 'lambert', 3, 1, ['lambert'])
    >>> row = cmp.rows[0]
    >>> row["p"], row["n"], bool(row["holdout_rmse_raw"] < 1e-6)  # 3 albedos, 3 rows x 3 channels; exact
    (3, 9, True)
    """

    rows: list
    recommended: str | None
    best: str | None
    tol: float
    n_fit: int
    n_holdout: int
    results: dict = field(default_factory=dict, repr=False)

    def summary(self) -> str:
        """A text table: one line per family (``p``, AIC, BIC, hold-out RMSE in the loss and in 1/sr,
        the recommended one marked; or a failed fit's error) and the recommended and best family."""
        lines = [f"model comparison: {self.n_fit} fit rows, {self.n_holdout} hold-out rows, tolerance {self.tol:.0%}",
                 f"  {'model':20s} {'p':>3s} {'AIC':>11s} {'BIC':>11s} {'hold-out RMSE':>13s} {'raw (1/sr)':>11s}"]
        for r in self.rows:
            if r.get("error"):
                lines.append(f"  {r['model']:20s} failed: {r['error']}")
                continue
            mark = "  <- recommended" if r["model"] == self.recommended else ""
            lines.append(f"  {r['model']:20s} {r['p']:3d} {r['aic']:11.4g} {r['bic']:11.4g} {r['holdout_rmse']:13.5g} "
                         f"{r['holdout_rmse_raw']:11.4g}{mark}")
        lines.append(f"  recommended: {self.recommended} (best hold-out: {self.best})")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """The comparison as JSON-serializable data, without the fit results."""
        return {"rows": self.rows, "recommended": self.recommended, "best": self.best, "tol": self.tol,
                "n_fit": self.n_fit, "n_holdout": self.n_holdout}


def recommend(rows, tol=DEFAULT_TOL):
    """``(recommended, best)`` family names from comparison rows (the rule: module docstring).

    Parameters
    ----------
    rows : list of dict
        Rows with ``model``, ``p`` and ``holdout_rmse``; rows with an ``error`` or a non-finite
        ``holdout_rmse`` are left out.
    tol : float, default :data:`DEFAULT_TOL`
        The families within ``best * (1 + tol)`` are candidates.

    Returns
    -------
    recommended, best : str or None
        The candidate with the fewest free parameters and the lowest hold-out RMSE (ties: the first
        row); ``(None, None)`` when no row is usable.

    Examples
    --------
    >>> rows = [{"model": "plastic", "p": 5, "holdout_rmse": 1.00},
    ...         {"model": "lambert", "p": 3, "holdout_rmse": 1.01}]
    >>> recommend(rows), recommend(rows, tol=0.001)
    (('lambert', 'plastic'), ('plastic', 'plastic'))
    """
    ok = [(i, r) for i, r in enumerate(rows) if not r.get("error") and math.isfinite(r.get("holdout_rmse", math.nan))]
    if not ok:
        return None, None
    best = min(ok, key=lambda ir: (ir[1]["holdout_rmse"], ir[0]))[1]
    limit = best["holdout_rmse"] * (1.0 + tol)
    within = [(i, r) for i, r in ok if r["holdout_rmse"] <= limit]
    rec = min(within, key=lambda ir: (ir[1]["p"], ir[0]))[1]
    return rec["model"], best["model"]


def robust_fit(table, model, init=None, fixed=None, tied=(), **fit_kwargs):
    """:func:`~matfit.fitting.fit` from two starting points; the result of lower objective.

    The first fit starts as :func:`~matfit.fitting.fit` does (``init`` replacing entries of the
    data-driven guess, and its screened candidates, the NDF-width one included), the second from a
    generic mid-range point (:meth:`~matfit.fitting.Family.generic_start`). Both runs share one compiled
    solver, so the second costs only its iterations. This guards against the data-driven guess
    landing in a poor basin (e.g. a conductor's ``k`` at its bound when a sparse table makes the
    peak look wide).

    Parameters
    ----------
    table, model : matfit.Table, str
        The measurements; a family name (see :data:`matfit.fitting.FAMILIES`).
    init, fixed, tied : optional
        Starting values of the first start, parameters held fixed, tied per-channel parameters.
    **fit_kwargs
        Passed to :func:`~matfit.fitting.fit` (``method``, ``loss``, ``starts``, ...).

    Returns
    -------
    matfit.fitting.FitResult
        The fit of lower objective (the first on a tie); a start whose fit raises
        :class:`~matfit.fitting.FitError` is skipped.

    Raises
    ------
    matfit.errors.ParameterError
        When ``table`` is not a :class:`~matfit.Table` or ``init`` does not fit the family.
    matfit.fitting.FitError
        The last start's error, when both starts fail.
    """
    if not isinstance(table, Table):
        raise ParameterError(f"robust_fit: table must be a matfit.Table, got {type(table).__name__}")
    par = Problem.of(model, table.n_channels, fixed, tied, fit_kwargs.get("loss"), fit_kwargs.get("robust"),
                     fit_kwargs.get("robust_scale", 1.0)).par
    if init is not None:
        par.check_theta("robust_fit: init", init)
    # the first fit starts where fit itself starts (init replacing entries of the data-driven
    # guess, whose NDF-width candidate then enters the screening); the second from mid-range
    guess = dict(init) if init is not None else initial_guess(table, par)
    second = par.family.generic_start(guess, [p.name for p in par.free])
    best, err = None, None
    for start in (init, second):
        try:
            r = fit(table, model=model, init=start, fixed=fixed, tied=tied, **fit_kwargs)
        except FitError as e:
            err = e
            continue
        if best is None or r.objective < best.objective:
            best = r
    if best is None:
        raise err
    return best


def _holdout_errors(result, table, loss):
    import jax.numpy as jnp

    valid = table.valid
    w = table.effective_weight()
    pred = np.asarray(result.model.eval(jnp.asarray(table.wo), jnp.asarray(table.wi)), dtype=np.float64)
    r = np.asarray(residuals(jnp.asarray(pred), jnp.asarray(table.values), jnp.asarray(w), jnp.asarray(table.wi[:, 2]),
                             loss=loss))
    used = w > 0
    n = int(used.sum())
    rmse = float(np.sqrt(np.sum(np.where(used, r, 0) ** 2) / max(n, 1)))
    raw = float(np.sqrt(np.mean((pred[valid] - table.values[valid]) ** 2))) if valid.any() else math.nan
    return rmse, raw


def information_criteria(rss, n, p):
    """``(aic, bic)`` of a least-squares fit: ``n log(RSS/n) + 2p`` and ``n log(RSS/n) + p log n``
    (the Gaussian log-likelihood with the residual variance estimated; RSS floored at 1e-300).

    Parameters
    ----------
    rss, n, p : float, int, int
        Residual sum of squares, number of residuals, number of free parameters.

    Returns
    -------
    tuple of float
    """
    ll = n * math.log(max(float(rss), 1e-300) / n)
    return ll + 2 * p, ll + p * math.log(n)


def compare_models(table, models=COMPARE_FAMILIES, holdout=0.2, seed=0, tol=DEFAULT_TOL,
                   **fit_kwargs) -> ModelComparison:
    """Fit each family in ``models`` with :func:`robust_fit` on a random ``1 - holdout`` of the rows
    and compare them; a family whose fit raises :class:`~matfit.fitting.FitError` gets a row with
    the error and no result.

    Parameters
    ----------
    table : matfit.Table
    models : sequence of str or str, default ("lambert", "conductor", "plastic")
        Distinct family names (see :data:`matfit.fitting.FAMILIES`); a string is split at commas.
    holdout : float, default 0.2
        Fraction of the rows held out (``Table.split(1 - holdout, seed)``), in (0, 1).
    seed : int, default 0
        Seed of the split.
    tol : float, default 0.02
        Relative hold-out tolerance of the recommendation (``>= 0``).
    **fit_kwargs
        Passed to :func:`matfit.fitting.fit`; a ``fixed``, ``tied`` or ``init`` that names a
        parameter a family lacks is applied to the families that have it.

    Returns
    -------
    ModelComparison
        The rows, the recommendation and the fits.

    Raises
    ------
    matfit.errors.ParameterError
        When ``table`` is not a :class:`~matfit.Table`, ``models`` is empty, repeats or names
        an unknown family, or ``holdout`` or ``tol`` is out of range.
    matfit.fitting.FitError
        When the split leaves no valid row in the fit part or in the hold-out part.
    """
    if not isinstance(table, Table):
        raise ParameterError(f"compare_models: table must be a matfit.Table, got {type(table).__name__}")
    if isinstance(models, str):
        models = tuple(m.strip() for m in models.split(",") if m.strip())
    models = tuple(models)
    if not models:
        raise ParameterError("compare_models: no models given")
    for m in models:
        get_family(m)
    if len(set(models)) != len(models):
        raise ParameterError(f"compare_models: models repeat: {list(models)}")
    if not (isinstance(holdout, (int, float)) and 0.0 < float(holdout) < 1.0):
        raise ParameterError(f"compare_models: holdout must be a fraction in (0, 1), got {holdout!r}")
    if not (isinstance(tol, (int, float)) and tol >= 0):
        raise ParameterError(f"compare_models: tol must be >= 0, got {tol!r}")
    fit_part, hold_part = table.split(1.0 - float(holdout), seed=seed)
    if fit_part.n_valid == 0 or hold_part.n_valid == 0:
        raise FitError(f"compare_models: the split leaves {fit_part.n_valid} valid fit rows and {hold_part.n_valid} "
                       f"valid hold-out rows; both must be > 0")
    loss = fit_kwargs.get("loss", DEFAULT_LOSS)
    fixed_all = dict(fit_kwargs.pop("fixed", None) or {})
    tied_all = tuple(fit_kwargs.pop("tied", ()) or ())
    rows, results = [], {}
    for m in models:
        names = {p.name for p in get_family(m).params}
        fixed = {k: v for k, v in fixed_all.items() if k in names}
        tied = tuple(t for t in tied_all if t in names)
        t0 = time.perf_counter()
        kw = dict(fit_kwargs)
        if kw.get("init") is not None:
            kw["init"] = {k: v for k, v in kw["init"].items() if k in names} or None
        try:
            res = robust_fit(fit_part, m, fixed=fixed, tied=tied, **kw)
        except FitError as e:
            rows.append({"model": m, "error": str(e), "seconds": time.perf_counter() - t0})
            continue
        n, p = int(res.n_residuals), len(res.labels)
        aic, bic = information_criteria(res.rss, n, p)
        h_rmse, h_raw = _holdout_errors(res, hold_part, loss)
        rows.append({"model": m, "p": p, "n": n, "rss": float(res.rss), "aic": aic, "bic": bic,
                     "holdout_rmse": h_rmse, "holdout_rmse_raw": h_raw, "objective": float(res.objective),
                     "converged": bool(res.converged), "seconds": time.perf_counter() - t0})
        results[m] = res
    rec, best = recommend(rows, tol)
    return ModelComparison(rows=rows, recommended=rec, best=best, tol=float(tol), n_fit=len(fit_part),
                           n_holdout=len(hold_part), results=results)
