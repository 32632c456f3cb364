"""Shared helpers for the benchmark scripts: timing with compile time apart, repeat statistics, JSON.

Every benchmark follows the same rules (see docs/performance.md): the first call of a jitted function
(compilation plus one run) is timed apart from the warm runs; warm runs are repeated and reported as
median and spread; ratios are against a baseline measured in the same process; results go to JSON under
``benchmarks/results/`` together with the machine, the library versions and the load at the time.

Typical use::

    from _common import time_jax, time_call, write_json, machine_info

    t = time_jax(f, *args, repeat=7)          # {'compile_s', 'median_s', 'spread', 'times_s', ...}
    b = time_call(numpy_reference, *args)     # same fields, no compile step (compile_s = None)
    print(fmt_row(...)); write_json("bench_x", rows, args=vars(ns))

Scripts import it as ``from _common import ...`` (the ``benchmarks/`` directory is on ``sys.path`` when a
script there is run directly) or as ``from benchmarks._common import ...`` from the repository root.
Importing it puts the repository root on ``sys.path`` (``REPO_ROOT``): the numpy references and
baselines (``numpy_ref``, shared with the tests) live there.
"""
from __future__ import annotations

import datetime as _dt
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable

REPO_ROOT = Path(__file__).resolve().parent.parent
if str(REPO_ROOT) not in sys.path:
    sys.path.insert(0, str(REPO_ROOT))

# Where results go: benchmarks/results/, or the folder named by MATFIT_BENCH_RESULTS (a GPU run writes
# there so that its figures do not overwrite this machine's).
RESULTS_DIR = Path(os.environ.get("MATFIT_BENCH_RESULTS") or Path(__file__).resolve().parent / "results")


# --------------------------------------------------------------------------------------------------
# blocking

def block(x: Any) -> Any:
    """Wait until every array in the pytree ``x`` is computed (jax is asynchronous); return ``x``.

    Works on numpy arrays and plain Python objects too (nothing to wait for)."""
    try:
        import jax
    except ImportError:  # pragma: no cover - benchmarks always have jax
        return x
    for leaf in jax.tree_util.tree_leaves(x):
        if isinstance(leaf, jax.Array):  # other array types (numpy, drjit) are computed already
            leaf.block_until_ready()
    return x


# --------------------------------------------------------------------------------------------------
# statistics of repeats

def summarize(times: list[float]) -> dict[str, Any]:
    """Median and spread of repeated timings (seconds).

    ``spread`` is (max - min) / median, a relative range: 0.05 means the slowest and the fastest run
    differ by 5 % of the median. ``iqr_rel`` is the interquartile range over the median (needs >= 4
    runs, else None). ``min_s`` is kept because on a shared machine the fastest run is the one least
    disturbed by other jobs."""
    ts = sorted(float(t) for t in times)
    if not ts:
        raise ValueError("summarize: no timings")
    med = statistics.median(ts)
    out = {
        "n": len(ts),
        "median_s": med,
        "min_s": ts[0],
        "max_s": ts[-1],
        "spread": (ts[-1] - ts[0]) / med if med > 0 else math.nan,
        "iqr_rel": None,
        "times_s": ts,
    }
    if len(ts) >= 4:
        q = statistics.quantiles(ts, n=4)
        out["iqr_rel"] = (q[2] - q[0]) / med if med > 0 else math.nan
    return out


def _repeat(fn, args, kwargs, repeat, number, res):
    """``repeat`` samples of the mean time of ``number`` blocked calls; returns (times, last result)."""
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(number):
            res = block(fn(*args, **kwargs))
        times.append((time.perf_counter() - t0) / number)
    return times, res


def time_call(fn: Callable, *args, repeat: int = 5, warmup: int = 1, number: int = 1, **kwargs) -> dict:
    """Time ``fn(*args, **kwargs)`` ``repeat`` times after ``warmup`` untimed calls.

    Each timed sample runs the call ``number`` times and records the mean per call (use number > 1 for
    calls much shorter than a millisecond). Results are blocked (:func:`block`) inside the timed region.
    Returns :func:`summarize`'s dict plus ``compile_s`` = None and ``result`` = the last result."""
    res = None
    for _ in range(warmup):
        res = block(fn(*args, **kwargs))
    times, res = _repeat(fn, args, kwargs, repeat, number, res)
    out = summarize(times)
    out["compile_s"] = None
    out["result"] = res
    return out


def time_jax(fn: Callable, *args, repeat: int = 5, number: int = 1, lower: bool = True, **kwargs) -> dict:
    """Time a jitted function with compilation apart from the warm runs.

    If ``lower`` and ``fn`` has ``.lower`` (a ``jax.jit`` object), compilation is measured exactly as
    ``fn.lower(*args).compile()`` (``compile_s``; tracing and lowering included) and the compiled
    executable is then called; otherwise ``compile_s`` is the first call minus the median warm call
    (an estimate: first call = compile + one run). ``first_call_s`` is always the wall time of the first
    call (``compile_s`` + one run when lowered). Returns :func:`summarize`'s dict plus ``compile_s``,
    ``first_call_s`` and ``result``."""
    call = fn
    compile_s = None
    t0 = time.perf_counter()
    if lower and hasattr(fn, "lower") and not kwargs:
        call = fn.lower(*args).compile()
        compile_s = time.perf_counter() - t0
    res = block(call(*args, **kwargs))
    first = time.perf_counter() - t0
    times, res = _repeat(call, args, kwargs, repeat, number, res)
    out = summarize(times)
    if compile_s is None:
        compile_s = max(first - out["median_s"], 0.0)
    out["compile_s"] = compile_s
    out["first_call_s"] = first
    out["result"] = res
    return out


