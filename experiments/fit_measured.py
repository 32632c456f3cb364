"""Fit every reflection family to every cell of measured BRDF tables; compare with every published fit.

Protocol (matfit issue #19, parts 3 and 5):

* **Tables.** MERL: the 100 surrogates of Sztrajman et al. 2021 in the MERL layout
  (``shared/tools/merl_surrogate.py``), read with :func:`matfit.io.merl.read_merl`, every cell of
  the 90 x 90 x 180 grid (:meth:`MerlBRDF.to_table`). RGL: the 7 files of ``shared/data/rgl``
  (:func:`matfit.io.load`), every row.
* **Split.** :meth:`matfit.Table.split` with ``frac = 0.8`` and seed :data:`SPLIT_SEED`: a fixed
  random 80 % of the rows (cells) for fitting, the other 20 % held out; invalid cells are dropped
  from both parts afterwards. Every MERL table has the same 1 458 000 rows, so every MERL material
  is split at the same cells and every published fit of a material is scored on exactly the cells
  matfit's fits are scored on.
* **Fits.** Each family (``--families``: any key of :data:`matfit.fitting.FAMILIES`; default every
  family that models reflection only, :func:`reflection_families`) is fitted with the default call
  ``fit(train, model=family, loss="e2")`` (default method, starts and steps). The training cells
  are padded to a fixed row count (:func:`padded`, a multiple of :data:`BUCKET`) with copies of one
  cell at weight :data:`PAD_WEIGHT`: ``fit`` drops rows of zero weight, which would give each
  material its own array shapes and so its own compilation; with the padding every MERL material
  has the same shapes and each family compiles once (and the persistent cache of
  :mod:`matfit.cache` keeps the programs across runs). The padding adds ``< 1e-150`` to the
  objective; AIC/BIC below count the real cells only.
* **Scores.** On the held-out valid cells, every cell and channel weighted equally:
  ``e2`` = mean of ``(log(1 + f cos_i) - log(1 + y cos_i))^2`` (the residuals of
  ``loss="e2"``, :func:`matfit.fitting.residuals`), and ``ngan_l2`` = root mean square of
  ``(f - y) cos_i`` (the cosine-weighted L2 of Ngan et al. 2005, ``loss="cosine"``). On the
  training cells ``aic = n log(RSS / n) + 2 p`` and ``bic = n log(RSS / n) + p log n`` with RSS the
  fit's E2 residual sum of squares and n the real residuals (as :func:`matfit.fitting.compare_models`
  defines them). **The chosen family is the one of lowest held-out E2** (the BIC choice is
  recorded too). A fit is flagged when ``FitResult.converged`` is false or its diagnostics
  (``FitResult.warnings``) say a parameter ends at a bound.
* **Published fits** (MERL only): every evaluable model of :func:`numpy_ref.published.published_fits`
  for the material (Löw CT / AS E1, E2, smooth and microfacet ABC; Bagher SGD; Ngan CT, AS,
  Blinn-Phong, Ward, Ward-Dür, Lafortune; Ngan's He et al. fits cannot be evaluated, see
  docs/published_fits.md) on the same held-out cells; ratio = held-out E2 of matfit's chosen family
  / that of the best published fit.
* **The published fits' own reading** (MERL only, :func:`own_reading`): the published fits
  minimized the E2 of Löw et al. 2012 over directions sampled the way bbm's ``lowLog`` loss samples
  them (``low_sin``, ``experiments/_low2012.py``'s ``direction_grid``: a regular (theta_i, phi_i,
  theta_o) grid with phi_o = 0, each sample weighted by sin theta_i), not over MERL cells, so on
  held-out cells they are judged by a metric they were not made for. The protocol is therefore
  repeated in their reading: every family of :data:`OWN_FAMILIES` fitted with ``loss="e2"`` and weights sin theta_i on the
  :data:`LOW_SIN_TRAIN` grid of the surrogate network's own values, and scored, like every
  published fit and like the cells protocol's chosen model, on the :data:`LOW_SIN_TEST` grid (other
  directions); ``own_reading.ratio`` = E2 of the best family there / that of the best published fit.
* **Output.** ``experiments/results/fit_measured/<kind>_<name>.json`` per material as soon as it is
  done (a rerun skips the families a file already has); a report of the chosen family
  (:func:`matfit.report.write_report`, on the held-out cells: relative RMSE, CIEDE2000) under
  ``experiments/results/reports/<name>/``; the page ``experiments/results/fit_measured.md`` and the
  plot ``fit_measured_ratio.png`` rebuilt from the JSON files at the end (or with ``--summary``).

Usage: python experiments/fit_measured.py [SHARED] [--quick] [--families a,b] [--materials a,b]
       [--rgl a,b] [--skip-merl] [--skip-rgl] [--no-report] [--summary] [--low-sin]
"""
from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
OUT = REPO / "experiments" / "results"
ITEMS = OUT / "fit_measured"
REPORTS = OUT / "reports"
CACHES = (REPO / "benchmarks" / "results" / "cache", OUT / "cache")  # surrogate .binary files, read first
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

#: Fraction of the cells fitted, and the seed of the split (:meth:`matfit.Table.split`).
TRAIN_FRACTION = 0.8
SPLIT_SEED = 0
#: Training tables are padded up to a multiple of this many rows (one compiled solver per family).
BUCKET = 1 << 15
#: Weight of the padding rows: positive, so that ``fit`` keeps them (shapes stay fixed), and
#: small enough that they change no objective, gradient or step.
PAD_WEIGHT = 1e-300
#: Families that model transmission as well: a reflection table cannot constrain them.
TRANSMISSIVE = ("dielectric",)
#: ``--quick``: four MERL surrogates (a plastic, a paint, a metal, a metallic paint) and one RGL file.
QUICK_MERL = ("white-paint", "red-plastic", "nickel", "blue-metallic-paint")
QUICK_RGL = ("paper_white_rgb",)
#: The spread of MERL materials of the earlier 1,500-row protocol (experiments/validate_low2012.py reads it).
MATERIALS = ["red-plastic", "yellow-matte-plastic", "black-phenolic", "blue-acrylic", "aluminium", "brass",
             "nickel", "gold-metallic-paint", "blue-metallic-paint", "white-paint", "beige-fabric", "pink-felt"]


