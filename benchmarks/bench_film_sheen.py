"""The new lobes' default calls: ``model.eval`` (jitted) of the ``film`` family's model (a
thin-film GGX lobe over a wide lobe) and of ``Sheen(Lambert)`` on 2^20 direction pairs, beside
their baselines measured in the same run: the ``lobes2`` model (two Schlick GGX lobes over a
Lambertian base) and ``Lambert``; and ``fresnel_thin_film`` against ``fresnel_dielectric`` on 2^20
cosines. Compilation apart from the warm median; peak RSS of the process at the end.

Usage: python benchmarks/bench_film_sheen.py [--n 1048576] [--repeat 5]
Writes benchmarks/results/film_sheen.json.
"""

from __future__ import annotations

import argparse
import resource
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from _common import print_table, time_jax, write_json  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from matfit.fitting import get_family  # noqa: E402
from matfit.fresnel import fresnel_dielectric, fresnel_thin_film  # noqa: E402
from matfit.models import Lambert, Sheen  # noqa: E402


def _dirs(rng, n):
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2]) + 0.05
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=2**20)
    ap.add_argument("--repeat", type=int, default=5)
    a = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    wo, wi = jnp.asarray(_dirs(rng, a.n)), jnp.asarray(_dirs(rng, a.n))
    film = get_family("film").build({"alpha_1": 0.08, "ks_1": 1.0, "thickness_1": 300.0, "film_eta_1": 1.8,
                                     "eta_1": 1.5, "ratio_2": 4.0, "ks_2": np.array([0.2, 0.1, 0.05]), "f0_2": 1.0}, 3)
    lobes2 = get_family("lobes2").build({"albedo": np.array([0.2, 0.1, 0.05]), "alpha_1": 0.08, "ks_1": np.ones(3),
                                         "f0": 0.04, "ratio_2": 4.0, "ks_2": np.full(3, 0.2)}, 3)
    base = Lambert(jnp.array([0.3, 0.05, 0.1]))
    sheen = Sheen(base, jnp.array([0.9, 0.4, 0.5]), 0.35)
    cos = jnp.asarray(rng.random(a.n))
    calls = [("film model.eval", "MultiLobe: thin-film GGX + wide GGX", lambda m: jax.jit(lambda x, y: m.eval(x, y)), film),
             ("lobes2 model.eval (baseline)", "MultiLobe: Lambert + 2 Schlick GGX", lambda m: jax.jit(lambda x, y: m.eval(x, y)), lobes2),
             ("Sheen(Lambert).eval", "Charlie sheen over Lambert", lambda m: jax.jit(lambda x, y: m.eval(x, y)), sheen),
             ("Lambert.eval (baseline)", "Lambert", lambda m: jax.jit(lambda x, y: m.eval(x, y)), base)]
    rows = []
    for name, what, make, m in calls:
        t = time_jax(make(m), wo, wi, repeat=a.repeat)
        rows.append({"call": name, "what": what, "compile_s": t["compile_s"], "median_s": t["median_s"],
                     "ns_per_pair": 1e9 * t["median_s"] / a.n})
    for name, fn in (("fresnel_thin_film (RGB, 81 wavelengths)", jax.jit(lambda c: fresnel_thin_film(c, 300.0, 1.8, 1.5))),
                     ("fresnel_dielectric (baseline)", jax.jit(lambda c: fresnel_dielectric(c, 1.5)))):
        t = time_jax(fn, cos, repeat=a.repeat)
        rows.append({"call": name, "what": "2^20 cosines", "compile_s": t["compile_s"], "median_s": t["median_s"],
                     "ns_per_pair": 1e9 * t["median_s"] / a.n})
    by = {r["call"]: r for r in rows}
    for r, b in ((rows[0], by["lobes2 model.eval (baseline)"]), (rows[2], by["Lambert.eval (baseline)"]),
                 (rows[4], by["fresnel_dielectric (baseline)"])):
        r["ratio_to_baseline"] = r["median_s"] / b["median_s"]
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print_table(rows, [("call", "call", "s"), ("compile_s", "compile s", ".2f"), ("median_s", "median s", ".4f"),
                       ("ns_per_pair", "ns/pair", ".1f"), ("ratio_to_baseline", "x baseline", ".1f")])
    print(f"peak RSS {peak:.0f} MB (n = {a.n})")
    write_json("film_sheen", rows, args=vars(a), extra={"peak_rss_mb": peak})


if __name__ == "__main__":
    main()
