"""Full-MERL fits through the default call, ``fit(table, model=family)``, against
``scipy.optimize.least_squares`` on a vectorized numpy model, same start, same loss.

For each family (plastic on ``white-paint``, conductor on ``silver-metallic-paint``; MERL neural
surrogates written by ``shared/tools/merl_surrogate.py``) the whole table is fitted: every valid
cell (about 1.1 million, RGB: 3.3 million residuals).

* matfit, **default call**: ``fit(table, model=family)`` with no other argument (method
  ``lm_fd``, loss ``l2``, 4 starts), in float32 and in float64 (``jax_enable_x64``), each in its
  own process so that its peak resident memory (``ru_maxrss``, the whole process: JAX, the
  table, compilation, the fit) is its own. Compile time (first call minus the warm median)
  apart; warm calls repeated (``--repeats``). The time is the whole ``fit`` call: starts, solve,
  covariance, diagnostics.
* matfit, tuned call (``--tuned``, labelled): ``fit(table, model, method="lm_fd", loss="e2",
  starts=1)``, the setting of earlier measurements, with scipy on the E2 loss beside it.
* scipy: ``least_squares(method="trf", jac="2-point")`` (its default finite-difference Jacobian,
  one evaluation per parameter) on ``benchmarks/_numpy_models.py``, from the data-driven start
  (``matfit.fitting.initial_guess``), in float64, default tolerances (1e-8).

Both final parameter vectors are evaluated by the same numpy loss in float64 (``vs scipy``: the
relative difference of the final losses; negative means matfit ended lower). Iterations: LM
accepted steps (matfit, best start) and Jacobian evaluations (scipy).

Usage: python benchmarks/bench_fit_merl.py [--quick] [--repeats 3] [--families plastic,conductor] [--tuned]
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

import jax  # noqa: E402  (float64 only in the float64 child: the default call runs in JAX's default dtype)
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


def merl_table(name, shared):
    path = CACHE / f"{name}.binary"
    if not path.exists():
        CACHE.mkdir(parents=True, exist_ok=True)
        (CACHE / ".gitignore").write_text("*\n")
        subprocess.run([sys.executable, str(Path(shared) / "tools" / "merl_surrogate.py"), "--out", str(CACHE), name],
                       check=True, capture_output=True)
    return read_merl(path).to_table()


def numpy_loss(family, z, wo, wi, y, loss):
    r = nm.residuals(family, np.asarray(z, float), wo, wi, y, 1.0, loss)
    return 0.5 * float(r @ r)


def run_scipy(family, z0, wo, wi, y, loss):
    from scipy.optimize import least_squares

    with np.errstate(all="ignore"):
        t0 = time.perf_counter()
        res = least_squares(lambda z: nm.residuals(family, z, wo, wi, y, 1.0, loss), z0, method="trf", jac="2-point")
        return time.perf_counter() - t0, res


def peak_rss_mb():
    """This process's peak resident memory (MB): ``VmHWM`` of ``/proc/self/status``, which starts
    afresh at exec (``ru_maxrss`` keeps the parent's resident size at the fork that started us)."""
    import resource

    try:
        for line in open("/proc/self/status"):
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def child(family, material, dtype, tuned, repeats, quick, shared):
    """One configuration in this process: prints one JSON line with times, loss and peak RSS."""
    import json

    if dtype == "float64":
        jax.config.update("jax_enable_x64", True)
    table = merl_table(material, shared)
    if quick:
        table = table.subsample(20000)
    kw = dict(method="lm_fd", loss="e2", starts=1) if tuned else {}
    t0 = time.perf_counter()
    r = fit(table, model=family, **kw)
    first = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        r = fit(table, model=family, **kw)
        times.append(time.perf_counter() - t0)
    peak = peak_rss_mb()  # before the numpy loss below
    valid = table.valid
    wo, wi, y = (np.asarray(a, float)[valid] for a in (table.wo, table.wi, table.values))
    out = {**summarize(times), "first_call_s": first, "compile_s": max(first - float(np.median(times)), 0.0),
           "loss": numpy_loss(family, r.z, wo, wi, y, r.loss), "iterations": r.steps, "converged": r.converged,
           "warnings": r.warnings, "info": r.info, "peak_rss_mb": peak,
           "call": f"fit(table, model={family!r}{''.join(f', {k}={v!r}' for k, v in kw.items())})"
                   + (" with jax_enable_x64" if dtype == "float64" else "")}
    print("RESULT " + json.dumps(out), flush=True)


def run_child(family, material, dtype, tuned, ns):
    import json

    cmd = [sys.executable, __file__, "--child", family, material, dtype, "--repeats", str(ns.repeats),
           "--shared", ns.shared] + (["--tuned"] if tuned else []) + (["--quick"] if ns.quick else [])
    p = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, "MATFIT_NO_CACHE": "1"})
    lines = [ln for ln in p.stdout.splitlines() if ln.startswith("RESULT ")]
    if p.returncode or not lines:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{p.stderr[-3000:]}")
    return json.loads(lines[-1][len("RESULT "):])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--shared", default=str(REPO.parent / "shared"))
    ap.add_argument("--repeats", type=int, default=3, help="warm matfit calls")
    ap.add_argument("--scipy-repeats", type=int, default=1, help="scipy runs (each takes minutes)")
    ap.add_argument("--quick", action="store_true", help="a 20,000-row subsample instead of the full table")
    ap.add_argument("--families", default="plastic,conductor")
    ap.add_argument("--tuned", action="store_true", help="also the tuned call (lm_fd, e2, one start), labelled")
    ap.add_argument("--child", nargs=3, metavar=("FAMILY", "MATERIAL", "DTYPE"), help=argparse.SUPPRESS)
    ap.add_argument("--out", default=None, help="JSON path (default RESULTS_DIR/fit_merl.json; name another for a partial run)")
    ns = ap.parse_args(argv)
    if ns.child:
        return child(*ns.child, ns.tuned, ns.repeats, ns.quick, ns.shared)
    rows = []
    for family, material in CASES:
        if family not in ns.families.split(","):
            continue
        table = merl_table(material, ns.shared)
        if ns.quick:
            table = table.subsample(20000)
        par = Parametrization(family, 3)
        z0 = np.asarray(par.z_from_theta(initial_guess(table, par)))
        valid = table.valid
        wo, wi, y = (np.asarray(a, float)[valid] for a in (table.wo, table.wi, table.values))
        print(f"{family} on {material}: {len(table)} cells ({valid.sum()} valid)", flush=True)
        for tuned in ((False, True) if ns.tuned else (False,)):
            loss = "e2" if tuned else "l2"
            label = "tuned (lm_fd, e2, 1 start)" if tuned else "default call"
            row = {"family": family, "material": material, "cells": int(valid.sum()), "setting": label, "loss": loss}
            times, res = [], None
            for _ in range(ns.scipy_repeats):
                t, res = run_scipy(family, z0, wo, wi, y, loss)
                times.append(t)
            row["scipy"] = {**summarize(times), "loss": numpy_loss(family, res.x, wo, wi, y, loss),
                            "iterations": int(res.njev), "nfev": int(res.nfev), "status": int(res.status)}
            print(f"  [{label}] scipy trf ({loss}): {row['scipy']['median_s']:.1f} s, loss {row['scipy']['loss']:.10g}, "
                  f"{res.njev} Jacobians", flush=True)
            for dtype in ("float64", "float32"):
                d = run_child(family, material, dtype, tuned, ns)
                d["loss_rel_diff_vs_scipy"] = (d["loss"] - row["scipy"]["loss"]) / row["scipy"]["loss"]
                d["speedup_vs_scipy"] = row["scipy"]["median_s"] / d["median_s"]
                row[f"matfit_{dtype}"] = d
                print(f"  [{label}] {d['call']}: {d['median_s']:.2f} s (spread {d['spread']:.2f}), compile "
                      f"{d['compile_s']:.1f} s, peak RSS {d['peak_rss_mb']:.0f} MB, loss {d['loss']:.10g} "
                      f"({d['loss_rel_diff_vs_scipy']:+.2e} vs scipy), {d['iterations']} steps, "
                      f"{d['speedup_vs_scipy']:.1f}x scipy", flush=True)
            rows.append(row)
    flat = []
    for r in rows:
        for k in ("scipy", "matfit_float64", "matfit_float32"):
            d = r[k]
            flat.append({"case": f"{r['family']} / {r['setting']}", "solver": k, "median_s": d["median_s"],
                         "compile_s": d.get("compile_s"), "rss": d.get("peak_rss_mb"), "iterations": d["iterations"],
                         "loss": d["loss"], "rel": d.get("loss_rel_diff_vs_scipy"), "x": d.get("speedup_vs_scipy")})
    print()
    print_table(flat, [("case", "case", "s"), ("solver", "solver", "s"), ("median_s", "run s", ".2f"),
                       ("compile_s", "compile s", ".1f"), ("rss", "peak RSS MB", ".0f"), ("iterations", "iter", "d"),
                       ("loss", "final loss", ".8g"), ("rel", "vs scipy", "+.1e"), ("x", "speedup", ".1f")])
    out = write_json("fit_merl", rows, args=vars(ns), extra={"devices": len(jax.devices())}, path=ns.out)
    print(f"wrote {out}")
    return rows


if __name__ == "__main__":
    main()
