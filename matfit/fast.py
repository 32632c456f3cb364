r"""Fast evaluation of a model on many direction pairs: structure of arrays, one kernel per channel,
split over every device.

``model.eval(wo, wi)`` derives its direction pairs (:class:`~matfit.models.SoAPairs`: components,
half vector, Fresnel cosine, validity) inside the same compiled program as its arithmetic. When the
same directions are evaluated many times (a fit, rendering a table), :func:`soa_pairs` keeps them
as a cache: laid out once as a structure of arrays, split along the batch over every device
(:mod:`matfit.parallel`), and :func:`eval_soa` evaluates each colour channel as its own
single-output XLA kernel on them, so that only the parameter-dependent arithmetic runs per call.

The kernels are the models' own :meth:`~matfit.models.AbstractBSDF.eval_pairs` applied to the
one-channel model of each channel (:func:`channel_model`). Models with
:attr:`~matfit.models.AbstractBSDF.pair_kernels` take this path; any other model is evaluated
by its ``eval`` on the rebuilt ``(N, 3)`` arrays, still split over every device.

Compilation happens once per model structure (class, static options, parameter shapes) and pair
count: new parameter values, or new directions of the same count, reuse the compiled kernels.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ._math import Vec3
from .errors import ParameterError
from .models import SoAPairs, half_vector
from .models import AbstractBSDF
from .parallel import shard_batch

__all__ = ["SoAPairs", "soa_pairs", "eval_soa", "eval_channel", "half_vector", "channel_model", "supports_soa"]


def soa_pairs(wo, wi, dtype=None, devices=None) -> SoAPairs:
    """Lay out direction pairs for :func:`eval_soa`: split into components, pad, shard.

    Parameters
    ----------
    wo, wi : array_like, shape (N, 3)
        Outgoing and incident unit directions (local frame, normal +z), broadcast together.
    dtype : dtype, optional
        Floating type of the components (default: that of ``wo``; float32 unless x64 is on).
    devices : sequence of jax devices, optional
        Devices to split the batch over (default: every device of the default backend; see
        :func:`matfit.parallel.use_host_devices` for the CPU cores).

    Returns
    -------
    SoAPairs
        The pairs, padded to a multiple of the device count (``n`` valid ones) and sharded.
        Raises :class:`ParameterError` for directions that are not ``(N, 3)`` arrays.
    """
    wo = np.asarray(wo)
    wi = np.asarray(wi)
    if wo.ndim != 2 or wo.shape[-1] != 3 or wi.ndim != 2 or wi.shape[-1] != 3:
        raise ParameterError(f"soa_pairs: wo and wi must have shape (N, 3), found {wo.shape} and {wi.shape}")
    wo, wi = np.broadcast_arrays(wo, wi)
    if dtype is None:
        dtype = jnp.result_type(jnp.asarray(wo[:1]))
        if not jnp.issubdtype(dtype, jnp.floating):
            dtype = jnp.result_type(float)
    comps = tuple(np.ascontiguousarray(a[:, j], dtype=dtype) for a in (wo, wi) for j in range(3))
    sharded, n = shard_batch(comps, devices)
    return SoAPairs.from_directions(Vec3(*sharded[:3]), Vec3(*sharded[3:]), n)


def supports_soa(model) -> bool:
    """True when ``model`` evaluates prepared pairs channel by channel on component arrays
    (its :attr:`~matfit.models.AbstractBSDF.pair_kernels`).

    Parameters
    ----------
    model : AbstractBSDF

    Returns
    -------
    bool
    """
    return bool(model.pair_kernels)


def channel_model(model: AbstractBSDF, c: int) -> AbstractBSDF:
    """The one-channel model of channel ``c``: every per-channel parameter sliced to ``[..., c:c+1]``.

    Per-channel parameters are the array leaves whose last axis has the model's channel count
    ``C`` (> 1); scalar and batch parameters are kept. Every model's channels are independent in
    ``eval``, so ``channel_model(m, c).eval(wo, wi)[..., 0] == m.eval(wo, wi)[..., c]``.

    Parameters
    ----------
    model : AbstractBSDF
    c : int
        The channel, ``0 <= c < model.channels`` (else :class:`ParameterError`).

    Returns
    -------
    AbstractBSDF
        A model of the same structure with one channel (``model`` itself when it has one).
    """
    C = model.channels
    if C == 1:
        return model
    if not 0 <= c < C:
        raise ParameterError(f"channel_model: channel {c} out of range for a {C}-channel model")

    def pick(x):
        if isinstance(x, (jax.Array, np.ndarray)) and x.ndim >= 1 and x.shape[-1] == C:
            return x[..., c : c + 1]
        return x

    return jax.tree_util.tree_map(pick, model)


def eval_channel(model: AbstractBSDF, pairs: SoAPairs, c: int):
    """Channel ``c`` of ``model.eval`` on SoA pairs, with the direction-only quantities (half
    vector, Fresnel cosine) taken from ``pairs``.

    Only for models that :func:`supports_soa` accepts; traced alone it is one single-output loop.

    Parameters
    ----------
    model : AbstractBSDF
    pairs : SoAPairs
        From :func:`soa_pairs` (or :meth:`SoAPairs.of <matfit.models.SoAPairs.of>`).
    c : int
        The channel.

    Returns
    -------
    jax.Array, shape (n_padded,)
        The channel's values on every pair (padding included).
    """
    return channel_model(model, c).eval_pairs(pairs)[..., 0]


@jax.jit
def _soa_kernel(model, pairs):
    # One output per channel. XLA compiles each into its own loop over the batch and computes the
    # channel-independent part (D G / (4 cos cos) for a microfacet lobe) once, in a loop of its own.
    return tuple(eval_channel(model, pairs, c) for c in range(model.channels))


@jax.jit
def _full_kernel(model, pairs):
    f = model.eval(pairs.wo.to_array(), pairs.wi.to_array())
    return tuple(f[..., c] for c in range(f.shape[-1]))


def eval_soa(model: AbstractBSDF, pairs: SoAPairs, stack: bool = False):
    """Evaluate ``model.eval`` on pairs laid out by :func:`soa_pairs`, one kernel per channel.

    Parameters
    ----------
    model : AbstractBSDF
        Any matfit model. :attr:`~matfit.models.AbstractBSDF.pair_kernels` models run one single-output kernel
        per channel on the component arrays; others run their ``eval`` on the ``(N, 3)`` arrays.
    pairs : SoAPairs
        From :func:`soa_pairs`.
    stack : bool
        False (default): a tuple of ``C`` arrays of shape ``(N,)`` (no copy). True: one ``(N, C)``
        array like ``model.eval`` (one interleaving copy).

    Returns
    -------
    tuple of jax.Array (N,) or jax.Array (N, C)
        Equal to ``model.eval(wo, wi)`` up to float rounding.

    Examples
    --------
    >>> import jax.numpy as jnp, numpy as np
    >>> from matfit.models import RoughConductor
    >>> from matfit.fast import soa_pairs, eval_soa
    >>> gold = RoughConductor(0.2, jnp.array([0.143, 0.374, 1.442]), jnp.array([3.983, 2.385, 1.603]))
    >>> wo = np.array([[0.0, 0.6, 0.8]]); wi = np.array([[0.0, -0.6, 0.8]])
    >>> r, g, b = eval_soa(gold, soa_pairs(wo, wi))
    >>> bool(jnp.allclose(jnp.stack([r, g, b], -1), gold.eval(jnp.asarray(wo), jnp.asarray(wi)), rtol=1e-5))
    True
    """
    if not isinstance(pairs, SoAPairs):
        raise ParameterError(f"eval_soa: pairs must come from matfit.fast.soa_pairs, got {type(pairs).__name__}")
    outs = (_soa_kernel if supports_soa(model) else _full_kernel)(model, pairs)
    if pairs.n != pairs.n_padded:
        outs = tuple(o[: pairs.n] for o in outs)
    if stack:
        return jnp.stack(outs, axis=-1)
    return outs
