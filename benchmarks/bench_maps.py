"""Parameter maps: ``matfit.maps.fit_map`` on a synthetic capture, and a 4096 x 4096 map's memory.

* **throughput** (default call): a 256 x 256 capture of 24 images (16-bit sRGB PNG, 1 % noise,
  alpha 0.05-0.6, ``data_synth.capture.render_capture``) loaded with ``load_capture`` and fitted
  by ``fit_map(cap.wo, cap.wi, cap.values, valid=cap.valid)`` (family ``diffuse_specular``, JAX's
  default float32); first call (compilation included) and the median of warm calls; the CLI
  ``matfit fit-map CAPTURE -o DIR --quiet`` timed as a process (persistent compile cache on).
* **baseline**, same run: ``scipy.optimize.least_squares`` (trf, 2-point Jacobian) on the numpy
  model (``numpy_ref.diffuse_specular_ggx``), relative residuals, texel after texel from the same
  data-driven starts, on the first ``--scipy-texels`` texels.
* **memory**: a 4096 x 4096 x 24 x 3 float32 value array on disk (``numpy.lib.format.open_memmap``,
  4.8 GB; only the fitted rows are rendered, the rest of the file stays a hole), fitted with a
  ``mask`` of the first ``--rows`` rows; every output map is allocated at the full 4096 x 4096
  size, so the peak resident memory (``VmHWM``) is that of the whole map's outputs plus one
  chunk's working set; the rows fitted add nothing (chunks are read with ``os.pread``).

Each configuration runs in its own process for its own peak RSS.

Usage: python benchmarks/bench_maps.py [--repeats 3] [--scipy-texels 200] [--rows 256] [--quick]
Writes benchmarks/results/maps.json.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))


def peak_rss_mb():
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def child_throughput(size, repeats, scipy_texels, workdir):
    import numpy as np
    from scipy.optimize import least_squares

    from _common import summarize

    import numpy_ref as R
    from data_synth.capture import ramp_maps, render_capture
    from matfit.fitting import Parametrization, guesses_from_arrays
    from matfit.maps import fit_map, load_capture

    truth = ramp_maps(size, size)
    cap_dir = render_capture(Path(workdir) / "capture", truth, model="diffuse_specular", noise=0.01, fmt="png16")
    t = time.perf_counter()
    cap = load_capture(cap_dir)
    load_s = time.perf_counter() - t
    call = lambda: fit_map(cap.wo, cap.wi, cap.values, valid=cap.valid)  # noqa: E731  the default call
    t = time.perf_counter()
    r = call()
    first = time.perf_counter() - t
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        r = call()
        times.append(time.perf_counter() - t)
    n = int(r.fitted.sum())
    acc = {k: {"within_2pct_rel": float(np.mean(np.abs(r.params[k] / truth[k] - 1) < 0.02)),
               "within_0.02_abs": float(np.mean(np.abs(r.params[k] - truth[k]) < 0.02))} for k in truth}
    s = fit_map(cap.wo, cap.wi, cap.values, valid=cap.valid, smooth=1e5)
    acc_smooth = {k: float(np.mean(np.abs(s.params[k] / truth[k] - 1) < 0.02)) for k in truth}
    # scipy baseline on the first texels, same starts, same (relative) residuals
    par = Parametrization("diffuse_specular", 3)
    V = cap.values.reshape(-1, cap.n_images, 3)[:scipy_texels].astype(float)
    wo, wi = cap.wo.astype(float), cap.wi.astype(float)
    g = guesses_from_arrays(np.broadcast_to(wo, V.shape), np.broadcast_to(wi, V.shape), V,
                            np.ones(V.shape[:2], bool), par)
    lo, hi = par.lower_upper()

    def theta(z):
        return lo + (hi - lo) / (1 + np.exp(-z))

    t = time.perf_counter()
    mine = r.objective.reshape(-1)[:scipy_texels]
    theirs = []
    for b in range(V.shape[0]):
        th0 = np.concatenate([g["albedo"][b], g["f0"][b], [g["alpha"][b]]])
        z0 = np.log((th0 - lo) / (hi - th0))
        y = V[b]

        def res(z):
            th = theta(z)
            return ((R.diffuse_specular_ggx(wo, wi, th[0:3], th[3:6], th[6]) - y) / (np.abs(y) + 1e-3)).ravel()

        sol = least_squares(res, z0, method="trf", max_nfev=64 * 8)
        theirs.append(sol.cost)
    scipy_s = time.perf_counter() - t
    st = summarize(times)
    return {"texels": n, "load_s": load_s, "first_call_s": first, "warm": st,
            "texels_per_s": n / st["median_s"], "scipy_texels": V.shape[0], "scipy_s": scipy_s,
            "scipy_texels_per_s": V.shape[0] / scipy_s, "speedup_vs_scipy": (n / st["median_s"]) / (V.shape[0] / scipy_s),
            "loss_rel_diff_vs_scipy_median": float(np.median(mine / np.asarray(theirs) - 1)),
            "accuracy": acc, "accuracy_smooth_1e5": acc_smooth, "converged": float(r.converged.mean()),
            "peak_rss_mb": peak_rss_mb(), "capture": str(cap_dir)}


def child_memory(size, rows, workdir):
    import jax
    import jax.numpy as jnp
    import numpy as np

    from data_synth.capture import capture_directions, ramp_maps
    from matfit.maps import fit_map
    from matfit.models import DiffuseSpecular

    lights, cams = capture_directions(24)
    path = Path(workdir) / "values.npy"
    f = jax.jit(jax.vmap(lambda a, b, c: DiffuseSpecular(b, c, a).eval(jnp.asarray(cams), jnp.asarray(lights))))
    band = 64

    def truth_band(r0, r1):  # rows r0..r1 of the size x size maps (not held whole)
        m = ramp_maps(size, size, rows=(r0, r1))
        return m["alpha"], m["albedo"], m["f0"]

    # written band after band with plain writes (pages written through a mapping would count in
    # this process's resident memory); rows past `rows` stay a hole of zeros
    with open(path, "wb") as fh:
        np.lib.format.write_array_header_1_0(fh, {"descr": "<f4", "fortran_order": False,
                                                  "shape": (size, size, 24, 3)})
        for r0 in range(0, rows, band):
            a, b, c = truth_band(r0, min(rows, r0 + band))
            fh.write(np.asarray(f(a.reshape(-1), b.reshape(-1, 3), c.reshape(-1, 3)), np.float32).tobytes())
        fh.truncate(fh.tell() + (size - rows) * size * 24 * 3 * 4)
    values = np.load(path, mmap_mode="r")
    mask = np.zeros((size, size), bool)
    mask[:rows] = True
    rss_before = peak_rss_mb()
    t = time.perf_counter()
    r = fit_map(cams, lights, values, mask=mask)
    wall = time.perf_counter() - t
    rss = peak_rss_mb()
    good = 0
    for r0 in range(0, rows, band):
        a = truth_band(r0, min(rows, r0 + band))[0]
        good += int(np.sum(np.abs(r.params["alpha"][r0:r0 + band] / a - 1) < 1e-3))
    ok = good / (rows * size)
    return {"map": [size, size], "rows_fitted": rows, "texels_fitted": int(r.fitted.sum()), "wall_s": wall,
            "texels_per_s": int(r.fitted.sum()) / wall, "peak_rss_mb": rss,
            "peak_rss_before_fit_mb": rss_before, "values_file_gb": path.stat().st_size / 1e9,
            "alpha_within_0.1pct_noise_free": ok}


def child_cli(capture):
    import shutil

    cache = tempfile.mkdtemp(prefix="matfit-cache-")
    env = dict(os.environ, MATFIT_CACHE_DIR=cache)
    out = []
    for i in range(2):
        d = tempfile.mkdtemp(prefix="maps-")
        t = time.perf_counter()
        subprocess.run([sys.executable, "-m", "matfit", "fit-map", capture, "-o", d, "--quiet"], check=True, env=env,
                       stdout=subprocess.DEVNULL)
        out.append(time.perf_counter() - t)
        shutil.rmtree(d)
    shutil.rmtree(cache)
    return {"call": "matfit fit-map CAPTURE -o DIR --quiet", "first_process_s": out[0], "second_process_s": out[1]}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--scipy-texels", type=int, default=200)
    ap.add_argument("--rows", type=int, default=256)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--big", type=int, default=4096)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--child", default=None)
    ap.add_argument("--workdir", default=None)
    args = ap.parse_args()
    if args.child:
        sys.path.insert(0, str(HERE.parent))
        fn = {"throughput": lambda: child_throughput(args.size, args.repeats, args.scipy_texels, args.workdir),
              "memory": lambda: child_memory(args.big, args.rows, args.workdir)}[args.child]
        print("RESULT " + json.dumps(fn()))
        return
    if args.quick:
        args.size, args.repeats, args.scipy_texels, args.big, args.rows = 64, 1, 20, 512, 64
    from _common import print_table, write_json

    results = {}
    with tempfile.TemporaryDirectory() as work:
        for name in ("throughput", "memory"):
            cmd = [sys.executable, __file__, "--child", name, "--workdir", work, "--size", str(args.size),
                   "--repeats", str(args.repeats), "--scipy-texels", str(args.scipy_texels), "--rows", str(args.rows),
                   "--big", str(args.big)]
            p = subprocess.run(cmd, capture_output=True, text=True, env=dict(os.environ, PYTHONPATH=str(HERE.parent)))
            line = [x for x in p.stdout.splitlines() if x.startswith("RESULT ")]
            if p.returncode or not line:
                raise SystemExit(f"{name} failed:\n{p.stderr[-3000:]}")
            results[name] = json.loads(line[0][7:])
        results["cli"] = child_cli(results["throughput"]["capture"])
    t, m, c = results["throughput"], results["memory"], results["cli"]
    print_table([
        {"call": f"fit_map(cap.wo, cap.wi, cap.values, valid=cap.valid), {t['texels']} texels", "s": t["warm"]["median_s"],
         "rate": t["texels_per_s"], "rss": t["peak_rss_mb"], "x": t["speedup_vs_scipy"]},
        {"call": "  first call (compilation included)", "s": t["first_call_s"], "rate": t["texels"] / t["first_call_s"]},
        {"call": f"scipy least_squares, texel by texel ({t['scipy_texels']})", "s": t["scipy_s"],
         "rate": t["scipy_texels_per_s"], "x": 1.0},
        {"call": f"fit_map, {m['map'][0]}x{m['map'][1]} map, first {m['rows_fitted']} rows (memmap)", "s": m["wall_s"],
         "rate": m["texels_per_s"], "rss": m["peak_rss_mb"]},
        {"call": c["call"] + " (first process)", "s": c["first_process_s"]},
        {"call": c["call"] + " (second process)", "s": c["second_process_s"]},
    ], [("call", "call", "s"), ("s", "wall s", ".2f"), ("rate", "texels/s", ".0f"), ("rss", "peak RSS MB", ".0f"),
        ("x", "vs scipy", ".0f")])
    print("accuracy:", json.dumps(t["accuracy"]), "\nwith smooth=1e5:", json.dumps(t["accuracy_smooth_1e5"]))
    write_json("maps", results, args=vars(args))


if __name__ == "__main__":
    main()
