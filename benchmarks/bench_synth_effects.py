"""Time per synthetic scene with and without each effect (data_synth).

Each variant is the base scene plus one effect (and one with all of them). Every variant is run once to
compile, then timed ``--repeat`` times (median reported). The table also shows the number of direction
pairs handed to ``model.eval`` (from :class:`data_synth.EvalCounter`): without an aperture it equals the
number of valid rows, a reflection-only scene evaluates no transmission pair.

    python benchmarks/bench_synth_effects.py [--repeat 3] [--out benchmarks/results/bench_synth_effects.json]
"""
from __future__ import annotations

import argparse
import copy
import json
import platform
import statistics
import time
from pathlib import Path

import jax

from _common import RESULTS_DIR  # benchmarks/ is on sys.path for a script run directly
from data_synth import EvalCounter, parse_scene, synthesize

BASE = {
    "scene": {"name": "bench", "seed": 0},
    "geometry": {"kind": "hemisphere", "theta_i": [0.0, 30.0, 60.0], "n_theta": 18, "n_phi": 48},
    "material": {"model": "RoughConductor", "metal": "gold", "alpha": 0.2},
}
GLASS = {"model": "RoughDielectric", "alpha": 0.3, "eta": 1.5}


def variants():
    def v(name, material=None, **effects):
        d = copy.deepcopy(BASE)
        if material is not None:
            d["material"] = copy.deepcopy(material)
        if effects:
            d["effects"] = effects
        return name, d

    noise = {"relative": 0.02, "photons": 1e4, "gain": 0.02, "outliers": 0.01}
    return [
        v("conductor: point, rgb (baseline)"),
        v("conductor: + aperture 1 deg (4x8)", aperture={"half_angle": 1.0}),
        v("conductor: + noise (rel+poisson+gain+outliers)", noise=noise),
        v("conductor: + jitter 0.2 deg", noise={"jitter": 0.2}),
        v("conductor: + spectral 41 wl -> rgb", colour={"mode": "spectral"}),
        v("conductor: all of the above", aperture={"half_angle": 1.0}, noise=dict(noise, jitter=0.2),
          colour={"mode": "spectral"}),
        v("glass: reflection only (baseline)", material=GLASS),
        v("glass: + transmission", material=GLASS, transmission=True),
        v("glass: transmission + aperture", material=GLASS, transmission=True, aperture={"half_angle": 1.0}),
    ]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out", default=str(RESULTS_DIR / "bench_synth_effects.json"))
    args = ap.parse_args(argv)
    rows = []
    for name, d in variants():
        scene = parse_scene(d)
        c = EvalCounter()
        t0 = time.perf_counter()
        table = synthesize(scene, counter=c)
        first = time.perf_counter() - t0
        times = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            synthesize(scene)
            times.append(time.perf_counter() - t0)
        rows.append({"variant": name, "rows": len(table), "valid": table.n_valid, "eval_pairs": c.pairs,
                     "transmission_pairs": c.transmission_pairs, "aperture_rules": c.aperture_rules,
                     "first_run_s": round(first, 4), "median_s": round(statistics.median(times), 4),
                     "effects": scene.effects})
    w = max(len(r["variant"]) for r in rows)
    print(f"{'variant':<{w}}  {'rows':>6} {'eval pairs':>10} {'trans.':>6} {'first (s)':>9} {'median (s)':>10}")
    for r in rows:
        print(f"{r['variant']:<{w}}  {r['rows']:>6} {r['eval_pairs']:>10} {r['transmission_pairs']:>6} "
              f"{r['first_run_s']:>9.3f} {r['median_s']:>10.4f}")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    meta = {"benchmark": "bench_synth_effects", "repeat": args.repeat, "jax": jax.__version__,
            "backend": jax.default_backend(), "machine": platform.machine(), "python": platform.python_version(),
            "date": time.strftime("%Y-%m-%dT%H:%M:%S")}
    out.write_text(json.dumps({"meta": meta, "results": rows}, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
