r"""Diagnostics of a finished fit: what the numbers alone do not say.

A least-squares solver can stop "successfully" at an answer the table does not support. After
every fit, :func:`diagnose` inspects the optimum and returns plain-language warnings, stored in
``FitResult.warnings`` (and ``FitResult.ok`` is ``converged and not warnings``):

=====================  =======================================================================
not converged          the solver hit ``max_steps`` or failed its tolerances.
not identifiable       the Gauss-Newton matrix :math:`J^T J` (natural parameters, each scaled
                       to its bound width) has a relative eigenvalue below
                       :data:`IDENT_RCOND`: the table cannot tell some parameter combination
                       apart (e.g. every row at one angle). The parameters that dominate the
                       weak directions are named, and their standard errors are set to ``inf``.
at a bound             a parameter ended within :data:`BOUND_TOL` (relative to its range) of
                       a bound. A physical limit (:attr:`Param.physical <matfit.fitting.Param>`:
                       a weight or albedo of 0 or 1, an extinction of 0) says the data ask
                       for none or all of a term; a range limit (a width of 1e-3, a metal
                       index of 8) says the best fit may lie beyond the family's range.
outliers               residuals beyond :data:`OUTLIER_Z` robust standard deviations
                       (1.4826 MAD) under the noise model below, on more rows than Gaussian
                       noise explains (``> max(2, 1e-4 n)``; ``P(|z| > 6) ~ 2e-9``): try
                       ``robust="huber"``/``"cauchy"`` or mask the rows.
poor fit               with the table's own sigma: reduced :math:`\chi^2` above
                       :data:`CHI2_MAX`.
multiple optima        another start reached an objective within 0.1 % of the best at
                       parameters more than 5 standard errors away.
=====================  =======================================================================

The outlier test's noise model, so that noise of a few per cent of the value is not a set of
outliers: additive (one scale), or proportional to the value :math:`y_i` (in the residuals'
space) with an additive floor :math:`\lambda m` (``m`` the median, :math:`\lambda` in
:data:`NOISE_FLOORS`, 0: purely proportional), :math:`s_i = \sqrt{y_i^2 + \lambda^2 m^2}`
(dark noise under a noise that grows with the signal); the model whose standardized residuals
have the lighter tail beyond 3 robust standard deviations is used. Fitted without sigma, the noise of
the peak moves the fitted curve by more than the small values' own noise: with each fitted
value's variance :math:`v_i` (from the parameters' covariance) the scale is
:math:`\sqrt{s_i^2 + v_i / c^2}`, ``c`` the residuals' spread relative to :math:`s`. A residual
spread below ``1e-7`` of the data's scale is an exact fit (no test on rounding noise).

References
----------
- P. C. Hansen, "Rank-Deficient and Discrete Ill-Posed Problems", SIAM, 1998 (numerical rank
  from the singular values of the Jacobian).
- P. J. Rousseeuw, C. Croux, "Alternatives to the Median Absolute Deviation", JASA 88, 1993
  (1.4826 MAD as a robust standard deviation).
"""

from __future__ import annotations

import numpy as np

__all__ = ["IDENT_RCOND", "BOUND_TOL", "OUTLIER_Z", "identifiability", "diagnose"]

#: relative eigenvalue of the scaled J^T J below which a direction counts as unidentified
IDENT_RCOND = 1e-10
#: distance to a bound, relative to the parameter's range (or to 1 for unbounded ranges)
BOUND_TOL = 1e-4
#: robust z-score beyond which a residual is an outlier
OUTLIER_Z = 6.0
#: additive floors of the proportional noise models of the outlier test, relative to the median
#: value (0: purely proportional; :func:`_standardized`)
NOISE_FLOORS = (0.0, 0.03, 0.1, 0.3, 1.0)
#: reduced chi-square above which a fit with known sigma is called poor
CHI2_MAX = 3.0


def _standardized(r, scale, data_scale, fit_var=None):
    """``(|z|, kind)``: the residuals over the robust noise scale of the lightest-tailed noise model
    (module docstring); ``(None, kind)`` when the spread is rounding."""
    best = None
    models = [("additive noise", None)]  # the residuals as they are: no array of ones to divide by
    if scale is not None:
        # a zero value keeps a positive scale: the floor's square (below) stays a normal number of r's dtype
        m = max(float(_median_of_copy(scale)), 1e3 * float(np.sqrt(np.finfo(r.dtype).tiny)))
        base = scale.astype(r.dtype, copy=False)
        for lam in NOISE_FLOORS:
            s = np.sqrt(base * base + (max(lam, 1e-3) * m) ** 2)
            if fit_var is not None:
                c = _robust_sd(r / s)[1]
                if c > 0:
                    s = np.sqrt(s * s + fit_var.astype(r.dtype, copy=False) / (c * c))
            kind = "proportional noise" if lam == 0 else f"proportional noise over a floor of {lam:g} x the median value"
            models.append((kind, s))
    for kind, s in models:
        dev, mad = _robust_sd(r if s is None else r / s)
        if s is None and not (mad > 1e-7 * data_scale and mad > 0):
            return None, kind  # an exact fit: no outlier test on rounding noise
        if not mad > 0:
            continue
        z = dev / mad
        tail = np.count_nonzero(z > 3)
        if best is None or tail < best[0]:
            best = (tail, z, kind)
    return best[1], best[2]


