"""The appearance judge: the default calls ``render_references(MeasuredRGL)`` (the measurement
under both judging lightings, once per file) and ``appearance_difference(fit, refs)`` (the fit's
renders and the three metrics), first calls (compilation) apart from warm ones; beside them the
Monte Carlo preview the report used before (``render_sphere(model, "sky", size=128, spp=32)``),
timed in the same run, with the noise each leaves: the FLIP between two renders of one material
(two seeds for Monte Carlo; the 3x finer quadrature for the noise-free render).

Usage: python benchmarks/bench_appearance.py [--file RGL.bsdf] [--repeat 3]
Writes benchmarks/results/appearance.json.
"""

from __future__ import annotations

import argparse
import resource
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from _common import print_table, time_jax, write_json  # noqa: E402

import numpy as np  # noqa: E402

from matfit.appearance import (LIGHTINGS, appearance_difference, display, flip_map, render_lit,  # noqa: E402
                               render_references)
from matfit.models import MeasuredRGL, MultiLobe, SpecularLobe  # noqa: E402
from matfit.render import render_sphere  # noqa: E402

DEFAULT_FILE = Path(__file__).resolve().parents[2] / "shared/data/rgl/paper_white_rgb.bsdf"


def _row(call, what, fn, repeat):
    t = time_jax(fn, repeat=repeat, lower=False)
    return {"call": call, "what": what, "first_s": t["first_call_s"], "median_s": t["median_s"],
            "times_s": t["times_s"]}, t["result"]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--file", default=str(DEFAULT_FILE))
    ap.add_argument("--repeat", type=int, default=3)
    ns = ap.parse_args(argv)
    meas = MeasuredRGL.from_file(ns.file)
    import jax.numpy as jnp

    fitted = MultiLobe(jnp.array([0.72, 0.73, 0.87]), [SpecularLobe(0.54, weight=1.0, f0=0.16)])  # paper's lobes1 fit
    row, refs = _row("render_references(MeasuredRGL(file))", "measurement, sky + studio, 96 px",
                     lambda: render_references(meas), ns.repeat)
    rows = [row]
    rows.append(_row("appearance_difference(fit, refs)", "fit's renders + FLIP, CIEDE2000, ITP",
                     lambda: appearance_difference(fitted, refs), ns.repeat)[0])
    for name in ("sky", "studio"):
        rows.append(_row(f'render_lit(MeasuredRGL, "{name}")', f"{LIGHTINGS[name].directions.shape[0]} directions",
                         lambda: render_lit(meas, name), ns.repeat)[0])
    rows.append(_row('render_sphere(MeasuredRGL, "sky", size=128, spp=32)', "baseline: the old Monte Carlo preview",
                     lambda: render_sphere(meas, "sky", size=128, spp=32), ns.repeat)[0])
    base = rows[-1]["median_s"]
    for r in rows:
        r["vs_baseline"] = r["median_s"] / base
    # the noise each leaves: FLIP between two renders of the same material
    e = LIGHTINGS["sky"].exposure
    a, inside = render_lit(meas, "sky")
    b, _ = render_lit(meas, "sky", refine=3)
    quad_floor = float(flip_map(display(a, e), display(b, e))[inside].mean())
    m1 = render_sphere(meas, "sky", size=96, spp=32, seed=0)
    m2 = render_sphere(meas, "sky", size=96, spp=32, seed=1)
    mc_floor = float(flip_map(display(m1, e) * inside[..., None], display(m2, e) * inside[..., None])[inside].mean())
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print_table(rows, [("call", "call", "s"), ("what", "what", "s"), ("first_s", "first s", ".2f"),
                       ("median_s", "warm s", ".3f"), ("vs_baseline", "vs MC preview", ".2f")])
    print(f"noise floor (sky, mean FLIP over the sphere): quadrature vs 3x finer {quad_floor:.4f}; "
          f"Monte Carlo 32 spp, two seeds {mc_floor:.4f}; peak RSS {peak:.0f} MB")
    write_json("appearance", rows, args=vars(ns), extra={"noise_floor_flip": {"quadrature_vs_3x_finer": quad_floor,
               "monte_carlo_32spp_two_seeds": mc_floor}, "peak_rss_mb": peak})


if __name__ == "__main__":
    main()
