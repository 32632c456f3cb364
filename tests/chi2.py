"""Chi-square goodness-of-fit machinery for testing direction samplers against their pdf.

Pure numpy/scipy (never imports matfit), float64 throughout. The pieces:

* :func:`cell_probabilities` -- integrate a density over every cell of a rectangular grid in a
  2-D parameter domain (x, y) with a tensor Gauss-Legendre rule, refined adaptively (2 x 2 split,
  recursively) in cells where the coarse and refined estimates disagree (lobe peaks, the cut-offs
  where the pdf drops to zero inside a cell, ...).
* Parametrisations of directions (all with a known Jacobian, so that "density in (x, y)" =
  "pdf in solid angle" x d omega / dx dy):

  - :class:`SphereGrid`: x = cos(theta) in [-1, 1], y = phi in [0, 2 pi): d omega = dx dy.
  - :class:`SlopeGrid`: the *stretched* hemisphere of microfacet normals m, for lobes far narrower
    than any fixed grid on the sphere. A normal m (m_z > 0) is mapped to the unit vector
    v = normalize(m_x / ax, m_y / ay, m_z) (the "standard" configuration of Heitz & d'Eon 2014, in
    which the distribution of m has unit width whatever the alphas), and v to (t, phi) with
    t = 1 - v_z in [0, 1] (uniform in solid angle of v). d omega_m = ax ay / |A v|^3 dt dphi with
    A = diag(ax, ay, 1). Directions wi are mapped to m through the (generalised) half vector, a
    bijection between the wi of one region (reflection / transmission) and the front-facing m.

* :func:`chi2_test` -- pooled Pearson chi-square test (cells with expected count < 5 merged) with
  a diagnostic of the cells that deviate most.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import stats

TWO_PI = 2.0 * np.pi


# ------------------------------------------------------------------------------------------------
# Adaptive tensor Gauss-Legendre integration over the cells of a grid
# ------------------------------------------------------------------------------------------------
def _gl(order):
    x, w = np.polynomial.legendre.leggauss(order)
    return 0.5 * (x + 1.0), 0.5 * w  # nodes and weights on [0, 1]


_EDGE = 1e-4  # relative offset of the edge probe points from the cell boundary


def _rect_rule(density, x0, x1, y0, y1, order):
    """Tensor GL estimate of the integral of ``density`` over each rectangle (vectorised).

    Also returns a Simpson estimate from a 3 x 3 grid of probe points (just inside the corners and
    edges, and the centre) -- the error indicator -- and whether the cell straddles a discontinuity
    of the support (density zero at some of the points and not at others: the probes near the
    edges catch thin slivers of support that all the interior GL nodes miss).
    """
    gx, gw = _gl(order)
    ex = np.array([_EDGE, 0.5, 1.0 - _EDGE])
    sw = np.array([1.0, 4.0, 1.0]) / 6.0
    dx = (x1 - x0)[:, None, None]
    dy = (y1 - y0)[:, None, None]
    xs, ys = np.broadcast_arrays(x0[:, None, None] + dx * gx[None, :, None], y0[:, None, None] + dy * gx[None, None, :])
    px, py = np.broadcast_arrays(x0[:, None, None] + dx * ex[None, :, None], y0[:, None, None] + dy * ex[None, None, :])
    n = len(x0)
    allv = np.asarray(density(np.concatenate([xs.ravel(), px.ravel()]), np.concatenate([ys.ravel(), py.ravel()])),
                      dtype=np.float64)
    vals = allv[: xs.size].reshape(xs.shape)
    pv = allv[xs.size:].reshape(px.shape)
    area = (dx * dy)[:, 0, 0]
    est = np.sum(vals * (gw[:, None] * gw[None, :])[None], axis=(1, 2)) * area
    simpson = np.sum(pv * (sw[:, None] * sw[None, :])[None], axis=(1, 2)) * area
    nz = np.concatenate([(vals > 0).reshape(n, -1), (pv > 0).reshape(n, -1)], 1)
    mixed = np.any(nz, axis=1) & ~np.all(nz, axis=1)
    return est, simpson, mixed


def cell_probabilities(density, xedges, yedges, order=3, n_samples=None, rtol=1e-3, atol=1e-9, max_depth=4,
                       stat_tol=0.05):
    """Integrals of ``density(x, y)`` over the cells of the grid ``xedges`` x ``yedges``.

    A cell (or sub-cell) is accepted when its GL estimate agrees with the coarser Simpson estimate
    to ``tol`` and it does not straddle a support cut-off; otherwise it is split into 2 x 2 children,
    recursively up to ``max_depth`` levels. ``tol = max(rtol |I|, atol)``, or, when ``n_samples``
    is given, ``max(stat_tol * sqrt(|I| / n_samples), atol)``: a fraction ``stat_tol`` of the
    Poisson standard deviation of the count expected in the cell (so quadrature errors are
    negligible for the chi-square test).

    Returns ``(P, unresolved)``: P of shape (len(xedges) - 1, len(yedges) - 1) and the summed error
    indicators of the cells still unresolved at ``max_depth``.
    """
    xedges = np.asarray(xedges, np.float64)
    yedges = np.asarray(yedges, np.float64)
    nx, ny = len(xedges) - 1, len(yedges) - 1
    ix, iy = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    ix, iy = ix.ravel(), iy.ravel()
    x0, x1, y0, y1 = xedges[ix], xedges[ix + 1], yedges[iy], yedges[iy + 1]
    owner = np.arange(nx * ny)
    total = np.zeros(nx * ny)
    unresolved = 0.0

    def tol(v):
        if n_samples is None:
            return np.maximum(rtol * np.abs(v), atol)
        return np.maximum(stat_tol * np.sqrt(np.abs(v) / n_samples), atol)

    for depth in range(max_depth + 1):
        est, simpson, mixed = _rect_rule(density, x0, x1, y0, y1, order)
        err = np.abs(est - simpson)
        # a cut-off inside a cell matters only if the cell holds a non-negligible mass
        negligible = np.abs(est) + np.abs(simpson) <= (atol if n_samples is None else 1e-3 / n_samples)
        ok = (err <= tol(est)) & (~mixed | negligible)
        if depth == max_depth:
            unresolved += float(np.sum(err[~ok]))
            ok[:] = True
        np.add.at(total, owner[ok], est[ok])
        if np.all(ok):
            break
        x0, x1, y0, y1, owner = x0[~ok], x1[~ok], y0[~ok], y1[~ok], owner[~ok]
        xm, ym = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
        x0, x1, y0, y1 = (np.concatenate([x0, xm, x0, xm]), np.concatenate([xm, x1, xm, x1]),
                          np.concatenate([y0, y0, ym, ym]), np.concatenate([ym, ym, y1, y1]))
        owner = np.tile(owner, 4)
    return total.reshape(nx, ny), unresolved


# ------------------------------------------------------------------------------------------------
# Direction parametrisations
# ------------------------------------------------------------------------------------------------
def _normalize(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def reflect(wo, m):
    return 2.0 * np.sum(wo * m, -1, keepdims=True) * m - wo


def refract(wo, m, etap):
    """Refraction of ``wo`` through a microfacet ``m`` (either orientation); etap = eta_i / eta_o
    relative index of the side of ``wi`` over the side of ``wo``. Returns (wi, ok) (ok false on
    total internal reflection). wi is on the other side of m than wo."""
    etap = np.asarray(etap, np.float64)
    c = np.sum(wo * m, -1)
    n = np.where((c < 0)[..., None], -m, m)
    c = np.abs(c)
    s2 = (1.0 - c * c) / (etap * etap)
    ok = s2 < 1.0
    ct = np.sqrt(np.maximum(0.0, 1.0 - s2))
    wi = -wo / etap[..., None] + (c / etap - ct)[..., None] * n
    return _normalize(wi), ok


@dataclass
class SphereGrid:
    """Cells in (cos theta, phi) of the whole sphere; d omega = d cos(theta) d phi."""

    n_cos: int = 32
    n_phi: int = 64

    @property
    def xedges(self):
        return np.linspace(-1.0, 1.0, self.n_cos + 1)

    @property
    def yedges(self):
        return np.linspace(0.0, TWO_PI, self.n_phi + 1)

    @staticmethod
    def to_dir(x, y):
        s = np.sqrt(np.maximum(0.0, 1.0 - x * x))
        return np.stack([s * np.cos(y), s * np.sin(y), x], -1)

    @staticmethod
    def from_dir(w):
        x = np.clip(w[..., 2], -1.0, 1.0)
        y = np.mod(np.arctan2(w[..., 1], w[..., 0]), TWO_PI)
        return x, y

    def describe(self, i, j):
        xe, ye = self.xedges, self.yedges
        th0, th1 = np.degrees(np.arccos(xe[i + 1])), np.degrees(np.arccos(xe[i]))
        return f"theta in [{th0:.1f},{th1:.1f}] deg, phi in [{np.degrees(ye[j]):.0f},{np.degrees(ye[j + 1]):.0f}] deg"


@dataclass
class SlopeGrid:
    """Cells in the stretched hemisphere of microfacet normals (see the module docstring)."""

    ax: float
    ay: float
    n_t: int = 24
    n_phi: int = 48

    @property
    def xedges(self):
        return np.linspace(0.0, 1.0, self.n_t + 1)

    @property
    def yedges(self):
        return np.linspace(0.0, TWO_PI, self.n_phi + 1)

    def to_m(self, t, phi):
        """Normal m (m_z > 0) and d omega_m / (dt dphi)."""
        cz = 1.0 - t
        s = np.sqrt(np.maximum(0.0, 1.0 - cz * cz))
        a = np.stack([self.ax * s * np.cos(phi), self.ay * s * np.sin(phi), cz], -1)
        na = np.linalg.norm(a, axis=-1)
        return a / na[..., None], self.ax * self.ay / na**3

    def from_m(self, m):
        m = np.where((m[..., 2] < 0)[..., None], -m, m)
        v = np.stack([m[..., 0] / self.ax, m[..., 1] / self.ay, m[..., 2]], -1)
        v = _normalize(v)
        return 1.0 - v[..., 2], np.mod(np.arctan2(v[..., 1], v[..., 0]), TWO_PI)

    def describe(self, i, j):
        xe, ye = self.xedges, self.yedges
        th0 = np.degrees(np.arccos(1 - xe[i]))
        th1 = np.degrees(np.arccos(1 - xe[i + 1]))
        return (f"stretched-normal theta' in [{th0:.1f},{th1:.1f}] deg, "
                f"phi in [{np.degrees(ye[j]):.0f},{np.degrees(ye[j + 1]):.0f}] deg")


def half_vector_reflect(wo, wi):
    """m for a reflection pair, oriented to m_z > 0."""
    m = _normalize(wo + wi)
    return np.where((m[..., 2] < 0)[..., None], -m, m)


def half_vector_refract(wo, wi, etap):
    """Generalised half vector normalize(etap wi + wo), oriented to m_z > 0."""
    m = _normalize(etap * wi + wo)
    return np.where((m[..., 2] < 0)[..., None], -m, m)


def wi_from_m_reflect(wo, m):
    """wi = reflect(wo, m) and d omega_i / d omega_m = 4 |wo.m|."""
    return reflect(wo, m), 4.0 * np.abs(np.sum(wo * m, -1))


def wi_from_m_refract(wo, m, etap):
    """wi = refract(wo, m) and d omega_i / d omega_m = (wi.m + wo.m / etap)^2 / |wi.m| (Walter 2007)."""
    wi, ok = refract(wo, m, etap)
    im = np.sum(wi * m, -1)
    om = np.sum(wo * m, -1)
    denom = im + om / etap
    jac = np.where(ok, denom * denom / np.maximum(np.abs(im), 1e-300), 0.0)
    return wi, jac, ok


# ------------------------------------------------------------------------------------------------
# Pearson chi-square with pooling
# ------------------------------------------------------------------------------------------------
@dataclass
class Chi2Result:
    stat: float
    dof: int
    pvalue: float
    n_bins: int
    worst: list = field(default_factory=list)  # (label, observed, expected, contribution)

    def summary(self, k=6):
        lines = [f"chi2={self.stat:.1f} dof={self.dof} p={self.pvalue:.3g} bins={self.n_bins}"]
        for lab, o, e, c in self.worst[:k]:
            lines.append(f"   {lab}: observed {o:.0f}, expected {e:.1f}, (O-E)^2/E={c:.1f}")
        return "\n".join(lines)


def chi2_test(observed, expected, labels=None, min_expected=5.0):
    """Pearson chi-square of observed counts against expected counts (same total up to quadrature).

    ``labels``: a sequence or a function of the flat cell index, describing the cells (diagnostics).

    Cells whose expected count is below ``min_expected`` are pooled into one bin (observed counts
    there -- e.g. samples where the pdf vanishes -- are kept in that bin, so they still count); if
    the pool still expects fewer than ``min_expected`` it is merged with the smallest regular cells.
    The expected counts are rescaled to the observed total (the quadrature error of the total is
    tested separately). dof = number of bins - 1.
    """
    o = np.asarray(observed, np.float64).ravel()
    e = np.asarray(expected, np.float64).ravel()
    e = np.maximum(e, 0.0)
    if labels is None:
        labels = str
    elif not callable(labels):
        labels = labels.__getitem__
    e = e * (o.sum() / e.sum())
    order = np.argsort(e)
    small = e[order] < min_expected
    n_small = int(np.sum(small))
    pool_e = e[order[:n_small]].sum()
    pool_o = o[order[:n_small]].sum()
    k = n_small
    while k < len(order) and pool_e < min_expected and (pool_o > 0 or pool_e > 0):
        pool_e += e[order[k]]
        pool_o += o[order[k]]
        k += 1
    reg = order[k:]
    bins_o = list(o[reg])
    bins_e = list(e[reg])
    labs = list(reg)  # cell indices, turned into labels only for the worst bins
    if pool_e > 0 or pool_o > 0:
        bins_o.append(pool_o)
        bins_e.append(pool_e)
        labs.append(f"pooled {k} cells with small expected count")
    bo, be = np.array(bins_o), np.array(bins_e)
    if np.any((be <= 0) & (bo > 0)):
        contrib = np.where(be > 0, (bo - be) ** 2 / np.maximum(be, 1e-300), np.inf)
        stat, p = float("inf"), 0.0
    else:
        contrib = (bo - be) ** 2 / be
        stat = float(np.sum(contrib))
        p = float(stats.chi2.sf(stat, max(len(bo) - 1, 1)))
    worst_idx = np.argsort(-contrib)[:10]
    worst = [(labs[i] if isinstance(labs[i], str) else labels(int(labs[i])), bo[i], be[i], contrib[i])
             for i in worst_idx]
    return Chi2Result(stat, len(bo) - 1, p, len(bo), worst)