def _robust_sd(x):
    """``(|x - median|, 1.4826 MAD)``: each value's deviation and the robust standard deviation."""
    dev = np.abs(x - _median_of_copy(x))
    return dev, 1.4826 * _median_of_copy(dev)


def identifiability(Jt, labels, lower, upper, gram=None):
    """Unidentified parameters from the Jacobian in natural parameters.

    The eigenvalues of the scaled :math:`J^T J` (the squared singular values of the scaled
    Jacobian) come from the (p, p) Gram matrix in float64, which resolves relative sizes far below
    :data:`IDENT_RCOND`: a table of millions of rows costs no SVD.

    Parameters
    ----------
    Jt : array_like (n, p) or None
        Jacobian of the residuals in the natural parameters (None when ``gram`` is given).
    labels : sequence of str (p,)
        Parameter names.
    lower, upper : ndarray (p,)
        Bounds (``inf`` upper: unbounded); each parameter is scaled to its bound width (1 if none).
    gram : array_like (p, p), optional
        :math:`J^T J`, used instead of ``Jt``.

    Returns
    -------
    list of str
        Labels of the parameters that dominate the directions of relative eigenvalue below
        :data:`IDENT_RCOND` (empty when every direction is determined).

    Examples
    --------
    >>> import numpy as np
    >>> J = np.array([[1.0, 1.0], [2.0, 2.0], [3.0, 3.0]])   # only a + b is seen
    >>> identifiability(J, ["a", "b"], np.zeros(2), np.ones(2))
    ['a', 'b']
    """
    span = np.where(np.isfinite(upper), upper - lower, 1.0)
    if gram is None:
        Jt = np.asarray(Jt, float)
        gram = Jt.T @ Jt
    G = np.asarray(gram, float) * np.outer(span, span)
    if not np.all(np.isfinite(G)):
        return list(labels)
    s2, v = np.linalg.eigh(G)
    vt = v.T
    top = s2.max() if s2.size else 0.0
    if top <= 0:
        return list(labels)
    weak = s2 < IDENT_RCOND * top
    if not weak.any():
        return []
    load = np.sum(vt[weak] ** 2, axis=0)
    return [lab for lab, w in zip(labels, load) if w > 0.1]


def _median_of_copy(a):
    """``np.median`` of a 1-D array (NaN if it holds one), partitioning one copy of it in place (a
    full MERL table's 3.3 million residuals: ``np.median``'s own copies and mean cost more than
    the partition)."""
    if np.isnan(a).any():
        return np.float64(np.nan)
    a = a.copy()
    k = a.size // 2
    if a.size % 2:
        a.partition(k)
        return a[k]
    a.partition([k - 1, k])
    return 0.5 * (a[k - 1] + a[k])


