"""Fit matfit families to measured BRDFs with the Löw 2012 E2 loss; compare with the published Löw fits.

MERL (neural surrogates of Sztrajman et al. 2021 in the MERL file layout, shared/tools/merl_surrogate.py):
for each material, a fit table of ``--n-rows`` direction pairs drawn as Löw's metric samples them
(bbm ``lowLog``, see experiments/_low2012.py): theta_i, phi_i, theta_o uniform, phi_o = 0, weight
sin(theta_i) (normalized to mean 1), values looked up in the MERL table with MERL's cell rule
(matfit.io.merl.MerlBRDF.lookup). matfit families are fitted with ``loss="e2"`` on that table, so
the fit minimizes the same weighted E2 that the published Löw Cook-Torrance E2 fit minimized; the
published fit (experiments/_low2012.py) is evaluated on the same rows. Secondary reading: E2 over
``--n-cells`` random valid MERL cells, every cell weighted equally (matfit's plain E2 on a MERL
table), for both.

RGL (Dupuy & Jakob 2018 measurements, shared/data/rgl/*.bsdf): every file fitted on its valid rows
(subsampled to ``--n-rgl`` where it has more; padded with zero-weight rows where it has fewer, so
all files share one compiled solver), loss ``e2`` with equal row weights.

Each material / file gets a JSON under experiments/results/fit_measured/ as soon as it is done (a
rerun skips what is there) and a report (matfit.report.write_report with the per-iteration loss
history of matfit.fitting.loss_history) for its best family under reports/<name>/. The summary
(fit_measured.md, fit_measured.json) is rebuilt from the JSON files at the end (or with --summary).

Usage: python experiments/fit_measured.py [SHARED] [--materials a,b] [--skip-rgl] [--skip-merl]
       [--extra] [--summary]
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
OUT = REPO / "experiments" / "results"
ITEMS = OUT / "fit_measured"
REPORTS = OUT / "reports"
sys.path.insert(0, str(HERE))

from _low2012 import e2_cells, e2_weighted, low_cooktorrance, parse_low_fits  # noqa: E402

# A spread: plastics, phenolic/acrylic, metals, metallic paints and paints, fabrics.
MATERIALS = ["red-plastic", "yellow-matte-plastic", "black-phenolic", "blue-acrylic", "aluminium", "brass",
             "nickel", "gold-metallic-paint", "blue-metallic-paint", "white-paint", "beige-fabric", "pink-felt"]
FAMILIES = ("plastic", "conductor")
EXTRA = {"car_paint": ["gold-metallic-paint", "blue-metallic-paint", "cc_ibiza_sunset_rgb", "cc_iris_purple_gem_rgb"]}


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("shared", nargs="?", default=str(REPO.parent / "shared"),
                    help="shared folder (default: ../shared relative to the repo root)")
    ap.add_argument("--materials", default=None, help="comma-separated MERL names (default: the built-in spread)")
    ap.add_argument("--n-rows", type=int, default=1500, help="Löw-sampled rows per MERL fit table")
    ap.add_argument("--n-cells", type=int, default=1500, help="MERL cells for the cell-uniform reading")
    ap.add_argument("--n-rgl", type=int, default=1500,
                    help="rows per RGL fit table (= --n-rows: one compiled solver serves both)")
    ap.add_argument("--starts", type=int, default=2)
    ap.add_argument("--two-inits", action="store_true", help="also fit from a generic mid-range point")
    ap.add_argument("--max-steps", type=int, default=50)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--rgl", default=None, help="comma-separated RGL file stems (default: every .bsdf)")
    ap.add_argument("--skip-rgl", action="store_true")
    ap.add_argument("--skip-merl", action="store_true")
    ap.add_argument("--extra", action="store_true", help="also fit car_paint to the metallic paints / films")
    ap.add_argument("--summary", action="store_true", help="only rebuild fit_measured.md/.json from the JSON files")
    ap.add_argument("--heldout", type=int, default=0,
                    help="evaluate the stored MERL fits and the Löw fit on N fresh Löw-sampled rows (seed + 1)")
    ap.add_argument("--x32", action="store_true", help="float32 instead of float64")
    return ap.parse_args(argv)


# ------------------------------------------------------------------ tables
def low_sampled_table(brdf, n, seed):
    """``n`` Löw-metric samples of a MERL table (see the module docstring) as a weighted Table."""
    import numpy as np

    from matfit import Table

    rng = np.random.default_rng(seed)
    ti = rng.uniform(0, np.pi / 2, n)
    pi_ = rng.uniform(0, np.pi, n)  # isotropy: phi_i in (pi, 2 pi) mirrors (0, pi) about the plane phi_o = 0
    to = rng.uniform(0, np.pi / 2, n)
    wi = np.stack([np.sin(ti) * np.cos(pi_), np.sin(ti) * np.sin(pi_), np.cos(ti)], -1)
    wo = np.stack([np.sin(to), np.zeros(n), np.cos(to)], -1)
    vals, ok = brdf.lookup(wo, wi)
    w = np.sin(ti) / np.mean(np.sin(ti))
    return Table(wo=wo, wi=wi, values=vals, valid=ok, weight=np.repeat(w[:, None], 3, 1), channels="rgb",
                 provenance={"format": "merl", "source": brdf.source,
                             "geometry": f"Löw E2 sampling: {n} uniform (theta_i, phi_i, theta_o), phi_o = 0, "
                                         f"weight sin(theta_i), seed {seed}"})


def padded(table, n, seed):
    """``n`` rows: a random subset of the valid rows, or all of them plus zero-weight copies."""
    import numpy as np

    valid = np.flatnonzero(table.valid)
    if valid.size >= n:
        return table.subsample(n, seed=seed), n
    idx = np.concatenate([valid, np.resize(valid, n - valid.size)])
    t = table.select(idx)
    ok = t.valid.copy()
    ok[valid.size:] = False
    return t.replace(valid=ok), int(valid.size)


# ------------------------------------------------------------------ fitting
def fit_family(table, fam, args):
    """fit() from the data-driven guess (``args.starts`` starts); from a generic mid-range point as well
    (as select.robust_fit does) with ``--two-inits`` or when the first fails. The better result and
    the init that gave it."""
    from matfit.fitting import FitError, fit
    from matfit.fitting.fit import initial_guess
    from matfit.fitting.params import Parametrization

    par = Parametrization(fam, table.n_channels)
    first = initial_guess(table, par)
    second = par.family.generic_start(first, [p.name for p in par.free])
    best, binit, err = None, None, None
    for init in (None, second):
        if init is not None and best is not None and not args.two_inits:
            break
        try:
            r = fit(table, model=fam, loss="e2", init=init, starts=args.starts, seed=args.seed, max_steps=args.max_steps)
        except FitError as e:
            err = e
            continue
        if best is None or r.objective < best.objective:
            best, binit = r, init
    if best is None:
        raise err
    return best, binit


def pred_of(model, wo, wi):
    import jax.numpy as jnp
    import numpy as np

    return np.asarray(model.eval(jnp.asarray(wo), jnp.asarray(wi)), dtype=np.float64)


def jsonable(x):
    import numpy as np

    if isinstance(x, dict):
        return {k: jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    return x


def fam_record(res, init, seconds):
    return {"objective": res.objective, "converged": bool(res.converged), "steps": int(res.steps), "seconds": seconds,
            "params": {k: jsonable(v) for k, v in res.params.items()},
            "labels": list(res.labels), "values": jsonable(res.values), "stderr": jsonable(res.stderr),
            "start_objectives": jsonable(res.start_objectives), "init": "generic" if init is not None else "data",
            "warnings": list(getattr(res, "warnings", []) or [])}


def report(res, init, fit_table, report_table, name, title, args):
    """Loss history (re-run with a callback) and write_report; errors are recorded, not fatal."""
    from matfit.fitting import loss_history
    from matfit.report import write_report

    out = REPORTS / name
    t0 = time.perf_counter()
    try:
        hist = loss_history(fit_table, res.family, loss="e2", starts=args.starts, seed=args.seed,
                            max_steps=args.max_steps, init=init)
        write_report(res, report_table, out, history=hist, title=title, max_rows=5000)
        return {"report": str(out.relative_to(REPO)), "report_seconds": time.perf_counter() - t0,
                "history_final": [float(h[-1]) for h in hist]}
    except Exception as e:  # noqa: BLE001 - a report bug must not lose the fit
        return {"report_error": f"{type(e).__name__}: {e}"}


def fit_and_report(rec, todo, table, args, metrics, name, title, report_table):
    """Fit each family in ``todo`` on ``table``, store its record and ``metrics`` (name -> f(model));
    the family of lowest first metric gets the report (``report_table()`` gives its table)."""
    rec.setdefault("fits", {})
    results = {}
    key = next(iter(metrics))
    for fam in todo:
        t1 = time.perf_counter()
        try:
            res, init = fit_family(table, fam, args)
        except Exception as e:  # noqa: BLE001 - one failed family must not stop the run
            rec["fits"][fam] = {"error": f"{type(e).__name__}: {e}"}
            continue
        r = fam_record(res, init, time.perf_counter() - t1)
        r.update({m: fn(res.model) for m, fn in metrics.items()})
        rec["fits"][fam] = r
        results[fam] = (res, init)
        print(f"[{rec['kind']}] {name} {fam}: " + " ".join(f"{m} {r[m]:.4g}" for m in metrics)
              + f" ({r['seconds']:.0f} s)", flush=True)
    ok_f = {f: d for f, d in rec["fits"].items() if key in d}
    best = min(ok_f, key=lambda f: ok_f[f][key]) if ok_f else None
    if best is not None and best in results and best != rec.get("best_reported"):
        res, init = results[best]
        rec.update(report(res, init, table, report_table(), name, title.format(best=best), args))
        rec["best_reported"] = best
    rec["best"] = best


# ------------------------------------------------------------------ MERL
def run_merl(name, low, args, shared):
    import numpy as np

    import merl_surrogate  # noqa: F401 (path set in main)
    from matfit.io.merl import read_merl

    jpath = ITEMS / f"merl_{name}.json"
    rec = json.loads(jpath.read_text()) if jpath.exists() else {"kind": "merl", "material": name}
    fams = list(FAMILIES) + [f for f, names in EXTRA.items() if args.extra and name in names]
    todo = [f for f in fams if f not in rec.get("fits", {})]
    if not todo:
        return rec
    t0 = time.perf_counter()
    cache = OUT / "cache"
    path = cache / f"{name}.binary"
    if not path.exists():
        merl_surrogate.write_merl(name, str(path))
    brdf = read_merl(path)
    table = low_sampled_table(brdf, args.n_rows, args.seed)
    cells = brdf.to_table().subsample(args.n_cells, seed=args.seed)
    w = table.effective_weight()[:, 0]
    ok = table.valid
    p = low[name]
    if "low_ct" not in rec:
        lw = {}
        for lab, dn in (("published", 1.0), ("D_over_pi", 1 / np.pi)):
            lw[lab] = {"e2_low_sin": e2_weighted(low_cooktorrance(p, table.wo, table.wi, dn)[ok], table.values[ok],
                                                 table.wi[ok, 2], w[ok]),
                       "e2_cells": e2_cells(low_cooktorrance(p, cells.wo, cells.wi, dn), cells.values, cells.wi[:, 2],
                                            cells.valid)}
        rec["low_ct"] = {"params": p, **lw}
        rec.update({"n_rows": len(table), "n_rows_valid": int(ok.sum()), "n_cells": len(cells), "seed": args.seed})
    metrics = {"e2_low_sin": lambda m: e2_weighted(pred_of(m, table.wo[ok], table.wi[ok]), table.values[ok],
                                                   table.wi[ok, 2], w[ok]),
               "e2_cells": lambda m: e2_cells(pred_of(m, cells.wo, cells.wi), cells.values, cells.wi[:, 2], cells.valid)}
    fit_and_report(rec, todo, table, args, metrics, name, f"MERL {name} (surrogate): {{best}}, E2 loss (Löw sampling)",
                   brdf.to_table)
    rec["seconds"] = rec.get("seconds", 0) + time.perf_counter() - t0
    jpath.write_text(json.dumps(jsonable(rec), indent=1))
    path.unlink()  # 35 MB; rebuilt on demand
    return rec


def model_from_params(fam, params, channels=3):
    import jax.numpy as jnp

    from matfit.fitting import get_family

    f = get_family(fam)
    full = {}
    for p in f.params:
        v = jnp.asarray(params[p.name], dtype=float)
        full[p.name] = jnp.broadcast_to(jnp.atleast_1d(v), (channels,)) if p.per_channel else v
    return f.build(full, channels)


def heldout_merl(name, low, args):
    """E2 (Löw sampling) of the stored fits and of the published fit on ``args.heldout`` fresh rows:
    rows the matfit fits did not see, so that neither side is scored on its own fitting sample."""
    import merl_surrogate  # noqa: F401 (path set in main)
    from matfit.io.merl import read_merl

    jpath = ITEMS / f"merl_{name}.json"
    if not jpath.exists():
        return
    rec = json.loads(jpath.read_text())
    if rec.get("heldout", {}).get("n") == args.heldout:
        return
    path = OUT / "cache" / f"{name}.binary"
    if not path.exists():
        merl_surrogate.write_merl(name, str(path))
    table = low_sampled_table(read_merl(path), args.heldout, args.seed + 1)
    ok = table.valid
    w = table.effective_weight()[ok, 0]
    wo, wi, y = table.wo[ok], table.wi[ok], table.values[ok]
    ho = {"n": args.heldout, "seed": args.seed + 1,
          "low_ct": e2_weighted(low_cooktorrance(low[name], wo, wi), y, wi[:, 2], w)}
    for fam, d in rec.get("fits", {}).items():
        if "params" in d:
            ho[fam] = e2_weighted(pred_of(model_from_params(fam, d["params"]), wo, wi), y, wi[:, 2], w)
    rec["heldout"] = ho
    jpath.write_text(json.dumps(jsonable(rec), indent=1))
    path.unlink()
    print(f"[heldout] {name}: " + " ".join(f"{k} {v:.4g}" for k, v in ho.items() if k not in ("n", "seed")), flush=True)


# ------------------------------------------------------------------ RGL
def run_rgl(path, args):
    from matfit.io import load

    name = path.stem
    jpath = ITEMS / f"rgl_{name}.json"
    rec = json.loads(jpath.read_text()) if jpath.exists() else {"kind": "rgl", "file": path.name}
    fams = list(FAMILIES) + [f for f, names in EXTRA.items() if args.extra and name in names]
    todo = [f for f in fams if f not in rec.get("fits", {})]
    if not todo:
        return rec
    t0 = time.perf_counter()
    full = load(path)
    table, n_real = padded(full, args.n_rgl, args.seed)
    rec.update({"n_rows_full": len(full), "n_valid_full": int(full.n_valid), "n_rows_fit": n_real})
    metrics = {"e2_fit_rows": lambda m: e2_cells(pred_of(m, table.wo, table.wi), table.values, table.wi[:, 2], table.valid),
               "e2_all_rows": lambda m: e2_cells(pred_of(m, full.wo, full.wi), full.values, full.wi[:, 2], full.valid)}
    fit_and_report(rec, todo, table, args, metrics, name, f"RGL {name}: {{best}}, E2 loss", lambda: full)
    rec["seconds"] = rec.get("seconds", 0) + time.perf_counter() - t0
    jpath.write_text(json.dumps(jsonable(rec), indent=1))
    return rec


# ------------------------------------------------------------------ main
def main(argv=None):
    args = parse_args(argv)
    shared = Path(args.shared).resolve()
    fitfile = shared / "data" / "published_fits" / "low_cooktorrance_E2.fit"
    need = [shared / "tools" / "merl_surrogate.py", fitfile, shared / "data" / "rgl"]
    missing = [str(p) for p in need if not p.exists()]
    if missing:
        sys.exit(f"fit_measured: shared folder {shared} is missing or incomplete; not found: {', '.join(missing)}.\n"
                 f"Pass the shared folder as the first argument (default: ../shared relative to the repo root).")
    ITEMS.mkdir(parents=True, exist_ok=True)
    if not args.summary:
        import jax

        if not args.x32:
            jax.config.update("jax_enable_x64", True)
        sys.path.insert(0, str(shared / "tools"))
        import merl_surrogate

        cache = OUT / "cache"
        cache.mkdir(parents=True, exist_ok=True)
        if not (cache / ".gitignore").exists():
            (cache / ".gitignore").write_text("*\n!.gitignore\n")
        low = parse_low_fits(fitfile)
        available = set(merl_surrogate.materials())
        names = args.materials.split(",") if args.materials else MATERIALS
        for n in names:
            if n not in low or n not in available:
                sys.exit(f"fit_measured: no published Löw fit or no surrogate for MERL material {n!r}")
        T0 = time.perf_counter()
        if args.heldout:
            for name in names:
                heldout_merl(name, low, args)
        elif not args.skip_merl:
            for name in names:
                run_merl(name, low, args, shared)
        if not args.skip_rgl and not args.heldout:
            for path in sorted((shared / "data" / "rgl").glob("*.bsdf")):
                if args.rgl is None or path.stem in args.rgl.split(","):
                    run_rgl(path, args)
        print(f"fits done in {time.perf_counter() - T0:.0f} s", flush=True)
    write_summary(args)


# ------------------------------------------------------------------ summary
def _g(v, nd=3):
    return f"{v:.{nd}g}" if isinstance(v, (int, float)) else "-"


def _params(d):
    parts = []
    for k, v in d.items():
        if isinstance(v, list):
            parts.append(f"{k}=[" + ", ".join(f"{x:.3g}" for x in v) + "]")
        else:
            parts.append(f"{k}={v:.3g}")
    return ", ".join(parts)


def write_summary(args):
    import jax

    merl = [json.loads(p.read_text()) for p in sorted(ITEMS.glob("merl_*.json"))]
    order = {n: i for i, n in enumerate(MATERIALS)}
    merl.sort(key=lambda r: order.get(r["material"], 99))
    rgl = [json.loads(p.read_text()) for p in sorted(ITEMS.glob("rgl_*.json"))]
    meta = {"machine": {"platform": platform.platform(), "cpus": os.cpu_count(), "python": platform.python_version(),
                        "jax": jax.__version__, "x64": not args.x32},
            "n_rows": args.n_rows, "n_cells": args.n_cells, "n_rgl": args.n_rgl, "starts": args.starts,
            "max_steps": args.max_steps, "seed": args.seed}
    (OUT / "fit_measured.json").write_text(json.dumps({"meta": meta, "merl": merl, "rgl": rgl}, indent=1))
    fams_m = sorted({f for r in merl for f in r.get("fits", {})}, key=lambda f: (f not in FAMILIES, f))
    L = ["# Fits to measured BRDFs with the E2 loss (Löw et al. 2012)", "",
         "`experiments/fit_measured.py` (per-material JSON in `fit_measured/`, reports in `reports/<name>/`). "
         f"{meta['machine']['cpus']} shared CPUs, JAX {meta['machine']['jax']}, float64. Each family: `fit(loss=\"e2\")`, "
         f"{args.starts} starts (the data-driven guess and perturbed copies), at most {args.max_steps} "
         "Levenberg-Marquardt steps" + (", and the same from a generic point; the better of the two." if args.two_inits
                                        else "."), "",
         "E2 per sample = mean over RGB of `(log(1 + f cos_i) - log(1 + y cos_i))^2`; the tables give means over "
         "samples (not square roots). How the published Löw model and metric were checked: "
         "`fit_measured_low2012.md`.", "",
         "## MERL (surrogates of Sztrajman et al. 2021 in the MERL layout, not the measurements)", "",
         f"**E2 (Löw)**: the metric Löw et al. fitted with (bbm `lowLog`): {args.n_rows} direction pairs with "
         "theta_i, phi_i, theta_o uniform, phi_o = 0, weighted by sin(theta_i), values looked up in the MERL table; "
         "the matfit families were fitted on exactly these rows and weights, and the published Löw Cook-Torrance E2 "
         "fit is evaluated on the same rows (in-sample for matfit: see the held-out table below). **E2 (cells)**: the unweighted mean over "
         f"{args.n_cells} random valid MERL cells (cells crowd near the mirror direction: 31 % of the valid cells have theta_h < 5 deg and 23 % "
         "theta_d > 60 deg), for the same two fits; no fit here minimized it; for the Löw fit, 1500 cells land within 15 % of the 50 000-cell value of `fit_measured_low2012.md`. "
         "Ratio = best matfit / Löw CT, E2 (Löw).", "",
         "| MERL material | " + " | ".join(f"E2 (Löw) {f}" for f in fams_m) + " | E2 (Löw) Löw CT | ratio | "
         + " | ".join(f"E2 (cells) {f}" for f in fams_m) + " | E2 (cells) Löw CT | report |",
         "|---|" + "---|" * (2 * len(fams_m) + 4)]
    for r in merl:
        fits = r.get("fits", {})
        lo = r["low_ct"]["published"]
        vals = [fits.get(f, {}).get("e2_low_sin") for f in fams_m]
        okv = [v for v in vals if isinstance(v, float)]
        ratio = min(okv) / lo["e2_low_sin"] if okv else None
        rep = f"[{r['material']}](reports/{r['material']}/report.md)" if "report" in r else r.get("report_error", "-")
        L.append(f"| {r['material']} | " + " | ".join(_g(v) for v in vals) + f" | {_g(lo['e2_low_sin'])} | {_g(ratio, 2)} | "
                 + " | ".join(_g(fits.get(f, {}).get("e2_cells")) for f in fams_m)
                 + f" | {_g(lo['e2_cells'])} | {rep} |")
    ho = [r for r in merl if "heldout" in r]
    if ho:
        L += ["", f"**Held out**: the same E2 (Löw) on {ho[0]['heldout']['n']} fresh Löw-sampled rows (seed "
              f"{ho[0]['heldout']['seed']}) that no matfit fit saw. Few samples fall near the mirror direction or at grazing angles, where the "
              "errors are large, so E2 on a 1500-row set differs from the 54 000-sample grid value of "
              "`fit_measured_low2012.md` by up to a factor of ~4 for the Löw fit. matfit was fitted to the rows of the "
              "table above and the Löw fit was not, so the ratio there flatters matfit (most for the sharp "
              "highlights that few rows sample); this table is the fair comparison.", "",
              "| MERL material | " + " | ".join(f"E2 {f}" for f in fams_m) + " | E2 Löw CT | ratio best / Löw CT |",
              "|---|" + "---|" * (len(fams_m) + 2)]
        for r in ho:
            h = r["heldout"]
            vals = [h.get(f) for f in fams_m]
            okv = [v for v in vals if isinstance(v, float)]
            L.append(f"| {r['material']} | " + " | ".join(_g(v) for v in vals) + f" | {_g(h['low_ct'])} | "
                     f"{_g(min(okv) / h['low_ct'], 2) if okv else '-'} |")
    L += ["", "Sensitivity of the Löw CT numbers to the one ambiguous factor of the model form (D with 1/pi, i.e. a "
          "normalized Beckmann, against the published form without it):", "",
          "| MERL material | E2 (Löw), published form | E2 (Löw), D/pi | E2 (cells), published form | E2 (cells), D/pi |",
          "|---|---|---|---|---|"]
    for r in merl:
        a, b = r["low_ct"]["published"], r["low_ct"]["D_over_pi"]
        L.append(f"| {r['material']} | {_g(a['e2_low_sin'])} | {_g(b['e2_low_sin'])} | {_g(a['e2_cells'])} | {_g(b['e2_cells'])} |")
    L += ["", "Fitted parameters (matfit families: `alpha` GGX width, `albedo` diffuse albedo, `eta`/`k` index; "
          "Löw CT: kd, ks, Beckmann m, eta):", "", "| MERL material | family | parameters | E2 (Löw) | steps | s |",
          "|---|---|---|---|---|---|"]
    for r in merl:
        for f in fams_m:
            d = r.get("fits", {}).get(f)
            if d is None:
                continue
            if "error" in d:
                L.append(f"| {r['material']} | {f} | failed: {d['error'][:80]} | - | - | - |")
                continue
            L.append(f"| {r['material']} | {f} | {_params(d['params'])} | {_g(d['e2_low_sin'])} | {d['steps']} | "
                     f"{d['seconds']:.0f} |")
        L.append(f"| {r['material']} | Löw CT | {_params(r['low_ct']['params'])} | {_g(r['low_ct']['published']['e2_low_sin'])} | - | - |")
    fams_r = sorted({f for r in rgl for f in r.get("fits", {})}, key=lambda f: (f not in FAMILIES, f))
    L += ["", "car_paint (`--extra`) was not run: on the shared CPUs its compilation alone did not fit the time "
          "left.", "", "## RGL (measured, Dupuy & Jakob 2018)", "",
          f"Fitted on the file's valid rows (a random {args.n_rgl} where there are more), equal weights; E2 on the fit "
          "rows and on all valid rows. Report for the family of lowest E2.", "",
          "| RGL file | valid rows (fit / all) | " + " | ".join(f"E2 {f}" for f in fams_r) + " | best | E2 best, all rows | report |",
          "|---|---|" + "---|" * (len(fams_r) + 3)]
    for r in rgl:
        fits = r.get("fits", {})
        b = r.get("best")
        rep = (f"[{Path(r['file']).stem}](reports/{Path(r['file']).stem}/report.md)" if "report" in r
               else r.get("report_error", "-"))
        L.append(f"| {r['file']} | {r['n_rows_fit']} / {r['n_valid_full']} | "
                 + " | ".join(_g(fits.get(f, {}).get("e2_fit_rows")) for f in fams_r)
                 + f" | {b} | {_g(fits.get(b, {}).get('e2_all_rows'))} | {rep} |")
    L += ["", "| RGL file | family | parameters | steps | s |", "|---|---|---|---|---|"]
    for r in rgl:
        for f in fams_r:
            d = r.get("fits", {}).get(f)
            if d and "params" in d:
                L.append(f"| {r['file']} | {f} | {_params(d['params'])} | {d['steps']} | {d['seconds']:.0f} |")
    (OUT / "fit_measured.md").write_text("\n".join(L) + "\n")
    print(f"-> {OUT / 'fit_measured.md'}")


if __name__ == "__main__":
    main()
