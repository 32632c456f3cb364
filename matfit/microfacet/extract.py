r"""The distribution of normals of a measured material, from its retro-reflection (Dupuy et al. 2015).

At backscattering (:math:`\omega_o = \omega_i = k`) the half vector is :math:`k` and the Fresnel
factor is :math:`F(0)` for every :math:`k`, so a microfacet BRDF reads its distribution directly:

.. math::
    f(k, k) = \frac{F(0)\,D(k)\,G_2(k, k)}{4\cos^2\theta_k},\qquad
    G_1(k) = \frac{\cos\theta_k}{\sigma(k)},\quad \sigma(k) = \int\max(0, k\cdot m)\,D(m)\,d\omega_m .

As :math:`G_1` is itself an integral of :math:`D`, :math:`D` is the fixed point of
:math:`D_{n+1}(k) \propto 4\cos\theta_o\cos\theta_i\,f(\omega_o, \omega_i)/G_2[D_n](\omega_o, \omega_i)`,
normalized to :math:`\int D_{n+1}\cos\theta\,d\omega = 1`, on the rows closest to backscattering
(:math:`\theta_d \le` ``max_theta_d``, each with its own :math:`\theta_o`, :math:`\theta_i`, at
:math:`\theta_h`); :math:`\sigma = \cos\theta + B` comes from :math:`D_n` by
:func:`~matfit.microfacet.back_facing_area` every iteration. With Dupuy et al.'s
:math:`G_2(k, k) = G_1(k)` (``masking="smith_g1"``: masking and shadowing fully correlated) the map
is linear, :math:`D = \lambda\,K D`, :math:`K(k, m) = 4\cos\theta_k f(k, k)\max(0, k\cdot m)`: the
paper's power iteration for the leading eigenvector; the normalization divides out :math:`F(0)`
(``f0``). ``"separable"`` (:math:`G_1^2`, matfit's default) and ``"height_correlated"``
(:math:`1/(1 + 2\Lambda)`) read the same data with those models' masking: use the form of the
model the start is for.

:func:`ndf_start` turns the extracted :math:`D` into starting values: the GGX and Beckmann
:math:`\alpha` of least projected-area misfit, the paper's slope-moment conversions
(:math:`\alpha_\text{GGX} = E|\tilde x|`, :math:`\alpha_\text{Beckmann} = \sqrt{2E[\tilde x^2]}`), a
suggested lobe count (one or two GGX lobes) and, where the rows cover several azimuths, an
anisotropy hint.

References
----------
- J. Dupuy, E. Heitz, J.-C. Iehl, P. Poulin, V. Ostromoukhov, "Extracting Microfacet-based BRDF
  Parameters from Arbitrary Materials with Power Iterations", CGF 34(4):21-30, 2015.
- E. Heitz, "Understanding the Masking-Shadowing Function in Microfacet-Based BRDFs", JCGT 3(2), 2014.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import ParameterError
from ..table import Table
from .beckmann import Beckmann
from .ggx import GGX
from .tabulated import TabulatedNDF, back_facing_area, interpolate_ndf, ndf_grid, projected_mass

__all__ = ["extract_ndf", "ndf_start", "nearest_analytic", "EXTRACTION_MASKING"]

#: Masking forms of the backscattering relation: :math:`G_2(k, k) = G_1^2` (``"separable"``),
#: :math:`1/(1 + 2\Lambda)` (``"height_correlated"``) or :math:`G_1` (``"smith_g1"``, Dupuy et al.).
EXTRACTION_MASKING = ("separable", "height_correlated", "smith_g1")

#: Luminance weights of RGB tables (Rec. 709), as Dupuy et al. combine channels.
_LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
#: A second GGX lobe is suggested when one lobe misfits by more than this (relative L2) ...
TWO_LOBE_MISFIT = 0.05
#: ... and two lobes at most halve it.
TWO_LOBE_GAIN = 0.5
#: The widths searched by the fits of the extracted D.
_ALPHA_RANGE = (1e-4, 3.0)
#: Nodes of the masking table during the iterations.
_N_MU = 128
#: The library distributions the extracted D is fitted with.
_DISTRIBUTIONS = {"ggx": GGX, "beckmann": Beckmann}


def _normals(theta):
    """Unit normals at ``theta`` from +z in the xz plane, in float64 (the horizon's cosine stays > 0 in float32)."""
    theta = np.asarray(theta, np.float64)
    return np.stack([np.sin(theta), np.zeros_like(theta), np.cos(theta)], -1)


@functools.partial(jax.jit, static_argnums=0)
def _d_at(kind, m, alpha):
    return _DISTRIBUTIONS[kind](alpha).D(m)


def _library_d(kind, theta, alpha):
    """"ggx" or "beckmann" D (isotropic ``alpha``) at angles ``theta`` as float64 numpy (broadcast)."""
    m = jnp.asarray(_normals(theta))
    return np.asarray(_d_at(kind, m, jnp.asarray(np.asarray(alpha, np.float64), m.dtype)), np.float64)


@jax.jit
def _two_lobe_d(p, m):
    """``s D_GGX(a1) + (1 - s) D_GGX(a2)`` with ``p = (logit s, log a1, log a2)``."""
    s = jax.nn.sigmoid(p[0])
    return s * GGX(jnp.exp(p[1])).D(m) + (1 - s) * GGX(jnp.exp(p[2])).D(m)


_two_lobe_jacobian = jax.jit(jax.jacfwd(_two_lobe_d))


# ------------------------------------------------------------------------------------------------
# The retro-reflection rows of a table
# ------------------------------------------------------------------------------------------------
def _retro_rows(table, max_theta_d, max_theta, diffuse, channel):
    owner = "extract_ndf"
    if not isinstance(table, Table):
        raise ParameterError(f"{owner}: table must be a matfit.Table, got {type(table).__name__}")
    for name, v, hi in (("max_theta_d", max_theta_d, math.pi / 4), ("max_theta", max_theta, math.pi / 2)):
        if not (isinstance(v, (int, float, np.floating)) and 0 < v <= hi):
            raise ParameterError(f"{owner}: {name} must be an angle in (0, {hi:.4g}] radians, got {v!r}")
    diffuse = np.asarray(diffuse, np.float64)
    if not (diffuse.ndim <= 1 and np.all(np.isfinite(diffuse)) and np.all(diffuse >= 0)):
        raise ParameterError(f"{owner}: diffuse must be a finite BRDF value >= 0 (1/sr), scalar or per channel, "
                             f"got {diffuse}")
    if diffuse.ndim == 1 and diffuse.size not in (1, table.n_channels):
        raise ParameterError(f"{owner}: diffuse has {diffuse.size} values for a table of {table.n_channels} channels")
    nc = table.n_channels
    if channel is None:
        cw = _LUMINANCE if table.channels == "rgb" else np.full(nc, 1.0 / nc)
    elif isinstance(channel, (int, np.integer)) and not isinstance(channel, bool) and 0 <= channel < nc:
        cw = np.eye(nc)[channel]
    else:
        raise ParameterError(f"{owner}: channel must be None or an index in [0, {nc}), got {channel!r}")

    # a cheap first cut on the whole table (wo . wi = cos 2 theta_d), so that the rest reads only
    # the few rows near backscattering (a MERL table: ~3 % of 1.1 M) and memory stays bounded
    two_d = min(2 * max_theta_d, math.pi)
    near = np.einsum("ni,ni->n", table.wo, table.wi) >= math.cos(two_d) - 1e-9
    idx = np.flatnonzero(near & np.asarray(table.valid, bool))
    wo, wi = np.asarray(table.wo[idx], np.float64), np.asarray(table.wi[idx], np.float64)
    f = np.asarray(table.values[idx], np.float64)
    s = wo + wi
    ns = np.linalg.norm(s, axis=1)
    ok = ns > 1e-12
    h = s / np.where(ok, ns, 1.0)[:, None]
    cos_d = np.clip(np.sum(wo * h, 1), -1, 1)
    theta_d = np.arccos(cos_d)
    mu_o, mu_i, mu_h = wo[:, 2], wi[:, 2], h[:, 2]
    cmax = math.cos(max_theta)
    keep = ok & (theta_d <= max_theta_d) & (mu_o >= cmax) & (mu_i >= cmax) & (mu_o > 0) & (mu_i > 0) \
        & np.all(np.isfinite(f), 1)
    if np.count_nonzero(keep) < 3:
        raise ParameterError(
            f"{owner}: the table has {np.count_nonzero(keep)} valid rows near backscattering "
            f"(theta_d <= {math.degrees(max_theta_d):.3g} deg, theta_o and theta_i <= {math.degrees(max_theta):.3g} deg); "
            "the extraction reads the distribution off retro-reflection rows (wo close to wi), which this table "
            "lacks: measure or select them, or raise max_theta_d")
    h = h[keep]
    theta_h = np.arctan2(np.hypot(h[:, 0], h[:, 1]), h[:, 2])
    fc = np.maximum(f[keep] - diffuse, 0.0)
    return {
        "mu_o": mu_o[keep], "mu_i": mu_i[keep], "mu_h": mu_h[keep], "theta_h": theta_h,
        "phi_h": np.arctan2(h[:, 1], h[:, 0]), "f": fc @ cw, "f_channels": fc,
    }


def _bin_to_nodes(u_rows, y_rows, u_nodes):
    """Mean of the rows in each node cell (in u), interpolated to the nodes (constant beyond the data)."""
    n = len(u_nodes)
    b = np.clip(np.floor(u_rows * (n - 1)).astype(np.int64), 0, n - 2)
    cnt = np.bincount(b, minlength=n - 1).astype(np.float64)
    occ = cnt > 0
    ub = np.bincount(b, u_rows, n - 1)[occ] / cnt[occ]
    if y_rows.ndim == 1:
        yb = np.bincount(b, y_rows, n - 1)[occ] / cnt[occ]
        return np.interp(u_nodes, ub, yb)
    return np.stack([_bin_to_nodes(u_rows, y_rows[:, c], u_nodes) for c in range(y_rows.shape[1])], -1)


def _occupied_cells(u_rows, n):
    return len(np.unique(np.clip(np.floor(u_rows * (n - 1)).astype(np.int64), 0, n - 2)))


def _y_rows(rows, f, theta, d, masking):
    """``4 mu_o mu_i f / G2[D]`` of every row: F(0) D(theta_h) when D is the table's."""
    mu_nodes = (np.arange(_N_MU) / (_N_MU - 1)) ** 2
    b = back_facing_area(theta, d, mu_nodes)
    mo, mi, mh = rows["mu_o"], rows["mu_i"], rows["mu_h"]
    bo, bi = np.interp(mo, mu_nodes, b), np.interp(mi, mu_nodes, b)
    if f.ndim == 2:
        mo, mi, mh, bo, bi = (a[:, None] for a in (mo, mi, mh, bo, bi))
    if masking == "separable":  # G2 = mo mi / ((mo + bo)(mi + bi))
        return 4 * f * (mo + bo) * (mi + bi)
    if masking == "height_correlated":  # G2 = 1 / (1 + bo/mo + bi/mi)
        return 4 * f * (mo * mi + bo * mi + bi * mo)
    bh = np.interp(rows["mu_h"], mu_nodes, b)
    if f.ndim == 2:
        bh = bh[:, None]
    return 4 * f * mo * mi * (mh + bh) / mh  # G2 = G1(h) = mh / (mh + bh)


def _extract(table, n_theta, masking, max_theta_d, max_theta, diffuse, channel, max_iter, tol):
    if masking not in EXTRACTION_MASKING:
        raise ParameterError(f"extract_ndf: masking must be one of {list(EXTRACTION_MASKING)}, got {masking!r}")
    if isinstance(n_theta, bool) or not isinstance(n_theta, (int, np.integer)) or not 8 <= n_theta <= 4096:
        raise ParameterError(f"extract_ndf: n_theta must be an integer in [8, 4096], got {n_theta!r}")
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 1:
        raise ParameterError(f"extract_ndf: max_iter must be an integer >= 1, got {max_iter!r}")
    rows = _retro_rows(table, max_theta_d, max_theta, diffuse, channel)
    theta = ndf_grid(n_theta)
    u_nodes = np.arange(n_theta) / (n_theta - 1)
    u_rows = np.sqrt(rows["theta_h"] / (np.pi / 2))
    if _occupied_cells(u_rows, n_theta) < 3:
        raise ParameterError("extract_ndf: the backscattering rows cover fewer than 3 distinct theta_h cells; "
                             "the extraction needs retro-reflection at several angles from the normal")
    if not np.any(rows["f"] > 0):
        raise ParameterError("extract_ndf: every backscattering value is 0 (after subtracting diffuse)")
    # D_0 from G2 = 1, then the fixed point of D = normalize(4 mu_o mu_i f / G2[D])
    d = _bin_to_nodes(u_rows, 4 * rows["f"] * rows["mu_o"] * rows["mu_i"], u_nodes)
    d = np.maximum(d, 0.0)
    d /= projected_mass(theta, d)
    change, it = np.inf, 0
    for it in range(1, max_iter + 1):
        new = np.maximum(_bin_to_nodes(u_rows, _y_rows(rows, rows["f"], theta, d, masking), u_nodes), 0.0)
        f0 = projected_mass(theta, new)
        new /= f0
        change = float(np.max(np.abs(new - d)) / np.max(new))
        d = new
        if change < tol:
            break
    yc = np.maximum(_bin_to_nodes(u_rows, _y_rows(rows, rows["f_channels"], theta, d, masking), u_nodes), 0.0)
    f0c = np.array([projected_mass(theta, yc[:, c]) for c in range(yc.shape[1])])
    return {"theta": theta, "d": d, "f0": f0c, "f0_read": f0, "iterations": it, "masking": masking, "converged": change < tol, "rows": rows,
            "u_rows": u_rows}


def extract_ndf(table, n_theta=128, masking="separable", max_theta_d=math.radians(2.0), max_theta=math.radians(85.0),
                diffuse=0.0, channel=None, max_iter=100, tol=1e-6, n_lambda=256, dtype=None):
    r"""The isotropic distribution of normals of a measured table, by the fixed-point (power) iteration
    of Dupuy et al. 2015 on its retro-reflection (module docstring).

    Parameters
    ----------
    table : matfit.Table
        Measured BRDF with valid rows near backscattering (MERL has them at :math:`\theta_d = 0.5^\circ`).
    n_theta : int, optional
        Nodes of :math:`D` on :func:`~matfit.microfacet.ndf_grid` (default 128).
    masking : {"separable", "height_correlated", "smith_g1"}, optional
        :math:`G_2` of the backscattering relation (:data:`EXTRACTION_MASKING`); default
        ``"separable"``, the models' default.
    max_theta_d, max_theta : float, optional
        Largest half angle between ``wo`` and ``wi`` of a row read (default 2 degrees), largest
        :math:`\theta_o`, :math:`\theta_i` read (default 85: measured grazing values are the least
        reliable); radians. :math:`D` is held constant beyond the last :math:`\theta_h` read.
    diffuse : float or array_like (C,), optional
        A diffuse floor (1/sr) subtracted from every value first (default 0).
    channel : int, optional
        The channel read; default: the luminance of an RGB table, else the mean of the channels.
    max_iter, tol : optional
        At most ``max_iter`` iterations (100); stop when no node of :math:`D` changes by more than
        ``tol`` (1e-6) times its peak.
    n_lambda : int, optional
        Nodes of the returned distribution's masking table (default 256).
    dtype : numpy dtype, optional
        Float type of the returned tables (default: JAX's default float).

    Returns
    -------
    TabulatedNDF
        The normalized distribution.

    Raises
    ------
    ParameterError
        For a table without rows near backscattering (or at fewer than 3 angles), an unknown
        masking form, arguments out of range.

    Examples
    --------
    >>> import numpy as np
    >>> from matfit import Table
    >>> from matfit.microfacet import GGX, extract_ndf
    >>> t = np.linspace(0.0, 1.4, 60); c, s = np.cos(t), np.sin(t)
    >>> w = np.stack([s, 0 * t, c], -1)                          # exact retro-reflection rows
    >>> g1 = 2 * c / (c + np.sqrt(c ** 2 + 0.09 * s ** 2))       # GGX's G1 at alpha = 0.3
    >>> f = 0.9 * np.asarray(GGX(0.3).D(w)) * g1 / (4 * c ** 2)  # F D G1 / (4 cos^2)
    >>> tab = extract_ndf(Table(wo=w, wi=w, values=f[:, None], channels="mono"), masking="smith_g1")
    >>> round(float(tab.alpha_x), 2)  # 1 / sqrt(pi D(0))
    0.3
    """
    r = _extract(table, n_theta, masking, max_theta_d, max_theta, diffuse, channel, max_iter, tol)
    dtype = jnp.result_type(float) if dtype is None else dtype
    return TabulatedNDF(r["theta"].astype(dtype), r["d"].astype(dtype), n_lambda)


# ------------------------------------------------------------------------------------------------
# Starting values from the extracted D
# ------------------------------------------------------------------------------------------------
def _quadrature_weights(theta):
    """Weights of the projected measure cos d omega = pi dx at the nodes (trapezoid in x)."""
    dx = np.diff(np.sin(theta) ** 2)
    w = np.zeros_like(theta)
    w[:-1] += dx / 2
    w[1:] += dx / 2
    return np.pi * w


def _misfit(d, model, w):
    return np.sqrt(np.sum(w * (d - model) ** 2, -1) / np.sum(w * d * d))


def _fit_alpha(theta, d, kind):
    """The alpha of the library distribution ``kind`` of least projected-area L2 misfit to ``d``
    (grid in log alpha, then a bounded refinement), and the misfit."""
    w = _quadrature_weights(theta)
    grid = np.geomspace(*_ALPHA_RANGE, 141)

    def ndf(t, a):
        return _library_d(kind, t, a)

    mis = _misfit(d, ndf(theta[None, :], grid[:, None]), w)
    i = int(np.argmin(mis))
    lo, hi = np.log(grid[max(i - 1, 0)]), np.log(grid[min(i + 1, len(grid) - 1)])
    from scipy import optimize  # on first use: `import matfit` stays quick (scipy.optimize is large)

    res = optimize.minimize_scalar(lambda la: _misfit(d, ndf(theta, np.exp(la)), w), bounds=(lo, hi),
                                   method="bounded", options={"xatol": 1e-7})
    a = float(np.exp(res.x))
    return a, float(_misfit(d, ndf(theta, a), w))


def _fit_two_lobes(theta, d, alpha1):
    """Two GGX lobes ``s GGX(a1) + (1 - s) GGX(a2)`` of least misfit, from a few starts."""
    w = _quadrature_weights(theta)
    sw = np.sqrt(w / np.sum(w * d * d))
    m = jnp.asarray(_normals(theta))

    def model(p):
        return np.asarray(_two_lobe_d(jnp.asarray(p, m.dtype), m), np.float64)

    def jac(p):  # exact derivatives: finite differences would not resolve a float32 D
        return sw[:, None] * np.asarray(_two_lobe_jacobian(jnp.asarray(p, m.dtype), m), np.float64)

    from scipy import optimize  # on first use, as in _fit_alpha

    best = None
    for s0, r1, r2 in ((0.5, 0.5, 2.0), (0.8, 1.0, 4.0), (0.2, 0.25, 1.0)):
        la, lb = np.log(_ALPHA_RANGE[0]), np.log(_ALPHA_RANGE[1])
        lo, hi = np.array([-12.0, la, la]), np.array([12.0, lb, lb])
        p0 = np.array([np.log(s0 / (1 - s0)), np.log(alpha1 * r1), np.log(alpha1 * r2)])
        p0 = np.clip(p0, lo + 1e-6, hi - 1e-6)
        res = optimize.least_squares(lambda p: sw * (model(p) - d), p0, jac=jac, bounds=(lo, hi))
        if best is None or res.cost < best.cost:
            best = res
    p = best.x
    s = float(1 / (1 + np.exp(-p[0])))
    a1, a2 = float(np.exp(p[1])), float(np.exp(p[2]))
    if a1 > a2:  # the narrow lobe first
        s, a1, a2 = 1 - s, a2, a1
    return {"weight": s, "alpha": (a1, a2), "misfit": float(_misfit(d, model(p), w))}


def _slope_moments(theta, d, max_theta):
    r""":math:`E|\tilde x|` and :math:`E[\tilde x^2]` of the slopes of the tabulated D (up to ``max_theta``)."""
    tq = np.linspace(0.0, max_theta, 4097)
    dq = interpolate_ndf(theta, d, tq)
    # E|x| = 4 int D sin^2 dtheta; E[x^2] = pi int D sin^3 / cos dtheta
    e1 = 4 * np.trapezoid(dq * np.sin(tq) ** 2, tq)
    e2 = np.pi * np.trapezoid(dq * np.sin(tq) ** 3 / np.cos(tq), tq)
    return float(e1), float(e2)


def _anisotropy(r, min_rows=16):
    """Anisotropic GGX widths from the azimuths of the retro-reflection rows, or None."""
    rows = r["rows"]
    theta, d = r["theta"], r["d"]
    y = _y_rows(rows, rows["f"], theta, d, r["masking"]) / r["f0_read"]  # D(theta_h, phi_h) per row
    # rows inside the lobe, where the width shows: 5 % to 90 % of the peak
    d0 = float(d[0])
    th = rows["theta_h"]
    ratio = y * np.cos(th) ** 4 / d0
    sel = (ratio > 0.05) & (ratio < 0.9) & (th > 1e-3)
    if np.count_nonzero(sel) < min_rows:
        return None
    phi2 = 2 * rows["phi_h"][sel]
    if abs(np.mean(np.exp(1j * phi2))) > 0.9:  # azimuths too concentrated (a MERL table: all 0)
        return None
    # GGX: D / D(0) = 1 / (cos^4 (1 + tan^2 / alpha_phi^2)^2); 1/alpha_phi^2 = A + B cos 2phi + C sin 2phi
    inv_a2 = (np.sqrt(1 / ratio[sel]) - 1) / np.tan(th[sel]) ** 2
    X = np.stack([np.ones_like(phi2), np.cos(phi2), np.sin(phi2)], -1)
    (A, B, C), *_ = np.linalg.lstsq(X, inv_a2, rcond=None)
    R = math.hypot(B, C)
    if not (A > R > 0 or (A > 0 and R == 0)):
        return None
    ax, ay = 1 / math.sqrt(A + B), 1 / math.sqrt(A - B) if A > abs(B) else math.inf
    return {"alpha_x": ax, "alpha_y": ay, "phi_wide": float((0.5 * math.atan2(-C, -B)) % math.pi),
            "ratio": math.sqrt((A + R) / (A - R)), "rows": int(np.count_nonzero(sel))}


def ndf_start(table, n_theta=128, masking="separable", max_theta_d=math.radians(2.0), max_theta=math.radians(85.0),
              diffuse=0.0, channel=None, max_iter=100, tol=1e-6):
    r"""Data-driven microfacet starting values: the distribution :func:`extract_ndf` extracts and what it
    says about widths, lobes and anisotropy.

    The GGX and Beckmann widths minimize the relative misfit :math:`\lVert D - D_\alpha\rVert / \lVert D\rVert`
    in the projected measure (:math:`\lVert g\rVert^2 = \int g^2\cos\theta\,d\omega`); the moment widths
    are Dupuy et al.'s conversions (:math:`E[\tilde x^2]` cut at ``max_theta``, where a GGX tail makes
    it diverge). Two GGX lobes are suggested when one misfits by more than :data:`TWO_LOBE_MISFIT`
    and two at most halve that misfit (:data:`TWO_LOBE_GAIN`).

    Parameters
    ----------
    table, n_theta, masking, max_theta_d, max_theta, diffuse, channel, max_iter, tol
        As for :func:`extract_ndf` (same defaults).

    Returns
    -------
    dict
        ``alpha`` (the GGX width: the start for ``alpha``), ``distribution`` (``"ggx"`` or
        ``"beckmann"``, whichever misfits less), ``alpha_ggx``, ``alpha_beckmann``,
        ``misfit_ggx``, ``misfit_beckmann``, ``alpha_ggx_moment``, ``alpha_beckmann_moment``,
        ``lobes`` (1 or 2), ``two_lobe`` (``weight`` of the narrow lobe, ``alpha`` (narrow,
        wide), ``misfit``), ``anisotropy`` (None for a table whose retro-reflection rows share
        one azimuth, as MERL's; else ``alpha_x``, ``alpha_y`` of an anisotropic GGX, ``ratio``
        of its widths, ``phi_wide`` the azimuth of the wide axis in [0, pi), ``rows``), ``f0``
        (:math:`F(0)` per channel, the eigenvalue), ``ndf`` (the :class:`~matfit.microfacet.TabulatedNDF`),
        ``iterations``, ``converged`` and ``rows`` (the number of rows read).

    Raises
    ------
    ParameterError
        As :func:`extract_ndf`.
    """
    r = _extract(table, n_theta, masking, max_theta_d, max_theta, diffuse, channel, max_iter, tol)
    theta, d = r["theta"], r["d"]
    a_g, m_g = _fit_alpha(theta, d, "ggx")
    a_b, m_b = _fit_alpha(theta, d, "beckmann")
    two = _fit_two_lobes(theta, d, a_g)
    lobes = 2 if (m_g > TWO_LOBE_MISFIT and two["misfit"] <= TWO_LOBE_GAIN * m_g) else 1
    e1, e2 = _slope_moments(theta, d, max_theta)
    return {
        "alpha": a_g, "distribution": "ggx" if m_g <= m_b else "beckmann",
        "alpha_ggx": a_g, "alpha_beckmann": a_b, "misfit_ggx": m_g, "misfit_beckmann": m_b,
        "alpha_ggx_moment": e1, "alpha_beckmann_moment": math.sqrt(2 * e2),
        "lobes": lobes, "two_lobe": two, "anisotropy": _anisotropy(r),
        "f0": r["f0"], "ndf": TabulatedNDF(theta, d), "iterations": r["iterations"], "converged": r["converged"],
        "rows": int(len(r["u_rows"])),
    }


def nearest_analytic(ndf, distribution="ggx"):
    r"""The isotropic analytic distribution closest to a tabulated one: the :math:`\alpha` of least
    relative misfit in the projected measure, as :func:`ndf_start` fits.

    Parameters
    ----------
    ndf : TabulatedNDF
        Another type raises ParameterError, as does an unknown ``distribution``.
    distribution : {"ggx", "beckmann"}, optional
        The analytic family (default ``"ggx"``).

    Returns
    -------
    dict
        ``distribution``, ``alpha`` (float) and ``misfit`` (relative L2, 0 for a table of that
        family up to its interpolation).
    """
    if not isinstance(ndf, TabulatedNDF):
        raise ParameterError(f"nearest_analytic: ndf must be a matfit.microfacet.TabulatedNDF, got {type(ndf).__name__}")
    if distribution not in _DISTRIBUTIONS:
        raise ParameterError(f"nearest_analytic: distribution must be one of {sorted(_DISTRIBUTIONS)}, "
                             f"got {distribution!r}")
    x = np.clip(np.asarray(ndf.x_nodes, np.float64), 0.0, 1.0)
    theta = np.arcsin(np.sqrt(x))
    alpha, misfit = _fit_alpha(theta, np.asarray(ndf.d_nodes, np.float64), distribution)
    return {"distribution": distribution, "alpha": alpha, "misfit": misfit}