def interleaved(fns: dict[str, Callable[[], Any]], repeat: int = 5, warmup: int = 1) -> dict[str, dict]:
    """Time several zero-argument callables with their repeats interleaved (a, b, c, a, b, c, ...).

    On a machine shared with other jobs, interleaving exposes every contender to the same load, so
    ratios measured in one run stay meaningful even when absolute times drift. Returns
    ``{name: summarize(times)}`` (each with ``compile_s`` = None and the last ``result``)."""
    results = {}
    for name, fn in fns.items():
        for _ in range(warmup):
            results[name] = block(fn())
    times: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(repeat):
        for name, fn in fns.items():
            t0 = time.perf_counter()
            results[name] = block(fn())
            times[name].append(time.perf_counter() - t0)
    out = {}
    for name in fns:
        out[name] = summarize(times[name])
        out[name]["compile_s"] = None
        out[name]["result"] = results.get(name)
    return out


def rate(n: int, stats: dict, key: str = "median_s") -> float:
    """Throughput in millions of items per second from a timing dict (``n`` items per call)."""
    t = stats[key]
    return n / t / 1e6 if t and t > 0 else math.nan


# --------------------------------------------------------------------------------------------------
# machine and JSON

def _lscpu_model() -> str | None:
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, timeout=10).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    for line in out.splitlines():
        if line.lower().startswith("model name"):
            return line.split(":", 1)[1].strip()
    return None


def machine_info() -> dict[str, Any]:
    """The machine and software a result was measured on, and the load at the time (``uptime``)."""
    info: dict[str, Any] = {
        "cpu": _lscpu_model() or platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "machine": platform.machine(),
        "python": platform.python_version(),
        "platform": platform.platform(),
        "date": _dt.datetime.now().isoformat(timespec="seconds"),
    }
    try:
        info["loadavg_1_5_15"] = [round(x, 2) for x in os.getloadavg()]
    except OSError:  # pragma: no cover
        info["loadavg_1_5_15"] = None
    try:
        info["uptime"] = subprocess.run(["uptime"], capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):  # pragma: no cover
        info["uptime"] = None
    if "jax" in sys.modules:
        import jax
        info["jax"] = jax.__version__
        info["backend"] = jax.default_backend()
        info["devices"] = [str(d) for d in jax.devices()]
        info["x64"] = bool(jax.config.read("jax_enable_x64"))
    import numpy as np
    info["numpy"] = np.__version__
    info["XLA_FLAGS"] = os.environ.get("XLA_FLAGS")
    return info


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items() if k != "result"}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, float):
        return None if not math.isfinite(x) else x
    try:
        import numpy as np
        if isinstance(x, np.generic):
            return _jsonable(x.item())
        if isinstance(x, np.ndarray):
            return _jsonable(x.tolist())
    except ImportError:  # pragma: no cover
        pass
    if isinstance(x, (str, int, bool)) or x is None:
        return x
    return str(x)


def write_json(name: str, results: Any, *, args: dict | None = None, extra: dict | None = None,
               path: str | os.PathLike | None = None) -> Path:
    """Write ``{"meta": {...}, "results": results}`` to ``RESULTS_DIR/<name>.json`` (or ``path``).

    ``meta`` holds the benchmark name, its arguments, :func:`machine_info` (load included) and ``extra``.
    Non-finite floats become null; keys named ``result`` (raw outputs from :func:`time_jax`) are dropped.
    Returns the path written."""
    p = Path(path) if path is not None else RESULTS_DIR / f"{name}.json"
    p.parent.mkdir(parents=True, exist_ok=True)
    meta = {"benchmark": name, "args": args or {}, **machine_info(), **(extra or {})}
    p.write_text(json.dumps(_jsonable({"meta": meta, "results": results}), indent=1) + "\n")
    return p


# --------------------------------------------------------------------------------------------------
# printing

def print_table(rows: list[dict], columns: list[tuple[str, str, str]]) -> None:
    """Print ``rows`` as an aligned table. ``columns`` = [(key, header, format spec)], e.g.
    ``("rate", "M/s", ".1f")``; missing or None values print as ``-``."""
    cells = [[h for _, h, _ in columns]]
    for r in rows:
        line = []
        for k, _, f in columns:
            v = r.get(k)
            line.append("-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, f))
        cells.append(line)
    widths = [max(len(c[i]) for c in cells) for i in range(len(columns))]
    for j, line in enumerate(cells):
        print("  ".join(s.rjust(w) if i else s.ljust(w) for i, (s, w) in enumerate(zip(line, widths))))
        if j == 0:
            print("  ".join("-" * w for w in widths))
