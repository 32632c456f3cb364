"""Error of the StochasticLayered reference against the sample count and the time spent.

Two stacks with a closed form (a smooth coat over a Lambertian base, where Plastic with internal
reflection is exact): the directional albedo and the BRDF value at fixed directions are
estimated with n = 2^8 ... 2^14 walks, and the absolute error against the closed form is
reported with the wall time (compile time reported apart). A third, rough-coated stack has no
closed form: there the table reports the random walk's standard error and its difference from
the analytic Plastic (the analytic model's own error).

Prints a table and writes benchmarks/results/stochastic_layered.json.
"""

from __future__ import annotations

import json
import platform

import jax

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from _common import RESULTS_DIR, time_jax  # noqa: E402  (benchmarks/ is on sys.path for a script run directly)
from matfit.models import Lambert, Plastic, RoughDielectric, SmoothDielectric, StochasticLayered  # noqa: E402

WO = jnp.array([[0.0, 0.0, 1.0], [np.sin(1.0), 0.0, np.cos(1.0)]])
WI = jnp.array([[0.3, 0.2, np.sqrt(1 - 0.13)], [-0.5, 0.1, np.sqrt(1 - 0.26)]])


def timed(fn, *args):
    """(result, compile s, median warm run s) of a jitted function (benchmarks/_common.time_jax)."""
    t = time_jax(fn, *args, repeat=3)
    return t["result"], t["compile_s"], t["median_s"]


def main():
    cases = [
        ("smooth coat 1.5 / Lambert 0.5", SmoothDielectric(1.5), 0.5, Plastic(0.5, 0.0, 1.5)),
        ("smooth coat 1.5 / Lambert 1.0", SmoothDielectric(1.5), 1.0, Plastic(1.0, 0.0, 1.5)),
        ("rough coat GGX 0.3 / Lambert 0.5", RoughDielectric(0.3, 1.5), 0.5, Plastic(0.5, 0.3, 1.5)),
    ]
    rows = []
    print(f"{'stack':34s} {'n':>6s} {'|dE| vs closed':>14s} {'|df| vs closed':>14s} {'stderr f':>9s} {'run s':>7s} {'compile s':>9s}")
    for name, coat, rho, analytic in cases:
        e_ref = np.asarray(analytic.albedo(WO))[:, 0]
        f_ref = np.asarray(analytic.eval(WO, WI))[:, 0]
        for log2n in (8, 10, 12, 14):
            n = 2**log2n
            sl = StochasticLayered(coat, Lambert(rho), n_samples=n, max_depth=24)
            f_eval = jax.jit(lambda wo, wi, key, sl=sl: sl.eval_with_error(wo, wi, key))
            e_eval = jax.jit(lambda wo, key, sl=sl: sl.albedo(wo, key=key))
            (f, se), c1, t1 = timed(f_eval, WO, WI, jax.random.PRNGKey(log2n))
            e, c2, t2 = timed(e_eval, WO, jax.random.PRNGKey(100 + log2n))
            row = {
                "stack": name,
                "n_samples": n,
                "albedo_abs_err": float(np.max(np.abs(np.asarray(e)[:, 0] - e_ref))),
                "f_abs_err": float(np.max(np.abs(np.asarray(f)[:, 0] - f_ref))),
                "f_stderr": float(np.max(np.asarray(se))),
                "run_s": t1 + t2,
                "compile_s": c1 + c2,
                "closed_form_exact": "smooth" in name,
            }
            rows.append(row)
            print(f"{name:34s} {n:6d} {row['albedo_abs_err']:14.2e} {row['f_abs_err']:14.2e} {row['f_stderr']:9.2e} {row['run_s']:7.3f} {row['compile_s']:9.2f}")
    out = RESULTS_DIR / "stochastic_layered.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"machine": platform.processor() or platform.machine(), "cpus": jax.device_count(),
                               "jax": jax.__version__, "rows": rows}, indent=1))
    print(f"wrote {out}")
    print("For the rough coat the 'closed' column is the analytic Plastic, itself approximate: the walk's")
    print("stderr shrinking while |df| stays put measures the analytic model's error, not the walk's.")


if __name__ == "__main__":
    main()
