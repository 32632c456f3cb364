r"""The data-driven start of an anisotropic lobe: its two widths and its orientation from the
shape of the measured peak.

For a GGX lobe near its peak (masking and Fresnel nearly constant there) the value is
proportional to the distribution of the half vector's slopes :math:`s = (-h_x/h_z, -h_y/h_z)`:

.. math::

    f\,\cos\theta_o\cos\theta_i \;\propto\; D(s) \;\propto\;
    \bigl(1 + s^\top A\, s\bigr)^{-2}, \qquad
    A = R_\varphi \,\mathrm{diag}(\alpha_x^{-2}, \alpha_y^{-2})\, R_\varphi^\top ,

so :math:`y = (f\cos\theta_o\cos\theta_i)^{-1/2}` is linear in :math:`(1, s_x^2, s_y^2, s_x s_y)`.
A weighted linear least-squares fit over the rows of the peak (within 1 % of its maximum,
weighted by the value) gives :math:`A` up to the fitted scale; its eigenvalues give the widths,
its eigenvectors the angle :math:`\varphi` of the ``alpha`` axis (in :math:`(-\pi/2, \pi/2]`).
Rows that all lie in one plane cannot show an ellipse: no guess then.
"""

from __future__ import annotations

import numpy as np

__all__ = ["anisotropy_guess", "refine_anisotropic", "ANISOTROPY_RATIO"]

#: The width ratio from which a table's peak counts as anisotropic (the choice's cue).
ANISOTROPY_RATIO = 1.5


def anisotropy_guess(wo, wi, values, valid=None, peak=0.01):
    """``(alpha_x, alpha_y, angle)`` of the measured peak (module docstring), or None.

    Parameters
    ----------
    wo, wi : numpy.ndarray (N, 3)
    values : numpy.ndarray (N, C)
    valid : numpy.ndarray (N,) of bool, optional
    peak : float, default 0.01
        Rows above this fraction of the largest value enter the fit.

    Returns
    -------
    tuple of float or None
        None when fewer than 8 rows qualify, their slopes span no area or the fitted form is
        not an ellipse.
    """
    wo, wi = np.asarray(wo, float), np.asarray(wi, float)
    v = np.mean(np.asarray(values, float), axis=-1)
    ok = (wo[:, 2] > 0.05) & (wi[:, 2] > 0.05) & np.isfinite(v) & (v > 0)
    if valid is not None:
        ok &= np.asarray(valid, bool)
    if ok.sum() < 8:
        return None
    h = wo[ok] + wi[ok]
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    d = v[ok] * wo[ok, 2] * wi[ok, 2]
    sx, sy = -h[:, 0] / h[:, 2], -h[:, 1] / h[:, 2]
    core = d >= peak * d.max()
    if core.sum() < 8:
        return None
    sx, sy, d = sx[core], sy[core], d[core]
    X = np.stack([np.ones_like(sx), sx * sx, sy * sy, sx * sy], 1)
    w = d / d.max()  # the peak's rows count most
    if np.linalg.matrix_rank(X * w[:, None], tol=1e-8) < 4:
        return None  # the slopes lie on a line (an in-plane sweep): no ellipse to read
    beta, *_ = np.linalg.lstsq(X * w[:, None], d ** -0.5 * w, rcond=None)
    if not np.all(np.isfinite(beta)) or beta[0] <= 0:
        return None
    A = np.array([[beta[1], beta[3] / 2], [beta[3] / 2, beta[2]]]) / beta[0]
    lam, vec = np.linalg.eigh(A)
    if lam[0] <= 0:
        return None
    # the narrow axis (largest eigenvalue) is alpha's; its angle folded into (-pi/2, pi/2]
    ax, ay = 1 / np.sqrt(lam[1]), 1 / np.sqrt(lam[0])
    phi = float(np.arctan2(vec[1, 1], vec[0, 1]))
    phi = phi - np.pi * np.round(phi / np.pi)
    return float(ax), float(ay), phi


def refine_anisotropic(isotropic):
    """The :attr:`~matfit.fitting.Family.refine` hook of an anisotropic family: ``isotropic``'s
    refinement first (the index, and one width), then per table the widths ``alpha``,
    ``alpha_y`` and the ``angle`` of :func:`anisotropy_guess` (isotropic at angle 0 where it has
    none).

    Parameters
    ----------
    isotropic : callable
        The isotropic family's ``refine`` hook (or None).

    Returns
    -------
    callable
    """

    def refine(WO, WI, V, M, guess, family):
        if isotropic is not None:
            isotropic(WO, WI, V, M, guess, family)
        B = V.shape[0]
        guess["alpha_y"] = np.array(guess["alpha"], float, copy=True)
        guess["angle"] = np.zeros(B)
        for b in range(B):
            g = anisotropy_guess(WO[b], WI[b], V[b], M[b])
            if g is not None:
                guess["alpha"][b], guess["alpha_y"][b], guess["angle"][b] = g

    return refine
