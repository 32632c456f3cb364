"""The main job in one call: table -> fit -> posterior -> report -> export.

:func:`run_pipeline` is what ``matfit fit`` and ``matfit demo`` both run: a fit of one family
(:func:`~matfit.fitting.robust_fit`: the data-driven start and a generic one), optionally the
posterior around it (:func:`~matfit.fitting.sample_posterior`), a report
(:func:`~matfit.report.write_report`), the model file (:func:`~matfit.export.save_model`), exports
to renderers (:func:`~matfit.export.export`) and a comparison of families
(:func:`~matfit.fitting.compare_models`). Each step prints one or a few lines through ``log``;
the returned :class:`PipelineResult` holds what every step produced.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional

import numpy as np

from .errors import ParameterError
from .table import Table

__all__ = ["PipelineResult", "run_pipeline"]


@dataclass
class PipelineResult:
    """What :func:`run_pipeline` produced.

    Attributes
    ----------
    result : matfit.fitting.FitResult
        The fit.
    posterior : matfit.fitting.PosteriorResult or None
        The posterior sample (``posterior_steps > 0``).
    truth : dict or None
        The ground truth given to the pipeline (for synthetic tables).
    report : dict or None
        The report's numbers (:func:`~matfit.report.write_report`), when one was written.
    comparison : matfit.fitting.ModelComparison or None
        The comparison of families, when asked for.
    files : list of pathlib.Path
        Every file written, in order.

    Examples
    --------
    >>> import numpy as np, tempfile
    >>> from matfit import Table
    >>> from matfit.pipeline import run_pipeline
    >>> wo = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, 0.6, 0.8]]); wi = wo[[1, 2, 0]]
    >>> with tempfile.TemporaryDirectory() as d:
    ...     out = run_pipeline(Table(wo=wo, wi=wi, values=np.full((3, 3), 0.1)), "lambert", starts=1,
    ...                        save_model=f"{d}/fit.json", log=None)
    ...     names = [p.name for p in out.files]
    >>> out.posterior is None, round(float(out.result.params["albedo"][0]), 4), names
    (True, 0.3142, ['fit.json'])
    """

    result: object
    posterior: object = None
    truth: Optional[dict] = None
    report: Optional[dict] = None
    comparison: object = None
    files: list = field(default_factory=list)


def _fixed_line(result):
    """The fixed parameters of a fit (those without a label), as one line, or None."""
    free = lambda k: any(l == k or l.startswith(k + "[") for l in result.labels)  # noqa: E731
    fixed = {k: v for k, v in result.params.items() if not free(k)}
    if not fixed:
        return None
    return "  fixed: " + ", ".join(f"{k}={np.asarray(v).round(6).tolist()}" for k, v in fixed.items())


def run_pipeline(table, model=None, *, candidates=None, method=None, loss=None, fixed=None, tied=(), starts=4, max_steps=256, seed=0,
                 posterior_steps=0, truth=None, report=None, report_table=None, title=None, save_model=None,
                 source=None, export=(), compare=(), holdout=0.2, compare_json=None,
                 log: Optional[Callable] = print) -> PipelineResult:
    """Fit ``model`` to ``table``, then sample, report, save and export as asked.

    Parameters
    ----------
    table : matfit.Table
        The measurements (else :class:`~matfit.errors.ParameterError`; the steps raise their own).
    model : str, optional
        The family (a key of :data:`matfit.fitting.FAMILIES`); None chooses it by appearance
        (:func:`matfit.fitting.choose_family`, against ``truth``'s model when given, else the
        measured file the table came from), among ``candidates`` (default: those the data call for).
    candidates : sequence of str, optional
    method, loss, fixed, tied
        As for :func:`matfit.fitting.fit` (``method`` default :data:`~matfit.fitting.DEFAULT_METHOD`;
        ``loss`` ``"l2"`` for a named family, ``"e2"`` when chosen); ``fixed`` holds for the posterior
        too.
    starts, max_steps : int, default 4, 256
        Starts of each of the two fits of :func:`~matfit.fitting.robust_fit`; solver steps per start.
    seed : int, default 0
        Seed of the fit's starts, the sampler and the comparison's split.
    posterior_steps : int, default 0
        Cap on MCMC steps of the posterior sample around the fit (0: no posterior). The noise
        model is the table's ``sigma`` when it has one and the loss is ``l2``, else fitted.
    truth : dict, optional
        The ground truth of a synthetic table (:func:`data_synth.truth_from_table`): shown beside
        the fit and in the report.
    report, report_table, title : optional
        Folder of the report (:func:`matfit.report.write_report`); the table it shows (default
        ``table``; the CLI passes the whole table when it fitted a subsample); its title.
    save_model, source : optional
        Write the fitted model as a JSON model file (:func:`matfit.export.save_model`), recording
        ``source``, where the table came from.
    export : sequence of (target, path), optional
        Renderer exports (:data:`matfit.export.EXPORTERS` targets).
    compare, holdout, compare_json : optional
        Families to compare on a hold-out split (:func:`matfit.fitting.compare_models`), its
        fraction (default 0.2), and a path to write the comparison as JSON.
    log : callable or None, default print
        Where the progress lines go (None: silent).

    Returns
    -------
    PipelineResult
        What every step produced; ``files`` lists ``report.md`` (when ``report`` is given), the
        model file, the exports and the comparison's JSON, in that order.
    """
    from .fitting import DEFAULT_LOSS, DEFAULT_METHOD, robust_fit

    if not isinstance(table, Table):
        raise ParameterError(f"run_pipeline: table must be a matfit.Table, got {type(table).__name__}")
    say = log if log is not None else (lambda *a, **k: None)
    method = DEFAULT_METHOD if method is None else method
    if model is None:
        from .fitting import choose_family

        if fixed or tied:
            raise ParameterError("run_pipeline: fixed and tied name parameters of one family: name the family "
                                 "(model=..., or --model NAME)")
        ref = truth.get("model") if isinstance(truth, dict) and truth.get("model") is not None else "auto"
        say("choosing the family: fitting the candidates the data call for and rendering each beside the "
            + ("truth" if ref != "auto" else "measurement"))
        result, choice = choose_family(table, reference=ref, candidates=candidates, loss=loss, method=method, starts=starts,
                                       max_steps=max_steps, seed=seed, log=say)
        model, loss = result.family, result.loss
        say(choice.summary().splitlines()[0])
        if choice.missing:
            say("  the data show effects no family here carries: " + "; ".join(choice.missing))
        if truth is not None and truth.get("family") not in (None, model):
            truth = dict(truth, params=None)  # the truth's parameters belong to another family
    else:
        loss = DEFAULT_LOSS if loss is None else loss
        result = robust_fit(table, model, method=method, loss=loss, fixed=fixed, tied=tied, starts=starts,
                            max_steps=max_steps, seed=seed)
    out = PipelineResult(result=result, truth=truth)
    say(result.summary().splitlines()[0])
    if getattr(result, "appearance", None) is not None:
        say("appearance: " + result.appearance.summary())
    if posterior_steps:
        from .fitting import sample_posterior

        noise = "table" if table.sigma is not None and loss == "l2" else "fit"
        out.posterior = sample_posterior(table, model=model, fixed=fixed, tied=tied, loss=loss, noise=noise,
                                         start=result, max_steps=posterior_steps, seed=seed, progress=False)
        say(out.posterior.summary().splitlines()[0])
    from .report import param_table

    say(param_table(result, truth["params"] if truth else None, out.posterior))
    for w in getattr(result, "warnings", []):
        say(f"  WARNING {w}")
    line = _fixed_line(result)
    if line:
        say(line)
    if report is not None:
        from .report import write_report

        out.report = write_report(result, report_table if report_table is not None else table, report,
                                  posterior=out.posterior, truth=truth, title=title)
        cd, m = out.report["colour_difference"], out.report["metrics"]
        say(f"relative RMSE {m['relative_rmse']:.4f}" + (
            f", CIEDE2000 of the mean appearance {cd['delta_e_mean_appearance']:.3f} (per row: median "
            f"{cd['delta_e_rows_median']:.3f})" if cd else ""))
        out.files.append(Path(report) / "report.md")
        say(f"wrote report to {out.files[-1]} (+ figures and report.json)")
    if save_model is not None:
        from .export import save_model as _save

        _save(save_model, result.model, family=model, **({} if source is None else {"source": str(source)}))
        out.files.append(Path(save_model))
        say(f"wrote {save_model}")
    for target, path in export or ():
        from .export import export as _export

        r = _export(result.model, target)
        r.write(path)
        say(r.summary())
        out.files.append(Path(path))
        say(f"wrote {path}")
    if compare:
        from .fitting import compare_models

        out.comparison = compare_models(table, models=list(compare), holdout=holdout, seed=seed)
        say(out.comparison.summary())
        if compare_json is not None:
            Path(compare_json).parent.mkdir(parents=True, exist_ok=True)
            with open(compare_json, "w") as fh:
                json.dump(out.comparison.to_dict(), fh, indent=2)
            out.files.append(Path(compare_json))
    return out
