"""Check the evaluation of the published Löw 2012 Cook-Torrance E2 fits (experiments/_low2012.py).

The published parameters were fitted by their authors, to the real MERL data, under their own model
form and metric. Evaluated with the right form and metric on a close reconstruction of that data
(the MERL surrogates), they should therefore sit near an optimum: scaling ks (or kd) should barely
lower the metric, and a free refit of all eight parameters should land near them. A wrong factor in
the model (e.g. a 1/pi in D) shows as an optimal ks scale of about pi or 1/pi; a metric that weights
configurations differently from theirs shows as a published fit far from that metric's optimum.

For each material (default: the spread of experiments/fit_measured.py) and each reading of the
metric (``low_sin``: bbm's lowLog sampling, uniform theta_i, phi_i, theta_o with phi_o = 0 and weight
sin theta_i, on a cell-centre grid; ``cells``: the mean over MERL cells) and each model form
(published: D without 1/pi; ``D/pi``) this writes the E2 of the published fit, the ks and kd scale
factors that minimize E2 (log grid) and, for the low_sin reading and the published form, a full
refit (scipy least_squares from the published point). The surrogate is evaluated directly with its
network (shared/tools/merl_surrogate.network_brdf) at the sample directions.

Usage: python experiments/validate_low2012.py [SHARED] [--materials a,b] [--refit N]
Writes experiments/results/fit_measured_low2012.{json,md}.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
OUT = REPO / "experiments" / "results"
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(REPO))

from _low2012 import best_scale, direction_grid, e2_cells, e2_weighted, low_cooktorrance, parse_low_fits  # noqa: E402


def refit(p, wo, wi, y, w, d_norm=1.0):
    """Least-squares refit of (kd, ks, m, eta) under the weighted E2, from the published point."""
    from scipy.optimize import least_squares

    c = np.clip(wi[:, 2], 0, None)[:, None]
    ly = np.log1p(y * c)
    sw = np.sqrt(w / np.sum(w))[:, None] / np.sqrt(3.0)

    def unpack(x):
        return {"kd": np.exp(x[0:3]).tolist(), "ks": np.exp(x[3:6]).tolist(), "m": float(np.exp(x[6])),
                "eta": float(1.0 + np.exp(x[7]))}

    def res(x):
        f = low_cooktorrance(unpack(x), wo, wi, d_norm)
        return (sw * (np.log1p(f * c) - ly)).ravel()

    x0 = np.concatenate([np.log(np.maximum(p["kd"], 1e-6)), np.log(np.maximum(p["ks"], 1e-6)), [np.log(p["m"])],
                         [np.log(max(p["eta"] - 1.0, 1e-3))]])
    sol = least_squares(res, x0, method="trf", x_scale=1.0, max_nfev=400)
    return unpack(sol.x), float(np.sum(sol.fun ** 2))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("shared", nargs="?", default=str(REPO.parent / "shared"))
    ap.add_argument("--materials", default=None)
    ap.add_argument("--refit", type=int, default=12, help="refit the first N materials of the list")
    ap.add_argument("--n-cells", type=int, default=50000)
    args = ap.parse_args(argv)
    shared = Path(args.shared).resolve()
    sys.path.insert(0, str(shared / "tools"))
    import merl_surrogate as ms

    from fit_measured import MATERIALS
    from matfit.io._halfdiff import dirs_to_half_diff

    low = parse_low_fits(shared / "data" / "published_fits" / "low_cooktorrance_E2.fit")
    avail = set(ms.materials())
    if args.materials:
        names = args.materials.split(",")
    else:
        names = [n for n in MATERIALS if n in low and n in avail]
    rng = np.random.default_rng(0)
    th, td, pd = ms.cell_centres()
    w1, w2 = ms.half_diff_to_dirs(th, td, pd)  # w1: light (i), w2: view (o)
    valid = ((w1[..., 2] > 0) & (w2[..., 2] > 0)).ravel()
    idx = rng.choice(np.flatnonzero(valid), args.n_cells, replace=False)
    TH, TD, PD = th.ravel()[idx], td.ravel()[idx], pd.ravel()[idx]
    wi_c, wo_c = w1.reshape(-1, 3)[idx], w2.reshape(-1, 3)[idx]
    wo_g, wi_g, wg = direction_grid(30, 60, 30)
    a, _, b, c = dirs_to_half_diff(wo_g, wi_g)
    rows = []
    t0 = time.perf_counter()
    for k, name in enumerate(names):
        p = low[name]
        y_c = ms.network_brdf(name, TH, TD, PD)
        y_g = ms.network_brdf(name, a, b, np.mod(c, np.pi))
        readings = {"low_sin": (lambda f, y: e2_weighted(f, y, wi_g[:, 2], wg), wo_g, wi_g, y_g),
                    "cells": (lambda f, y: e2_cells(f, y, wi_c[:, 2]), wo_c, wi_c, y_c)}
        row = {"material": name, "params": p}
        for rname, (metric, wo, wi, y) in readings.items():
            for form, dn in (("published", 1.0), ("D_over_pi", 1 / np.pi)):
                e = metric(low_cooktorrance(p, wo, wi, dn), y)
                sks, eks = best_scale(metric, p, wo, wi, y, "ks", d_norm=dn)
                skd, ekd = best_scale(metric, p, wo, wi, y, "kd", d_norm=dn)
                row[f"{rname}/{form}"] = {"e2": e, "ks_scale": sks, "e2_ks_scaled": eks, "kd_scale": skd,
                                          "e2_kd_scaled": ekd}
        if k < args.refit:
            q, e = refit(p, wo_g, wi_g, y_g, wg)
            row["refit_low_sin"] = {"params": q, "e2": e}
        rows.append(row)
        r = row["low_sin/published"]
        print(f"{name:26s} low_sin E2 {r['e2']:.3g} ks x{r['ks_scale']:.2f} kd x{r['kd_scale']:.2f} | D/pi ks x"
              f"{row['low_sin/D_over_pi']['ks_scale']:.2f} | cells E2 {row['cells/published']['e2']:.3g} ks x"
              f"{row['cells/published']['ks_scale']:.2f}" + (f" | refit m {p['m']:.3g}->{row['refit_low_sin']['params']['m']:.3g}"
                                                             f" E2 {row['refit_low_sin']['e2']:.3g}" if "refit_low_sin" in row else "")
              + f" ({time.perf_counter() - t0:.0f} s)", flush=True)
    (OUT / "fit_measured_low2012.json").write_text(json.dumps(rows, indent=1))
    write_md(rows)


def write_md(rows):
    def med(key, field):
        v = np.array([r[key][field] for r in rows])
        return np.median(v), np.percentile(v, 25), np.percentile(v, 75)

    L = ["# Checking the evaluation of the published Löw 2012 Cook-Torrance E2 fits", "",
         "`experiments/validate_low2012.py`; model and metric: `experiments/_low2012.py`. "
         f"{len(rows)} MERL materials (surrogates evaluated with their network at the sample directions). "
         "Scale = factor on the published ks (or kd) that minimizes E2 on a log grid (0.05 to 20); "
         "a published fit evaluated with its own model form and metric should need about 1.", "",
         "| reading | model form | median E2 of the published fit | ks scale: median [quartiles] | "
         "kd scale: median [quartiles] | median E2 after the ks scale |", "|---|---|---|---|---|---|"]
    for rd in ("low_sin", "cells"):
        for form in ("published", "D_over_pi"):
            k = f"{rd}/{form}"
            e, s, d, es = med(k, "e2"), med(k, "ks_scale"), med(k, "kd_scale"), med(k, "e2_ks_scaled")
            L.append(f"| {rd} | {'D without 1/pi (published)' if form == 'published' else 'D / pi'} | {e[0]:.3g} | "
                     f"{s[0]:.2f} [{s[1]:.2f}, {s[2]:.2f}] | {d[0]:.2f} [{d[1]:.2f}, {d[2]:.2f}] | {es[0]:.3g} |")
    ref = [r for r in rows if "refit_low_sin" in r]
    if ref:
        L += ["", "Free refit of all eight parameters under the low_sin reading and the published form, from the "
              "published point (scipy least_squares):", "",
              "| material | m published -> refit | eta | ks (G) | kd (G) | E2 published -> refit |", "|---|---|---|---|---|---|"]
        for r in ref:
            p, q = r["params"], r["refit_low_sin"]["params"]
            L.append(f"| {r['material']} | {p['m']:.3g} -> {q['m']:.3g} | {p['eta']:.3g} -> {q['eta']:.3g} | "
                     f"{p['ks'][1]:.3g} -> {q['ks'][1]:.3g} | {p['kd'][1]:.3g} -> {q['kd'][1]:.3g} | "
                     f"{r['low_sin/published']['e2']:.3g} -> {r['refit_low_sin']['e2']:.3g} |")
    L += ["", "Per material (low_sin and cells readings, published form):", "",
          "| material | E2 low_sin | ks scale | kd scale | ks scale if D/pi | E2 cells | ks scale (cells) |",
          "|---|---|---|---|---|---|---|"]
    for r in rows:
        a, b, c = r["low_sin/published"], r["low_sin/D_over_pi"], r["cells/published"]
        L.append(f"| {r['material']} | {a['e2']:.3g} | {a['ks_scale']:.2f} | {a['kd_scale']:.2f} | {b['ks_scale']:.2f} | "
                 f"{c['e2']:.3g} | {c['ks_scale']:.2f} |")
    (OUT / "fit_measured_low2012.md").write_text("\n".join(L) + "\n")
    print(f"-> {OUT / 'fit_measured_low2012.md'}")


if __name__ == "__main__":
    main()
