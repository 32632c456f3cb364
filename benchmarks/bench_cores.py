"""How JAX uses the CPU cores: one device on every core, one device on one core, two host devices.

``docs/performance.md`` and ``matfit.parallel`` once assumed that XLA's CPU backend runs one
fused loop on one core, so that only splitting the batch over host devices
(``--xla_force_host_platform_device_count``) would use the second core. This script measures it,
each configuration in its own process (the device count is fixed when JAX starts):

* ``1 device``: the kernel on the default single CPU device, every core allowed;
* ``1 device, 1 core``: the same process pinned to one core (``os.sched_setaffinity``);
* ``2 host devices``: the batch sharded over two host devices (``NamedSharding``), every core allowed.

Kernels (N = 2^21, float32): a compute-bound chain of 30 ``sin`` (one output) and
``matfit.fast.eval_soa`` of the GGX rough conductor (RGB, N = 10^6).

Usage: python benchmarks/bench_cores.py [--repeat 15]
Writes benchmarks/results/cores.json.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent

CHILD = r"""
import json, os, sys, time
cfg = json.loads(sys.argv[1])
os.environ["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={cfg['devices']}"
if cfg["pin"]:
    os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
sys.path.insert(0, cfg["repo"])
import jax, jax.numpy as jnp, numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec as P
from matfit.fast import eval_soa, soa_pairs
from matfit.models import RoughConductor

def times(fn, repeat):
    jax.block_until_ready(fn())
    out = []
    for _ in range(repeat):
        t = time.perf_counter(); jax.block_until_ready(fn()); out.append(time.perf_counter() - t)
    return out

@jax.jit
def chain(x):
    for _ in range(30):
        x = jnp.sin(x) * 1.01 + 0.1
    return x

devs = jax.devices()
x = np.random.default_rng(0).random(2 ** 21).astype(np.float32)
xs = jax.device_put(x, NamedSharding(Mesh(np.array(devs), ("d",)), P("d"))) if len(devs) > 1 else jnp.asarray(x)
rng = np.random.default_rng(1)
def dirs(n):
    v = rng.normal(size=(n, 3)); v[:, 2] = np.abs(v[:, 2]); return (v / np.linalg.norm(v, axis=1, keepdims=True)).astype(np.float32)
m = RoughConductor(0.3, jnp.array([0.2, 0.9, 1.1], jnp.float32), jnp.array([3.9, 2.4, 1.6], jnp.float32))
pairs = soa_pairs(dirs(10 ** 6), dirs(10 ** 6), devices=devs)
print(json.dumps({"sin_chain_s": times(lambda: chain(xs), cfg["repeat"]),
                  "eval_soa_s": times(lambda: eval_soa(m, pairs), cfg["repeat"]),
                  "cores_allowed": len(os.sched_getaffinity(0)), "jax_devices": len(devs)}))
"""

CONFIGS = [("1 device", 1, False), ("1 device, 1 core", 1, True), ("2 host devices", 2, False)]


def main(argv=None):
    sys.path.insert(0, str(HERE))
    from _common import print_table, summarize, write_json

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=15)
    args = ap.parse_args(argv)
    rows = []
    for name, devices, pin in CONFIGS:
        cfg = {"devices": devices, "pin": pin, "repeat": args.repeat, "repo": str(HERE.parent)}
        out = subprocess.run([sys.executable, "-c", CHILD, json.dumps(cfg)], capture_output=True, text=True, check=True)
        res = json.loads(out.stdout.strip().splitlines()[-1])
        s1, s2 = summarize(res["sin_chain_s"]), summarize(res["eval_soa_s"])
        rows.append({"config": name, "jax_devices": res["jax_devices"], "cores_allowed": res["cores_allowed"],
                     "sin_chain_ms": 1e3 * s1["median_s"], "sin_chain_spread": s1["spread"],
                     "eval_soa_Mps": 1.0 / s2["median_s"], "eval_soa_spread": s2["spread"],
                     "sin_times_s": res["sin_chain_s"], "eval_times_s": res["eval_soa_s"]})
    base = rows[0]
    for r in rows:
        r["sin_speed_vs_1_device"] = base["sin_chain_ms"] / r["sin_chain_ms"]
        r["eval_speed_vs_1_device"] = r["eval_soa_Mps"] / base["eval_soa_Mps"]
    print_table(rows, [("config", "configuration", "s"), ("jax_devices", "devices", "d"),
                       ("cores_allowed", "cores", "d"), ("sin_chain_ms", "sin chain ms", ".0f"),
                       ("sin_speed_vs_1_device", "speed", ".2f"), ("eval_soa_Mps", "eval_soa M/s", ".0f"),
                       ("eval_speed_vs_1_device", "speed", ".2f")])
    write_json("cores", {"rows": rows}, args=vars(args))


if __name__ == "__main__":
    main()
