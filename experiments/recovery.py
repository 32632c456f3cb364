"""Parameter recovery on random synthetic tables: how often do fits land within 2 % of the truth?

For each family (rough conductor, rough dielectric, plastic, car paint) draw R random true
parameter sets from the documented ranges (:data:`RANGES`), synthesize a gonioreflectometer
table with 1 % relative Gaussian noise (the table carries ``sigma = 0.01 f``), fit all R tables
with the batched fitter (:func:`matfit.fitting.fit_batch`, Levenberg-Marquardt; one compilation
per family and start count): first from the data-driven guess (:data:`STARTS`), then the tables
whose fit ends above ``chi^2 / n = REFIT_CHI2`` (a local minimum, visible to any user from the
fit's residuals) again with ``refit_starts`` starts, keeping the better fit. Count, per parameter, the fraction of fits within 2 % relative
error of the truth.

Measurement design (:data:`GEOMETRIES`)
    * Reflection-only families: a MERL-like half/difference grid (``data_synth.geometry.merl_grid``,
      ``theta_h`` squared spacing so the specular peak is sampled densely, ``theta_d`` uniform up to
      grazing, ``phi_d`` over 180 deg); the cells with a direction below the horizon are dropped.
      ``theta_d`` reaching ~88 deg is what separates a metal's ``eta`` from ``k`` (the shape of
      the Fresnel curve, not only its normal-incidence value).
    * The dielectric: a hemispherical grid (both hemispheres, transmission included).
    * Rows whose value is below ``1e-5`` of the table's maximum are dropped (a detector's
      dynamic range of 10^5).

Alongside the empirical fractions the experiment reports the Cramer-Rao prediction: for each
truth the Gauss-Newton (Fisher) standard error at the truth, and the fraction of truths for
which ``P(|N(0, se)| <= 2 %)`` -- i.e. the fraction expected from the noise alone for an
unbiased estimator that always finds the global optimum. A gap between the two means
optimizer failures (local minima); a low prediction means the design cannot resolve the
parameter at 1 % noise.

Writes experiments/results/recovery.md and recovery.json (partial results after every chunk).

Usage: python experiments/recovery.py [--reps 100] [--families conductor ...] [--chunk 10] [--part i/n]
       python experiments/recovery.py --merge [--from-partial --families F --starts S --max-steps M --chunk C]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import re
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from data_synth import geometry  # noqa: E402
from matfit import Table  # noqa: E402
from matfit.fitting import Parametrization, fit_batch, get_family  # noqa: E402

OUT = Path(__file__).parent / "results"
NOISE = 0.01
DYNAMIC_RANGE = 1e-5
TOL = 0.02
#: Tables whose first fit ends above this chi^2 per residual are refitted with more starts.
REFIT_CHI2 = 1.05

#: Ranges of the random truths (uniform; per-channel parameters drawn independently per channel).
RANGES = {
    "conductor": {"alpha": (0.05, 0.5), "eta": (0.1, 3.0), "k": (1.0, 8.0)},
    "dielectric": {"alpha": (0.05, 0.5), "eta": (1.3, 2.0)},
    "plastic": {"albedo": (0.05, 0.9), "alpha": (0.05, 0.5), "eta": (1.3, 1.8)},
    "car_paint": {"alpha_base": (0.1, 0.5), "k_base": (1.0, 8.0),
                  "alpha_coat": (0.05, 0.3), "eta_coat": (1.3, 1.8)},
}

#: Real index of aluminium at (650, 550, 450) nm (Rakic 1995): the flakes of metallic car paint.
ALUMINIUM_ETA = (1.657, 0.880, 0.521)

#: Parameters known to the user and held fixed in the fit (and in the truths). Through a clear coat
#: the metal is seen only inside Snell's window (internal angles below asin(1 / eta_coat) ~ 40 deg),
#: where a conductor's Fresnel curve is flat: the data fix its normal-incidence reflectance, not
#: eta and k apart (Cramer-Rao: 11-32 % of eta_base, k_base within 2 %; see docs/fitting.md). With
#: the flake metal's eta known, k_base carries the base colour and is identifiable.
FIXED = {"car_paint": {"eta_base": ALUMINIUM_ETA}}

#: Measurement geometry per family: (builder name, keyword arguments).
GEOMETRIES = {
    "conductor": ("merl", dict(n_theta_h=16, n_theta_d=32, n_phi_d=32)),
    "dielectric": ("hemisphere", dict(theta_i=(0.0, 30.0, 60.0), n_theta=9, n_phi=24, transmission=True)),
    "plastic": ("merl", dict(n_theta_h=8, n_theta_d=8, n_phi_d=16)),
    "car_paint": ("merl", dict(n_theta_h=8, n_theta_d=8, n_phi_d=16)),
}

#: Starts per table (the data-driven guess plus perturbed copies).
STARTS = {"conductor": 1, "dielectric": 4, "plastic": 1, "car_paint": 1}


def channels_of(family):
    """RGB tables for a family with per-channel parameters, mono ones otherwise (the dielectric)."""
    return 3 if get_family(family).has_channels else 1


def _car_paint_base_f0(par, vec):
    """Normal-incidence reflectance of the metal base seen from inside the coat, per channel:
    ``((eta - eta_c)^2 + k^2) / ((eta + eta_c)^2 + k^2)`` -- the identifiable combination of the
    base's ``eta`` and ``k`` (inside the coat the metal is only seen within Snell's window)."""
    p = par.full(par.split(vec))
    e, k, c = p["eta_base"], p["k_base"], p["eta_coat"][..., None]
    return ((e - c) ** 2 + k ** 2) / ((e + c) ** 2 + k ** 2)


#: Derived, identifiable quantities reported next to the raw parameters: name -> (labels, fn(par, vec)).
DERIVED = {"car_paint": ("base_F0", _car_paint_base_f0)}


def draw(family, rng, C):
    out = {}
    par = Parametrization(family, C, fixed=FIXED.get(family))
    for p in par.free:
        lo, hi = RANGES[family][p.name]
        out[p.name] = rng.uniform(lo, hi, C) if (p.per_channel and C > 1) else (
            rng.uniform(lo, hi, 1) if p.per_channel else rng.uniform(lo, hi))
    return out


def geometry_for(family):
    name, kw = GEOMETRIES[family]
    wo, wi, valid, info = geometry.BUILDERS[name](**kw)
    return np.asarray(wo)[valid], np.asarray(wi)[valid], info


def make_tables(family, R, rng, C, wo, wi):
    par = Parametrization(family, C, fixed=FIXED.get(family))
    ev = jax.jit(lambda z: par.model(z).eval(jnp.asarray(wo), jnp.asarray(wi)))
    truths, tables = [], []
    for _ in range(R):
        th = draw(family, rng, C)
        z = par.z_from_theta(th)
        f = np.asarray(ev(z)).reshape(len(wo), C)
        ok = np.all(np.isfinite(f), axis=1) & np.all(f > DYNAMIC_RANGE * np.max(f), axis=1)
        y = f * (1 + NOISE * rng.normal(size=f.shape))
        sigma = NOISE * np.maximum(np.abs(f), 1e-300)
        tables.append(Table(wo=wo, wi=wi, values=np.where(ok[:, None], y, 0), sigma=np.where(ok[:, None], sigma, 1.0),
                            valid=ok, channels="mono" if C == 1 else "rgb"))
        truths.append(np.asarray(par.theta_vector(z)))
    return par, np.stack(truths), tables


def fisher_cov(par, truths, tables):
    """Gauss-Newton (Fisher) covariance of the natural parameters at the truth, one per table."""
    wo = jnp.asarray(tables[0].wo)
    wi = jnp.asarray(tables[0].wi)

    def scaled(z, w):
        return (par.model(z).eval(wo, wi) * jnp.sqrt(w)).reshape(-1)

    jac = jax.jit(jax.jacfwd(scaled))
    out = []
    for t, tv in zip(tables, truths):
        z = par.z_from_theta(par.split(jnp.asarray(tv)))
        J = np.asarray(jac(z, jnp.asarray(t.effective_weight())))
        dth = np.asarray(jax.jacfwd(par.theta_vector)(z)).diagonal()
        Jt = J / dth
        out.append(np.linalg.pinv(Jt.T @ Jt))
    return np.stack(out)


def with_derived(family, par, vals, cov=None):
    """Append the family's derived quantities (and their delta-method covariance) to the values."""
    if family not in DERIVED:
        return vals, cov, []
    name, fn = DERIVED[family]
    d = np.asarray(jax.vmap(lambda v: fn(par, v))(jnp.asarray(vals)))
    labels = [f"{name}[{i}]" for i in range(d.shape[1])]
    out = np.concatenate([vals, d], axis=1)
    if cov is None:
        return out, None, labels
    G = np.asarray(jax.vmap(jax.jacfwd(lambda v: fn(par, v)))(jnp.asarray(vals)))  # (R, q, p)
    p, q = vals.shape[1], d.shape[1]
    full = np.zeros((len(vals), p + q, p + q))
    full[:, :p, :p] = cov
    full[:, p:, :p] = G @ cov
    full[:, :p, p:] = np.transpose(full[:, p:, :p], (0, 2, 1))
    full[:, p:, p:] = G @ cov @ np.transpose(G, (0, 2, 1))
    return out, full, labels


