"""Fit matfit families to measured BRDFs with the Löw 2012 E2 loss and compare with published fits.

1. MERL: for N_MERL materials that appear in the Löw et al. 2012 Cook-Torrance E2 fits, write the
   neural surrogate .binary (shared/tools/merl_surrogate.py) into experiments/results/cache/, load it,
   subsample the valid cells to a fixed count (same for all materials so that the compiled solver is
   reused), fit "plastic" and "conductor" with loss="e2" (robust_fit, starts=4) and evaluate the
   published Löw CT-E2 fit on the same rows.
2. RGL: fit "plastic" and "conductor" (loss="e2") to each .bsdf in shared/data/rgl/ and write a
   report (matfit.report.write_report) for the better family.
3. Write experiments/results/fit_measured.md and .json.

E2 metric (same definition everywhere): mean over valid rows and channels of
``(log(1 + f cos_i) - log(1 + y cos_i))^2`` computed with matfit.fitting.residuals(loss="e2").

Published model (Löw 2012 Cook-Torrance, as in bsdfbenchmark/bbm):
    f = kd/pi + ks D G F / (pi cos_i cos_o),
    D = exp(-tan^2 th_h / m^2) / (m^2 cos^4 th_h)   (Beckmann without 1/pi),
    G = min(1, 2 (n.h)(n.o)/(o.h), 2 (n.h)(n.i)/(o.h))   (V-groove),
    F = Cook-Torrance dielectric Fresnel at c = i.h with index eta.

Usage: python experiments/fit_measured.py [SHARED_DIR] [--n-merl N] [--n-sub 20000] [--materials a,b,...]
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import re
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
OUT = REPO / "experiments" / "results"

MATERIALS = ["red-plastic", "aluminium", "beige-fabric", "gold-metallic-paint", "blue-acrylic", "brass",
             "pink-felt", "blue-metallic-paint", "yellow-matte-plastic", "chrome-steel", "white-paint",
             "black-phenolic", "nickel", "green-fabric", "silver-metallic-paint"]
FAMILIES = ("plastic", "conductor")


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("shared", nargs="?", default=str(REPO.parent / "shared"),
                    help="shared folder (default: ../shared relative to the repo root)")
    ap.add_argument("--n-merl", type=int, default=int(os.environ.get("N_MERL", 10)))
    ap.add_argument("--materials", default=None, help="comma-separated MERL names (overrides the default list)")
    ap.add_argument("--n-sub", type=int, default=20000, help="valid rows per table (fixed: solver reused)")
    ap.add_argument("--starts", type=int, default=4)
    ap.add_argument("--max-steps", type=int, default=256)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--skip-rgl", action="store_true")
    ap.add_argument("--x32", action="store_true", help="float32 instead of float64")
    return ap.parse_args(argv)


# ------------------------------------------------------------------ published Löw CT-E2 fit
_FIT_RE = re.compile(
    r"^(?P<name>[\w\-]+)\s*=\s*Aggregate\(\s*Lambertian\(\s*albedo\s*=\s*\[(?P<kd>[^\]]*)\]\s*\)\s*,\s*"
    r"LowCookTorrance\(\s*albedo\s*=\s*\[(?P<ks>[^\]]*)\]\s*,\s*roughness\s*=\s*(?P<m>[-+\deE.]+)\s*,\s*"
    r"eta\s*=\s*(?P<eta>[-+\deE.]+)\s*\)\s*\)\s*$")


def parse_low_fits(path):
    """{material: {"kd": [3], "ks": [3], "m": float, "eta": float}} from low_cooktorrance_E2.fit."""
    out = {}
    for line in Path(path).read_text().splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        mt = _FIT_RE.match(line)
        if mt is None:
            raise ValueError(f"{path}: cannot parse line {line[:80]!r}")
        out[mt["name"]] = {"kd": [float(x) for x in mt["kd"].split(",")],
                           "ks": [float(x) for x in mt["ks"].split(",")],
                           "m": float(mt["m"]), "eta": float(mt["eta"])}
    return out


def low_cooktorrance(p, wo, wi):
    """Löw 2012 Cook-Torrance BRDF (N, 3) in numpy (see the module docstring)."""
    import numpy as np

    kd, ks = np.asarray(p["kd"]), np.asarray(p["ks"])
    m, eta = p["m"], p["eta"]
    co, ci = wo[:, 2], wi[:, 2]
    h = wo + wi
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    ch = np.clip(h[:, 2], 1e-12, 1.0)
    oh = np.clip(np.sum(wo * h, 1), 1e-12, 1.0)
    tan2 = (1.0 - ch * ch) / (ch * ch)
    D = np.exp(-tan2 / (m * m)) / (m * m * ch ** 4)
    G = np.minimum(1.0, np.minimum(2 * ch * co / oh, 2 * ch * ci / oh))
    c = oh  # i.h == o.h
    g = np.sqrt(eta * eta - 1.0 + c * c)
    F = 0.5 * (g - c) ** 2 / (g + c) ** 2 * (1.0 + ((c * (g + c) - 1.0) / (c * (g - c) + 1.0)) ** 2)
    spec = D * G * F / (np.pi * np.maximum(ci * co, 1e-12))
    return kd[None, :] / np.pi + ks[None, :] * spec[:, None]


# ------------------------------------------------------------------ helpers
def e2_metric(pred, table):
    """Mean squared E2 residual over valid rows and channels, and the sum."""
    import jax.numpy as jnp
    import numpy as np

    from matfit.fitting import residuals

    w = table.effective_weight()
    r = np.asarray(residuals(jnp.asarray(pred),
                             jnp.asarray(table.values), jnp.asarray(w), jnp.asarray(table.wi[:, 2]), loss="e2"))
    used = w > 0
    s = float(np.sum(np.where(used, r, 0.0) ** 2))
    return s / max(int(used.sum()), 1), s


def model_pred(model, table):
    import jax.numpy as jnp
    import numpy as np

    return np.asarray(model.eval(jnp.asarray(table.wo), jnp.asarray(table.wi)), dtype=np.float64)


def params_dict(res):
    return {k: (v.tolist() if hasattr(v, "tolist") else v) for k, v in res.params.items()}


def fmt_params(d, nd=4):
    parts = []
    for k, v in d.items():
        if isinstance(v, list):
            parts.append(f"{k}=[" + ", ".join(f"{x:.{nd}g}" for x in v) + "]")
        else:
            parts.append(f"{k}={v:.{nd}g}")
    return ", ".join(parts)


def fit_families(table, starts, seed, max_steps=256):
    from matfit.fitting import FitError
    from matfit.fitting.select import robust_fit

    out = {}
    for fam in FAMILIES:
        t0 = time.perf_counter()
        try:
            res = robust_fit(table, fam, loss="e2", starts=starts, seed=seed, max_steps=max_steps)
        except FitError as e:
            out[fam] = {"error": str(e), "seconds": time.perf_counter() - t0}
            continue
        out[fam] = {"result": res, "seconds": time.perf_counter() - t0}
        print(f"  {fam}: objective {res.objective:.5g}, {res.steps} steps, {out[fam]['seconds']:.1f} s", flush=True)
    return out


# ------------------------------------------------------------------ main
def main(argv=None):
    args = parse_args(argv)
    shared = Path(args.shared).resolve()
    need = [shared / "tools" / "merl_surrogate.py", shared / "data" / "published_fits" / "low_cooktorrance_E2.fit",
            shared / "data" / "rgl"]
    missing = [str(p) for p in need if not p.exists()]
    if missing:
        sys.exit(f"fit_measured: shared folder {shared} is missing or incomplete; not found: {', '.join(missing)}.\n"
                 f"Pass the shared folder as the first argument (default: ../shared relative to the repo root).")

    import jax

    if not args.x32:
        jax.config.update("jax_enable_x64", True)
    import numpy as np

    from matfit.io import load
    from matfit.report import write_report

    sys.path.insert(0, str(shared / "tools"))
    import merl_surrogate  # noqa: E402

    T0 = time.perf_counter()
    cache = OUT / "cache"
    cache.mkdir(parents=True, exist_ok=True)
    gi = cache / ".gitignore"
    if not gi.exists():
        gi.write_text("*\n!.gitignore\n")
    low = parse_low_fits(need[1])
    available = set(merl_surrogate.materials())
    names = args.materials.split(",") if args.materials else MATERIALS[:args.n_merl]
    names = [n for n in names if n in low and n in available]

    merl_rows = []
    for name in names:
        t0 = time.perf_counter()
        path = cache / f"{name}.binary"
        if not path.exists():
            merl_surrogate.write_merl(name, str(path))
        full = load(path)
        table = full.subsample(args.n_sub, seed=args.seed)
        t_load = time.perf_counter() - t0
        fits = fit_families(table, args.starts, args.seed, args.max_steps)
        row = {"material": name, "n_valid_full": int(full.n_valid), "n_rows": len(table), "load_seconds": t_load}
        for fam, d in fits.items():
            if "error" in d:
                row[fam] = {"error": d["error"], "seconds": d["seconds"]}
                continue
            res = d["result"]
            mse, s = e2_metric(model_pred(res.model, table), table)
            row[fam] = {"e2_mean": mse, "e2_sum": s, "objective": res.objective, "converged": res.converged,
                        "steps": res.steps, "seconds": d["seconds"], "params": params_dict(res),
                        "start_objectives": np.asarray(res.start_objectives).tolist()}
        mse, s = e2_metric(low_cooktorrance(low[name], table.wo, table.wi), table)
        row["low_ct"] = {"e2_mean": mse, "e2_sum": s, "params": low[name]}
        best = min((row[f]["e2_mean"] for f in FAMILIES if "e2_mean" in row[f]), default=float("nan"))
        row["ratio_best_over_low"] = best / mse if mse > 0 else float("nan")
        merl_rows.append(row)
        print(f"[merl] {name}: plastic {row['plastic'].get('e2_mean', float('nan')):.4g} "
              f"conductor {row['conductor'].get('e2_mean', float('nan')):.4g} low {mse:.4g} "
              f"({time.perf_counter() - t0:.1f} s)", flush=True)
        path.unlink()  # 35 MB each; rebuilt on demand

    rgl_rows = []
    if not args.skip_rgl:
        paths = sorted((shared / "data" / "rgl").glob("*.bsdf"))
        tables = {p: load(p) for p in paths}
        # One row count for every file (the smallest valid count caps it), so the solver compiles once.
        n = min([args.n_sub] + [int(t.n_valid) for t in tables.values()])
        for path in paths:
            t0 = time.perf_counter()
            full = tables[path]
            table = full.subsample(n, seed=args.seed)
            fits = fit_families(table, args.starts, args.seed, args.max_steps)
            row = {"file": path.name, "n_rows_full": len(full), "n_valid_full": int(full.n_valid), "n_rows_fit": n}
            for fam, d in fits.items():
                if "error" in d:
                    row[fam] = {"error": d["error"]}
                    continue
                res = d["result"]
                mse_fit, _ = e2_metric(model_pred(res.model, table), table)
                mse_full, _ = e2_metric(model_pred(res.model, full), full)
                row[fam] = {"e2_mean_fit_rows": mse_fit, "e2_mean_all_rows": mse_full, "converged": res.converged,
                            "steps": res.steps, "seconds": d["seconds"], "params": params_dict(res)}
            ok = [f for f in FAMILIES if "e2_mean_fit_rows" in row[f]]
            best = min(ok, key=lambda f: row[f]["e2_mean_fit_rows"]) if ok else None
            row["best"] = best
            if best is not None:
                rep = OUT / "reports" / path.stem
                try:
                    write_report(fits[best]["result"], full, rep, title=f"{path.stem}: {best} (E2 loss)",
                                 max_rows=20000)
                    row["report"] = str(rep.relative_to(REPO))
                except Exception as e:  # report bugs are reported, not fatal
                    row["report_error"] = f"{type(e).__name__}: {e}"
            row["seconds"] = time.perf_counter() - t0
            rgl_rows.append(row)
            print(f"[rgl] {path.name}: best {best} "
                  + " ".join(f"{f} {row[f].get('e2_mean_fit_rows', float('nan')):.4g}" for f in FAMILIES)
                  + f" ({row['seconds']:.1f} s)", flush=True)

    total = time.perf_counter() - T0
    meta = {"machine": {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
                        "cpus": os.cpu_count(), "python": platform.python_version(), "jax": jax.__version__,
                        "backend": jax.default_backend(), "x64": not args.x32},
            "total_seconds": total, "n_sub": args.n_sub, "starts": args.starts, "max_steps": args.max_steps, "seed": args.seed,
            "e2_definition": "mean over valid rows x channels of (log1p(f cos_i) - log1p(y cos_i))^2",
            "shared": str(shared)}
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "fit_measured.json").write_text(json.dumps({"meta": meta, "merl": merl_rows, "rgl": rgl_rows}, indent=1,
                                                      default=float))
    write_md(OUT / "fit_measured.md", meta, merl_rows, rgl_rows)
    print(f"done in {total:.1f} s -> {OUT / 'fit_measured.md'}")


def _g(d, k="e2_mean"):
    v = d.get(k)
    return f"{v:.4g}" if isinstance(v, float) else ("failed" if "error" in d else "-")


def write_md(path, meta, merl_rows, rgl_rows):
    m = meta["machine"]
    L = ["# Fits to measured BRDFs with the E2 loss (Löw et al. 2012)", "",
         f"Machine: {m['platform']}, {m['cpus']} CPUs, JAX {m['jax']} ({m['backend']}, x64={m['x64']}); "
         f"total {meta['total_seconds']:.0f} s. Rows per fit: {meta['n_sub']} (valid, seed {meta['seed']}); "
         f"robust_fit, starts={meta['starts']}, max_steps={meta['max_steps']}, method lm.", "",
         f"E2 = {meta['e2_definition']} (matfit.fitting.residuals, loss=\"e2\"; the same rows for every model).", "",
         "## MERL (neural surrogates of Sztrajman et al. 2021, not the raw measurements)", "",
         "The published fit is the Löw 2012 Cook-Torrance E2 fit (bsdfbenchmark/bbm), fitted by its authors to the "
         "real MERL data, evaluated here on the surrogate. Ratio = best matfit E2 / Löw CT E2.", "",
         "| MERL material | E2 matfit plastic | E2 matfit conductor | E2 Löw CT | ratio | fit s (pl / co) |",
         "|---|---|---|---|---|---|"]
    for r in merl_rows:
        L.append(f"| {r['material']} | {_g(r['plastic'])} | {_g(r['conductor'])} | {_g(r['low_ct'])} | "
                 f"{r['ratio_best_over_low']:.3g} | {r['plastic'].get('seconds', 0):.0f} / {r['conductor'].get('seconds', 0):.0f} |")
    L += ["", "Fitted parameters:", "", "| MERL material | plastic | conductor | Löw CT (kd, ks, m, eta) |", "|---|---|---|---|"]
    for r in merl_rows:
        L.append(f"| {r['material']} | {fmt_params(r['plastic'].get('params', {}))} | "
                 f"{fmt_params(r['conductor'].get('params', {}))} | {fmt_params(r['low_ct']['params'])} |")
    L += ["", "## RGL (measured, Dupuy & Jakob 2018)", "",
          "Fitted to a fixed-size random subset of the valid rows; E2 on the fit rows and on all valid rows of the file. "
          "The report (reports/<name>/) is for the family with the lower E2.", "",
          "| RGL file | family | parameters | E2 (fit rows) | E2 (all rows) | other family E2 | report |", "|---|---|---|---|---|---|---|"]
    for r in rgl_rows:
        b = r["best"]
        if b is None:
            L.append(f"| {r['file']} | failed | - | - | - | - | - |")
            continue
        other = [f for f in FAMILIES if f != b][0]
        L.append(f"| {r['file']} | {b} | {fmt_params(r[b]['params'])} | {_g(r[b], 'e2_mean_fit_rows')} | "
                 f"{_g(r[b], 'e2_mean_all_rows')} | {other}: {_g(r[other], 'e2_mean_fit_rows')} | "
                 f"{r.get('report', r.get('report_error', '-'))} |")
    Path(path).write_text("\n".join(L) + "\n")


if __name__ == "__main__":
    main()
