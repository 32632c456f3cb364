"""Preview renders: the default call ``render_sphere(model, "sky")`` (256 x 256, 64 spp, MIS)
per model, with the first call (compilation plus one render) timed apart from warm calls, and
the furnace (BSDF sampling only) and BSDF-only sampling beside it for the cost of each strategy.

Usage: python benchmarks/bench_render.py [--quick] [--repeat 3] [--out PATH]
Writes benchmarks/results/render.json.
"""

from __future__ import annotations

import argparse
import resource
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from _common import print_table, write_json  # noqa: E402

from matfit.models import Blend, Lambert, Plastic, RoughConductor, RoughDielectric  # noqa: E402
from matfit.render import render_sphere  # noqa: E402

GOLD = ([0.143, 0.374, 1.442], [3.983, 2.385, 1.603])
MODELS = {
    "Lambert": Lambert([0.7, 0.5, 0.3]),
    "RoughConductor GGX": RoughConductor(0.2, *GOLD),
    "RoughDielectric": RoughDielectric(0.3, 1.5),
    "Plastic (rough coat)": Plastic([0.7, 0.2, 0.1], 0.15, 1.5),
    "Blend Lambert+GGX": Blend(Lambert([0.7, 0.5, 0.3]), RoughConductor(0.2, *GOLD), 0.5),
}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="64 x 64 images")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out", default=None)
    ns = ap.parse_args(argv)
    size = 64 if ns.quick else 256
    rows = []
    for name, m in MODELS.items():
        for env, strategy in (("sky", "mis"), ("sky", "bsdf"), ("furnace", "mis")):
            call = f'render_sphere(model, "{env}"' + (f', strategy="{strategy}"' if strategy != "mis" else "") + \
                   (f", size={size}" if size != 256 else "") + ")"
            t0 = time.perf_counter()
            render_sphere(m, env, size=size, strategy=strategy)
            first = time.perf_counter() - t0
            warm = []
            for _ in range(ns.repeat):
                t0 = time.perf_counter()
                render_sphere(m, env, size=size, strategy=strategy)
                warm.append(time.perf_counter() - t0)
            rows.append({"model": name, "call": call, "first_s": first, "warm_s": statistics.median(warm),
                         "spread": (max(warm) - min(warm)) / statistics.median(warm),
                         "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024})
            print(f"{name:22s} {call:50s} first {first:6.2f} s  warm {rows[-1]['warm_s']:6.2f} s", flush=True)
    print_table(rows, [("model", "model", "s"), ("call", "call", "s"), ("first_s", "first s", ".2f"),
                       ("warm_s", "warm s", ".2f"), ("peak_rss_mb", "peak RSS MB", ".0f")])
    p = write_json("render", rows, args=vars(ns), path=ns.out)
    print(f"wrote {p}")


if __name__ == "__main__":
    main()