def run(family, R, seed, chunk, starts, max_steps, log, partial, rtol=1e-6, atol=1e-9, refit_starts=6, part=(0, 1)):
    """Fit the tables ``part[0]::part[1]`` of the family's R random tables (all R are drawn, so
    the truths do not depend on the split); returns the raw per-table results of that part."""
    rng = np.random.default_rng(seed)
    C = channels_of(family)
    wo, wi, info = geometry_for(family)
    par, truths, tables = make_tables(family, R, rng, C, wo, wi)
    ids = list(range(R))[part[0]::part[1]]
    truths, tables = truths[ids], [tables[j] for j in ids]
    R = len(ids)
    t0 = time.perf_counter()
    cov = fisher_cov(par, truths, tables)
    t_fisher = time.perf_counter() - t0
    log(f"{family}: {len(wo)} rows, Fisher SE for {R} truths in {t_fisher:.0f} s")
    n_res = np.array([np.count_nonzero(t.effective_weight()) for t in tables])
    chunk_s = []

    def fit_all(idx, n_starts, stage):
        vals, objs = [], []
        for i in range(0, len(idx), chunk):
            batch = [tables[j] for j in idx[i:i + chunk]]
            pad = chunk - len(batch)  # keep one batch shape: one compilation per start count
            t1 = time.perf_counter()
            v, o, labels = fit_batch(batch + [batch[-1]] * pad, model=family, fixed=FIXED.get(family), starts=n_starts,
                                     max_steps=max_steps, rtol=rtol, atol=atol)
            chunk_s.append(time.perf_counter() - t1)
            vals.append(v[:len(batch)])
            objs.append(o[:len(batch)])
            log(f"{family} {stage}: {min(i + chunk, len(idx))}/{len(idx)} fitted ({chunk_s[-1]:.0f} s)")
            partial({"family": family, "stage": stage, "done": int(sum(len(x) for x in vals)),
                     "values": np.concatenate(vals).tolist(), "truths": truths.tolist()})
        return np.concatenate(vals), np.concatenate(objs), labels

    # Pass 1: every table from its data-driven guess (plus starts - 1 perturbed copies). Pass 2: the
    # tables whose fit is statistically poor (chi^2 per residual > REFIT_CHI2: a local minimum, as a
    # user would see from the fit report) are refitted with refit_starts starts; the better one is kept.
    values, objective, labels = fit_all(list(range(R)), starts, "pass 1")
    chi2 = 2 * objective / n_res
    redo = [int(j) for j in np.flatnonzero(~(chi2 <= REFIT_CHI2))]
    log(f"{family}: {len(redo)} of {R} tables above chi^2/n = {REFIT_CHI2}: refit with {refit_starts} starts")
    if redo:
        v2, o2, _ = fit_all(redo, refit_starts, "pass 2")
        better = o2 < objective[redo]
        values[np.array(redo)[better]] = v2[better]
        objective[np.array(redo)[better]] = o2[better]
    return {"family": family, "ids": ids, "labels": list(labels), "geometry": info, "n_rows": int(len(wo)),
            "valid_rows": [int(t.valid.sum()) for t in tables], "starts": starts, "max_steps": max_steps,
            "chunk": chunk, "chunk_s": chunk_s, "fisher_wall_s": t_fisher, "rtol": rtol, "atol": atol,
            "refit_starts": refit_starts, "n_refit": len(redo), "n_refit_improved": int(np.sum(better)) if redo else 0,
            "truths": truths.tolist(), "values": values.tolist(), "objective": objective.tolist(),
            "n_res": n_res.tolist(), "fisher_cov": cov.tolist()}


