"""The residuals a fit minimizes, in the layouts the solvers take: flat, ``(N, C)``, or one array
per colour channel (the structure-of-arrays kernels of :mod:`matfit.fast`); and the table's
arrays they are evaluated on."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .._math import Vec3
from ..fast import SoAPairs, eval_channel
from ..parallel import device_count, shard_batch
from .lm import GRAM_BLOCK
from .losses import prepare_targets, residuals_from_targets

__all__ = ["prepared_residual_fn", "split_residual_fn", "objective_fn", "residual_fn", "split_rows", "by_channel",
           "table_arrays"]


def prepared_residual_fn(par, loss, robust, scale):
    """``(prepare, fn)``: ``prepare(arrays)`` turns a table's ``(wo, wi, values, weight)`` into
    ``(wo, wi, target, factor)`` once (:func:`~matfit.fitting.losses.prepare_targets`: the loss's
    transform of the data and the residual weights), and ``fn(z, prepared)`` are the residuals at
    ``z`` -- inside a solver's loop only the model's part is recomputed. ``fn`` returns them as
    ``(N, C)``, the layout the model writes: flattening them inside the same
    compiled function made XLA rewrite the model's loop into a slower one (``docs/performance.md``)."""

    def prepare(arrays):
        wo, wi, values, weight = arrays
        return (wo, wi) + tuple(prepare_targets(values, weight, wi[..., 2], loss))

    def fn(z, prepared):
        wo, wi, target, factor = prepared
        pred = par.model(z).eval(wo, wi)
        return residuals_from_targets(pred, target, factor, wi[..., 2], loss, robust, scale)

    # jitted: a solver calls fn many times (trial step, Jacobian columns, extrapolation), and a
    # jitted fn is traced once per argument shape instead of once per call site
    return prepare, jax.jit(fn)


def split_residual_fn(par, loss, robust, scale):
    """``(prepare, fn)`` like :func:`prepared_residual_fn`, channel-split for :func:`lm_fd`.

    ``prepare`` lays the table out once as :class:`~matfit.fast.SoAPairs` (component arrays,
    half vector, Fresnel cosine: everything that depends only on the directions) and the
    prepared targets as ``(C, n)``, padded to a multiple of :data:`~matfit.fitting.lm.GRAM_BLOCK`
    rows (padding rows: normal incidence, weight 0, residual 0). ``fn(z, prepared)`` returns one
    residual array ``(n,)`` per channel, each the single-output kernel of
    :func:`matfit.fast.eval_channel`: on a full MERL table faster than the ``(N, C)`` layout
    (figures in ``docs/performance.md``). Only for models :func:`matfit.fast.supports_soa` accepts.
    """

    def prepare(arrays):
        wo, wi, values, weight = arrays
        pad = (-wo.shape[0]) % GRAM_BLOCK
        up = jnp.zeros((pad, 3), wo.dtype).at[:, 2].set(1)
        wo, wi = jnp.concatenate([wo, up]), jnp.concatenate([wi, up])
        values, weight = (jnp.concatenate([a, jnp.zeros((pad,) + a.shape[1:], a.dtype)]) for a in (values, weight))
        target, factor = prepare_targets(values, weight, wi[:, 2], loss)
        o, i = Vec3.from_array(wo), Vec3.from_array(wi)
        return SoAPairs.from_directions(o, i, wo.shape[0]), target.T, factor.T

    def fn(z, prepared):
        pairs, target, factor = prepared
        model = par.model(z)
        return tuple(
            residuals_from_targets(eval_channel(model, pairs, c)[:, None], target[c][:, None], factor[c][:, None],
                                   pairs.wi.z, loss, robust, scale)[:, 0]
            for c in range(target.shape[0]))

    return prepare, jax.jit(fn)  # traced once per argument shape (see prepared_residual_fn)


def objective_fn(prepare, fn):
    """``objective(zs, arrays)``: ``0.5 |r|^2`` for a stack of ``z`` on raw table arrays (prepared
    once per call), from the pair of :func:`prepared_residual_fn`."""

    def objective(zs, arrays):
        prepared = prepare(arrays)
        r = jax.vmap(lambda z: fn(z, prepared))(zs)
        return 0.5 * jnp.sum(r * r, axis=tuple(range(1, r.ndim)))

    return objective


def residual_fn(par, loss, robust, scale):
    """Flat residuals ``fn(z, (wo, wi, values, weight))`` (the data prepared at every call)."""
    prepare, fn = prepared_residual_fn(par, loss, robust, scale)
    return lambda z, arrays: fn(z, prepare(arrays)).reshape(-1)


def split_rows(arrays):
    """Rows split over every device (:mod:`matfit.parallel`; a no-op on one device). Padding rows
    copy the last row with weight 0, so they add nothing to the residuals."""
    nd = device_count()
    pad = (-arrays[0].shape[0]) % nd
    if nd == 1:
        return arrays
    if pad:
        wo, wi, v = (jnp.concatenate([a, jnp.repeat(a[-1:], pad, axis=0)]) for a in arrays[:3])
        arrays = (wo, wi, v, jnp.concatenate([arrays[3], jnp.zeros((pad,) + arrays[3].shape[1:], arrays[3].dtype)]))
    return shard_batch(arrays)[0]


def by_channel(fn):
    """The flat residuals of ``fn`` as (N, C), the layout :func:`lm_fd` works on."""
    return lambda z, arrays: fn(z, arrays).reshape(arrays[2].shape)


def table_arrays(table, dtype, weight=None):
    """``(wo, wi, values, weight)`` of a table as JAX arrays; given the table's ``weight``
    (:meth:`~matfit.Table.effective_weight`), only the rows with a nonzero weight in some channel
    (the others add nothing to any residual: a MERL table's invalid cells, a quarter of its rows,
    cost neither memory nor time)."""
    if weight is not None:
        w = weight
        keep = np.any(w > 0, axis=1)
        if not keep.all():
            rows = np.flatnonzero(keep)  # np.take of row indices: faster than a boolean mask of (N, 3) arrays
            f = lambda x: jnp.asarray(np.take(x, rows, axis=0), dtype=dtype)  # noqa: E731  (dtype None: x's own)
            return (f(table.wo), f(table.wi), f(table.values), f(w))
    a = table.as_jax(dtype)
    return (a.wo, a.wi, a.values, a.weight)
