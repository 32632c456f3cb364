"""emcee throughput: matfit's vectorized JAX log-posterior against a numpy log-posterior.

Posterior of the conductor family (7 parameters) given a synthetic 2048-row RGB table with known
sigma (2 % noise), Gaussian likelihood, uniform priors, sampled in the unconstrained ``z`` space
(``matfit.fitting.make_log_prob``, ``noise="table"``). The numpy log-posterior
(``benchmarks/_numpy_models.log_prob``) is the same function, checked equal at the start.

* log-probability evaluations per second: one emcee half-ensemble (``n_walkers/2`` points) per
  call; matfit evaluates them in one jitted, vmapped call, numpy one point after another.
* emcee steps per second and effective samples per second: ``EnsembleSampler`` runs of
  ``--steps`` steps (matfit, ``vectorize=True``) and ``--numpy-steps`` (numpy) from the same
  start, interleaved in ``--rounds`` rounds (each round continues every sampler for its share of
  the steps): the speedup is reported over the whole runs and per round (median, min, max), so
  that the machine's load changing between contenders shows as spread; effective samples =
  walkers * steps / max(tau), with tau estimated on the matfit chain (the same sampler and
  target: the autocorrelation time does not depend on who evaluates).

``--cores 1`` limits the process to one core before JAX starts (``matfit.parallel.use_cores``):
XLA's thread pool then has one thread, and these small calls (16 points x 2048 rows) run faster
without handing their loops to a second one. ``--sync`` also turns JAX's asynchronous CPU
dispatch off (``matfit.parallel.for_small_calls``): the caller runs each call itself instead of
handing it to a runtime thread and waiting. Both contenders run in that same process.

Usage: python benchmarks/bench_emcee.py [--steps 3000] [--numpy-steps 200] [--rounds 5] [--quick] [--cores 1] [--sync]
Writes benchmarks/results/emcee.json.
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
from matfit.fitting import make_log_prob  # noqa: E402
from matfit.fitting.params import Parametrization  # noqa: E402
from matfit.parallel import for_small_calls, use_cores  # noqa: E402
from matfit.models import RoughConductor  # noqa: E402

N_ROWS = 2048
TRUE = {"alpha": 0.25, "eta": [0.2, 0.9, 1.4], "k": [3.6, 2.5, 1.9]}


def table(seed=0):
    rng = np.random.default_rng(seed)

    def dirs(k):
        th = np.arccos(rng.uniform(0.1, 1.0, k))
        ph = rng.uniform(0, 2 * np.pi, k)
        return np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1)

    wo, wi = dirs(N_ROWS), dirs(N_ROWS)
    f = np.asarray(RoughConductor(TRUE["alpha"], jnp.asarray(TRUE["eta"]), jnp.asarray(TRUE["k"])).eval(
        jnp.asarray(wo), jnp.asarray(wi)))
    sigma = 0.02 * f + 1e-4
    return Table(wo=wo, wi=wi, values=f + sigma * rng.standard_normal(f.shape), sigma=sigma, channels="rgb")


def main(argv=None):
    import emcee

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--walkers", type=int, default=32)
    ap.add_argument("--steps", type=int, default=3000)
    ap.add_argument("--numpy-steps", type=int, default=200)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--rounds", type=int, default=5,
                    help="the emcee runs are interleaved in this many rounds (a speedup per round)")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--cores", type=int, default=None,
                    help="limit the process to this many cores before JAX starts (matfit.parallel.use_cores)")
    ap.add_argument("--out", default=None, help="JSON path (default RESULTS_DIR/emcee.json)")
    ap.add_argument("--sync", action="store_true",
                    help="JAX's asynchronous CPU dispatch off, with --cores if given (matfit.parallel.for_small_calls)")
    ns = ap.parse_args(argv)
    if ns.sync:
        for_small_calls(ns.cores)
    elif ns.cores:
        use_cores(ns.cores)
    if ns.quick:
        ns.steps, ns.numpy_steps, ns.repeats, ns.rounds = 600, 40, 3, 2
    t = table()
    par = Parametrization("conductor", 3)
    z_true = np.asarray(par.z_from_theta(TRUE))
    wo, wi, y, sig = (np.asarray(a, float) for a in (t.wo, t.wi, t.values, t.sigma))
    np_lp = lambda z: nm.log_prob("conductor", z, wo, wi, y, sig)  # noqa: E731
    rng = np.random.default_rng(1)
    p0 = z_true + 1e-3 * rng.standard_normal((ns.walkers, par.size))
    half = p0[: ns.walkers // 2]
    rows = []
    # ---- evaluations per second (one half-ensemble per call)
    st_np = summarize([_timed(lambda: [np_lp(x) for x in half]) for _ in range(ns.repeats)])
    rows.append({"evaluator": "numpy (one point at a time)", "dtype": "float64", **st_np, "compile_s": None,
                 "evals_per_s": len(half) / st_np["median_s"]})
    ref = np.array([np_lp(x) for x in half])
    lps = {}
    for dtype in (jnp.float64, jnp.float32):
        lp = make_log_prob(t, "conductor", noise="table", block=len(half), dtype=dtype)
        t0 = time.perf_counter()
        out = lp(half)
        first = time.perf_counter() - t0
        st = summarize([_timed(lambda: lp(half)) for _ in range(ns.repeats)])
        rows.append({"evaluator": "matfit make_log_prob (vmapped, jitted)", "dtype": jnp.dtype(dtype).name, **st,
                     "compile_s": max(first - st["median_s"], 0.0), "evals_per_s": len(half) / st["median_s"],
                     "max_abs_diff_vs_numpy": float(np.max(np.abs(out - ref)))})
        lps[jnp.dtype(dtype).name] = lp
    for r in rows[1:]:
        r["speedup_evals"] = r["evals_per_s"] / rows[0]["evals_per_s"]
    print_table(rows, [("evaluator", "log-probability", "s"), ("dtype", "dtype", "s"), ("evals_per_s", "evals/s", ".0f"),
                       ("spread", "spread", ".2f"), ("compile_s", "compile s", ".1f"),
                       ("max_abs_diff_vs_numpy", "|lp - lp_numpy|", ".1e"), ("speedup_evals", "speedup", ".0f")])
    # ---- emcee runs, interleaved: each round runs every sampler for its share of the steps, so
    # that a change in the machine's load between contenders shows as spread, not as a ratio
    contenders = (("matfit float64", lps["float64"], ns.steps, True),
                  ("matfit float32", lps["float32"], ns.steps, True),
                  ("numpy", np_lp, ns.numpy_steps, False))
    runs = []
    for name, fn, steps, vec in contenders:
        sampler = emcee.EnsembleSampler(ns.walkers, par.size, fn, vectorize=vec)
        runs.append({"evaluator": name, "steps": 0, "wall_s": 0.0, "round_steps_per_s": [], "sampler": sampler,
                     "state": emcee.State(p0, random_state=np.random.RandomState(0).get_state())})
    for k in range(ns.rounds):
        for r, (_, _, steps, _) in zip(runs, contenders):
            n = steps // ns.rounds + (k < steps % ns.rounds)
            t0 = time.perf_counter()
            r["state"] = r["sampler"].run_mcmc(r["state"], n, progress=False)
            wall = time.perf_counter() - t0
            r["steps"] += n
            r["wall_s"] += wall
            r["round_steps_per_s"].append(n / wall)
    for r in runs:
        r["steps_per_s"] = r["steps"] / r["wall_s"]
        r["acceptance"] = float(np.mean(r["sampler"].acceptance_fraction))
    tau = np.asarray(runs[0]["sampler"].get_autocorr_time(tol=0, discard=ns.steps // 4,
                                                           quiet=True))
    tau_max = float(np.max(tau))
    base = runs[-1]
    for r in runs:
        r["tau_max"] = tau_max
        r["ess_per_s"] = ns.walkers * r["steps_per_s"] / tau_max
        r["speedup_per_step"] = r["steps_per_s"] / base["steps_per_s"]
        ratios = [a / b for a, b in zip(r["round_steps_per_s"], base["round_steps_per_s"])]
        r["speedup_rounds"] = ratios
        r["speedup_median"] = float(np.median(ratios))
        r["speedup_min"], r["speedup_max"] = float(np.min(ratios)), float(np.max(ratios))
        r.pop("sampler")
        r.pop("state")
    print()
    print_table(runs, [("evaluator", "emcee with", "s"), ("steps", "steps", "d"), ("wall_s", "wall s", ".1f"),
                       ("steps_per_s", "steps/s", ".1f"), ("ess_per_s", "eff. samples/s", ".1f"),
                       ("acceptance", "acceptance", ".2f"), ("speedup_per_step", "speedup", ".1f"),
                       ("speedup_median", "median/round", ".1f"), ("speedup_min", "min", ".1f"),
                       ("speedup_max", "max", ".1f")])
    print(f"tau (max over parameters) = {tau_max:.1f} steps, {ns.walkers} walkers")
    out = write_json("emcee", {"evaluations": rows, "runs": runs}, args=vars(ns),
                     extra={"rows": N_ROWS, "family": "conductor", "devices": len(jax.devices()),
                            "cores_allowed": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
                            "async_dispatch": bool(jax.config.values["jax_cpu_enable_async_dispatch"])},
                     path=ns.out)
    print(f"wrote {out}")
    return rows, runs


def _timed(fn):
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


if __name__ == "__main__":
    main()
