r"""Residuals and losses for fitting BRDF tables.

For predictions :math:`f` and measurements :math:`y` at the table's directions, with weights
:math:`w` (``1/sigma^2`` when the table has standard deviations) and the valid mask applied:

=============  =======================================================================
``"l2"``       :math:`r = \sqrt{w}\,(f - y)` (weighted least squares on values)
``"e2"``       :math:`r = \sqrt{w}\,(\log(1 + f\cos\theta_i) - \log(1 + y\cos\theta_i))`
               (Löw et al. 2012, the E2 metric)
``"cbrt"``     :math:`r = \sqrt{w}\,(\sqrt[3]{f\cos\theta_i + \delta} - \sqrt[3]{y\cos\theta_i + \delta})`
               (Fores et al. 2012, the cube-root metric; :math:`\delta` = :data:`CBRT_DELTA`
               keeps the gradient finite at zero, negative values clipped to 0)
``"cosine"``   :math:`r = \sqrt{w}\,(f - y)\cos\theta_i` (Ngan et al. 2005, cosine-weighted)
``"relative"`` :math:`r = \sqrt{w}\,(f - y)/(|y| + \epsilon)`
=============  =======================================================================

Robust variants (``robust="huber"`` or ``"cauchy"``, scale ``c``) replace each residual by
:math:`\operatorname{sign}(r)\sqrt{2\rho(r)}` so that least squares minimizes
:math:`\sum\rho(r)`: Huber :math:`\rho = r^2/2` for :math:`|r| \le c`, else
:math:`c(|r| - c/2)`; Cauchy :math:`\rho = (c^2/2)\log(1 + r^2/c^2)`. The constant is
:math:`c = 1.345\,s` (Huber) or :math:`c = 2.385\,s` (Cauchy) for the ``scale`` argument
:math:`s` of :func:`residuals`.

References
----------
- J. Löw, J. Kronander, A. Ynnerman, J. Unger, "BRDF Models for Accurate and Efficient
  Rendering of Glossy Surfaces", ACM ToG 31(1), 2012.
- A. Fores, J. Ferwerda, J. Gu, "Toward a Perceptually Based Metric for BRDF Modeling", Color
  and Imaging Conference 2012.
- A. Ngan, F. Durand, W. Matusik, "Experimental Analysis of BRDF Models", EGSR 2005.
- P. J. Huber, "Robust Estimation of a Location Parameter", Ann. Math. Stat. 35(1), 1964.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["DEFAULT_LOSS", "LOSSES", "ROBUST", "REL_EPS", "CBRT_DELTA", "check_loss", "residuals", "prepare_targets", "residuals_from_targets"]

from .._math import safe_sqrt
from ..errors import ParameterError

LOSSES = ("l2", "e2", "cbrt", "cosine", "relative")
#: The loss of a fit, a posterior or a comparison that names none (a family chosen by appearance
#: uses :data:`~matfit.fitting._choose.CHOICE_LOSS`).
DEFAULT_LOSS = "l2"
ROBUST = (None, "huber", "cauchy")
REL_EPS = 1e-3
#: Offset of the cube-root loss: its slope at zero is (1/3) CBRT_DELTA^(-2/3), about 3e3.
CBRT_DELTA = 1e-6


def check_loss(loss, robust) -> None:
    """Raise unless ``loss`` is one of :data:`LOSSES` and ``robust`` one of :data:`ROBUST`.

    Parameters
    ----------
    loss : str
    robust : str or None

    Raises
    ------
    matfit.errors.ParameterError
        Naming the accepted values.
    """
    if loss not in LOSSES:
        raise ParameterError(f"loss must be one of {list(LOSSES)}, got {loss!r}")
    if robust not in ROBUST:
        raise ParameterError(f"robust must be one of {list(ROBUST)}, got {robust!r}")


def residuals(pred, values, weight, cos_i, loss=DEFAULT_LOSS, robust=None, scale=1.0):
    """Residual vector (N, C) for predictions ``pred`` against ``values``: the same as
    ``residuals_from_targets(pred, *prepare_targets(values, weight, cos_i, loss), cos_i, loss,
    robust, scale)`` (a fit prepares the data's part once).

    Parameters
    ----------
    pred, values : array_like (N, C)
        Model predictions and measurements at the table's directions (``values`` may be NaN
        where ``weight`` is 0).
    weight : array_like (N, C)
        Weights, ``1/sigma^2`` when the table has standard deviations; zero on invalid rows
        (see :meth:`matfit.Table.effective_weight`).
    cos_i : array_like (N,)
        Cosine of the incident zenith angle of each row.
    loss : {"l2", "e2", "cbrt", "cosine", "relative"}, default "l2"
        The loss (see the module docstring).
    robust : {None, "huber", "cauchy"}, default None
        The robust variant.
    scale : float or array_like, default 1.0
        Scale ``s`` of the robust variant (finite, > 0); ignored when ``robust`` is None.

    Returns
    -------
    jax.Array (N, C)
        The residuals; 0 where ``weight`` is 0.

    Raises
    ------
    matfit.errors.ParameterError
        When ``loss`` or ``robust`` is unknown, the shapes do not broadcast, or ``scale`` is not
        finite and > 0 with a robust variant.

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.fitting.losses import residuals
    >>> float(residuals(jnp.array([[2.0]]), jnp.array([[1.0]]), jnp.array([[4.0]]), jnp.array([1.0]))[0, 0])  # sqrt(4) (2 - 1)
    2.0
    """
    check_loss(loss, robust)
    shapes = {"pred": jnp.shape(pred), "values": jnp.shape(values), "weight": jnp.shape(weight),
              "cos_i": jnp.shape(cos_i) + (1,)}
    try:
        jnp.broadcast_shapes(*shapes.values())
    except ValueError:
        raise ParameterError("residuals: shapes do not broadcast: " + ", ".join(
            f"{k} {v if k != 'cos_i' else v[:-1]}" for k, v in shapes.items())) from None
    if robust is not None and not isinstance(scale, jax.core.Tracer) and not (np.all(np.isfinite(scale))
                                                                           and np.all(np.asarray(scale) > 0)):
        raise ParameterError(f"residuals: scale must be finite and > 0 for robust={robust!r}, got {scale!r}")
    target, factor = prepare_targets(values, weight, cos_i, loss)
    return residuals_from_targets(pred, target, factor, cos_i, loss, robust, scale)


def _transform(x, cos_i, loss):
    """The map applied to predictions and measurements alike before they are differenced."""
    if loss == "e2":
        return jnp.log1p(jnp.maximum(x * cos_i[..., None], -0.999))
    if loss == "cbrt":
        return jnp.cbrt(jnp.maximum(x * cos_i[..., None], 0) + CBRT_DELTA)
    return x


def prepare_targets(values, weight, cos_i, loss=DEFAULT_LOSS):
    """The data's part of :func:`residuals`, computed once per table: ``r = factor * (T(pred) -
    target)`` (0 where ``factor`` is 0), ``T`` the loss's transform (``log(1 + f cos_i)`` for
    ``"e2"``, ``cbrt(f cos_i + delta)`` for ``"cbrt"``, identity otherwise), ``factor`` ``sqrt(w)``
    times the loss's weight (``cos_i`` for ``"cosine"``, ``1 / (|y| + eps)`` for ``"relative"``,
    ``eps`` = :data:`REL_EPS`).

    Parameters
    ----------
    values, weight, cos_i, loss
        As for :func:`residuals`.

    Returns
    -------
    target, factor : jax.Array (N, C)
        ``T(values)`` and the residual factor; both 0 on rows with ``weight = 0``.

    Raises
    ------
    matfit.errors.ParameterError
        When ``loss`` is unknown.
    """
    ok = weight > 0
    sw = safe_sqrt(jnp.where(ok, weight, 0))
    values = jnp.where(ok, values, 0)
    if loss == "cosine":
        sw = sw * cos_i[..., None]
    elif loss == "relative":
        sw = sw / (jnp.abs(values) + REL_EPS)
    elif loss not in LOSSES:
        raise ParameterError(f"loss must be one of {list(LOSSES)}, got {loss!r}")
    return jnp.where(ok, _transform(values, cos_i, loss), 0), jnp.where(ok, sw, 0)


def residuals_from_targets(pred, target, factor, cos_i, loss=DEFAULT_LOSS, robust=None, scale=1.0):
    """Residuals from data prepared by :func:`prepare_targets`.

    Parameters
    ----------
    pred, cos_i, loss, robust
        As for :func:`residuals` (``loss`` the one ``target`` and ``factor`` were prepared for).
    target, factor : array_like (N, C)
        The output of :func:`prepare_targets`.
    scale : float or array_like, default 1.0
        Scale ``s`` of the robust variant; not checked here (see :func:`residuals`).

    Returns
    -------
    jax.Array (N, C)
        ``factor * (T(pred) - target)``, 0 where ``factor`` is 0; with a robust variant
        ``sign(r) sqrt(2 rho(r))``.

    Raises
    ------
    matfit.errors.ParameterError
        When ``robust`` is unknown.
    """
    r = jnp.where(factor != 0, factor * (_transform(pred, cos_i, loss) - target), 0)
    if robust is None:
        return r
    a = jnp.abs(r) / scale
    if robust == "huber":
        rho = jnp.where(a <= 1.345, 0.5 * a * a, 1.345 * (a - 0.5 * 1.345))
    elif robust == "cauchy":
        rho = 0.5 * 2.385**2 * jnp.log1p((a / 2.385) ** 2)
    else:
        raise ParameterError(f"robust must be one of {list(ROBUST)}, got {robust!r}")
    return jnp.sign(r) * scale * safe_sqrt(2 * rho)