def diagnose(*, labels, values, stderr, lower, upper, residuals, converged, steps, max_steps, known_sigma,
             dof, Jt=None, gram=None, data_scale=0.0, start_values=None, start_objectives=None, best=0,
             start_reference=None, start_stderr=None, scale=None, physical=None, fit_var=None):
    """Warnings about a fit's optimum (each check: the module docstring). Keywords only.

    Parameters
    ----------
    labels : sequence of str (p,)
        Parameter names.
    values, stderr, lower, upper : ndarray (p,)
        The optimum, its standard errors and the bounds, in natural parameters.
    residuals : array_like
        The residuals at the optimum; exact zeros (unused entries) are left out of the outlier and
        chi-square checks.
    converged, known_sigma : bool
        The solver met its tolerances; the residuals are in units of the table's own sigma
        (enables the chi-square check).
    steps, max_steps : int
        Steps taken and the cap (``steps >= max_steps``: the reason given for not converging).
    dof : int
        Degrees of freedom of the chi-square check (residuals minus free parameters).
    Jt, gram : array_like, optional
        The Jacobian in natural parameters or its Gram matrix (:func:`identifiability`).
    data_scale : float, default 0.0
        The root mean square of the weighted data (the exact-fit threshold).
    start_values, start_objectives : array_like (starts, p), (starts,), optional
        What each start reached and its objective; ``best`` (default 0) indexes the best start.
    start_reference, start_stderr : ndarray (p,), optional
        Where and at which standard errors the starts are compared (default ``values``,
        ``stderr``; a large table's starts are compared where they ended on its subset).
    scale : array_like, optional
        The measured values in the residuals' space and layout (the loss's target times the
        square root of the weight), for proportional noise; without it the noise is additive.
    physical : array_like (p, 2) of bool, optional
        Whether each lower/upper bound is a physical limit
        (:meth:`~matfit.fitting.Parametrization.physical_bounds`); default: range limits.
    fit_var : array_like, optional
        Each fitted value's variance (residuals' layout) from the parameters' covariance.

    Returns
    -------
    warnings : list of str
        One plain-language warning per finding.
    unidentified : list of str
        The labels whose standard errors should be reported as ``inf``.
    """
    out = []
    if not converged:
        why = f"it stopped at max_steps={max_steps}" if steps >= max_steps else "it did not meet its tolerances"
        out.append(f"not converged: the solver did not converge ({why}); raise max_steps or use more starts")
    unident = identifiability(Jt, labels, lower, upper, gram)
    if unident:
        out.append(f"not identifiable: the table does not constrain {', '.join(unident)} (rank-deficient Jacobian); "
                   "add rows at other angles, fix or tie parameters, or use a simpler family")
    span = np.where(np.isfinite(upper), upper - lower, 1.0)
    at_lo = (values - lower) <= BOUND_TOL * span
    at_hi = np.isfinite(upper) & ((upper - values) <= BOUND_TOL * span)
    phys = np.zeros((len(labels), 2), bool) if physical is None else np.asarray(physical, bool).reshape(-1, 2)
    for i, (lab, v, lo, hi, a, b) in enumerate(zip(labels, values, lower, upper, at_lo, at_hi)):
        if a or b:
            side = "lower" if a else "upper"
            if phys[i, 0 if a else 1]:
                why = ("a physical limit: the data ask for none (or all) of what it scales, so a smaller "
                       "family may explain them as well")
            else:
                why = ("a range limit of the family, not of physics: the best fit may lie beyond it "
                       "(widen it with compose_family(bounds=...), or read the fit as a boundary fit)")
            out.append(f"at a bound: {lab} = {v:.6g} is at its {side} bound {lo if a else hi:g}, {why}")
    r_all = np.asarray(residuals)
    keep = r_all != 0
    r = r_all[keep].astype(np.result_type(r_all.dtype, np.float32), copy=False)  # float32 stays float32 (medians of millions)
    if r.size >= 8:
        flat = keep.reshape(-1)
        z, kind = _standardized(r, None if scale is None else np.abs(np.asarray(scale)).reshape(-1)[flat], data_scale,
                                None if fit_var is None else np.asarray(fit_var).reshape(-1)[flat])
        if z is not None:
            n_out = int(np.count_nonzero(z > OUTLIER_Z))
            # Gaussian noise gives P(|z| > 6) ~ 2e-9: a handful is already significant
            if n_out > max(2, 1e-4 * r.size):
                out.append(f"outliers: {n_out} of {r.size} residuals are more than {OUTLIER_Z:g} robust standard "
                           f"deviations from the fit under {kind} (largest {z.max():.3g}); use robust='huber' "
                           "or 'cauchy', or mask them")
    if known_sigma and dof > 0:
        chi2 = float(np.sum(np.square(r, dtype=float))) / dof
        if chi2 > CHI2_MAX:
            out.append(f"poor fit: reduced chi-square {chi2:.4g} > {CHI2_MAX:g} with the table's own sigma: the model "
                       "does not explain the data (wrong family, outliers, or a local optimum)")
    if start_values is not None and start_objectives is not None and len(start_objectives) > 1:
        ob = np.asarray(start_objectives, float)
        sv = np.asarray(start_values, float)
        best_obj = ob[best]
        ref = values if start_reference is None else np.asarray(start_reference, float)
        sref = stderr if start_stderr is None else np.asarray(start_stderr, float)
        se = np.where(np.isfinite(sref) & (sref > 0), sref, np.inf)
        for j in range(len(ob)):
            if j == best or not np.isfinite(ob[j]):
                continue
            close = abs(ob[j] - best_obj) <= 1e-3 * max(abs(best_obj), 1e-300)
            far = np.any(np.abs(sv[j] - ref) > 5 * se)
            if close and far:
                out.append("multiple optima: another start reached the same objective at different parameters "
                           f"({', '.join(f'{l}={v:.4g}' for l, v in zip(labels, sv[j]))}); the table does not "
                           "single out one answer")
                break
    return out, unident