def from_partial(family, path, R, seed, part, settings):
    """Raw results (as :func:`run` returns them) for the tables a run finished before it was
    stopped, read from its partial file: the objective and the Fisher covariance are recomputed."""
    d = json.loads(Path(path).read_text())
    if d.get("stage", "pass 1") != "pass 1":
        raise ValueError(f"{path}: the run was stopped in its second pass; its first-pass values are not in the file")
    C = channels_of(family)
    wo, wi, info = geometry_for(family)
    par, truths, tables = make_tables(family, R, np.random.default_rng(seed), C, wo, wi)
    ids = list(range(R))[part[0]::part[1]][:d["done"]]
    truths, tables = truths[ids], [tables[j] for j in ids]
    values = np.asarray(d["values"], float)[:len(ids)]
    assert np.allclose(truths, np.asarray(d["truths"], float)[:len(ids)]), "partial file does not match the draw"
    ev = jax.jit(lambda z: par.model(z).eval(jnp.asarray(wo), jnp.asarray(wi)))
    obj = []
    for t, v in zip(tables, values):
        f = np.asarray(ev(par.z_from_theta(par.split(jnp.asarray(v))))).reshape(len(wo), C)
        obj.append(0.5 * np.sum(t.effective_weight() * (f - t.values) ** 2))
    t0 = time.perf_counter()
    cov = fisher_cov(par, truths, tables)
    return dict(settings, family=family, ids=ids, labels=par.labels, geometry=info, n_rows=int(len(wo)),
                valid_rows=[int(t.valid.sum()) for t in tables], chunk_s=[], fisher_wall_s=time.perf_counter() - t0,
                n_refit=0, n_refit_improved=0, truths=truths.tolist(), values=values.tolist(), objective=obj,
                n_res=[int(np.count_nonzero(t.effective_weight())) for t in tables], fisher_cov=cov.tolist(),
                stopped_early=True)


