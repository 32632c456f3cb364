"""Single fits: how often the default call recovers every parameter, how often it ends in a false
minimum, and which warnings fire (issue #39's recovery matrix, the single fits' part).

For each family, ``--tables`` random tables: a truth drawn from the ranges of
``map_recovery.RANGES`` and a direction design of its own (``--pairs`` random pairs, a third near
the mirror, :func:`data_synth.geometry.mirror_biased_pairs`), rendered with 1 % Gaussian noise,
either multiplicative (sigma = 1 % of each value) or additive (sigma = 1 % of the table's median
value). Each table is fitted by the default call ``fit(table, model=family)`` twice: with the
table's sigma (``Table(sigma=...)``) and without it.

Per configuration:

* ``alpha``: tables whose every width is within 2 % of the truth;
* ``all``: tables whose every parameter is within 2 % or within 3 of its standard errors (the
  Gauss-Newton, i.e. Cramer-Rao, bound the design allows at this noise);
* ``global``: fits whose objective (the fit's own: weighted by 1 / sigma^2 where sigma is given) is
  at most the truth's (the optimizer found a minimum as deep as the truth's, whatever the spread
  of the parameters);
* ``false minima``: fits neither ``all`` nor ``global``; ``... converged``: of those, the ones
  whose result says ``converged``; ``... ok``: the ones with ``ok`` (converged, no warning);
* ``warned``: fits with any warning, and the warning classes that fired (a correctly specified
  table should raise none).

Usage: python experiments/fit_recovery.py [--families plastic ...] [--tables 200] [--pairs 24]
       [--noise multiplicative additive]
Writes experiments/results/fit_recovery.json and .md.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import Counter
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from map_recovery import FIXED, RANGES, load_rows, recovered, truths, write_table  # noqa: E402

from data_synth.geometry import mirror_biased_pairs  # noqa: E402
from matfit import Table  # noqa: E402
from matfit.fitting import fit, get_family  # noqa: E402

NOISE = 0.01


def one_table(family, n, noise, rng):
    """(table with sigma, truth, clean values, sigma)."""
    wo, wi, _, _ = mirror_biased_pairs(n, rng)
    truth = {k: v[0] for k, v in truths(family, 1, rng).items()}
    model = get_family(family).build({k: np.asarray(v) for k, v in truth.items()}, 3)
    clean = np.broadcast_to(np.asarray(model.eval(wo, wi), float), (n, 3))
    sigma = NOISE * (clean if noise == "multiplicative" else np.full_like(clean, np.median(clean)))
    sigma = np.maximum(sigma, 1e-30)  # a value of exactly 0 (none here) keeps a positive sigma
    noisy = clean + sigma * rng.standard_normal(clean.shape)
    return Table(wo=wo, wi=wi, values=noisy, sigma=sigma), truth, clean


def judge(family, r, truth, table, clean):
    fam = get_family(family)
    alpha_ok = all_ok = True
    for p in fam.params:
        if p.name in FIXED.get(family, {}):
            continue
        est, tr = np.atleast_1d(r.params[p.name]), np.atleast_1d(truth[p.name])
        se = _se(r, p.name, est.size)
        rel, within = (bool(np.all(x)) for x in recovered(est, tr, se))
        if p.name.startswith("alpha"):
            alpha_ok &= rel
        all_ok &= within
    # the truth's objective under the fit's own loss (weighted by 1 / sigma^2 when given)
    w = 1.0 if table.sigma is None else 1 / table.sigma**2
    f_true = 0.5 * float(np.sum(w * (clean - table.values) ** 2))
    glob = r.objective <= f_true * (1 + 1e-3) + 1e-300
    return alpha_ok, all_ok, glob


def _se(r, name, size):
    """The standard errors of parameter ``name`` from the result's labels (per channel or one)."""
    if size == 1:
        return np.array([r.stderr[r.labels.index(name)]])
    return np.array([r.stderr[r.labels.index(f"{name}[{c}]")] for c in range(size)])


def run(family, n, tables, noise, seed=0):
    rng = np.random.default_rng(seed)
    rows = {"sigma": Counter(), "no sigma": Counter()}
    warn = {"sigma": Counter(), "no sigma": Counter()}
    wall = {"sigma": 0.0, "no sigma": 0.0}
    for _ in range(tables):
        t_sig, truth, clean = one_table(family, n, noise, rng)
        for case, t in (("sigma", t_sig), ("no sigma", t_sig.replace(sigma=None))):
            t0 = time.perf_counter()
            r = fit(t, model=family, fixed=FIXED.get(family))
            wall[case] += time.perf_counter() - t0
            a, al, g = judge(family, r, truth, t, clean)
            c = rows[case]
            c["alpha"] += a
            c["all"] += al
            c["global"] += g
            fm = not al and not g
            c["false"] += fm
            c["false_converged"] += fm and r.converged
            c["false_ok"] += fm and r.ok
            c["warned"] += bool(r.warnings)
            c["refitted"] += any("refitted" in i for i in r.info)
            for w in r.warnings:
                kind = w.split(":")[0]
                if kind == "at a bound":  # which parameter, and which kind of bound
                    kind += " " + w.split(": ")[1].split(" = ")[0] + (" (physical)" if "physical limit" in w else "")
                warn[case][kind] += 1
    return [{"family": family, "pairs": n, "noise": noise, "sigma": case, "tables": tables, "wall_s": wall[case],
             **{k: int(v) for k, v in rows[case].items()}, "warnings": dict(warn[case])} for case in rows]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--families", nargs="+", default=list(RANGES))
    ap.add_argument("--tables", type=int, default=200)
    ap.add_argument("--pairs", type=int, default=24)
    ap.add_argument("--noise", nargs="+", default=["multiplicative", "additive"])
    a = ap.parse_args()
    path, rows = load_rows("fit_recovery")
    for fam in a.families:
        for noise in a.noise:
            res = run(fam, a.pairs, a.tables, noise)
            keys = {(x["family"], x["pairs"], x["noise"], x["sigma"]) for x in res}
            rows = [x for x in rows if (x["family"], x["pairs"], x["noise"], x["sigma"]) not in keys] + res
            for x in res:
                print(json.dumps(x), flush=True)
            path.write_text(json.dumps({"noise": NOISE, "rows": rows}, indent=1))
    lines = ["| family | pairs | noise | sigma given | tables | alpha within 2 % | all within 2 % or 3 se | fit >= truth "
             "| false minima (converged / ok) | warned | refitted | warnings | s per fit |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    order = list(RANGES)
    for x in sorted(rows, key=lambda x: (order.index(x["family"]), x["pairs"], x["noise"], x["sigma"])):
        n = x["tables"]
        w = ", ".join(f"{k} {v}" for k, v in sorted(x["warnings"].items())) or "-"
        lines.append(f"| {x['family']} | {x['pairs']} | {x['noise']} | {'yes' if x['sigma'] == 'sigma' else 'no'} | {n} | "
                     f"{x['alpha'] / n:.1%} | {x['all'] / n:.1%} | {x['global'] / n:.1%} | "
                     f"{x['false']} ({x['false_converged']} / {x['false_ok']}) | {x['warned']} | {x['refitted']} | {w} | "
                     f"{x['wall_s'] / n:.2f} |")
    write_table("fit_recovery", lines)


if __name__ == "__main__":
    main()
