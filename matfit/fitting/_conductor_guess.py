"""Data-driven starting values for a rough conductor: width from the lobe's shape, then the
complex index from the Fresnel curve read off the table.

A rough conductor is ``f = F(theta_d) * D(h) G2(wo, wi, h) / (4 cos_o cos_i)`` with ``theta_d``
the angle between ``wi`` and the half vector ``h``. The microfacet factor
``m = D G2 / (4 cos_o cos_i)`` depends on ``alpha`` only, so

1. for each ``alpha`` on a grid around the half-width estimate (0.4x to 2.5x, then one
   parabolic step in ``log alpha``), ``log(f / m)`` must be a function of ``theta_d`` alone;
   the ``alpha`` whose ``log(f / m)`` varies least within bins of ``theta_d`` wins;
2. with that ``alpha``, the median of ``f / m`` in each ``theta_d`` bin is a measured Fresnel
   curve ``F(theta_d)`` per channel, and ``(eta, k)`` come from a grid search of
   :func:`matfit.fresnel.fresnel_conductor` against that curve (relative error, bins weighted by
   their row counts).

Only rows that carry shape information are read: valid, both directions above the surface,
every channel positive, channel mean above ``_MIN_RELATIVE`` of the brightest row's; a curve
needs ``_MIN_BINS`` bins of ``_MIN_ROWS_PER_BIN`` rows. A start from this guess lies in the
basin of the global optimum for the tables of ``experiments/recovery.py`` where the half-width
guess with ``eta = 1`` ran into the bounds of ``eta`` and ``k`` (local minima at ``eta -> 8`` or
``k -> 0``).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from ..fresnel import fresnel_conductor
from ..microfacet import make_distribution
from ._compose import METAL_ETA_RANGE, METAL_K_RANGE

#: Rows darker than this fraction of the brightest row carry no shape information for the guess.
_MIN_RELATIVE = 1e-3
#: Width of the theta_d bins (degrees).
_BIN_DEG = 2.0
#: A Fresnel curve is read only from at least _MIN_BINS bins holding _MIN_ROWS_PER_BIN rows each.
_MIN_BINS, _MIN_ROWS_PER_BIN = 6, 8
_N_BINS = int(90 / _BIN_DEG)
#: Larger tables are read from this many of their rows (a fixed random subset): a full MERL
#: table's million rows give the same start to a few 1e-3.
_MAX_ROWS = 50_000


def _theta_d_bins(wo, wi, v, valid):
    """``(keep, h, theta_d in degrees, bin index)`` of rows ``(..., N, 3)``, values ``(..., N, C)``
    and a validity mask ``(..., N)``: the rows that carry shape information and their bins."""
    mean = v.mean(axis=-1)
    mmax = np.where(valid, mean, -np.inf).max(axis=-1, keepdims=True)
    keep = (valid & (mean > _MIN_RELATIVE * mmax) & (wo[..., 2] > 1e-3) & (wi[..., 2] > 1e-3)
            & np.all(v > 0, axis=-1))
    h = wo + wi
    h /= np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-12)
    theta_d = np.degrees(np.arccos(np.clip(np.sum(wi * h, axis=-1), -1, 1)))
    return keep, h, theta_d, np.minimum((theta_d / _BIN_DEG).astype(int), _N_BINS - 1)


def curve_readable(wo, wi, values, valid):
    """Which of a stack of tables (``wo, wi`` (B, N, 3), ``values`` (B, N, C), ``valid`` (B, N))
    hold enough rows to read a Fresnel curve from, all at once: (B,) bool (:func:`conductor_guess`
    returns None for the others)."""
    keep, _, _, bins = _theta_d_bins(wo, wi, values, valid)
    B = keep.shape[0]
    counts = np.zeros((B, _N_BINS), int)
    np.add.at(counts, (np.broadcast_to(np.arange(B)[:, None], bins.shape)[keep], bins[keep]), 1)
    return np.count_nonzero(counts >= _MIN_ROWS_PER_BIN, axis=1) >= _MIN_BINS


@functools.partial(jax.jit, static_argnums=4)
def _microfacet_factor(wo, wi, h, alpha, distribution):
    """``m = D G2 / (4 cos_o cos_i)`` of ``alpha`` (scalar, or (K, 1) for a grid of widths) on
    the rows: one compiled call for the whole grid."""
    d = make_distribution(distribution, alpha)
    return d.D(h) * d.G2(wo, wi, h) / (4 * wo[:, 2] * wi[:, 2])


@functools.partial(jax.jit, static_argnums=6)
def _width_scores(wo, wi, h, alphas, mean, bins, distribution):
    """Mean squared within-bin deviation of ``log(f / m)`` per candidate width (rows of
    ``alphas`` (K, 1)), ``m`` the microfacet factor: small where ``f / m`` is a function of
    ``theta_d`` alone. Bins are the ``_N_BINS`` theta_d bins (empty ones add nothing)."""
    m = _microfacet_factor(wo, wi, h, alphas, distribution)
    ok = m > 0
    lr = jnp.where(ok, jnp.log(mean / jnp.where(ok, m, 1.0)), 0.0)
    n = jnp.maximum(jax.ops.segment_sum(ok.T.astype(lr.dtype), bins, _N_BINS), 1)  # (bins, K)
    s = jax.ops.segment_sum((lr * ok).T, bins, _N_BINS)
    dev = lr - (s / n)[bins].T
    return jnp.sum(ok * dev**2, axis=1) / jnp.maximum(ok.sum(axis=1), 1)


def conductor_guess(wo, wi, values, alpha0, distribution="ggx", eta_range=METAL_ETA_RANGE, k_range=METAL_K_RANGE,
                    valid=None):
    """Starting ``(alpha, eta (C,), k (C,))`` for a rough conductor table, or None when it is too
    sparse to read a Fresnel curve from.

    ``wo, wi`` (N, 3) and ``values`` (N, C) are the rows (``valid`` (N,) selects some; tables of more
    than ``_MAX_ROWS`` rows are read from a fixed random subset); ``alpha0`` is the half-width
    estimate; ``distribution`` is ``"ggx"`` or ``"beckmann"``; ``eta_range``, ``k_range`` bound the
