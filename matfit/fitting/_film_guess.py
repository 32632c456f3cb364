r"""The data-driven start of a thin film: its thickness and index from how the highlight's hue
turns with the angle.

A thin film's reflectance :math:`F(\theta_d; d, \eta_f)` (:func:`~matfit.fresnel.fresnel_thin_film`)
colours the highlight, and its colour turns with the difference angle :math:`\theta_d` (the
optical path :math:`2\eta_f d\cos\theta_f` shortens). The film's start is read from the rows near
the mirror direction (half angle :math:`\theta_h` below :data:`NEAR_DEGREES`): their
excess over the diffuse floor (per channel, the median of the rows with :math:`\theta_h > 30°`),
summed over each band of :data:`BANDS`, has a chromaticity :math:`\hat v_b = v_b / \sum_c v_{b,c}`.
Every candidate of the grid :data:`THICKNESSES` x :data:`FILM_ETAS` x :data:`BASE_ETAS`
predicts the band's mean film colour :math:`\hat F_b` at the same rows; the candidates are
ranked by :math:`\sum_b w_b\|\hat v_b - \hat F_b\|^2` (:data:`BAND_WEIGHTS`: every film is
nearly white at grazing light, so the last band weighs less). The best few per table start
the variable projection of :meth:`~matfit.fitting.LobeSpec.refine`, which keeps the one whose
lobes fit best.

Example
-------
>>> import numpy as np
>>> from matfit.fitting._film_guess import film_candidates
>>> from matfit.fresnel import fresnel_thin_film
>>> cos_d = np.linspace(0.2, 1.0, 40)[None]
>>> th_h = np.zeros_like(cos_d); th_h[:, ::2] = 40.0  # half the rows off the mirror: the floor of 0.1
>>> v = 0.1 + 5 * np.asarray(fresnel_thin_film(cos_d, 420.0, 1.6, 1.5)) * (th_h == 0)[..., None]  # a 420 nm film
>>> best = film_candidates(th_h, cos_d, v, np.ones(cos_d.shape, bool), n=1)[0]
>>> float(best["thickness"][0]) * float(best["film_eta"][0])  # the optical thickness 420 x 1.6
672.0
"""

from __future__ import annotations

import functools

import jax
import numpy as np

from ..fresnel import fresnel_thin_film

__all__ = ["film_candidates", "FILM_GENERIC", "THICKNESSES", "FILM_ETAS", "BASE_ETAS", "BANDS", "NEAR_DEGREES", "NEAR_ROWS"]

#: The generic film (a thin-film lobe's generic start, and the start where a table shows no
#: highlight to read): thickness (nm), film index, index under the film.
FILM_GENERIC = {"thickness": 300.0, "film_eta": 1.8, "eta": 1.5}
#: The candidate film thicknesses (nm).
THICKNESSES = np.arange(20.0, 1001.0, 10.0)
#: The candidate film indices.
FILM_ETAS = (1.3, 1.45, 1.6, 1.75, 1.9, 2.1, 2.3, 2.5)
#: The candidate indices under the film.
BASE_ETAS = (1.3, 1.5, 2.0, 2.5)
#: The bands of difference angle (degrees) whose colours are compared, and their weights (every
#: film is nearly white at grazing light: the last band weighs less).
BANDS, BAND_WEIGHTS = ((0, 20), (20, 40), (40, 60), (60, 90)), (1.0, 1.0, 1.0, 0.25)
#: The rows near the mirror a table's film is read from: half angle below this many degrees,
#: or the :data:`NEAR_ROWS` rows nearest the mirror where fewer are.
NEAR_DEGREES, NEAR_ROWS = 5.0, 64
#: The cosine grid the candidates' colours are tabulated on (interpolated per row).
_COS_GRID = np.linspace(0.0, 1.0, 129)


@functools.lru_cache(maxsize=1)
def _colour_table():
    """The candidates' RGB on the cosine grid, (K, G, 3), and their thickness, film and base index."""
    d, n, nb = (x.ravel() for x in np.meshgrid(THICKNESSES, FILM_ETAS, BASE_ETAS, indexing="ij"))
    F = np.asarray(jax.jit(fresnel_thin_film)(_COS_GRID[None, :], d[:, None], n[:, None], nb[:, None]), float)
    return F, d, n, nb


def film_candidates(th_h, cos_d, V, ok, n=3):
    """The ``n`` best film candidates of every table, best first: ``n`` dicts ``{"thickness",
    "film_eta", "eta"}`` of (B,) arrays, read from the rows ``ok`` of half angles ``th_h``
    (degrees), difference-angle cosines ``cos_d`` (B, N) and RGB values ``V`` (B, N, 3); a table
    without a highlight to read gets :data:`FILM_GENERIC`.
    """
    table, d_all, n_all, nb_all = _colour_table()
    B = V.shape[0]
    keys = ("thickness", "film_eta", "eta")
    out = [{k: np.empty(B) for k in keys} for _ in range(n)]
    td_all = np.degrees(np.arccos(np.clip(cos_d, -1.0, 1.0)))
    for b in range(B):
        rows = np.flatnonzero(ok[b])
        th = np.where(np.isfinite(th_h[b, rows]), th_h[b, rows], 90.0)
        off = rows[th > 30.0]
        floor = np.median(V[b, off], axis=0) if off.size >= 8 else np.min(V[b, rows], axis=0) if rows.size else 0.0
        near = rows[th < NEAR_DEGREES] if (th < NEAR_DEGREES).sum() >= NEAR_ROWS else rows[np.argsort(th)[:NEAR_ROWS]]
        ex = np.clip(V[b, near] - floor, 0.0, None)
        td, c = td_all[b, near], cos_d[b, near]
        pos = np.clip(c, 0.0, 1.0) * (len(_COS_GRID) - 1)
        i0 = np.minimum(pos.astype(int), len(_COS_GRID) - 2)
        t = (pos - i0)[None, :, None]
        pred = table[:, i0] * (1 - t) + table[:, i0 + 1] * t  # (K, rows, 3)
        err = np.zeros(len(d_all))
        used = 0
        for (lo, hi), w in zip(BANDS, BAND_WEIGHTS):
            m = (td >= lo) & (td < hi)
            e = ex[m].sum(0)
            if m.sum() < 3 or e.sum() <= 0:
                continue
            p = pred[:, m].mean(1)
            p = p / np.maximum(p.sum(-1, keepdims=True), 1e-12)
            err += w * np.sum((p - e / e.sum()) ** 2, axis=-1)
            used += 1
        if not used:  # no highlight to read: the generic film
            for i in range(n):
                for k in keys:
                    out[i][k][b] = FILM_GENERIC[k]
            continue
        for i, k in enumerate(np.argsort(err)[:n]):
            out[i]["thickness"][b], out[i]["film_eta"][b], out[i]["eta"][b] = d_all[k], n_all[k], nb_all[k]
    return out

