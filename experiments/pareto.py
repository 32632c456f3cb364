"""What accuracy costs in time: error against run time for matfit's accuracy knobs.

One small sweep per knob, each against a reference computed with the same code at a much higher
setting (or in float64), run time warm (compile time is reported apart in the JSON):

1. dtype: Plastic (rough coat) and RoughConductor on 200,000 pairs, float32 vs float64;
   error = max relative difference to float64 (values above 1e-3 of the maximum).
2. coat quadrature: Plastic's coat transmittance table, Gauss-Legendre order per axis x tabulated
   cosines (default 12 x 24); error = max relative error of f against order 32 x 96 nodes.
3. StochasticLayered sample count (smooth coat 1.5 over Lambert 0.5, where Plastic is exact):
   error = max abs. error of f at 2 direction pairs.
4. aperture quadrature (data_synth.effects.cone_directions, 2 degree cone, GGX conductor
   alpha 0.1): n_polar x n_azimuth; error = max relative error against 16 x 32.
5. table subsampling for fitting: conductor fitted (lm_fd, E2) to n rows of the MERL
   silver-metallic-paint surrogate; error = relative excess of the full-table E2 loss at the
   subsample's solution over the full-table fit's loss.
6. optimizer: lm_fd, optimistix lm, optimistix bfgs on 20,000 rows of the same table; error =
   relative excess of the final loss over the best.
7. MCMC length: emcee (32 walkers) on the benchmarks/bench_emcee.py posterior; error = max over
   parameters of |posterior mean - reference mean| / reference std (reference: 8,000 steps).

The Pareto front of each knob (settings no other setting beats in both error and time) is drawn
in experiments/results/pareto.png; the numbers go to experiments/results/pareto.json.

Usage: python experiments/pareto.py [--skip fit,mcmc,...]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

# One CPU device, as in benchmarks/: it already runs large loops on every core, and two host
# devices were measured no faster (benchmarks/bench_cores.py).
os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=1")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO / "benchmarks"))
sys.path.insert(0, str(REPO))
OUT = REPO / "experiments" / "results"


def timed(fn, *args, repeat=3):
    """(result, compile_s, median warm run_s)."""
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    first = time.perf_counter() - t0
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = jax.block_until_ready(fn(*args))
        ts.append(time.perf_counter() - t0)
    med = float(np.median(ts))
    return out, max(first - med, 0.0), med


def rand_dirs(rng, n, lo=0.05):
    th = np.arccos(rng.uniform(lo, 1.0, n))
    ph = rng.uniform(0, 2 * np.pi, n)
    return np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1)


def rel_err(a, ref):
    a, ref = np.asarray(a, float), np.asarray(ref, float)
    m = np.abs(ref) > 1e-3 * np.abs(ref).max()
    return float(np.max(np.abs(a[m] - ref[m]) / np.abs(ref[m])))


def sweep(run, ref_setting, settings, knob, case, label):
    """Rows of one quadrature knob: ``run(*setting) -> (out, compile_s, time_s)`` at each setting,
    its relative error against ``run(*ref_setting)``."""
    ref, _, _ = run(*ref_setting)
    rows = []
    for setting in settings:
        out, c, t = run(*setting)
        rows.append({"knob": knob, "case": case, "setting": label(*setting), "error": rel_err(out, ref), "time_s": t,
                     "compile_s": c})
    return rows


def knob_dtype(rng):
    from matfit.models import Plastic, RoughConductor

    wo, wi = rand_dirs(rng, 200_000), rand_dirs(rng, 200_000)
    rows = []
    for name, make in (("plastic", lambda dt: Plastic(jnp.asarray([0.6, 0.3, 0.1], dt), jnp.asarray(0.2, dt), jnp.asarray(1.5, dt))),
                       ("conductor", lambda dt: RoughConductor(jnp.asarray(0.2, dt), jnp.asarray([0.2, 0.9, 1.4], dt),
                                                               jnp.asarray([3.6, 2.5, 1.9], dt)))):
        ref = None
        for dt in (jnp.float64, jnp.float32):
            f = jax.jit(lambda wo, wi, m: m.eval(wo, wi))
            out, c, t = timed(f, jnp.asarray(wo, dt), jnp.asarray(wi, dt), make(dt))
            ref = out if ref is None else ref
            rows.append({"knob": "dtype", "case": name, "setting": jnp.dtype(dt).name, "error": rel_err(out, ref) or 1e-17,
                         "time_s": t, "compile_s": c})
    return rows


def knob_coat(rng):
    from matfit.models import Plastic
    from matfit.models._coat import coat_transmittance_table

    wo, wi = jnp.asarray(rand_dirs(rng, 50_000)), jnp.asarray(rand_dirs(rng, 50_000))
    m = Plastic(jnp.asarray([0.6, 0.3, 0.1]), 0.3, 1.5)

    def run(order, nodes):
        f = jax.jit(lambda wo, wi, m: m._eval_t(wo, wi, coat_transmittance_table(m.coat, order=order, nodes=nodes)))
        return timed(f, wo, wi, m)

    return sweep(run, (32, 96), ((4, 8), (6, 12), (8, 16), (12, 24), (16, 48), (24, 64)), "coat quadrature",
                 "plastic alpha 0.3", lambda order, nodes: f"{order}x{order}, {nodes} nodes")


def knob_stochastic(rng):
    from matfit.models import Lambert, Plastic, SmoothDielectric, StochasticLayered

    wo = jnp.array([[0.0, 0.0, 1.0], [np.sin(1.0), 0.0, np.cos(1.0)]])
    wi = jnp.array([[0.3, 0.2, np.sqrt(1 - 0.13)], [-0.5, 0.1, np.sqrt(1 - 0.26)]])
    ref = np.asarray(Plastic(0.5, 0.0, 1.5).eval(wo, wi))
    rows = []
    for log2n in (8, 10, 12, 14):
        sl = StochasticLayered(SmoothDielectric(1.5), Lambert(0.5), n_samples=2**log2n, max_depth=24)
        f = jax.jit(lambda wo, wi, key, sl=sl: sl.eval_with_error(wo, wi, key)[0])
        out, c, t = timed(f, wo, wi, jax.random.PRNGKey(log2n))
        rows.append({"knob": "stochastic layered samples", "case": "smooth coat / Lambert", "setting": f"{2**log2n}",
                     "error": float(np.max(np.abs(np.asarray(out) - ref))), "time_s": t, "compile_s": c})
    return rows


def knob_aperture(rng):
    from data_synth.effects import cone_directions
    from matfit.models import RoughConductor

    wo, wi = rand_dirs(rng, 2592, 0.2), rand_dirs(rng, 2592, 0.2)
    wi = wo * np.array([-1, -1, 1]) * 0.7 + 0.3 * wi
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    m = RoughConductor(0.1, jnp.asarray([0.2, 0.9, 1.4]), jnp.asarray([3.6, 2.5, 1.9]))

    def run(npol, naz):
        d, w = cone_directions(wo, 2.0, npol, naz)
        f = jax.jit(lambda d, wi, w: jnp.einsum("nqc,q->nc", m.eval(d, jnp.broadcast_to(wi[:, None], d.shape)), w))
        return timed(f, jnp.asarray(d), jnp.asarray(wi), jnp.asarray(w))

    return sweep(run, (16, 32), ((1, 1), (1, 4), (2, 4), (2, 8), (4, 8), (8, 16)), "aperture quadrature",
                 "2 deg cone, alpha 0.1", lambda npol, naz: f"{npol}x{naz}")


def _merl_conductor():
    from bench_fit_merl import merl_table

    return merl_table("silver-metallic-paint", str(REPO.parent / "shared"))


def knob_fit(rng):
    import _numpy_models as nm

    from matfit.fitting import fit

    full = _merl_conductor()
    wo, wi, y = (np.asarray(a, float) for a in (full.wo, full.wi, full.values))

    def full_loss(z):
        r = nm.residuals("conductor", np.asarray(z, float), wo, wi, y, 1.0, "e2")
        return 0.5 * float(r @ r)

    rows = []
    sizes = (2_000, 8_000, 32_000, 128_000, len(full))
    res = {}
    for n in sizes:
        t = full if n == len(full) else full.subsample(n, seed=1)
        fit(t, model="conductor", method="lm_fd", loss="e2", starts=1)  # compile
        t0 = time.perf_counter()
        r = fit(t, model="conductor", method="lm_fd", loss="e2", starts=1)
        res[n] = (time.perf_counter() - t0, full_loss(r.z))
    best = min(v[1] for v in res.values())
    for n in sizes:
        rows.append({"knob": "table subsampling (fit)", "case": "conductor, MERL silver-metallic-paint", "setting": f"{n} rows",
                     "error": max((res[n][1] - best) / best, 1e-12), "time_s": res[n][0], "compile_s": None})
    sub = full.subsample(20_000, seed=2)
    res = {}
    for method in ("lm_fd", "lm", "bfgs"):
        fit(sub, model="conductor", method=method, loss="e2", starts=1, max_steps=512)
        t0 = time.perf_counter()
        r = fit(sub, model="conductor", method=method, loss="e2", starts=1, max_steps=512)
        res[method] = (time.perf_counter() - t0, r.objective)
    best = min(v[1] for v in res.values())
    for method, (t, o) in res.items():
        rows.append({"knob": "optimizer", "case": "conductor, 20,000 MERL rows", "setting": method,
                     "error": max((o - best) / best, 1e-12), "time_s": t, "compile_s": None})
    return rows


def knob_mcmc(rng):
    import emcee
    from bench_emcee import TRUE, table

    from matfit.fitting import make_log_prob
    from matfit.fitting.params import Parametrization

    t = table()
    par = Parametrization("conductor", 3)
    lp = make_log_prob(t, "conductor", noise="table", block=16)
    p0 = np.asarray(par.z_from_theta(TRUE)) + 1e-3 * np.random.default_rng(1).standard_normal((32, par.size))

    def chain(steps, seed):
        s = emcee.EnsembleSampler(32, par.size, lp, vectorize=True)
        t0 = time.perf_counter()
        s.run_mcmc(emcee.State(p0, random_state=np.random.RandomState(seed).get_state()), steps, progress=False)
        x = lp.to_natural(s.get_chain(discard=steps // 4, flat=True))
        return x, time.perf_counter() - t0

    ref, _ = chain(8000, 99)
    mu, sd = ref.mean(0), ref.std(0)
    rows = []
    for steps in (250, 500, 1000, 2000, 4000):
        x, t = chain(steps, steps)
        rows.append({"knob": "MCMC length", "case": "conductor posterior, 32 walkers", "setting": f"{steps} steps",
                     "error": float(np.max(np.abs(x.mean(0) - mu) / sd)), "time_s": t, "compile_s": None})
    return rows


KNOBS = {"dtype": knob_dtype, "coat": knob_coat, "stochastic": knob_stochastic, "aperture": knob_aperture,
         "fit": knob_fit, "mcmc": knob_mcmc}


def pareto_front(rows):
    """Indices of the rows no other row beats in both error and time."""
    return [i for i, r in enumerate(rows)
            if not any((o["error"] <= r["error"] and o["time_s"] <= r["time_s"]) and
                       (o["error"] < r["error"] or o["time_s"] < r["time_s"]) for o in rows)]


def plot(rows, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker  # noqa: F401

    groups = {}
    for r in rows:
        groups.setdefault((r["knob"], r["case"]), []).append(r)
    n = len(groups)
    cols = 3
    fig, axes = plt.subplots((n + cols - 1) // cols, cols, figsize=(4.2 * cols, 3.4 * ((n + cols - 1) // cols)))
    for ax, ((knob, case), rs) in zip(np.ravel(axes), groups.items()):
        t = np.array([r["time_s"] for r in rs])
        e = np.array([max(r["error"], 1e-17) for r in rs])
        front = pareto_front(rs)
        ax.scatter(t, e, c="0.6", s=18)
        order = sorted(front, key=lambda i: t[i])
        ax.plot(t[order], e[order], "o-", c="C3", ms=5, label="Pareto front")
        for r, ti, ei in zip(rs, t, e):
            ax.annotate(r["setting"], (ti, ei), fontsize=6, xytext=(3, 3), textcoords="offset points")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(f"{knob}\n{case}", fontsize=8)
        ax.set_xlabel("time (s)", fontsize=7)
        ax.set_ylabel("error", fontsize=7)
        ax.tick_params(labelsize=6)
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.yaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    for ax in np.ravel(axes)[n:]:
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--skip", default="", help="comma-separated knobs to skip: " + ",".join(KNOBS))
    ap.add_argument("--plot-only", action="store_true", help="redraw pareto.png from pareto.json")
    ns = ap.parse_args(argv)
    if ns.plot_only:
        plot(json.loads((OUT / "pareto.json").read_text())["rows"], OUT / "pareto.png")
        return
    rng = np.random.default_rng(0)
    rows = []
    for name, fn in KNOBS.items():
        if name in ns.skip.split(","):
            continue
        t0 = time.perf_counter()
        new = fn(rng)
        for r in new:
            print(f"{r['knob']:28s} {r['case']:38s} {r['setting']:22s} error {r['error']:.2e}  time {r['time_s']:.4f} s",
                  flush=True)
        print(f"  ({name}: {time.perf_counter() - t0:.0f} s in all)", flush=True)
        rows += new
    for key in {(r["knob"], r["case"]) for r in rows}:
        grp = [r for r in rows if (r["knob"], r["case"]) == key]
        for i in pareto_front(grp):
            grp[i]["pareto"] = True
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "pareto.json").write_text(json.dumps({"jax": jax.__version__, "devices": len(jax.devices()),
                                                 "load": os.getloadavg(), "rows": rows}, indent=1))
    plot(rows, OUT / "pareto.png")
    print(f"wrote {OUT / 'pareto.json'} and {OUT / 'pareto.png'}")


if __name__ == "__main__":
    main()