grid search (the fit's bounds)."""
    wo = np.asarray(wo, float)
    v = np.asarray(values, float).reshape(len(wo), -1)
    rows = np.arange(len(wo)) if valid is None else np.flatnonzero(valid)
    if len(rows) > _MAX_ROWS:
        rows = rows[np.sort(np.random.default_rng(0).choice(len(rows), _MAX_ROWS, replace=False))]
    wo, wi, v = wo[rows], np.asarray(wi, float)[rows], v[rows]
    keep, h, theta_d, bins = _theta_d_bins(wo, wi, v, np.ones(len(wo), bool))
    wo, wi, v, h, theta_d = wo[keep], wi[keep], v[keep], h[keep], theta_d[keep]
    mean = v.mean(axis=1)
    _, inv, counts = np.unique(bins[keep], return_inverse=True, return_counts=True)
    if np.count_nonzero(counts >= _MIN_ROWS_PER_BIN) < _MIN_BINS:
        return None  # too sparse to read a Fresnel curve (e.g. a 32-row texel): keep the simple guess

    alphas = np.clip(alpha0 * np.geomspace(0.4, 2.5, 31), 0.005, 1.4)
    scores = np.asarray(_width_scores(wo, wi, h, jnp.asarray(alphas[:, None]), mean, bins[keep], distribution))
    j = int(np.argmin(scores))
    # one parabolic refinement step in log(alpha)
    alpha = alphas[j]
    if 0 < j < len(alphas) - 1:
        s0, s1, s2 = scores[j - 1], scores[j], scores[j + 1]
        den = s0 - 2 * s1 + s2
        if den > 0:
            step = 0.5 * (s0 - s2) / den
            alpha = float(np.exp(np.log(alphas[j]) + step * (np.log(alphas[j + 1]) - np.log(alphas[j]))))
    m = np.asarray(_microfacet_factor(wo, wi, h, jnp.asarray(alpha, jnp.asarray(wo).dtype), distribution))
    ratio = v / np.maximum(m, 1e-300)[:, None]
    order = np.argsort(inv, kind="stable")  # rows grouped by bin, one slice per bin
    ends = np.cumsum(counts)
    curve = np.stack([np.median(ratio[order[e - c:e]], axis=0) for e, c in zip(ends, counts)])
    cos_b = np.cos(np.radians(np.bincount(inv, theta_d) / counts))
    eta_grid = np.geomspace(max(eta_range[0], 1e-3) * 1.05, eta_range[1] / 1.05, 72)
    k_grid = np.linspace(k_range[0], k_range[1], 97)[:-1] + 0.5 * (k_range[1] - k_range[0]) / 96
    E, K = np.meshgrid(eta_grid, k_grid, indexing="ij")
    F = np.asarray(fresnel_conductor(jnp.asarray(cos_b)[:, None], jnp.asarray(E.ravel()), jnp.asarray(K.ravel())))
    logF = np.log(np.maximum(F, 1e-12))  # (bins, grid)
    eta, k = [], []
    for c in range(v.shape[1]):
        y = np.maximum(curve[:, c], 1e-12)
        err = np.sum(counts[:, None] * (logF - np.log(y)[:, None]) ** 2, axis=0)
        i = int(np.argmin(err))
        eta.append(E.ravel()[i])
        k.append(K.ravel()[i])
    return float(alpha), np.array(eta), np.array(k)


def refine_conductor(distribution):
    """The :attr:`~matfit.fitting.Family.refine` hook of the rough conductor families for
    ``distribution``: ``refine(WO, WI, V, M, guess, family)`` sets ``guess["alpha"]``, ``["eta"]``,
    ``["k"]`` in place per table from :func:`conductor_guess` where the table allows."""

    def refine(WO, WI, V, M, guess, family):
        # eta = 1 and the half-width alpha start in the basin of a bound (eta -> 8, k -> 0) for
        # many metals; conductor_guess checks each table itself, curve_readable only spares a
        # batch its loop
        bounds = {p.name: (p.lower, p.upper) for p in family.params}
        B = V.shape[0]
        for b in (range(B) if B == 1 else np.flatnonzero(curve_readable(WO, WI, V, M))):
            g = conductor_guess(WO[b], WI[b], V[b], guess["alpha"][b], distribution, bounds["eta"], bounds["k"],
                                valid=M[b])
            if g is not None:
                guess["alpha"][b], guess["eta"][b], guess["k"][b] = g

    return refine
