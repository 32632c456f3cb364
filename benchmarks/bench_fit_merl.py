"""Full-MERL Levenberg-Marquardt fits: matfit (JAX, ``method="lm_fd"``) against
``scipy.optimize.least_squares`` on a vectorized numpy model, same start, same loss.

For each family (plastic on ``white-paint``, conductor on ``silver-metallic-paint``; MERL neural
surrogates written by ``shared/tools/merl_surrogate.py``) the whole table is fitted: every valid
cell (about 1.1 million, RGB: 3.3 million residuals) with the E2 loss of Löw et al. 2012,
``r = log(1 + f cos_i) - log(1 + y cos_i)``.

* matfit: ``fit(table, model, method="lm_fd", starts=1)`` in float64 and in float32 (one CPU
  device unless ``XLA_FLAGS=--xla_force_host_platform_device_count=N`` is set: one device
  already uses every core, see ``benchmarks/bench_cores.py``). Compile time (first call minus the warm median) apart; the warm calls are
  repeated (``--repeats``). The time is the whole ``fit`` call: solve, covariance, diagnostics.
* scipy: ``least_squares(method="trf", jac="2-point")`` (its default finite-difference Jacobian,
  one evaluation per parameter) on ``benchmarks/_numpy_models.py``, from the same start
  (``matfit.fitting.initial_guess``), in float64, default tolerances (1e-8).

Both final parameter vectors are evaluated by the same numpy loss in float64: the final losses
must agree to a small relative tolerance (``--loss-rtol``, 1e-6). Iterations: LM accepted steps
(matfit) and Jacobian evaluations (scipy).

Usage: python benchmarks/bench_fit_merl.py [--quick] [--repeats 3] [--scipy-repeats 1]
Writes benchmarks/results/fit_merl.json (or ``--out``; MATFIT_BENCH_RESULTS moves the results folder).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

# One CPU device unless XLA_FLAGS says otherwise: it already runs large loops on every core, and
# two host devices were measured no faster (benchmarks/bench_cores.py; batched fits stall on them).
os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=1")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _numpy_models as nm  # noqa: E402
from _common import print_table, summarize, write_json  # noqa: E402

from matfit.fitting import fit, initial_guess  # noqa: E402
from matfit.fitting.params import Parametrization  # noqa: E402
from matfit.io.merl import read_merl  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
CACHE = REPO / "benchmarks" / "results" / "cache"
CASES = (("plastic", "white-paint"), ("conductor", "silver-metallic-paint"))
LOSS = "e2"


def merl_table(name, shared):
    path = CACHE / f"{name}.binary"
    if not path.exists():
        CACHE.mkdir(parents=True, exist_ok=True)
        (CACHE / ".gitignore").write_text("*\n")
        subprocess.run([sys.executable, str(Path(shared) / "tools" / "merl_surrogate.py"), "--out", str(CACHE), name],
                       check=True, capture_output=True)
    return read_merl(path).to_table(drop_invalid=True)


def numpy_loss(family, z, wo, wi, y):
    r = nm.residuals(family, np.asarray(z, float), wo, wi, y, 1.0, LOSS)
    return 0.5 * float(r @ r)


def run_scipy(family, z0, wo, wi, y):
    from scipy.optimize import least_squares

    with np.errstate(all="ignore"):
        t0 = time.perf_counter()
        res = least_squares(lambda z: nm.residuals(family, z, wo, wi, y, 1.0, LOSS), z0, method="trf", jac="2-point")
        return time.perf_counter() - t0, res


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--shared", default=str(REPO.parent / "shared"))
    ap.add_argument("--repeats", type=int, default=3, help="warm matfit runs")
    ap.add_argument("--scipy-repeats", type=int, default=1, help="scipy runs (each takes minutes)")
    ap.add_argument("--quick", action="store_true", help="a 20,000-row subsample instead of the full table")
    ap.add_argument("--loss-rtol", type=float, default=1e-6)
    ap.add_argument("--families", default="plastic,conductor")
    ap.add_argument("--out", default=None, help="JSON path (default RESULTS_DIR/fit_merl.json; name another for a partial run)")
    ns = ap.parse_args(argv)
    rows = []
    for family, material in CASES:
        if family not in ns.families.split(","):
            continue
        table = merl_table(material, ns.shared)
        if ns.quick:
            table = table.subsample(20000)
        par = Parametrization(family, 3)
        z0 = np.asarray(par.z_from_theta(initial_guess(table, par)))
        wo, wi, y = (np.asarray(a, float) for a in (table.wo, table.wi, table.values))
        print(f"{family} on {material}: {len(table)} cells, start {np.round(np.asarray(par.theta_vector(jnp.asarray(z0))), 4)}",
              flush=True)
        row = {"family": family, "material": material, "cells": len(table), "residuals": 3 * len(table)}
        # scipy baseline first (it needs no compilation); same start, float64.
        times, res = [], None
        for _ in range(ns.scipy_repeats):
            t, res = run_scipy(family, z0, wo, wi, y)
            times.append(t)
        row["scipy"] = {**summarize(times), "loss": numpy_loss(family, res.x, wo, wi, y), "iterations": int(res.njev),
                        "nfev": int(res.nfev), "status": int(res.status), "jac": "2-point (default finite differences)"}
        print(f"  scipy trf: {row['scipy']['median_s']:.1f} s, loss {row['scipy']['loss']:.10g}, "
              f"{res.njev} Jacobians, {res.nfev} evaluations", flush=True)
        for dtype in (jnp.float64, jnp.float32):
            kw = dict(model=family, method="lm_fd", loss=LOSS, starts=1, dtype=dtype)
            t0 = time.perf_counter()
            r = fit(table, **kw)
            first = time.perf_counter() - t0
            times = []
            for _ in range(ns.repeats):
                t0 = time.perf_counter()
                r = fit(table, **kw)
                times.append(time.perf_counter() - t0)
            st = summarize(times)
            loss = numpy_loss(family, r.z, wo, wi, y)
            key = f"matfit_{jnp.dtype(dtype).name}"
            row[key] = {**st, "compile_s": max(first - st["median_s"], 0.0), "first_call_s": first, "loss": loss,
                        "iterations": r.steps, "converged": r.converged,
                        "loss_rel_diff_vs_scipy": (loss - row["scipy"]["loss"]) / row["scipy"]["loss"],
                        "speedup_vs_scipy": row["scipy"]["median_s"] / st["median_s"]}
            print(f"  matfit lm_fd {jnp.dtype(dtype).name}: {st['median_s']:.2f} s (spread {st['spread']:.2f}), "
                  f"compile {row[key]['compile_s']:.1f} s, loss {loss:.10g} "
                  f"(rel. diff {row[key]['loss_rel_diff_vs_scipy']:+.2e}), {r.steps} steps, "
                  f"{row[key]['speedup_vs_scipy']:.1f}x", flush=True)
        row["losses_equal"] = abs(row["matfit_float64"]["loss_rel_diff_vs_scipy"]) <= ns.loss_rtol
        rows.append(row)
    flat = []
    for r in rows:
        for k in ("scipy", "matfit_float64", "matfit_float32"):
            d = r[k]
            flat.append({"case": f"{r['family']} / {r['material']}", "solver": k, "median_s": d["median_s"],
                         "spread": d["spread"], "compile_s": d.get("compile_s"), "iterations": d["iterations"],
                         "loss": d["loss"], "rel": d.get("loss_rel_diff_vs_scipy"), "x": d.get("speedup_vs_scipy")})
    print()
    print_table(flat, [("case", "case", "s"), ("solver", "solver", "s"), ("median_s", "run s", ".2f"),
                       ("spread", "spread", ".2f"), ("compile_s", "compile s", ".1f"), ("iterations", "iter", "d"),
                       ("loss", "final loss", ".8g"), ("rel", "vs scipy", "+.1e"), ("x", "speedup", ".1f")])
    out = write_json("fit_merl", rows, args=vars(ns), extra={"loss": LOSS, "devices": len(jax.devices())},
                     path=ns.out)
    print(f"wrote {out}")
    return rows


if __name__ == "__main__":
    main()
