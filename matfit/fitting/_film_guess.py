r"""The data-driven start of a thin film: its thickness and index from how the highlight's hue
turns with the angle.

A thin film's reflectance :math:`F(\theta_d; d, \eta_f)` (:func:`~matfit.fresnel.fresnel_thin_film`)
colours the highlight, and its colour turns with the difference angle :math:`\theta_d` (the
optical path :math:`2\eta_f d\cos\theta_f` shortens). The film's start is read from the rows near
the mirror direction (the :data:`NEAR_ROWS` rows of smallest half angle :math:`\theta_h`): their
excess over the diffuse floor (per channel, the median of the rows with :math:`\theta_h > 30°`)
has a chromaticity :math:`\hat v = v / \sum_c v_c` per row. Every candidate of the grid
:data:`THICKNESSES` x :data:`FILM_ETAS` (on a base of index 1.5) predicts the chromaticity
:math:`\hat F(\theta_d)`; the candidates are ranked by :math:`\sum_\text{rows}\|\hat v - \hat F\|^2`
(the rows weighted by :math:`\sqrt{\sum_c v_c}`, so that the brightest rows of the peak lead
without the grazing ones, where every film is white, taking over). The best few per table start
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
>>> float(best["thickness"][0]), float(best["film_eta"][0])
(420.0, 1.6)
"""

from __future__ import annotations

import functools

import jax
import numpy as np

from ..fresnel import fresnel_thin_film

__all__ = ["film_candidates", "THICKNESSES", "FILM_ETAS", "NEAR_ROWS"]

#: The candidate film thicknesses (nm).
THICKNESSES = np.arange(20.0, 1001.0, 10.0)
#: The candidate film indices.
FILM_ETAS = (1.3, 1.45, 1.6, 1.8, 2.1, 2.4)
#: The rows near the mirror a table's film is read from.
NEAR_ROWS = 256
#: The cosine grid the candidates' colours are tabulated on (interpolated per row).
_COS_GRID = np.linspace(0.0, 1.0, 129)


@functools.lru_cache(maxsize=1)
def _chroma_table():
    """The candidates' chromaticity on the cosine grid: (K, G, 3), and their (thickness, index)."""
    d, n = np.meshgrid(THICKNESSES, FILM_ETAS, indexing="ij")
    d, n = d.ravel(), n.ravel()
    F = np.asarray(jax.jit(fresnel_thin_film)(_COS_GRID[None, :], d[:, None], n[:, None], 1.5), float)
    return F / np.maximum(F.sum(-1, keepdims=True), 1e-12), d, n


def film_candidates(th_h, cos_d, V, ok, n=3):
    """The ``n`` best film candidates of every table, best first.

    Parameters
    ----------
    th_h : numpy.ndarray (B, N)
        Half angles of the rows (degrees).
    cos_d : numpy.ndarray (B, N)
        Cosines of the difference angles.
    V : numpy.ndarray (B, N, 3)
        Values (RGB).
    ok : numpy.ndarray of bool (B, N)
        Rows to read.
    n : int
        How many candidates.

    Returns
    -------
    list of dict
        ``n`` dicts ``{"thickness": (B,), "film_eta": (B,)}``, the best candidate of every
        table first.

    Examples
    --------
    >>> import numpy as np
    >>> from matfit.fitting._film_guess import film_candidates
    >>> c = film_candidates(np.zeros((1, 4)), np.ones((1, 4)), np.ones((1, 4, 3)), np.ones((1, 4), bool), n=2)
    >>> len(c), c[0]["thickness"].shape
    (2, (1,))
    """
    table, d_all, n_all = _chroma_table()
    B = V.shape[0]
    out = [{"thickness": np.empty(B), "film_eta": np.empty(B)} for _ in range(n)]
    for b in range(B):
        rows = np.flatnonzero(ok[b])
        th = np.where(np.isfinite(th_h[b, rows]), th_h[b, rows], 90.0)
        off = rows[th > 30.0]
        floor = np.median(V[b, off], axis=0) if off.size >= 8 else np.min(V[b, rows], axis=0) if rows.size else 0.0
        near = rows[np.argsort(th)[:NEAR_ROWS]]
        ex = np.clip(V[b, near] - floor, 0.0, None)
        tot = ex.sum(-1)
        keep = tot > 0
        if keep.sum() < 3:  # no highlight to read: the generic film
            for i in range(n):
                out[i]["thickness"][b], out[i]["film_eta"][b] = 300.0, 1.8
            continue
        ex, tot, c = ex[keep], tot[keep], cos_d[b, near][keep]
        chroma = ex / tot[:, None]
        w = np.sqrt(tot)
        # the candidates' chromaticity at the rows' cosines (linear in the grid)
        pos = np.clip(c, 0.0, 1.0) * (len(_COS_GRID) - 1)
        i0 = np.minimum(pos.astype(int), len(_COS_GRID) - 2)
        t = (pos - i0)[None, :, None]
        pred = table[:, i0] * (1 - t) + table[:, i0 + 1] * t  # (K, rows, 3)
        err = np.einsum("r,krc->k", w, (pred - chroma[None]) ** 2)
        for i, k in enumerate(np.argsort(err)[:n]):
            out[i]["thickness"][b], out[i]["film_eta"][b] = d_all[k], n_all[k]
    return out