def refit(family, R, seed, chunk, n_starts, max_steps, part, out, log):
    """Second pass for a family whose run stopped after its first pass: refit the tables of its
    summary (``recovery_<family>.json``) that ended above ``chi^2/n = REFIT_CHI2`` with ``n_starts``
    starts; writes ``recovery_<family>_refit<N>_part<i>of<n>.json`` after every chunk (used by --merge)."""
    summary = json.loads((out / f"recovery_{family}.json").read_text())
    chi2 = np.asarray(summary["chi2_per_residual"])
    redo = [int(j) for j in np.flatnonzero(~(chi2 <= REFIT_CHI2))]
    n_sel, redo = len(redo), redo[part[0]::part[1]]
    C = channels_of(family)
    wo, wi, _ = geometry_for(family)
    _, _, tables = make_tables(family, R, np.random.default_rng(seed), C, wo, wi)
    vals, objs, secs = [], [], []
    for i in range(0, len(redo), chunk):
        batch = [tables[j] for j in redo[i:i + chunk]]
        t1 = time.perf_counter()
        v, o, _ = fit_batch(batch + [batch[-1]] * (chunk - len(batch)), model=family, fixed=FIXED.get(family), starts=n_starts,
                            max_steps=max_steps, rtol=1e-6, atol=1e-9)
        secs.append(time.perf_counter() - t1)
        vals += v[:len(batch)].tolist()
        objs += o[:len(batch)].tolist()
        # the name carries the number of tables selected, so a later --refit (on the tables still above
        # REFIT_CHI2 after merging) does not overwrite the refits of an earlier one
        (out / f"recovery_{family}_refit{n_sel}_part{part[0]}of{part[1]}.json").write_text(json.dumps(
            {"ids": redo[:len(vals)], "values": vals, "objective": objs, "starts": n_starts, "chunk_s": secs}))
        log(f"{family} refit: {len(vals)}/{len(redo)} ({secs[-1]:.0f} s)")


