"""Run every benchmark script (``benchmarks/bench_*.py``), one process each, in name order.

Each script prints its table and writes its JSON under ``benchmarks/results/``; a process per
script lets every one set its own ``XLA_FLAGS`` (host device count) before jax starts. Extra
arguments are passed to every script that accepts them (e.g. ``--quick`` for the scripts that
have a quick mode). The exit status is non-zero when a script failed; the others still run.

Usage: python benchmarks/run_all.py [--quick] [--only fit_merl,emcee] [--list]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def scripts():
    return sorted(HERE.glob("bench_*.py"))


def accepts(script, flag):
    """Whether a script's source mentions an argparse option ``flag`` (cheap, no import)."""
    return f'"{flag}"' in script.read_text()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="pass --quick to the scripts that have it")
    ap.add_argument("--only", default="", help="comma-separated names (bench_<name>.py) to run")
    ap.add_argument("--list", action="store_true", help="list the scripts and exit")
    ns = ap.parse_args(argv)
    todo = scripts()
    if ns.only:
        keep = {f"bench_{n.strip()}.py" for n in ns.only.split(",")}
        todo = [s for s in todo if s.name in keep]
    if ns.list:
        print("\n".join(s.name for s in todo))
        return 0
    failed = []
    for s in todo:
        cmd = [sys.executable, str(s)]
        if ns.quick and accepts(s, "--quick"):
            cmd.append("--quick")
        print(f"==== {s.name} {' '.join(cmd[2:])}", flush=True)
        t0 = time.perf_counter()
        rc = subprocess.run(cmd, cwd=HERE.parent).returncode
        print(f"==== {s.name}: exit {rc}, {time.perf_counter() - t0:.0f} s\n", flush=True)
        if rc:
            failed.append(s.name)
    if failed:
        print(f"failed: {', '.join(failed)}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