def reflection_families():
    """The registry's families that model reflection only (every key of FAMILIES but TRANSMISSIVE)."""
    from matfit.fitting import FAMILIES

    return [f for f in FAMILIES if f not in TRANSMISSIVE]


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("shared", nargs="?", default=str(REPO.parent / "shared"),
                    help="shared folder (default: ../shared relative to the repo root)")
    ap.add_argument("--quick", action="store_true",
                    help=f"only MERL {', '.join(QUICK_MERL)} and RGL {', '.join(QUICK_RGL)}")
    ap.add_argument("--families", default=None,
                    help="comma-separated family names, any key of matfit.fitting.FAMILIES "
                         "(default: every reflection family)")
    ap.add_argument("--materials", default=None, help="comma-separated MERL names (default: all 100)")
    ap.add_argument("--rgl", default=None, help="comma-separated RGL file stems (default: every .bsdf)")
    ap.add_argument("--skip-merl", action="store_true")
    ap.add_argument("--skip-rgl", action="store_true")
    ap.add_argument("--no-report", action="store_true", help="no write_report per material")
    ap.add_argument("--summary", action="store_true", help="only rebuild the page from the JSON files")
    ap.add_argument("--low-sin", action="store_true",
                    help="only the passes after the fits (where missing): where each MERL loss lies, the "
                         "comparison in the published fits' own reading (low_sin), the RGL claims; then the page")
    return ap.parse_args(argv)


def check_families(names):
    """``names`` (a comma-separated string or a list) as a list of registry keys; a clear error otherwise."""
    from matfit.fitting import FAMILIES

    fams = [f.strip() for f in names.split(",") if f.strip()] if isinstance(names, str) else list(names)
    bad = [f for f in fams if f not in FAMILIES]
    if bad or not fams:
        raise SystemExit(f"fit_measured: --families must name families of matfit.fitting.FAMILIES "
                         f"({', '.join(FAMILIES)}); unknown: {bad or 'none given'}")
    return fams


# ------------------------------------------------------------------ tables
def split_cells(table, frac=TRAIN_FRACTION, seed=SPLIT_SEED):
    """``(train, heldout)``: :meth:`Table.split` of all rows, then each part's valid rows only."""
    fit_part, hold_part = table.split(frac, seed=seed)
    return fit_part.select(fit_part.valid), hold_part.select(hold_part.valid)