def apply_refits(family, parts, out):
    """Replace first-pass fits by the refits of :func:`refit` where those reach a lower objective."""
    files = sorted(out.glob(f"recovery_{family}_refit*_part*of*.json"))
    for q in files:
        d = json.loads(q.read_text())
        for j, v, o in zip(d["ids"], d["values"], d["objective"]):
            for p in parts:
                if j in p["ids"]:
                    k = p["ids"].index(j)
                    p["extra_refit"] = p.get("extra_refit", 0) + 1
                    p["extra_refit_starts"] = d["starts"]
                    if o < p["objective"][k]:
                        p["values"][k], p["objective"][k] = v, o
                        p["extra_refit_improved"] = p.get("extra_refit_improved", 0) + 1
    return sum(sum(json.loads(q.read_text())["chunk_s"]) for q in files) if files else None


def summarize(parts):
    """Statistics of one family from the raw results of its parts (see :func:`run`)."""
    r0 = parts[0]
    family, labels = r0["family"], r0["labels"]
    order = np.argsort(np.concatenate([p["ids"] for p in parts]))
    cat = lambda key: np.concatenate([np.asarray(p[key], float) for p in parts])[order]  # noqa: E731
    truths, values, objective, n_res, cov = (cat(k) for k in ("truths", "values", "objective", "n_res", "fisher_cov"))
    chunk_s = [x for p in parts for x in p["chunk_s"]]
    par = Parametrization(family, channels_of(family), fixed=FIXED.get(family))
    R = len(truths)
    n_raw = values.shape[1]
    if parts[0].get("R_planned") is None:
        parts[0]["R_planned"] = R
    truths, cov, dlabels = with_derived(family, par, truths, cov)
    values, _, _ = with_derived(family, par, values)
    labels = list(labels) + dlabels
    se = np.sqrt(np.clip(np.diagonal(cov, axis1=1, axis2=2), 0, None))
    rel = np.abs(values - truths) / np.abs(truths)
    within = rel <= TOL
    rel_se = se / np.abs(truths)
    predicted = np.vectorize(lambda s: math.erf(TOL / (math.sqrt(2) * s)) if s > 0 else 1.0)(rel_se)
    return {
        "family": family, "R": R, "noise": NOISE, "labels": labels, "derived_labels": dlabels,
        "geometry": r0["geometry"], "n_rows": r0["n_rows"], "parts": len(parts),
        "median_valid_rows": float(np.median([v for p in parts for v in p["valid_rows"]])),
        "ranges": RANGES[family], "fixed": FIXED.get(family), "starts": r0["starts"], "max_steps": r0["max_steps"], "chunk": r0["chunk"],
        "fit_wall_s": float(sum(chunk_s)), "first_chunk_s": chunk_s[0] if chunk_s else None,
        "stopped_early": any(p.get("stopped_early", False) for p in parts),
        "refit_separately": any(p.get("refit_separately", False) for p in parts),
        "refit_wall_s": parts[0].get("refit_wall_s"), "R_planned": parts[0].get("R_planned"),
        "later_chunk_median_s": float(np.median(chunk_s[1:])) if len(chunk_s) > 1 else None,
        "fisher_wall_s": float(sum(p["fisher_wall_s"] for p in parts)),
        "fraction_within_2pct": {lab: float(within[:, i].mean()) for i, lab in enumerate(labels)},
        "predicted_within_2pct": {lab: float(predicted[:, i].mean()) for i, lab in enumerate(labels)},
        "all_params_within_2pct": float(np.all(within[:, :n_raw], axis=1).mean()),
        "rtol": r0["rtol"], "atol": r0["atol"], "refit_starts": r0["refit_starts"], "refit_chi2": REFIT_CHI2,
        "n_refit": sum(p["n_refit"] for p in parts), "n_refit_improved": sum(p["n_refit_improved"] for p in parts),
        "extra_refit": sum(p.get("extra_refit", 0) for p in parts),
        "extra_refit_improved": sum(p.get("extra_refit_improved", 0) for p in parts),
        "extra_refit_starts": max(p.get("extra_refit_starts", 0) for p in parts),
        "median_rel_err": {lab: float(np.median(rel[:, i])) for i, lab in enumerate(labels)},
        "median_rel_se": {lab: float(np.median(rel_se[:, i])) for i, lab in enumerate(labels)},
        "max_rel_se": {lab: float(np.max(rel_se[:, i])) for i, lab in enumerate(labels)},
        "chi2_per_residual": (2 * objective / n_res).tolist(),
        "median_chi2_per_residual": float(np.median(2 * objective / n_res)),
        "truths": truths.tolist(), "values": values.tolist(), "fisher_se": se.tolist(),
    }


