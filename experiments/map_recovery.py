"""Parameter maps: how often every texel comes back, how often a false minimum stays, and whether
each one is flagged (issue #39's recovery matrix, the maps' part).

For each family and direction design, a 32 x 32 map (16 x 16 for car paint) of random truths
(:data:`RANGES`, drawn per texel, independently: no texel's neighbours resemble it, the hardest
case for the neighbour starts) is rendered at the design's directions with 1 % multiplicative
Gaussian noise and fitted by the default call ``fit_map(wo, wi, values, model=family)`` (relative
residuals, refits on). Design: ``N`` random direction pairs (cosines uniform in (0.05, 1)), a
third of them within ~3 degrees of the mirror direction (a gonioreflectometer that looks at the
highlight).

Per configuration:

* ``alpha``: texels whose every width is within 2 % of the truth;
* ``all``: texels whose every parameter is within 2 % or within 3 of its standard errors (the
  Gauss-Newton, i.e. Cramer-Rao, bound the design allows at this noise);
* ``global``: texels whose fit explains the data at least as well as the truth
  (``F(fit) <= F(truth)``; the optimizer found a minimum as deep as the truth's, whatever the
  parameters' spread);
* ``false minima``: texels neither within their bounds nor global, with
  ``2 (F(fit) - F(truth)) / noise^2 > 4`` (a chi-square gap the noise does not explain);
* ``suspect``: texels flagged by the map; ``unflagged > 10x``: texels ending above 10 times the
  map's noise level without the flag (must be 0).

Usage: python experiments/map_recovery.py [--families conductor ...] [--pairs 16 24 48] [--side 32] [--starts 1]
Writes experiments/results/map_recovery.json and .md.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from data_synth.geometry import mirror_biased_pairs  # noqa: E402
from matfit.fitting import get_family  # noqa: E402
from matfit.fitting.losses import REL_EPS  # noqa: E402
from matfit.maps import fit_map  # noqa: E402

OUT = Path(__file__).parent / "results"
NOISE = 0.01
ALUMINIUM_ETA = (1.657, 0.880, 0.521)
RANGES = {
    "conductor": {"alpha": (0.02, 0.8), "eta": (0.1, 3.0), "k": (1.0, 8.0)},
    "conductor_beckmann": {"alpha": (0.02, 0.8), "eta": (0.1, 3.0), "k": (1.0, 8.0)},
    "dielectric": {"alpha": (0.02, 0.8), "eta": (1.3, 2.0)},
    "plastic": {"albedo": (0.05, 0.9), "alpha": (0.02, 0.8), "eta": (1.3, 1.8)},
    "car_paint": {"alpha_base": (0.1, 0.5), "k_base": (1.0, 8.0), "alpha_coat": (0.02, 0.3), "eta_coat": (1.3, 1.8)},
    "diffuse_specular": {"albedo": (0.05, 0.9), "f0": (0.02, 0.9), "alpha": (0.02, 0.8)},
    "lobes2": {"albedo": (0.05, 0.9), "alpha_1": (0.02, 0.3), "ks_1": (0.05, 0.9), "f0": (0.02, 0.9),
               "ratio_2": (1.5, 10.0), "ks_2": (0.05, 0.5)},
}
#: Held fixed (and known): through a clear coat a metal's eta and k are not separable (recovery.py).
FIXED = {"car_paint": {"eta_base": ALUMINIUM_ETA}}


def recovered(est, truth, se):
    """Elementwise: the estimates within 2 % of the truth, and those within 2 % or within 3 of
    their standard errors ``se``."""
    rel = np.abs(est / truth - 1) < 0.02
    return rel, rel | (np.abs(est - truth) < 3 * se)


def load_rows(name):
    """``(path, rows)``: the results file ``results/NAME.json`` and the rows it holds (none yet
    when it is absent)."""
    OUT.mkdir(exist_ok=True)
    path = OUT / f"{name}.json"
    return path, (json.loads(path.read_text())["rows"] if path.exists() else [])


def write_table(name, lines):
    """Write the Markdown table ``lines`` to ``results/NAME.md`` and print it."""
    (OUT / f"{name}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def design(n, rng):
    wo, wi, _, _ = mirror_biased_pairs(n, rng)
    return wo, wi


def truths(family, B, rng):
    out = {}
    for p in get_family(family).params:
        if p.name in FIXED.get(family, {}):
            out[p.name] = np.broadcast_to(np.asarray(FIXED[family][p.name]), (B, 3))
            continue
        lo, hi = RANGES[family][p.name]
        out[p.name] = rng.uniform(lo, hi, (B, 3) if p.per_channel else (B,))
    if family == "lobes2":  # the second lobe's width stays <= 0.8 (wider is a second diffuse term)
        out["ratio_2"] = rng.uniform(1.5, np.maximum(1.6, np.minimum(10.0, 0.8 / out["alpha_1"])))
    return out


def run(family, n, side, seed=0, starts=1):
    rng = np.random.default_rng(seed)
    wo, wi = design(n, rng)
    B = side * side
    truth = truths(family, B, rng)
    fam = get_family(family)
    ev = jax.jit(jax.vmap(lambda p: fam.build(p, 3).eval(jnp.asarray(wo), jnp.asarray(wi))))
    clean = np.asarray(ev({k: jnp.asarray(v) for k, v in truth.items()}))
    clean = np.broadcast_to(clean, clean.shape[:-1] + (3,))
    noisy = clean * (1 + NOISE * rng.standard_normal(clean.shape))
    t = time.perf_counter()
    r = fit_map(wo, wi, noisy.reshape(side, side, n, 3), model=family, fixed=FIXED.get(family), starts=starts)
    wall = time.perf_counter() - t
    alpha_ok = np.ones(B, bool)
    all_ok = np.ones(B, bool)
    per = {}
    for p in fam.params:
        if p.name in FIXED.get(family, {}):
            continue
        est, tr = r.params[p.name].reshape(B, -1), truth[p.name].reshape(B, -1)
        se = r.stderr[p.name].reshape(B, -1)
        rel, within = (x.all(-1) for x in recovered(est, tr, se))
        per[p.name] = {"within_2pct": float(rel.mean()), "within_2pct_or_3se": float(within.mean())}
        if p.name.startswith("alpha"):
            alpha_ok &= rel
        all_ok &= within
    obj = r.objective.reshape(B).astype(float)
    f_true = 0.5 * (((clean - noisy) / (np.abs(noisy) + REL_EPS)) ** 2).sum((1, 2))  # the relative loss
    glob = obj <= f_true * (1 + 1e-3) + 1e-12
    gap = 2 * (obj - f_true) / NOISE**2
    false_min = ~all_ok & ~glob & (gap > 4)
    dof = np.maximum(n * 3 - len(r.labels), 1)
    q = 2 * obj / dof
    level = np.median(q)
    suspect = r.suspect.reshape(B)
    return {"family": family, "pairs": n, "starts": starts, "texels": B, "wall_s": wall, "refitted": r.refitted,
            "alpha": float(alpha_ok.mean()), "all": float(all_ok.mean()), "global": float(glob.mean()),
            "false_minima": int(false_min.sum()), "false_minima_flagged": int((false_min & suspect).sum()),
            "suspect": int(suspect.sum()), "unflagged_over_10x": int(((q > 10 * level) & ~suspect).sum()),
            "params": per}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--families", nargs="+", default=list(RANGES))
    ap.add_argument("--pairs", nargs="+", type=int, default=[16, 24, 48])
    ap.add_argument("--side", type=int, default=32)
    ap.add_argument("--starts", type=int, default=1, help="first-pass starts per texel (fit_map's starts)")
    a = ap.parse_args()
    path, rows = load_rows("map_recovery")
    for fam in a.families:
        for n in a.pairs:
            side = min(a.side, 16) if fam == "car_paint" else a.side
            res = run(fam, n, side, starts=a.starts)
            rows = [x for x in rows if not (x["family"] == fam and x["pairs"] == n and x.get("starts", 1) == a.starts)]
            rows.append(res)
            print(json.dumps({k: v for k, v in res.items() if k != "params"}), flush=True)
            path.write_text(json.dumps({"noise": NOISE, "rows": rows}, indent=1))
    lines = ["| family | pairs | starts | texels | alpha within 2 % | all within 2 % or 3 se | fit >= truth | false minima "
             "(flagged) | suspect | unflagged > 10x | refitted | wall s |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for x in sorted(rows, key=lambda x: (list(RANGES).index(x["family"]), x["pairs"], x.get("starts", 1))):
        lines.append(f"| {x['family']} | {x['pairs']} | {x.get('starts', 1)} | {x['texels']} | {x['alpha']:.2%} | {x['all']:.2%} | "
                     f"{x['global']:.2%} | {x['false_minima']} ({x['false_minima_flagged']}) | {x['suspect']} | "
                     f"{x['unflagged_over_10x']} | {x['refitted']} | {x['wall_s']:.1f} |")
    write_table("map_recovery", lines)


if __name__ == "__main__":
    main()