def padded(table, bucket=BUCKET):
    """``table`` (valid rows, unit weight) padded with copies of its first row at weight
    :data:`PAD_WEIGHT` up to the next multiple of ``bucket`` rows; and the real row count."""
    from matfit import Table

    n = len(table)
    m = max(bucket, -(-n // bucket) * bucket)
    idx = np.concatenate([np.arange(n), np.zeros(m - n, dtype=int)])
    w = np.ones((m, table.n_channels))
    w[n:] = PAD_WEIGHT
    t = Table(wo=table.wo[idx], wi=table.wi[idx], values=table.values[idx], weight=w, channels=table.channels,
              provenance={**table.provenance, "padding": f"{m - n} copies of row 0 at weight {PAD_WEIGHT:g}"})
    return t, n


def scores(pred, table):
    """Held-out scores of predictions ``pred`` (N, C) on ``table`` (valid rows, unit weights):
    ``e2`` (mean squared E2 residual) and ``ngan_l2`` (RMS cosine-weighted difference), both from
    :func:`matfit.fitting.residuals`."""
    import jax.numpy as jnp

    from matfit.fitting import residuals

    w = jnp.ones_like(jnp.asarray(table.values))
    args = (jnp.asarray(pred, dtype=float), jnp.asarray(table.values), w, jnp.asarray(table.wi[:, 2]))
    e2 = float(jnp.mean(residuals(*args, loss="e2") ** 2))
    ngan = float(jnp.sqrt(jnp.mean(residuals(*args, loss="cosine") ** 2)))
    return {"e2": e2, "ngan_l2": ngan}


def predict(model, table):
    """A matfit model's BRDF (N, C) at the rows of ``table`` (float64 numpy)."""
    import jax.numpy as jnp

    return np.asarray(model.eval(jnp.asarray(table.wo), jnp.asarray(table.wi)), dtype=np.float64)


def jsonable(x):
    if isinstance(x, dict):
        return {k: jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, (np.floating, np.integer, np.bool_)):
        return x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


# ------------------------------------------------------------------ one material
def fit_family(train, n_real, heldout, fam):
    """The default ``fit(train, model=fam, loss="e2")``, and its record: held-out scores, AIC/BIC on
    the ``n_real`` real training rows, convergence and bound warnings as the fit reports them."""
    from matfit.fitting import fit
    from matfit.fitting.select import information_criteria

    t0 = time.perf_counter()
    res = fit(train, model=fam, loss="e2")
    seconds = time.perf_counter() - t0
    n, p = n_real * train.n_channels, len(res.labels)
    aic, bic = information_criteria(res.rss, n, p)
    warns = list(res.warnings or [])
    rec = {"held_out": scores(predict(res.model, heldout), heldout), "train_e2": 2 * res.objective / n,
           "aic": aic, "bic": bic, "p": p, "n": n,
           "converged": bool(res.converged), "steps": int(res.steps), "seconds": seconds,
           "at_bound": [w for w in warns if w.startswith("at a bound")], "warnings": warns, "info": list(res.info),
           "params": {k: jsonable(np.asarray(v)) for k, v in res.params.items()}}
    return res, rec


def published_scores(models, heldout):
    """Held-out scores of every evaluable published model ``{source: model}``; ``{source: reason}``
    for the others."""
    out, skipped = {}, {}
    for src, mdl in sorted(models.items()):
        try:
            pred = mdl(heldout.wo, heldout.wi)
        except NotImplementedError as e:
            skipped[src] = str(e).split("\n")[0][:160]
            continue
        out[src] = scores(pred, heldout)
    return out, skipped


def fit_material(table, families, published=None, rec=None, bucket=BUCKET, log=print):
    """The protocol on one table: split, every family fitted and scored, published fits scored.

    Parameters
    ----------
    table : matfit.Table
        The whole measured table (invalid rows allowed).
    families : list of str
        Keys of :data:`matfit.fitting.FAMILIES`.
    published : dict, optional
        ``{source: model}`` of numpy_ref.published models to score on the same held-out cells.
    rec : dict, optional
        A record of an earlier run: families it has are not fitted again.
    bucket : int
        Padding granularity of the training rows (:func:`padded`).

    Returns
    -------
    rec : dict
        JSON-ready: split sizes, ``fits`` per family, ``chosen`` (lowest held-out E2), ``chosen_bic``,
        ``published``, ``best_published``, ``ratio``.
    results : dict
        ``{family: FitResult}`` of the families fitted in this call.
    heldout : matfit.Table
        The held-out valid cells.
    """
    rec = dict(rec or {})
    train, heldout = split_cells(table)
    ptrain, n_real = padded(train, bucket)
    rec.update({"n_rows": len(table), "n_valid": int(table.n_valid), "n_train": n_real, "n_train_padded": len(ptrain),
                "n_heldout": len(heldout), "split": {"frac": TRAIN_FRACTION, "seed": SPLIT_SEED}})
    fits = dict(rec.get("fits", {}))
    results = {}
    for fam in families:
        if "held_out" in fits.get(fam, {}):  # fitted before (a failed family is tried again)
            continue
        try:
            results[fam], fits[fam] = fit_family(ptrain, n_real, heldout, fam)
        except Exception as e:  # noqa: BLE001 - one failed family must not stop the protocol
            fits[fam] = {"error": f"{type(e).__name__}: {e}"[:400]}
            log(f"  {fam}: failed: {fits[fam]['error']}")
            continue
        d = fits[fam]
        flag = ("" if d["converged"] else " NOT CONVERGED") + (f" {len(d['at_bound'])} at bound" if d["at_bound"] else "")
        log(f"  {fam}: held-out E2 {d['held_out']['e2']:.4g}, BIC {d['bic']:.5g} ({d['seconds']:.1f} s){flag}")
    rec["fits"] = fits
    ok = {f: d for f, d in fits.items() if "held_out" in d and f in families}
    rec["chosen"] = min(ok, key=lambda f: ok[f]["held_out"]["e2"]) if ok else None
    rec["chosen_bic"] = min(ok, key=lambda f: ok[f]["bic"]) if ok else None
    if published is not None:
        rec["published"], rec["published_skipped"] = published_scores(published, heldout)
        pub = rec["published"]
        rec["best_published"] = min(pub, key=lambda s: pub[s]["e2"]) if pub else None
        if rec["best_published"] and rec["chosen"]:
            rec["ratio"] = ok[rec["chosen"]]["held_out"]["e2"] / pub[rec["best_published"]]["e2"]
    return rec, results, heldout


def write_material_report(rec, results, heldout, name, title):
    """write_report on the held-out cells of the chosen family, or, where its report fails, of the
    next family by held-out E2 (``report_family`` says which; ``report_errors`` why); only
    families fitted in this run (a FitResult is needed)."""
    import shutil

    from matfit.report import write_report

    fits = rec["fits"]
    order = sorted((f for f in results if "held_out" in fits[f]), key=lambda f: fits[f]["held_out"]["e2"])
    if rec.get("chosen") not in results:
        return
    out = REPORTS / name
    shutil.rmtree(out, ignore_errors=True)  # no file of an earlier report stays next to this one
    errors = {}
    for fam in order:
        t0 = time.perf_counter()
        try:
            s = write_report(results[fam], heldout, out, title=f"{title}: {fam}, E2 loss; metrics on the held-out cells")
        except Exception as e:  # noqa: BLE001 - a report bug must not lose the fits
            errors[fam] = f"{type(e).__name__}: {e}"[:300]
            shutil.rmtree(out, ignore_errors=True)
            continue
        cd = s.get("colour_difference") or {}
        rec.update({"report": str(out.relative_to(REPO)), "report_family": fam,
                    "report_seconds": time.perf_counter() - t0, "relative_rmse": s["metrics"].get("relative_rmse"),
                    "ciede2000": cd.get("delta_e_mean_appearance"),
                    "ciede2000_rows_median": cd.get("delta_e_rows_median")})
        break
    for k in ("report_errors", "report_error"):
        rec.pop(k, None)
    if errors:
        rec["report_errors"] = errors


# ------------------------------------------------------------------ drivers
def merl_table(name, merl_surrogate):
    """The MERL table of a surrogate: a cached .binary (CACHES) or one written now (and removed after)."""
    from matfit.io.merl import read_merl

    for d in CACHES:
        if (d / f"{name}.binary").exists():
            return read_merl(d / f"{name}.binary").to_table()
    tmp = CACHES[-1] / f"{name}.binary"
    tmp.parent.mkdir(parents=True, exist_ok=True)
    merl_surrogate.write_merl(name, str(tmp))
    try:
        return read_merl(tmp).to_table()
    finally:
        tmp.unlink()


#: The ``low_sin`` reading's (theta_i, phi_i, theta_o) cell-centre grids (experiments/_low2012.py,
#: :func:`direction_grid`): fitted on the first, scored on the second, whose directions differ.
LOW_SIN_TRAIN = (30, 60, 30)
LOW_SIN_TEST = (23, 46, 23)
#: The families fitted in that reading: those the cells protocol chooses (every other family is a
#: special case of one of them: lobes1 of lobes2, conductor and plastic of metal2 and car_paint).
OWN_FAMILIES = ("diffuse_specular", "car_paint", "metal2", "lobes2", "lobes3")


def recorded_model(rec, fam, channels):
    """The model of family ``fam`` built from the parameters a record holds (float64)."""
    import jax.numpy as jnp

    from matfit.fitting import FAMILIES

    values = {k: jnp.asarray(v, dtype=jnp.float64) for k, v in rec["fits"][fam]["params"].items()}
    return FAMILIES[fam].build(values, channels)


def low_sin_data(name, grid, merl_surrogate):
    """The ``low_sin`` samples of MERL material ``name``: ``wo, wi`` (N, 3), the weights sin theta_i
    (N,) and the surrogate network's BRDF (N, 3) at those very directions (no table lookup)."""
    from _low2012 import direction_grid
    from matfit.io import dirs_to_half_diff

    wo, wi, w = direction_grid(*grid)
    th, _, td, pd = dirs_to_half_diff(wo, wi)
    return wo, wi, w, merl_surrogate.network_brdf(name, th, td, np.mod(pd, np.pi))


def own_reading(rec, published, merl_surrogate, families):
    """The comparison under the published fits' own reading (``low_sin``) for one MERL material.

    Every family is fitted by the default call ``fit(table, model=family, loss="e2")`` on the
    :data:`LOW_SIN_TRAIN` samples with weights sin theta_i (so the fit minimizes that reading's E2),
    and scored, like every published fit, by the weighted E2 on the :data:`LOW_SIN_TEST` samples.
    The chosen family of the cells protocol (``rec["chosen"]``, rebuilt from its parameters) is
    scored there too. Returns the JSON-ready record (``chosen`` = lowest test E2, ``ratio`` = its E2
    / the best published one's).
    """
    import jax.numpy as jnp

    from _low2012 import e2_weighted
    from matfit import Table
    from matfit.fitting import fit

    name = rec["material"]
    wo, wi, w, y = low_sin_data(name, LOW_SIN_TRAIN, merl_surrogate)
    two, twi, tw, ty = low_sin_data(name, LOW_SIN_TEST, merl_surrogate)

    def score(model):
        return e2_weighted(np.asarray(model.eval(jnp.asarray(two), jnp.asarray(twi))), ty, twi[:, 2], tw)

    table = Table(wo=wo, wi=wi, values=y, weight=np.repeat(w[:, None], y.shape[1], 1),
                  provenance={"source": f"merl_surrogate {name}", "reading": f"low_sin {LOW_SIN_TRAIN}"})
    out = {"train_grid": list(LOW_SIN_TRAIN), "test_grid": list(LOW_SIN_TEST), "fits": {}}
    for fam in families:
        try:
            res = fit(table, model=fam, loss="e2")
        except Exception as e:  # noqa: BLE001 - one failed family must not stop the protocol
            out["fits"][fam] = {"error": f"{type(e).__name__}: {e}"[:400]}
            continue
        out["fits"][fam] = {"e2": score(res.model), "converged": bool(res.converged),
                            "at_bound": [x for x in (res.warnings or []) if x.startswith("at a bound")],
                            "params": {k: jsonable(np.asarray(v)) for k, v in res.params.items()}}
    ok = {f: d for f, d in out["fits"].items() if "e2" in d}
    if ok:
        out["chosen"] = min(ok, key=lambda f: ok[f]["e2"])
    if rec.get("chosen"):
        fam = rec["chosen"]
        out["cells_fit"] = {"family": fam, "e2": score(recorded_model(rec, fam, y.shape[1]))}
    pub = {}
    for src, mdl in sorted((published or {}).items()):
        try:
            pub[src] = e2_weighted(mdl(two, twi), ty, twi[:, 2], tw)
        except NotImplementedError:
            continue
    out["published"] = pub
    if pub and ok:
        out["best_published"] = min(pub, key=pub.get)
        out["ratio"] = ok[out["chosen"]]["e2"] / pub[out["best_published"]]
    return out


#: Disjoint regions of the held-out cells (Rusinkiewicz angles in degrees) over which a loss is
#: broken down: grazing first, then by the distance of the half vector from the normal.
REGIONS = (("grazing (theta_d >= 70)", lambda th, td: td >= 70),
           ("mirror peak (theta_h < 2)", lambda th, td: (td < 70) & (th < 2)),
           ("near mirror (theta_h 2-10)", lambda th, td: (td < 70) & (th >= 2) & (th < 10)),
           ("lobe tail (theta_h 10-30)", lambda th, td: (td < 70) & (th >= 10) & (th < 30)),
           ("off-specular (theta_h >= 30)", lambda th, td: (td < 70) & (th >= 30)))


def loss_regions(rec, published, heldout):
    """Where a loss comes from: each :data:`REGIONS` part's contribution to the held-out E2 (its
    cells' sum of the per-cell E2 / all held-out cells) of the chosen family and of the best
    published fit, ``{region: {"cells", "chosen", "published"}}``."""
    from matfit.io import dirs_to_half_diff

    fam = rec["chosen"]
    model = recorded_model(rec, fam, heldout.n_channels)

    def per_cell(pred):  # the squared E2 residuals that scores() averages, per cell (mean over channels)
        import jax.numpy as jnp

        from matfit.fitting import residuals

        y = jnp.asarray(heldout.values)
        r = residuals(jnp.asarray(pred, dtype=float), y, jnp.ones_like(y), jnp.asarray(heldout.wi[:, 2]), loss="e2")
        return np.mean(np.asarray(r, dtype=np.float64) ** 2, 1)

    e_m = per_cell(predict(model, heldout))
    e_p = per_cell(published[rec["best_published"]](heldout.wo, heldout.wi))
    th, _, td, _ = dirs_to_half_diff(heldout.wo, heldout.wi)
    th, td, n = np.degrees(th), np.degrees(td), len(heldout)
    out = {}
    for label, inside in REGIONS:
        m = inside(th, td)
        out[label] = {"cells": int(m.sum()), "chosen": float(e_m[m].sum() / n), "published": float(e_p[m].sum() / n)}
    return out


def check_claims(rec, train, max_steps=1024):
    """What each fit of a record claims, checked against the fit itself (RGL files; ``train`` the
    padded training table): the parameters within :data:`matfit.fitting.diagnostics.BOUND_TOL` of a
    family bound, recounted from the recorded values and bounds, against the fit's own bound
    warnings; and a fit that claims convergence, restarted from its solution with ``max_steps``
    steps, against its recorded objective (``rel_drop``: how much lower the restart ends)."""
    from matfit.fitting import FAMILIES, fit
    from matfit.fitting.diagnostics import BOUND_TOL

    out = {}
    for fam, d in rec["fits"].items():
        if "params" not in d:
            continue
        n_at, init = 0, {}
        for p in FAMILIES[fam].params:
            v = np.asarray(d["params"][p.name], float)
            span = p.upper - p.lower if np.isfinite(p.upper) else 1.0
            n_at += int(np.sum(((v - p.lower) <= BOUND_TOL * span) | ((p.upper - v) <= BOUND_TOL * span)))
            # a start strictly inside the open range (a value rounded onto its bound is not one)
            init[p.name] = np.clip(v, p.lower + 1e-9 * span, p.upper - 1e-9 * span if np.isfinite(p.upper) else np.inf)
        c = {"at_bound_warned": len(d["at_bound"]), "at_bound_recounted": n_at, "converged": d["converged"]}
        if d["converged"]:
            claimed = 0.5 * d["train_e2"] * d["n"]
            again = fit(train, model=fam, loss="e2", init=init, starts=1, max_steps=max_steps)
            c["rel_drop"] = (claimed - again.objective) / claimed
        out[fam] = c
    return out


def add_claims(paths):
    """:func:`check_claims` for the RGL files of ``paths`` fitted before (where missing)."""
    from matfit.io import load

    for p in paths:
        jpath = ITEMS / f"rgl_{p.stem}.json"
        if not jpath.exists():
            continue
        rec = json.loads(jpath.read_text())
        if set(rec.get("claims", {})) >= {f for f, d in rec["fits"].items() if "params" in d}:
            continue
        train, _ = split_cells(load(p))
        rec["claims"] = check_claims(rec, padded(train)[0])
        jpath.write_text(json.dumps(jsonable(rec), indent=1))
        worst = max((c.get("rel_drop", 0) for c in rec["claims"].values()), default=0)
        print(f"[rgl] {p.stem}: claims checked, largest drop on a restart {worst:.2g}", flush=True)


def add_loss_regions(names, pub, merl_surrogate):
    """:func:`loss_regions` for every MERL material of ``names`` that matfit loses (ratio > 1) and
    whose JSON has no breakdown for its chosen family (written back to the JSON)."""
    for n in names:
        jpath = ITEMS / f"merl_{n}.json"
        if not jpath.exists():
            continue
        rec = json.loads(jpath.read_text())
        if rec.get("ratio", 0) <= 1 or rec.get("loss_regions", {}).get("family") == rec["chosen"]:
            continue
        _, heldout = split_cells(merl_table(n, merl_surrogate))
        rec["loss_regions"] = {"family": rec["chosen"], "regions": loss_regions(rec, pub.get(n, {}), heldout)}
        jpath.write_text(json.dumps(jsonable(rec), indent=1))


def add_own_reading(names, pub, merl_surrogate, families):
    """:func:`own_reading` for every MERL material of ``names`` with a JSON file and no
    ``own_reading`` entry with every family of ``families`` (written back to the JSON)."""
    for n in names:
        jpath = ITEMS / f"merl_{n}.json"
        if not jpath.exists():
            continue
        rec = json.loads(jpath.read_text())
        have = rec.get("own_reading", {}).get("fits", {})
        if all("e2" in have.get(f, {}) for f in families):
            continue
        t0 = time.perf_counter()
        rec["own_reading"] = own_reading(rec, pub.get(n, {}), merl_surrogate, families)
        rec["own_reading"]["seconds"] = time.perf_counter() - t0
        jpath.write_text(json.dumps(jsonable(rec), indent=1))
        o = rec["own_reading"]
        print(f"[merl] {n} (low_sin reading): chosen {o.get('chosen')} E2 {o['fits'].get(o.get('chosen'), {}).get('e2', float('nan')):.4g}, "
              f"ratio {o.get('ratio', float('nan')):.3g} vs {o.get('best_published')} ({o['seconds']:.0f} s)", flush=True)


def run_one(kind, name, families, get_table, published, args):
    """Fit one material and write its JSON (and report); None where it was done before (skipped)."""
    jpath = ITEMS / f"{kind}_{name}.json"
    old = json.loads(jpath.read_text()) if jpath.exists() else {"kind": kind, "material": name}
    if all("held_out" in old.get("fits", {}).get(f, {}) for f in families) and (published is None or "published" in old):
        print(f"[{kind}] {name}: done before, skipped", flush=True)
        return None
    print(f"[{kind}] {name}", flush=True)
    t0 = time.perf_counter()
    rec, results, heldout = fit_material(get_table(), families, published, rec=old,
                                         log=lambda s: print(s, flush=True))
    if not args.no_report:
        write_material_report(rec, results, heldout, name, f"{kind.upper()} {name}")
    rec["seconds"] = rec.get("seconds", 0) + time.perf_counter() - t0
    jpath.write_text(json.dumps(jsonable(rec), indent=1))
    r = f", ratio {rec['ratio']:.3g} vs {rec['best_published']}" if rec.get("ratio") is not None else ""
    print(f"[{kind}] {name}: chosen {rec['chosen']}{r} ({time.perf_counter() - t0:.0f} s)", flush=True)
    return rec


def main(argv=None):
    args = parse_args(argv)
    shared = Path(args.shared).resolve()
    need = [shared / "tools" / "merl_surrogate.py", shared / "data" / "published_fits", shared / "data" / "rgl"]
    missing = [str(p) for p in need if not p.exists()]
    if missing:
        sys.exit(f"fit_measured: shared folder {shared} is missing or incomplete; not found: {', '.join(missing)}.\n"
                 f"Pass the shared folder as the first argument (default: ../shared relative to the repo root).")
    ITEMS.mkdir(parents=True, exist_ok=True)
    if args.summary:
        return write_summary(None)
    import jax

    jax.config.update("jax_enable_x64", True)
    from matfit.cache import enable_compilation_cache

    enable_compilation_cache()
    families = check_families(args.families) if args.families else reflection_families()
    sys.path.insert(0, str(shared / "tools"))
    import merl_surrogate

    from matfit.io import load
    from numpy_ref.published import published_fits

    pub = published_fits(shared)
    available = set(merl_surrogate.materials())
    names = list(QUICK_MERL) if args.quick else (args.materials.split(",") if args.materials else sorted(available))
    unknown = [n for n in names if n not in available]
    if unknown:
        sys.exit(f"fit_measured: no surrogate for MERL material(s) {unknown}; see merl_surrogate.py --list")
    rgl = sorted((shared / "data" / "rgl").glob("*.bsdf"))
    wanted = QUICK_RGL if args.quick else (args.rgl.split(",") if args.rgl else None)
    if wanted is not None:
        rgl = [p for p in rgl if p.stem in wanted]
    if args.low_sin:
        add_loss_regions(names, pub, merl_surrogate)
        add_own_reading(names, pub, merl_surrogate, [f for f in OWN_FAMILIES if f in families])
        add_claims(rgl)
        return write_summary(None)
    T0 = time.perf_counter()
    fitted = 0
    if not args.skip_merl:
        for n in names:
            fitted += run_one("merl", n, families, lambda n=n: merl_table(n, merl_surrogate), pub.get(n, {}), args) is not None
    if not args.skip_rgl:
        for p in rgl:
            fitted += run_one("rgl", p.stem, families, lambda p=p: load(p), None, args) is not None
    wall = time.perf_counter() - T0
    print(f"fits done in {wall:.0f} s", flush=True)
    if not args.skip_merl:
        add_loss_regions(names, pub, merl_surrogate)
        add_own_reading(names, pub, merl_surrogate, [f for f in OWN_FAMILIES if f in families])  # the published fits' own reading
    if not args.skip_rgl:
        add_claims(rgl)
    write_summary({"wall_s": wall, "quick": args.quick, "families": families, "n_merl": 0 if args.skip_merl else len(names),
                   "n_rgl": 0 if args.skip_rgl else len(rgl), "n_fitted": fitted})


# ------------------------------------------------------------------ summary
def _g(v, nd=3):
    return f"{v:.{nd}g}" if isinstance(v, (int, float)) and not isinstance(v, bool) else "-"


def _why(rec):
    """What can be seen of a loss: the published model that wins, where on the held-out cells the
    excess error lies (:func:`loss_regions`), and the chosen family's flags."""
    d = rec["fits"][rec["chosen"]]
    why = [f"chosen {rec['chosen']}", f"best published {rec['best_published']}"]
    regions = rec.get("loss_regions", {}).get("regions")
    if regions:
        excess = {k: v["chosen"] - v["published"] for k, v in regions.items()}
        worst = sorted(excess, key=excess.get, reverse=True)
        parts = [f"{k}, {regions[k]['cells']} cells: {regions[k]['chosen']:.3g} against {regions[k]['published']:.3g}"
                 for k in worst[:2] if excess[k] > 0]
        better = [k for k in worst if excess[k] < 0]
        if parts:
            why.append(f"held-out E2 (net excess {sum(excess.values()):.3g}) lost in " + "; ".join(parts)
                       + (f"; won back in {', '.join(better)}" if better else ""))
    if not d["converged"]:
        why.append("not converged")
    if d["at_bound"]:
        why.append("at bound: " + "; ".join(w.split(":")[1].split(" is at")[0].strip() for w in d["at_bound"]))
    return ", ".join(why)


def _report_link(r):
    if "report" not in r:
        return "no report" + (f" ({'; '.join(r['report_errors'])} failed)" if r.get("report_errors") else "")
    other = f" ({r['report_family']}: the chosen family's report failed)" if r["report_family"] != r["chosen"] else ""
    return f"[report](reports/{r['material']}/report.md){other}"


def estimate(merl, rgl):
    """Seconds of a full run (100 MERL + 7 RGL) estimated from the per-material times of a partial one."""
    ts = sorted((r["seconds"] for r in merl if "seconds" in r), reverse=True)
    tr = [r["seconds"] for r in rgl if "seconds" in r]
    if len(ts) < 2 or not tr:
        return None
    return ts[0] + 99 * float(np.median(ts[1:])) + 7 * max(tr)  # ts[0]: the one that compiled


def plot_ratios(merl, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rs = sorted((r["ratio"], r["material"]) for r in merl if r.get("ratio") is not None)
    if not rs:
        return
    fig, ax = plt.subplots(figsize=(max(6, 0.12 * len(rs) + 2), 4))
    x = np.arange(len(rs))
    v = np.array([a for a, _ in rs])
    col = np.where(v <= 1, "tab:blue", "tab:red")
    ax.vlines(x, np.minimum(v, 1.0), np.maximum(v, 1.0), colors=col, lw=2)  # from the break-even line
    ax.scatter(x, v, c=col, s=14, zorder=3)
    ax.set_ylim(min(v.min(), 0.5) / 1.5, max(v.max(), 1.0) * 1.5)
    ax.axhline(1.0, color="k", lw=0.8)
    ax.axhline(0.5, color="k", lw=0.8, ls="--")
    ax.set_yscale("log")
    ax.set_ylabel("held-out E2: matfit chosen / best published")
    if len(rs) <= 40:
        ax.set_xticks(x)
        ax.set_xticklabels([n for _, n in rs], rotation=90, fontsize=7)
    else:
        ax.set_xlabel("MERL materials, sorted")
    ax.set_title(f"{len(rs)} MERL materials: {int((v <= 1).sum())} won by matfit, median ratio {np.median(v):.3g}")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def own_reading_section(merl):
    """The page's section on the comparison in the published fits' own reading (:func:`own_reading`)."""
    rows = [r for r in merl if r.get("own_reading", {}).get("ratio") is not None]
    if not rows:
        return []
    own = np.array([r["own_reading"]["ratio"] for r in rows])
    cells = np.array([r["own_reading"]["cells_fit"]["e2"] / r["own_reading"]["published"][r["own_reading"]["best_published"]]
                      for r in rows if "cells_fit" in r["own_reading"]])
    o0 = rows[0]["own_reading"]
    L = ["", "### In the published fits' own reading (`low_sin`)", "",
         "The published fits minimized E2 over directions sampled the way bbm's `lowLog` loss samples them "
         "(a regular theta_i, phi_i, theta_o grid with phi_o = 0, each sample weighted by sin theta_i), not over "
         "MERL cells, so the ratios above judge them by a metric they were not made for. Here every family of "
         f"`OWN_FAMILIES` is fitted by the default `fit(table, model=family, loss=\"e2\")` on the surrogate's values "
         f"at a {'x'.join(map(str, o0['train_grid']))} grid with weights sin theta_i, and every model is scored on a "
         f"{'x'.join(map(str, o0['test_grid']))} grid of other directions.", "",
         f"matfit wins on **{int((own <= 1).sum())} of {own.size}** materials; median ratio **{np.median(own):.3g}** "
         f"(quartiles {np.percentile(own, 25):.3g}, {np.percentile(own, 75):.3g}). The model chosen on cells, scored in "
         f"this reading, has a median ratio of {np.median(cells):.3g} and wins on {int((cells <= 1).sum())} of "
         f"{cells.size}: the two readings weight the directions so differently that a fit made for one loses in the "
         "other, whichever side made it.", "",
         "| material | chosen | E2 chosen | best published | E2 published | ratio | cells-chosen model, ratio |",
         "|---|---|---|---|---|---|---|"]
    for r in sorted(rows, key=lambda r: r["own_reading"]["ratio"]):
        o = r["own_reading"]
        cf = o.get("cells_fit")
        L.append(f"| {r['material']} | {o['chosen']} | {_g(o['fits'][o['chosen']]['e2'])} | {o['best_published']} | "
                 f"{_g(o['published'][o['best_published']])} | {_g(o['ratio'])} | "
                 f"{(cf['family'] + ', ' + _g(cf['e2'] / o['published'][o['best_published']])) if cf else '-'} |")
    lost = [r for r in rows if r["own_reading"]["ratio"] > 1]
    L += ["", "Where matfit loses in this reading:", ""]
    L += [f"- **{r['material']}** (ratio {r['own_reading']['ratio']:.3g}): chosen {r['own_reading']['chosen']}, "
          f"best published {r['own_reading']['best_published']}." for r in lost] or ["None."]
    return L


def write_summary(run):
    import jax

    merl = [json.loads(p.read_text()) for p in sorted(ITEMS.glob("merl_*.json"))]
    rgl = [json.loads(p.read_text()) for p in sorted(ITEMS.glob("rgl_*.json"))]
    summary = OUT / "fit_measured.json"
    if run is not None:
        run["machine"] = {"platform": platform.platform(), "cpus": os.cpu_count(), "jax": jax.__version__}
    elif summary.exists():
        run = json.loads(summary.read_text()).get("run")
    summary.write_text(json.dumps({"run": run, "merl": merl, "rgl": rgl}, indent=1))
    merl = [r for r in merl if r.get("chosen")]
    run = run or {}
    plot_ratios(merl, OUT / "fit_measured_ratio.png")
    fams = sorted({f for r in merl + rgl for f in r.get("fits", {})})
    ratios = np.array([r["ratio"] for r in merl if r.get("ratio") is not None])
    wins = int((ratios <= 1).sum())
    L = ["# Measured materials: every family on every cell, against every published fit", "",
         "`experiments/fit_measured.py` (protocol in its docstring; one JSON per material in `fit_measured/`, "
         "reports in `reports/<name>/`).", ""]
    # the protocol's time: every material's own recorded seconds (its fits, held-out scores and report,
    # with the compilations where they happened), summed over the invocations that fitted them
    secs = [r["seconds"] for r in merl + rgl if "seconds" in r]
    complete = len(merl) >= 100 and len(rgl) >= 7
    if secs:
        L += [f"**Protocol time{' (complete: 100 MERL + 7 RGL)' if complete else ''}**: {sum(secs):.0f} s "
              f"({sum(secs) / 3600:.2f} h) for the {len(merl)} MERL + {len(rgl)} RGL materials recorded, the sum of "
              "each material's own time (fits of every family, held-out scores, report; the compilations counted "
              "where they happened), which adds up the invocations that fitted them.", ""]
    if run:
        fitted = run.get("n_fitted")
        what = (f", {fitted} of them fitted in it and the rest done before (skipped at no cost)"
                if fitted is not None else "; materials done before were skipped at no cost")
        L += [f"Last invocation: {'`--quick`, ' if run.get('quick') else ''}{run['n_merl']} MERL + {run['n_rgl']} RGL "
              f"materials{what}; families {', '.join(run['families'])}; wall time {run['wall_s']:.0f} s "
              f"({run['wall_s'] / 60:.1f} min) on {run['machine']['cpus']} shared CPUs, JAX {run['machine']['jax']}, "
              "float64.", ""]
        est = estimate(merl, rgl)
        if run.get("quick") and est and not complete:
            L += [f"**Estimated full run** (100 MERL + 7 RGL) from this run: {est / 60:.0f} min (the longest MERL "
                  "material's time, which includes the compilations, plus 99 times the median of the other MERL "
                  "materials, plus 7 times the longest RGL file, which includes the RGL compilations).", ""]
    L += ["**Split**: `Table.split(0.8, seed=0)` of every row (cell) of the table, then the valid cells of each "
          "part: 80 % of the cells fitted, 20 % held out, the same cells for every MERL material and for the "
          "published fits. **Fit**: `fit(train, model=family, loss=\"e2\")`, the default method, starts and steps, "
          "on every training cell (padded to a fixed row count with weight-1e-300 rows so that one compiled solver "
          "serves every material). **Held-out E2**: mean over held-out cells and channels of "
          "`(log(1 + f cos_i) - log(1 + y cos_i))^2`; **Ngan L2**: RMS of `(f - y) cos_i` over the same cells "
          "(Ngan et al. 2005). **Chosen family: lowest held-out E2** (the BIC choice is in the JSON, `chosen_bic`). "
          "Ratio = held-out E2 of the chosen family / that of the best published fit of the material.", "",
          "## MERL (surrogates of Sztrajman et al. 2021 in the MERL layout, not the measurements)", ""]
    if ratios.size:
        L += [f"matfit wins (ratio <= 1) on **{wins} of {ratios.size}** materials; median ratio "
              f"**{np.median(ratios):.3g}** (quartiles {np.percentile(ratios, 25):.3g}, {np.percentile(ratios, 75):.3g}).",
              "", "![ratios](fit_measured_ratio.png)", ""]
    L += ["| material | chosen | E2 chosen | best published | E2 published | ratio | Ngan L2 chosen | Ngan L2 published "
          "| BIC choice | flags | report |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in sorted(merl, key=lambda r: r.get("ratio", np.inf)):
        d = r["fits"][r["chosen"]]
        bp = r.get("published", {}).get(r.get("best_published"), {})
        flags = ", ".join((["not converged"] if not d["converged"] else []) + ([f"{len(d['at_bound'])} at bound"]
                                                                               if d["at_bound"] else [])) or "-"
        L.append(f"| {r['material']} | {r['chosen']} | {_g(d['held_out']['e2'])} | {r.get('best_published')} | "
                 f"{_g(bp.get('e2'))} | {_g(r.get('ratio'))} | {_g(d['held_out']['ngan_l2'])} | {_g(bp.get('ngan_l2'))} | "
                 f"{r['chosen_bic']} | {flags} | {_report_link(r)} |")
    lost = [r for r in merl if r.get("ratio", 0) > 1]
    L += ["", "### Where matfit loses", ""]
    L += [f"- **{r['material']}** (ratio {r['ratio']:.3g}): {_why(r)}." for r in lost] or ["None."]
    L += own_reading_section(merl)
    L += ["", "### Held-out E2 per family (MERL)", "",
          "| material | " + " | ".join(fams) + " |", "|---|" + "---|" * len(fams)]
    for r in merl:
        L.append(f"| {r['material']} | " + " | ".join(
            _g(r["fits"].get(f, {}).get("held_out", {}).get("e2")) + ("*" if r["fits"].get(f, {}).get("at_bound") else "")
            + ("!" if r["fits"].get(f, {}).get("converged") is False else "") for f in fams) + " |")
    L += ["", "`*` a parameter ends at a bound (FitResult diagnostics), `!` not converged (FitResult.converged).", "",
          "## RGL (measured, Dupuy & Jakob 2018)", "",
          "| file | valid rows (train / held out) | chosen | held-out E2 | Ngan L2 | relative RMSE | CIEDE2000 "
          "| BIC choice | flags | report |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rgl:
        if not r.get("chosen"):
            L.append(f"| {r['material']} | - | every fit failed | | | | | | | |")
            continue
        d = r["fits"][r["chosen"]]
        flags = "; ".join((["not converged"] if not d["converged"] else []) + d["at_bound"]) or "-"
        L.append(f"| {r['material']} | {r['n_train']} / {r['n_heldout']} | {r['chosen']} | {_g(d['held_out']['e2'])} | "
                 f"{_g(d['held_out']['ngan_l2'])} | {_g(r.get('relative_rmse'))} | {_g(r.get('ciede2000'))} | "
                 f"{r['chosen_bic']} | {flags} | {_report_link(r)} |")
    L += ["", "Relative RMSE (RMSE / RMS value) and CIEDE2000 (mean appearance) are the report's "
          "(`matfit.report.write_report` on the held-out rows)."]
    claims = [(r["material"], f, c) for r in rgl for f, c in r.get("claims", {}).items()]
    if claims:
        mism = [f"{m}/{f}" for m, f, c in claims if c["at_bound_warned"] != c["at_bound_recounted"]]
        conv = [(m, f, c["rel_drop"]) for m, f, c in claims if "rel_drop" in c]
        worst = max(conv, key=lambda x: x[2]) if conv else None
        L += ["", f"**Claims checked** (`check_claims`, {len(claims)} fits of {len({m for m, _, _ in claims})} files): "
              f"parameters within `BOUND_TOL` of a bound, recounted from the recorded values and the family bounds, "
              f"equal the fit's own bound warnings in {len(claims) - len(mism)} of {len(claims)} fits"
              + (f" (not in {', '.join(mism)})" if mism else "") + "; "
              + (f"the {len(conv)} fits that claim convergence, restarted from their solution with 1024 steps, end at most "
                 f"{worst[2]:.2g} (relative) below their recorded objective ({worst[0]} / {worst[1]})"
                 if worst else "no fit claims convergence") + "."]
    failed = {}
    for r in merl + rgl:
        for f, d in r.get("fits", {}).items():
            if "error" in d:
                failed.setdefault(f, []).append((r["material"], d["error"]))
    if failed:
        L += ["", "## Failed fits (recorded, tried again on a rerun)", ""]
        L += [f"- **{f}** on {len(v)} material(s) ({', '.join(m for m, _ in v[:6])}{' ...' if len(v) > 6 else ''}): "
              f"{v[0][1][:240]}" for f, v in sorted(failed.items())]
    rep_err = [(r["material"], f, e) for r in merl + rgl for f, e in r.get("report_errors", {}).items()]
    if rep_err:
        L += ["", "## Reports that failed (the next family by held-out E2 was reported instead)", ""]
        L += [f"- {m} / {f}: {e[:200]}" for m, f, e in rep_err]
    (OUT / "fit_measured.md").write_text("\n".join(L) + "\n")
    print(f"-> {OUT / 'fit_measured.md'}")


if __name__ == "__main__":
    main()