def write_md(res, path):
    L = ["# Parameter recovery (synthetic, 1 % relative noise)", "",
         f"Generated by `experiments/recovery.py` on {time.strftime('%Y-%m-%d %H:%M')} "
         f"({platform.machine()}, {os.cpu_count()} CPUs, float64). Success = relative error <= 2 %. "
         "'Predicted' = mean over the truths of P(|N(0, se)| <= 2 %) with se the Gauss-Newton (Cramer-Rao) "
         "standard error at the truth: what an unbiased fitter that always finds the global optimum would reach.", ""]
    for r in res:
        g = r["geometry"]
        gdesc = (f"MERL-like grid {g['n_theta_h']} x {g['n_theta_d']} x {g['n_phi_d']} (theta_h, theta_d, phi_d)"
                 if g["kind"] == "merl" else
                 f"hemisphere, theta_i = {g['theta_i']}, {g['n_theta']} x {g['n_phi']} detector positions up to "
                 f"{g['theta_o_max']} deg, transmission={g['transmission']}")
        ranges = ", ".join(f"{k} in [{lo}, {hi}]" for k, (lo, hi) in r["ranges"].items())
        if r.get("fixed"):
            ranges += "; known to the user and held fixed: " + ", ".join(f"{k} = {v}" for k, v in r["fixed"].items())
        later = (f", later chunks {r['later_chunk_median_s']:.0f} s each" if r["later_chunk_median_s"] else "")
        if r.get("parts", 1) > 1:
            later += f"; summed over {r['parts']} parallel processes"
        ok = np.asarray(r["chi2_per_residual"]) <= REFIT_CHI2
        rel = np.abs(np.asarray(r["values"]) - np.asarray(r["truths"])) / np.abs(np.asarray(r["truths"]))
        stop = (f" (of {r['R_planned']} planned: the run was stopped at the session's time limit; these are the "
                f"tables it had finished, first pass only)" if r.get("stopped_early") else "")
        if r.get("refit_separately"):
            stop = (f" ({r['n_refit']} tables above chi^2/n = {REFIT_CHI2} after the first pass were refitted in the run "
                    f"with {r['refit_starts']} starts ({r['n_refit_improved']} improved); the {r['extra_refit']} still "
                    f"above were then refitted with {r['extra_refit_starts']} starts by a separate `--refit` run, "
                    f"{r['refit_wall_s']:.0f} s; {r['extra_refit_improved']} improved)")
        L += [f"## {r['family']}", "",
              f"R = {r['R']}{stop} random truths ({ranges}; per-channel parameters drawn per channel). Geometry: {gdesc}; "
              f"{r['n_rows']} rows above the horizon, median {r['median_valid_rows']:.0f} kept (dynamic range 1e5). "
              f"Fit: `fit_batch`, LM, {r['starts']} start(s), max {r['max_steps']} steps, chunks of {r['chunk']} tables"
              + (f"; {r['n_refit']} tables ended above chi^2/n = {r['refit_chi2']} and were refitted with "
                 f"{r['refit_starts']} starts ({r['n_refit_improved']} improved). "
                 if "n_refit" in r and not r.get("stopped_early") and not r.get("refit_separately") else ". ")
              + 
              (f"Wall: {r['fit_wall_s']:.0f} s fitting (first chunk incl. compilation {r['first_chunk_s']:.0f} s{later}), "
               if r["first_chunk_s"] is not None else "Wall: see the run log; ")
              + f"{r['fisher_wall_s']:.0f} s Fisher. Median chi^2 per residual {r['median_chi2_per_residual']:.3f}. ",
              f"{int(np.sum(~ok))} of {r['R']} fits end above chi^2/n = {REFIT_CHI2} (visible in the fit's residuals).", "",
              f"| parameter | within 2 % | within 2 %, fits with chi^2/n <= {REFIT_CHI2} ({int(ok.sum())}) | predicted | "
              "median rel. error | median rel. SE | max rel. SE |",
              "| --- | --- | --- | --- | --- | --- | --- |"]
        for i, lab in enumerate(r["labels"]):
            L.append(f"| {lab} | {r['fraction_within_2pct'][lab]:.0%} | {np.mean(rel[ok, i] <= TOL):.0%} | "
                     f"{r['predicted_within_2pct'][lab]:.0%} | "
                     f"{r['median_rel_err'][lab]:.2e} | {r['median_rel_se'][lab]:.2e} | {r['max_rel_se'][lab]:.2e} |")
        L += [f"| **all at once** | {r['all_params_within_2pct']:.0%} | | | | |", ""]
    Path(path).write_text("\n".join(L) + "\n")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--reps", type=int, default=100)
    ap.add_argument("--families", nargs="+", default=list(RANGES), choices=list(RANGES))
    ap.add_argument("--chunk", type=int, default=10)
    ap.add_argument("--starts", type=int, default=None, help="starts per table (default: STARTS)")
    ap.add_argument("--max-steps", type=int, default=200)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=str(OUT))
    ap.add_argument("--part", default="0/1", help="i/n: fit the tables i::n only (parallel processes), then --merge")
    ap.add_argument("--from-partial", action="store_true",
                    help="with --merge: also summarize the tables that stopped runs of --families finished "
                         "(their --starts/--max-steps/--chunk must be given as they ran)")
    ap.add_argument("--refit", action="store_true",
                    help="second pass only: refit (--part i/n) the tables of recovery_<family>.json above REFIT_CHI2")
    ap.add_argument("--merge", action="store_true",
                    help="only merge the per-family results recovery_<family>.json into recovery.md/.json")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()

    def log(msg):
        print(f"[{time.perf_counter() - t0:7.1f} s] {msg}", flush=True)

    i, n = (int(x) for x in args.part.split("/"))
    if args.refit:
        for fam in args.families:
            refit(fam, args.reps, args.seed + list(RANGES).index(fam), args.chunk, args.starts or 6, args.max_steps,
                  (i, n), out, log)
        return
    if not args.merge:  # families run one after the other here, or in parallel processes
        for fam in args.families:
            seed = args.seed + list(RANGES).index(fam)
            tag = f"{fam}_part{i}of{n}"
            r = run(fam, args.reps, seed, args.chunk, args.starts or STARTS[fam], args.max_steps, log,
                    lambda d, tag=tag: (out / f"recovery_{tag}_partial.json").write_text(json.dumps(d)), part=(i, n))
            (out / f"recovery_{tag}.json").write_text(json.dumps(r))
    for fam in RANGES:
        finals = [q for q in sorted(out.glob(f"recovery_{fam}_part*of*.json")) if not q.name.endswith("_partial.json")]
        parts = [json.loads(q.read_text()) for q in finals]
        if args.merge and args.from_partial and fam in args.families:
            settings = dict(starts=args.starts or STARTS[fam], max_steps=args.max_steps, chunk=args.chunk,
                            rtol=1e-6, atol=1e-9, refit_starts=0)
            for q in sorted(out.glob(f"recovery_{fam}*_partial.json")):
                if q.name.replace("_partial", "") in {f.name for f in finals}:
                    continue
                m = re.search(r"_part(\d+)of(\d+)_partial", q.name)
                part = (int(m[1]), int(m[2])) if m else (0, 1)
                parts.append(from_partial(fam, q, args.reps, args.seed + list(RANGES).index(fam), part, settings))
                log(f"{fam}: {len(parts[-1]['ids'])} finished tables read from {q.name}")
        if parts and (sum(len(q["ids"]) for q in parts) == args.reps or (args.merge and args.from_partial)):
            parts[0]["R_planned"] = args.reps
            refit_s = apply_refits(fam, parts, out)
            if refit_s is not None:
                for p in parts:
                    p["refit_separately"] = True
                parts[0]["refit_wall_s"] = refit_s
            (out / f"recovery_{fam}.json").write_text(json.dumps(summarize(parts), indent=1))
    res = [json.loads((out / f"recovery_{f}.json").read_text()) for f in RANGES if (out / f"recovery_{f}.json").exists()]
    (out / "recovery.json").write_text(json.dumps(res, indent=1))
    write_md(res, out / "recovery.md")
    log(f"wrote {out / 'recovery.md'}")


if __name__ == "__main__":
    main()
