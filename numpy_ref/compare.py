"""Comparison helpers: relative errors with a floor, an assertion that reports the worst points,
and the sensitivity of a reference to rounding of its inputs."""

from __future__ import annotations

import numpy as np

__all__ = ["rel_err", "assert_rel", "input_sensitivity"]


def rel_err(actual, expected, floor):
    """|a - e| / max(|e|, floor), elementwise (0 where both are exactly equal, inf where NaN)."""
    a = np.asarray(actual, dtype=np.float64)
    e = np.asarray(expected, dtype=np.float64)
    a, e = np.broadcast_arrays(a, e)
    with np.errstate(all="ignore"):
        err = np.abs(a - e) / np.maximum(np.abs(e), floor)
    err = np.where((a == e), 0.0, err)  # includes both exactly 0 and equal infinities
    return np.where(np.isnan(err), np.inf, err)


def assert_rel(actual, expected, rtol, floor, what="", **inputs):
    """Assert max relative error <= rtol; on failure report the worst entries with their inputs."""
    a = np.asarray(actual, dtype=np.float64)
    e = np.asarray(expected, dtype=np.float64)
    assert a.shape == e.shape, f"{what}: shape {a.shape} != reference {e.shape}"
    err = rel_err(a, e, floor)
    if not np.all(err <= rtol):
        flat = err.reshape(err.shape[0], -1).max(axis=-1) if err.ndim > 1 else err
        bad = np.argsort(-flat)[:5]
        lines = [f"{what}: max rel err {flat.max():.3e} > {rtol:.1e} ({int((flat > rtol).sum())}/{flat.size} bad)"]
        for i in bad:
            if flat[i] <= rtol:
                break
            ins = ", ".join(f"{k}={np.asarray(v)[i].tolist() if np.ndim(v) else v}" for k, v in inputs.items())
            lines.append(f"  [{i}] lib={a[i].tolist()} ref={e[i].tolist()} err={flat[i]:.3e} | {ins}")
        raise AssertionError("\n".join(lines))


def input_sensitivity(fn, arrays, u, rng, trials=6, floor=1e-300):
    """Estimated relative sensitivity of fn(*arrays) (per point, first axis) to random relative
    perturbations of size ~u of every input component (a backward-error view of rounding to a
    precision with unit roundoff u). Large values mark ill-conditioned points, where no
    implementation in that precision can be accurate (e.g. 1 - F at the critical angle)."""
    base = np.asarray(fn(*arrays), dtype=np.float64)
    base = base.reshape(base.shape[0], -1)
    worst = np.zeros(base.shape[0])
    for _ in range(trials):
        pert = [a * (1.0 + u * rng.standard_normal(a.shape)) for a in arrays]
        p = np.asarray(fn(*pert), dtype=np.float64).reshape(base.shape)
        with np.errstate(all="ignore"):
            r = np.abs(p - base) / np.maximum(np.abs(base), floor)
        r = np.where(p == base, 0.0, r)
        worst = np.maximum(worst, np.nan_to_num(r, nan=np.inf).max(axis=-1))
    return worst
