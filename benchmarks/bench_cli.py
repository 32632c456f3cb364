"""Two consecutive ``matfit fit`` processes on one measured file, with a fresh compilation cache.

The first process compiles the fit and writes the compiled programs to the persistent cache
(:mod:`matfit.cache`); the second loads them. Each is timed as a whole command (start of Python
to exit), as a user meets it:

    matfit fit ../shared/data/rgl/paper_white_rgb.bsdf --model plastic

``MATFIT_CACHE_DIR`` points at a new temporary folder, so the first run is cold. A third run
with ``MATFIT_NO_CACHE=1`` shows what every process paid before the cache.

Usage: python benchmarks/bench_cli.py [--file PATH] [--model plastic] [--no-uncached]
Writes benchmarks/results/cli.json (or ``--out``).
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import print_table, write_json  # noqa: E402

REPO = Path(__file__).resolve().parent.parent


def timed(cmd, env):
    t0 = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    if p.returncode:
        raise RuntimeError(f"{' '.join(cmd)} failed ({p.returncode}):\n{p.stderr[-2000:]}")
    return wall, p.stdout


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--file", default=str(REPO.parent / "shared" / "data" / "rgl" / "paper_white_rgb.bsdf"))
    ap.add_argument("--model", default="plastic")
    ap.add_argument("--no-uncached", action="store_true", help="skip the run without the cache")
    ap.add_argument("--out", default=None)
    ns = ap.parse_args(argv)
    if not Path(ns.file).exists():
        raise SystemExit(f"{ns.file}: no such file (the RGL files are in ../shared/data/rgl)")
    exe = shutil.which("matfit", path=str(Path(sys.executable).parent)) or shutil.which("matfit")
    cmd = [exe, "fit", ns.file, "--model", ns.model] if exe else [sys.executable, "-m", "matfit", "fit", ns.file,
                                                                  "--model", ns.model]
    cache = Path(tempfile.mkdtemp(prefix="matfit-cache-"))
    env = {**os.environ, "MATFIT_CACHE_DIR": str(cache)}
    env.pop("MATFIT_NO_CACHE", None)
    rows = []
    try:
        for label in ("first process (cold cache)", "second process (warm cache)"):
            wall, out = timed(cmd, env)
            rows.append({"run": label, "wall_s": wall, "cache_mb": sum(f.stat().st_size for f in cache.rglob("*")
                                                                        if f.is_file()) / 2**20,
                         "first_line": out.splitlines()[0] if out else ""})
            print(f"{label}: {wall:.1f} s", flush=True)
        if not ns.no_uncached:
            wall, out = timed(cmd, {**env, "MATFIT_NO_CACHE": "1"})
            rows.append({"run": "without the cache (MATFIT_NO_CACHE=1)", "wall_s": wall, "cache_mb": None,
                         "first_line": out.splitlines()[0] if out else ""})
            print(f"without the cache: {wall:.1f} s", flush=True)
    finally:
        shutil.rmtree(cache, ignore_errors=True)
    print(f"\n`{' '.join(Path(c).name if i == 0 else c for i, c in enumerate(cmd))}`")
    print_table(rows, [("run", "run", "s"), ("wall_s", "wall s", ".1f"), ("cache_mb", "cache MB", ".1f")])
    p = write_json("cli", rows, args=vars(ns), extra={"command": cmd}, path=ns.out)
    print(f"wrote {p}")
    return rows


if __name__ == "__main__":
    main()
