"""Evaluation throughput of every model: matfit (float32, float64) vs the numpy reference and Mitsuba 3.

For each model, N direction pairs (default 10^6) are evaluated by

* ``numpy``: the independent numpy reference ``numpy_ref`` (at the repository root, shared with the
  tests; float64, complex-arithmetic Fresnel; the smooth plastic and the smooth-coated conductor
  from their documented closed forms); for the GGX conductor also ``numpy_lean``, the vectorized
  baseline of the fitting benchmarks (``numpy_ref.conductor_ggx``: GGX in Cartesian form,
  real-arithmetic Fresnel) as a second baseline;
* ``eval``: ``jax.jit(model.eval)`` on ``(N, 3)`` arrays on one device (the plain user path);
* ``soa``: :func:`matfit.fast.eval_soa` (structure of arrays, one kernel per channel, the batch
  split over ``--devices`` host devices, default 1: one device already uses every core);
* ``mitsuba``: Mitsuba 3's ``llvm_ad_rgb`` variant, ``BSDF.eval`` on the same directions and
  parameters (the cosine factor it includes is divided out for the value comparison), when
  ``mitsuba`` is installed (``--mitsuba-variant cuda_ad_rgb`` on a GPU); the best of a plain call and a
  ``drjit.freeze``-recorded call.

Compile time (first call minus a warm call, or lowering + compilation) is reported apart from the
warm run time; warm repeats of all contenders are interleaved, so that every one sees the same
load of this shared machine, and reported as median and spread ((max - min) / median). Values are
compared too: float32 vs float64, soa vs eval, numpy and Mitsuba vs matfit float64 (max relative
difference over the entries above 1e-6 of the largest value).

    python benchmarks/bench_eval.py [--n 1000000] [--repeat 7] [--models conductor_ggx,lambert]
                                    [--devices 1] [--no-mitsuba] [--out benchmarks/results/bench_eval.json]

``--alone R`` measures instead each contender (numpy, ``jax.jit(model.eval)`` float32, Mitsuba) in
a process of its own, ``R`` rounds of the three processes in turn: nothing else runs in the
process while one is timed. In one process, Mitsuba's worker threads keep spinning for about
10 ms after each of its calls (measured with ``os.times``), and an XLA call right after one ran
several times slower; the interleaved run above orders the contenders so that none follows
Mitsuba directly. Each sample there is one call after other work (cold caches). In ``--alone``
each sample is a warm call followed by ``--number`` timed calls; a contender's figure is the
median over rounds of its per-process medians. Writes ``bench_eval_alone.json``.

The host device count must be fixed before JAX starts, so it is set from ``--devices`` (default:
1, see ``benchmarks/bench_cores.py``) at the top of ``main``.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _common import RESULTS_DIR, interleaved, machine_info, print_table, rate, time_jax, write_json  # noqa: E402

# Gold as Mitsuba's "Au" preset in its RGB variants (so both sides use the same numbers).
AU_ETA = [0.143036, 0.375307, 1.44205]
AU_K = [3.983, 2.38556, 1.60336]
ALBEDO = [0.8, 0.5, 0.2]


# --------------------------------------------------------------------------------------------------
# the models

def model_specs(jnp, M, R):
    """(name, make(dtype), directions, numpy fn(wo, wi), mitsuba dict or None, note)."""
    rgb = lambda v: {"type": "rgb", "value": list(v)}  # noqa: E731
    mi_cond = lambda d: {"type": "roughconductor", "distribution": d, "alpha": 0.2,  # noqa: E731
                         "eta": rgb(AU_ETA), "k": rgb(AU_K)}
    mi_diffuse = {"type": "diffuse", "reflectance": rgb(ALBEDO)}
    A = lambda x, dt: jnp.asarray(x, dt)  # noqa: E731
    return [
        ("lambert", lambda dt: M.Lambert(A(ALBEDO, dt)), "refl",
         lambda wo, wi: R.lambert_eval(wo, wi, ALBEDO), mi_diffuse, ""),
        ("conductor_ggx", lambda dt: M.RoughConductor(A(0.2, dt), A(AU_ETA, dt), A(AU_K, dt)), "refl",
         lambda wo, wi: R.conductor_eval(wo, wi, R.Dist("ggx", 0.2), AU_ETA, AU_K), mi_cond("ggx"), ""),
        ("conductor_beckmann", lambda dt: M.RoughConductor(A(0.2, dt), A(AU_ETA, dt), A(AU_K, dt), "beckmann"),
         "refl", lambda wo, wi: R.conductor_eval(wo, wi, R.Dist("beckmann", 0.2), AU_ETA, AU_K), mi_cond("beckmann"),
         "Mitsuba's Beckmann G1 is a rational approximation (rel. error ~1e-3)"),
        ("conductor_blinn_phong", lambda dt: M.RoughConductor(A(0.2, dt), A(AU_ETA, dt), A(AU_K, dt), "blinn_phong"),
         "refl", lambda wo, wi: R.conductor_eval(wo, wi, R.Dist("blinn_phong", 0.2), AU_ETA, AU_K), None,
         "no Blinn-Phong in Mitsuba 3"),
        ("conductor_ggx_aniso", lambda dt: M.RoughConductor(A(0.1, dt), A(AU_ETA, dt), A(AU_K, dt), alpha_y=A(0.3, dt)),
         "refl", lambda wo, wi: R.conductor_eval(wo, wi, R.Dist("ggx", 0.1, 0.3), AU_ETA, AU_K),
         dict(mi_cond("ggx"), alpha=None, alpha_u=0.1, alpha_v=0.3), ""),
        ("dielectric_ggx", lambda dt: M.RoughDielectric(A(0.2, dt), A(1.5, dt)), "sphere",
         lambda wo, wi: R.dielectric_eval(wo, wi, R.Dist("ggx", 0.2), 1.5),
         {"type": "roughdielectric", "distribution": "ggx", "alpha": 0.2, "int_ior": 1.5, "ext_ior": 1.0},
         "one channel; reflection and transmission"),
        ("plastic_smooth", lambda dt: M.Plastic(A(ALBEDO, dt), 0.0, A(1.5, dt)), "refl",
         lambda wo, wi: R.plastic_smooth_eval(wo, wi, ALBEDO, 1.5),
         {"type": "plastic", "diffuse_reflectance": rgb(ALBEDO), "int_ior": 1.5, "ext_ior": 1.0, "nonlinear": True},
         "Mitsuba's internal Fresnel average is a polynomial fit"),
        ("plastic_rough", lambda dt: M.Plastic(A(ALBEDO, dt), A(0.1, dt), A(1.5, dt)), "refl", None,
         {"type": "roughplastic", "distribution": "ggx", "alpha": 0.1, "diffuse_reflectance": rgb(ALBEDO),
          "int_ior": 1.5, "ext_ior": 1.0, "nonlinear": True},
         "different models of the rough coat's transmittance (matfit: quadrature table; Mitsuba: fitted table)"),
        ("blend_lambert_ggx", lambda dt: M.Blend(M.Lambert(A(ALBEDO, dt)),
                                                 M.RoughConductor(A(0.2, dt), A(AU_ETA, dt), A(AU_K, dt)), A(0.3, dt)),
         "refl", lambda wo, wi: 0.7 * R.lambert_eval(wo, wi, ALBEDO)
         + 0.3 * R.conductor_eval(wo, wi, R.Dist("ggx", 0.2), AU_ETA, AU_K),
         {"type": "blendbsdf", "weight": 0.3, "bsdf_0": mi_diffuse, "bsdf_1": mi_cond("ggx")}, ""),
        ("coated_conductor", lambda dt: M.CoatedConductor(A(0.2, dt), A(AU_ETA, dt), A(AU_K, dt), 0.0, A(1.5, dt)),
         "refl", lambda wo, wi: R.coated_conductor_smooth_eval(wo, wi, R.Dist("ggx", 0.2), AU_ETA, AU_K, 1.5), None,
         "smooth coat over GGX gold; no Mitsuba equivalent"),
        ("stochastic_layered", lambda dt: M.StochasticLayered(M.SmoothDielectric(A(1.5, dt)), M.Lambert(A(ALBEDO, dt)),
                                                              n_samples=64, max_depth=8), "refl", None, None,
         "Monte Carlo model, 64 walks per eval, N/64 pairs"),
    ]


# --------------------------------------------------------------------------------------------------
# Mitsuba

def load_mitsuba(use, variant="llvm_ad_rgb"):
    """((mitsuba, drjit), note) with ``variant`` set, or (None, why not)."""
    if not use:
        return None, "disabled by --no-mitsuba"
    try:
        import drjit as dr
        import mitsuba as mi
    except ImportError as e:
        return None, f"mitsuba not installed ({e}); pip install mitsuba"
    try:
        mi.set_variant(variant)
    except Exception as e:  # noqa: BLE001 - report any failure to start the JIT backend
        needs = "libLLVM (Debian libllvm19)" if variant.startswith("llvm") else "a CUDA driver"
        return None, f"mitsuba variant {variant} unavailable ({type(e).__name__}: {e}); needs {needs}"
    return (mi, dr), f"mitsuba {mi.__version__}, drjit {dr.__version__}, {variant}"


def mitsuba_eval(mod, d, wo, wi):
    """(callables, value(N, C) without the cosine): plain and frozen ``BSDF.eval``."""
    mi, dr = mod
    d = {k: v for k, v in d.items() if v is not None}
    bsdf = mi.load_dict(d)
    si = dr.zeros(mi.SurfaceInteraction3f)
    si.wi = mi.Vector3f(wo[:, 0], wo[:, 1], wo[:, 2])  # Mitsuba's wi points to the viewer: our wo
    si.n = mi.Normal3f(0, 0, 1)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    wim = mi.Vector3f(wi[:, 0], wi[:, 1], wi[:, 2])
    ctx = mi.BSDFContext()
    dr.eval(si, wim)

    def plain():
        v = bsdf.eval(ctx, si, wim)
        dr.eval(v)
        dr.sync_thread()
        return v

    fns = {"mitsuba": plain}
    if hasattr(dr, "freeze"):
        frozen_eval = dr.freeze(lambda s, w: bsdf.eval(ctx, s, w))

        def frozen():
            v = frozen_eval(si, wim)
            dr.eval(v)
            dr.sync_thread()
            return v

        fns["mitsuba_frozen"] = frozen
    v = np.array(plain())
    v = v.T if v.ndim == 2 and v.shape[0] == 3 else v.reshape(len(wo), -1)
    return fns, v / np.abs(wi[:, 2:3])


# --------------------------------------------------------------------------------------------------

def rel_diff(a, b):
    """Max |a - b| / |b| over entries with |b| > 1e-6 max|b| (None when either is missing)."""
    if a is None or b is None:
        return None
    a = np.asarray(a, np.float64).reshape(len(b), -1)
    b = np.asarray(b, np.float64).reshape(len(b), -1)
    if a.shape[1] != b.shape[1]:
        a = np.broadcast_to(a[:, :1], b.shape) if a.shape[1] == 1 else a[:, : b.shape[1]]
    ok = np.abs(b) > 1e-6 * np.max(np.abs(b))
    if not ok.any():
        return 0.0
    bad = ~np.isfinite(a[ok])
    if bad.any():
        return float("inf")
    return float(np.max(np.abs(a[ok] - b[ok]) / np.abs(b[ok])))


def hlo_loops(jitted, *args):
    """Fused loops (``fusion`` instructions of the entry computation) of a jitted function's
    optimized HLO, per device: the number of passes over the batch."""
    txt = jitted.lower(*args).compile().as_text()
    if "\nENTRY" not in txt:  # another backend's text format: nothing to count
        return None
    entry = txt.split("\nENTRY", 1)[1]
    names = [ln.split("=")[0].strip().lstrip("ROOT ").strip("%") for ln in entry.splitlines() if " fusion(" in ln]
    return {"count": len(names), "loops": names}


def directions(R, n, kind, seed=0):
    rng = np.random.default_rng(seed)
    wo = R.random_directions(rng, n, "upper", 1e-3)
    wi = R.random_directions(rng, n, "upper" if kind == "refl" else "both", 1e-3)
    return wo, wi


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=2**20)
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--models", default="all", help="comma-separated names, or 'all'")
    ap.add_argument("--devices", type=int, default=1,
                    help="host devices to split over (1: one device already uses every core)")
    ap.add_argument("--no-mitsuba", action="store_true")
    ap.add_argument("--mitsuba-variant", default="llvm_ad_rgb",
                    help="Mitsuba's JIT variant: llvm_ad_rgb (CPU) or cuda_ad_rgb (GPU runs)")
    ap.add_argument("--numpy-n", type=int, default=None, help="pairs for the numpy baselines (default: --n)")
    ap.add_argument("--out", default=None, help="JSON path (default RESULTS_DIR/bench_eval.json, "
                                                "bench_eval_alone.json with --alone)")
    ap.add_argument("--alone", type=int, default=0, metavar="ROUNDS",
                    help="each contender in a process of its own, ROUNDS rounds (see the docstring)")
    ap.add_argument("--number", type=int, default=5, help="calls per timed sample with --alone")
    ap.add_argument("--alone-child", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.alone_child:
        return alone_child(args)
    if args.alone:
        return run_alone(args)
    args.out = args.out or str(RESULTS_DIR / "bench_eval.json")
    load_start = machine_info()["uptime"]

    import jax

    from matfit.parallel import use_host_devices

    use_host_devices(args.devices)
    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    import matfit.models as M
    import numpy_ref as R
    from matfit.fast import _soa_kernel, eval_soa, soa_pairs, supports_soa

    mit, mit_note = load_mitsuba(not args.no_mitsuba, args.mitsuba_variant)
    print(f"devices: {jax.devices()}; {mit_note}")
    if mit is None:
        print(f"Mitsuba skipped: {mit_note}")
    specs = model_specs(jnp, M, R)
    if args.models != "all":
        want = set(args.models.split(","))
        specs = [s for s in specs if s[0] in want]
    dirs = {}
    rows = []
    t_start = time.time()
    for name, make, dkind, np_fn, mi_dict, note in specs:
        n = args.n // 64 if name == "stochastic_layered" else args.n
        key = (dkind, n)
        if key not in dirs:
            dirs[key] = directions(R, n, dkind)
        wo, wi = dirs[key]
        n_np = min(args.numpy_n or n, n)
        print(f"\n== {name} (N = {n}) {note}", flush=True)
        fns, compile_s, values, loops = {}, {}, {}, {}
        if np_fn is not None:
            wo_np, wi_np = wo[:n_np], wi[:n_np]
            fns["numpy"] = lambda f=np_fn, a=wo_np, b=wi_np: f(a, b)
            values["numpy"] = np_fn(wo, wi) if n_np == n else None
        if name == "conductor_ggx":
            fns["numpy_lean"] = lambda a=wo[:n_np], b=wi[:n_np]: R.conductor_ggx(a, b, 0.2, AU_ETA, AU_K)
        for dname, dt in (("f32", jnp.float32), ("f64", jnp.float64)):
            model = make(dt)
            a, b = jnp.asarray(wo, dt), jnp.asarray(wi, dt)
            f_eval = jax.jit(lambda m, x, y: m.eval(x, y))
            t = time_jax(f_eval, model, a, b, repeat=1)
            compile_s[f"eval_{dname}"] = t["compile_s"]
            values[f"eval_{dname}"] = np.asarray(t["result"])
            fns[f"eval_{dname}"] = lambda c=f_eval, m=model, x=a, y=b: c(m, x, y)
            pairs = soa_pairs(wo, wi, dtype=dt)
            t = time_jax(lambda m=model, p=pairs: eval_soa(m, p), repeat=1, lower=False)
            compile_s[f"soa_{dname}"] = t["compile_s"]
            values[f"soa_{dname}"] = np.stack([np.asarray(o) for o in t["result"]], axis=-1)
            fns[f"soa_{dname}"] = lambda m=model, p=pairs: eval_soa(m, p)
            if name == "conductor_ggx":
                loops[dname] = hlo_loops(_soa_kernel, model, pairs)
            print(f"  compiled {dname}: eval {compile_s[f'eval_{dname}']:.1f} s, soa {compile_s[f'soa_{dname}']:.1f} s"
                  f" ({'SoA kernels' if supports_soa(model) else 'fallback: eval on (N, 3)'})", flush=True)
        if mit is not None and mi_dict is not None:
            t0 = time.perf_counter()
            mfns, values["mitsuba"] = mitsuba_eval(mit, mi_dict, wo.astype(np.float32), wi.astype(np.float32))
            fns.update(mfns)
            compile_s["mitsuba"] = time.perf_counter() - t0
        stats = interleaved(fns, repeat=args.repeat)
        row = {"model": name, "n": n, "n_numpy": n_np if np_fn is not None else None, "note": note,
               "soa_path": "soa" if supports_soa(make(jnp.float64)) else "fallback",
               "calls": {"eval_f32": "jax.jit(lambda m, wo, wi: m.eval(wo, wi))(model, wo, wi); wo, wi (N, 3) float32 "
                                     "(the default call)",
                         "eval_f64": "the same in float64",
                         "soa_f32": "matfit.fast.eval_soa(model, pairs), pairs = soa_pairs(wo, wi) prepared once "
                                    "(tuned: a fit's cached pairs)",
                         "numpy": "the numpy reference (numpy_ref), float64",
                         "mitsuba": "mi.load_dict(d).eval(ctx, si, wi) (llvm_ad_rgb; best of plain and drjit.freeze)"}}
        for k, s in stats.items():
            nn = n_np if k.startswith("numpy") else n
            row[f"{k}_Mps"] = rate(nn, s)
            row[f"{k}_best_Mps"] = rate(nn, s, "min_s")
            row[f"{k}_spread"] = s["spread"]
            row[f"{k}_times_s"] = s["times_s"]
        row["compile_s"] = compile_s
        if loops:
            row["soa_hlo_loops"] = loops
            print(f"  optimized HLO of the SoA kernel: {loops}")
        if "mitsuba_Mps" in row:
            best = max(("mitsuba", "mitsuba_frozen"), key=lambda k: row.get(f"{k}_Mps") or 0)
            row["mitsuba_best"] = best
            row["mitsuba_peer_Mps"] = row[f"{best}_Mps"]
        for dname in ("f32", "f64"):
            for path in ("eval", "soa"):
                r = row.get(f"{path}_{dname}_Mps")
                if "numpy_Mps" in row:
                    row[f"{path}_{dname}_vs_numpy"] = r / row["numpy_Mps"]
                if "numpy_lean_Mps" in row:
                    row[f"{path}_{dname}_vs_numpy_lean"] = r / row["numpy_lean_Mps"]
                if "mitsuba_peer_Mps" in row:
                    row[f"{path}_{dname}_vs_mitsuba"] = r / row["mitsuba_peer_Mps"]
        ref = values["eval_f64"]
        # (a Monte Carlo model draws other random numbers in float32: its f32/f64 difference is noise)
        row["err_f32_vs_f64"] = rel_diff(values["soa_f32"], ref)
        row["err_eval_f32_vs_f64"] = rel_diff(values["eval_f32"], ref)
        row["err_soa_vs_eval_f64"] = rel_diff(values["soa_f64"], ref)
        row["err_numpy_vs_f64"] = rel_diff(ref, values.get("numpy")) if values.get("numpy") is not None else None
        row["err_mitsuba_vs_f64"] = rel_diff(values.get("mitsuba"), ref) if "mitsuba" in values else None
        rows.append(row)
        for k in fns:
            print(f"  {k:16s} {row[f'{k}_Mps']:9.2f} M/s (best {row[f'{k}_best_Mps']:9.2f}, spread {row[f'{k}_spread']:.2f})")
        print(f"  errors: f32 vs f64 {row['err_f32_vs_f64']:.1e}, soa vs eval {row['err_soa_vs_eval_f64']:.1e}, "
              f"numpy {row['err_numpy_vs_f64']}, mitsuba {row['err_mitsuba_vs_f64']}", flush=True)
        write_json("bench_eval", rows, args=vars(args), extra={"mitsuba": mit_note, "load_start": load_start}, path=args.out)

    print(f"\nN = {args.n} pairs, median of {args.repeat} interleaved repeats; M evaluations/s "
          f"({time.time() - t_start:.0f} s total)")
    print("eval: jax.jit(model.eval) on (N, 3) arrays, the default call; soa: eval_soa on pairs prepared once (tuned)")
    print_table(rows, [
        ("model", "model", "s"), ("numpy_Mps", "numpy", ".2f"), ("eval_f32_Mps", "eval f32", ".1f"),
        ("soa_f32_Mps", "soa f32", ".1f"), ("eval_f64_Mps", "eval f64", ".1f"),
        ("mitsuba_peer_Mps", "mitsuba", ".1f"), ("eval_f32_vs_numpy", "eval32/np", ".0f"),
        ("eval_f32_vs_mitsuba", "eval32/mi", ".2f"), ("soa_f32_vs_mitsuba", "soa32/mi", ".2f"),
        ("eval_f32_spread", "spread", ".2f"), ("err_eval_f32_vs_f64", "f32 err", ".1e"),
        ("err_mitsuba_vs_f64", "mi diff", ".1e"),
    ])
    p = write_json("bench_eval", rows, args=vars(args),
                   extra={"mitsuba": mit_note, "load_start": load_start, "load_after": machine_info()["uptime"],
                          "niceness": os.nice(0)},
                   path=args.out)
    print(f"wrote {p}")


# --------------------------------------------------------------------------------------------------
# --alone: every contender in a process of its own

ALONE = ("numpy", "eval_f32", "mitsuba")
ALONE_CALLS = {"numpy": "the numpy reference (numpy_ref), float64",
               "eval_f32": "jax.jit(lambda m, wo, wi: m.eval(wo, wi))(model, wo, wi); wo, wi (N, 3) float32",
               "mitsuba": "mi.load_dict(d).eval(ctx, si, wi) (plain call)"}


def alone_child(args):
    """One contender (``--alone-child``) on every model it has: prints ``RESULT {model: median s}``."""
    import json

    import jax
    import jax.numpy as jnp

    import matfit.models as M
    import numpy_ref as R
    from _common import block

    who = args.alone_child
    if who == "mitsuba":
        mit, note = load_mitsuba(True, args.mitsuba_variant)
        if mit is None:
            print("RESULT " + json.dumps({"error": note}))
            return
    out = {}
    for name, make, dkind, np_fn, mi_dict, _ in model_specs(jnp, M, R):
        if args.models != "all" and name not in args.models.split(","):
            continue
        wo, wi = directions(R, args.n, dkind)
        if who == "numpy":
            if np_fn is None:
                continue
            fn, number = (lambda f=np_fn: f(wo, wi)), 1
        elif who == "mitsuba":
            if mi_dict is None:
                continue
            fn, number = mitsuba_eval(mit, mi_dict, wo.astype(np.float32), wi.astype(np.float32))[0]["mitsuba"], args.number
        else:
            if name == "stochastic_layered":
                continue
            f = jax.jit(lambda m, x, y: m.eval(x, y))
            model, a, b = make(jnp.float32), jnp.asarray(wo, jnp.float32), jnp.asarray(wi, jnp.float32)
            fn, number = (lambda: f(model, a, b)), args.number
        block(fn())
        times = []
        for _ in range(args.repeat):
            block(fn())
            t0 = time.perf_counter()
            for _ in range(number):
                block(fn())
            times.append((time.perf_counter() - t0) / number)
        out[name] = float(np.median(times))
    print("RESULT " + json.dumps(out), flush=True)


def run_alone(args):
    import json
    import subprocess

    load_start = machine_info()["uptime"]
    runs = {who: [] for who in ALONE}
    for _ in range(args.alone):
        for who in ALONE:
            cmd = [sys.executable, __file__, "--alone-child", who, "--models", args.models, "--n", str(args.n),
                   "--repeat", str(args.repeat), "--number", str(args.number), "--mitsuba-variant", args.mitsuba_variant]
            p = subprocess.run(cmd, capture_output=True, text=True)
            lines = [ln for ln in p.stdout.splitlines() if ln.startswith("RESULT ")]
            if p.returncode or not lines:
                raise RuntimeError(f"{' '.join(cmd)} failed:\n{p.stderr[-3000:]}")
            res = json.loads(lines[-1][len("RESULT "):])
            if "error" in res:
                print(f"{who} skipped: {res['error']}")
                continue
            runs[who].append(res)
    names = list(dict.fromkeys(m for who in ("eval_f32", "mitsuba", "numpy") for r in runs[who] for m in r))
    rows = []
    for name in names:
        row = {"model": name, "n": args.n, "calls": ALONE_CALLS}
        for who in ALONE:
            ts = [r[name] for r in runs[who] if name in r]
            if ts:
                row[f"{who}_s_per_round"] = ts
                row[f"{who}_Mps"] = args.n / float(np.median(ts)) / 1e6
        if "eval_f32_Mps" in row:
            for who in ("numpy", "mitsuba"):
                if f"{who}_Mps" in row:
                    row[f"eval_f32_vs_{who}"] = row["eval_f32_Mps"] / row[f"{who}_Mps"]
        rows.append(row)
    print(f"\nN = {args.n} pairs; each contender alone in its process, {args.alone} round(s); M evaluations/s "
          f"(median over rounds of the median of {args.repeat} samples)")
    print_table(rows, [("model", "model", "s"), ("numpy_Mps", "numpy", ".2f"), ("eval_f32_Mps", "eval f32", ".1f"),
                       ("mitsuba_Mps", "mitsuba", ".1f"), ("eval_f32_vs_numpy", "eval/np", ".0f"),
                       ("eval_f32_vs_mitsuba", "eval/mi", ".2f")])
    p = write_json("bench_eval_alone", rows, args=vars(args),
                   extra={"load_start": load_start, "load_after": machine_info()["uptime"]},
                   path=args.out or RESULTS_DIR / "bench_eval_alone.json")
    print(f"wrote {p}")


if __name__ == "__main__":
    main()
