"""Batched fits of a texel map: ``matfit.fitting.fit_batch`` on 10,000 small tables.

Every texel is a 32-row RGB table at the same 32 direction pairs (a sparse gonioreflectometer
pattern, as in SVBRDF capture), measured from a rough conductor with its own parameters
(alpha in [0.1, 0.5], eta in [0.2, 2.5], k in [1, 5] per channel) and 2 % multiplicative noise.

* matfit: ``fit_batch(tables, model="conductor", method="lm_fd")`` (one start per texel), the
  batch on one CPU device unless ``XLA_FLAGS=--xla_force_host_platform_device_count=N`` is set
  (one device already uses every core; see ``benchmarks/bench_cores.py``). Compile time (first call minus the warm median) apart, warm calls
  repeated. The time includes fit_batch's host work (stacking, data-driven starts).
* baseline: ``scipy.optimize.least_squares`` (trf, 2-point Jacobian) on the numpy model
  (``benchmarks/_numpy_models.py``), one texel after another from the same starts, timed on the
  first ``--scipy-texels`` texels; the final losses of the two are compared texel by texel.

Usage: python benchmarks/bench_batched.py [--texels 10000] [--repeats 3] [--quick]
Writes benchmarks/results/batched.json.
"""

from __future__ import annotations

import argparse
import os
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

from matfit import Table  # noqa: E402
from matfit.fitting import fit_batch, initial_guess  # noqa: E402
from matfit.fitting.params import Parametrization  # noqa: E402
from matfit.models import RoughConductor  # noqa: E402

N_ROWS = 32


def texels(n, seed=0):
    """(tables, true parameter vectors (n, 7)) of a synthetic conductor texel map."""
    rng = np.random.default_rng(seed)

    def dirs(k):
        th = np.arccos(rng.uniform(0.15, 1.0, k))
        ph = rng.uniform(0, 2 * np.pi, k)
        return np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1)

    wo = dirs(N_ROWS)
    # Half of the incident directions near the mirror direction, so the specular peak is sampled.
    wi = dirs(N_ROWS)
    mirror = wo * np.array([-1, -1, 1]) + rng.normal(0, 0.15, (N_ROWS, 3))
    mirror[:, 2] = np.abs(mirror[:, 2]) + 0.1
    wi[: N_ROWS // 2] = (mirror / np.linalg.norm(mirror, axis=1, keepdims=True))[: N_ROWS // 2]
    alpha = rng.uniform(0.1, 0.5, n)
    eta = rng.uniform(0.2, 2.5, (n, 3))
    k = rng.uniform(1.0, 5.0, (n, 3))
    f = jax.jit(jax.vmap(lambda a, e, kk: RoughConductor(a, e, kk).eval(jnp.asarray(wo), jnp.asarray(wi))))(
        alpha, eta, k)
    vals = np.asarray(f) * (1 + 0.02 * rng.standard_normal((n, N_ROWS, 3)))
    tables = [Table(wo=wo, wi=wi, values=v, channels="rgb") for v in vals]
    return tables, np.column_stack([alpha, eta, k])


def scipy_fits(tables, par):
    from scipy.optimize import least_squares

    losses, t0 = [], time.perf_counter()
    for t in tables:
        z0 = np.asarray(par.z_from_theta(initial_guess(t, par)))
        wo, wi, y = np.asarray(t.wo), np.asarray(t.wi), np.asarray(t.values)
        with np.errstate(all="ignore"):
            r = least_squares(lambda z: nm.residuals("conductor", z, wo, wi, y, 1.0), z0, method="trf", jac="2-point")
        losses.append(r.cost)
    return time.perf_counter() - t0, np.array(losses)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--texels", type=int, default=10000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--scipy-texels", type=int, default=200)
    ap.add_argument("--quick", action="store_true", help="1,000 texels, 50 for scipy, 2 repeats")
    ns = ap.parse_args(argv)
    if ns.quick:
        ns.texels, ns.scipy_texels, ns.repeats = 1000, 50, 2
    tables, truth = texels(ns.texels)
    par = Parametrization("conductor", 3)
    rows = []
    for dtype in (jnp.float64, jnp.float32):
        kw = dict(model="conductor", method="lm_fd", loss="l2", starts=1, max_steps=32, dtype=dtype)
        t0 = time.perf_counter()
        values, obj, labels = fit_batch(tables, **kw)
        first = time.perf_counter() - t0
        times = []
        for _ in range(ns.repeats):
            t0 = time.perf_counter()
            values, obj, labels = fit_batch(tables, **kw)
            times.append(time.perf_counter() - t0)
        st = summarize(times)
        rel = np.abs(values - truth) / np.abs(truth)
        rows.append({"solver": f"matfit lm_fd {jnp.dtype(dtype).name}", "texels": ns.texels, **st,
                     "compile_s": max(first - st["median_s"], 0.0), "fits_per_s": ns.texels / st["median_s"],
                     "median_rel_err_alpha": float(np.median(rel[:, 0])), "median_rel_err_eta": float(np.median(rel[:, 1:4])),
                     "median_rel_err_k": float(np.median(rel[:, 4:])), "objective": np.asarray(obj)})
        print(f"{rows[-1]['solver']}: {st['median_s']:.2f} s for {ns.texels} texels "
              f"({rows[-1]['fits_per_s']:.0f} fits/s), compile {rows[-1]['compile_s']:.1f} s, "
              f"median rel. error alpha {rows[-1]['median_rel_err_alpha']:.3f}", flush=True)
    t_sc, loss_sc = scipy_fits(tables[: ns.scipy_texels], par)
    rate_sc = ns.scipy_texels / t_sc
    ours = rows[0]["objective"][: ns.scipy_texels]
    rel_loss = (ours - loss_sc) / loss_sc
    rows.append({"solver": "scipy trf (numpy), one by one", "texels": ns.scipy_texels, "median_s": t_sc, "spread": None,
                 "compile_s": None, "fits_per_s": rate_sc})
    for r in rows[:-1]:
        r["speedup_vs_scipy"] = r["fits_per_s"] / rate_sc
    summary = {"loss_rel_diff_float64_vs_scipy_median": float(np.median(rel_loss)),
               "loss_rel_diff_float64_vs_scipy_max": float(np.max(rel_loss)),
               "texels_lower_than_scipy": int(np.sum(rel_loss < -1e-6)),
               "texels_higher_than_scipy": int(np.sum(rel_loss > 1e-6))}
    print()
    print_table(rows, [("solver", "solver", "s"), ("texels", "texels", "d"), ("median_s", "run s", ".2f"),
                       ("spread", "spread", ".2f"), ("compile_s", "compile s", ".1f"), ("fits_per_s", "fits/s", ".0f"),
                       ("speedup_vs_scipy", "speedup", ".0f")])
    print(f"final loss vs scipy (float64, first {ns.scipy_texels} texels): median rel. diff "
          f"{summary['loss_rel_diff_float64_vs_scipy_median']:+.1e}, max {summary['loss_rel_diff_float64_vs_scipy_max']:+.1e}; "
          f"lower {summary['texels_lower_than_scipy']}, higher {summary['texels_higher_than_scipy']}")
    for r in rows:
        r.pop("objective", None)
    out = write_json("batched", rows, args=vars(ns), extra={"summary": summary, "devices": len(jax.devices()),
                                                          "rows_per_texel": N_ROWS, "family": "conductor"})
    print(f"wrote {out}")
    return rows, summary


if __name__ == "__main__":
    main()
