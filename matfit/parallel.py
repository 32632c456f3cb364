"""Spread a batch of independent evaluations over every device: GPUs, or host CPU devices.

A batch laid out along its first axis with :func:`batch_sharding` is split into one contiguous
block per device, and every jitted elementwise function of it runs on all devices (the sharding
propagates through ``jax.jit``). The same code runs unchanged on one device, on several host
devices and on GPUs.

On a CPU, measure before splitting (``benchmarks/bench_cores.py``, figures in
``docs/performance.md``): one CPU device already runs a large fused loop on every core, while
two *host devices* (:func:`use_host_devices`) were measured running their blocks one after the
other. So the default is one CPU device; host devices are for the cases where a measurement
shows a gain, and for testing the multi-device code path.

Examples
--------
>>> import jax.numpy as jnp
>>> from matfit.parallel import shard_batch
>>> x, n = shard_batch(jnp.arange(5.0))     # padded to a multiple of the device count
>>> n, x.shape[0] % len(x.sharding.device_set)
(5, 0)
"""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from .errors import MatfitError

#: Name of the mesh axis that the batch is split along.
BATCH_AXIS = "batch"

__all__ = ["BATCH_AXIS", "use_host_devices", "use_cores", "for_small_calls", "batch_mesh", "batch_sharding",
           "shard_batch", "device_count", "pad_to_power_of_two"]


def _backend_started():
    try:  # the public API has no "is the backend started" query
        from jax._src import xla_bridge

        return xla_bridge.backends_are_initialized()
    except (ImportError, AttributeError):
        return None


def use_host_devices(n: int | None = None) -> int:
    """Expose ``n`` CPU cores as separate JAX host devices (default: every core).

    Must run before JAX starts its backend (before the first array is created or
    ``jax.devices()`` is called; importing jax or matfit first is fine); once started with the
    same count it is a no-op. Equivalent to ``XLA_FLAGS=--xla_force_host_platform_device_count=n``
    in the environment before Python starts. No effect on GPU backends (every GPU is a device).

    Parameters
    ----------
    n : int, optional
        Host devices, >= 1 (default: ``os.cpu_count()``).

    Returns
    -------
    int
        The number requested. Raises :class:`MatfitError` for ``n < 1``, or when the backend has
        already started with a different count.
    """
    n = int(n if n is not None else (os.cpu_count() or 1))
    if n < 1:
        raise MatfitError(f"use_host_devices: n must be >= 1, got {n}")
    started = _backend_started()
    if started is None:  # another JAX version: ask the config, which refuses once started
        try:
            jax.config.update("jax_num_cpu_devices", n)
            return n
        except Exception:  # noqa: BLE001 - the check below names the problem
            started = True
    if started:
        have = len(jax.devices("cpu"))
        if have != n:
            raise MatfitError(
                f"use_host_devices({n}): the JAX backend already started with {have} CPU device(s); call it before "
                f"the first JAX computation, or set XLA_FLAGS=--xla_force_host_platform_device_count={n} before "
                "starting Python"
            )
        return n
    jax.config.update("jax_num_cpu_devices", n)
    return n


def use_cores(n: int) -> int:
    """Limit this process to ``n`` of the CPU cores it may use (its CPU affinity, Linux).

    XLA sizes its CPU thread pool from the cores a process may use when JAX starts its backend,
    so this must run before that (before the first array or ``jax.devices()``; importing jax or
    matfit first is fine); ``taskset -c 0 python ...`` does the same from outside. Many small
    calls gain from one core: a small log-posterior call spends more on handing each of its loops
    to a second thread than the thread gives back (``benchmarks/bench_emcee.py --cores 1``,
    ``docs/performance.md``). Large tables lose: a full MERL fit's loops run on one core instead
    of two.

    Parameters
    ----------
    n : int
        Cores, >= 1: the first ``n`` of those the process may use now.

    Returns
    -------
    int
        The number of cores the process may now use. Raises :class:`MatfitError` for ``n < 1``,
        once JAX's backend has started, or where the platform cannot set an affinity.
    """
    n = int(n)
    if n < 1:
        raise MatfitError(f"use_cores: n must be >= 1, got {n}")
    if not hasattr(os, "sched_setaffinity"):
        raise MatfitError("use_cores: this platform cannot set a CPU affinity (Linux only); start Python with one "
                          "core allowed instead (e.g. `start /affinity 1` on Windows)")
    if _backend_started() is not False:
        raise MatfitError(f"use_cores({n}): the JAX backend already started (or this JAX version cannot tell): its "
                          "CPU thread pool is sized; call use_cores before the first JAX computation, or start "
                          f"Python under `taskset -c 0-{n - 1}`")
    allowed = sorted(os.sched_getaffinity(0))
    os.sched_setaffinity(0, allowed[:n])
    return len(os.sched_getaffinity(0))


def for_small_calls(cores: int | None = 1) -> int:
    """Set this process up for many small JAX calls on the CPU, such as an emcee run's: limit it
    to ``cores`` cores (:func:`use_cores`; ``None`` keeps them all) and turn JAX's asynchronous
    CPU dispatch off (``jax_cpu_enable_async_dispatch``).

    With asynchronous dispatch, JAX's default, each call is handed to a runtime thread and the
    caller then waits for its result: for a small call (an emcee step's log-posterior) that
    hand-over is a noticeable part of the call, more when the thread has gone idle while
    emcee's own Python ran. With dispatch off the caller runs the call itself (figures in
    ``docs/performance.md``, emcee section). Large calls (a full MERL table's fit) run on one
    core instead of all: ``cores=None`` keeps every core and only turns the dispatch off.
    Like :func:`use_cores`, it must run before JAX starts its backend.

    Parameters
    ----------
    cores : int or None, default 1
        Cores to keep (:func:`use_cores`), or None for all.

    Returns
    -------
    int
        The number of cores the process may use. Raises :class:`MatfitError` once the backend has
        started (or, with ``cores``, where the platform cannot set an affinity).
    """
    if _backend_started() is not False:
        raise MatfitError("for_small_calls: the JAX backend already started (or this JAX version cannot tell): its "
                          "dispatch mode and CPU thread pool are set; call it before the first JAX computation")
    if cores is not None:
        n = use_cores(cores)
    else:
        n = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    jax.config.update("jax_cpu_enable_async_dispatch", False)
    return n


def _devices(devices=None):
    return list(jax.devices() if devices is None else devices)


def device_count(devices=None) -> int:
    """Number of devices a batch is split over: the blocks :func:`shard_batch` makes.

    Parameters
    ----------
    devices : sequence of jax devices, optional
        The devices to count (default ``jax.devices()``).

    Returns
    -------
    int
    """
    return len(_devices(devices))


def batch_mesh(devices=None) -> Mesh:
    """A one-axis mesh (:data:`BATCH_AXIS`) over ``devices``, in order.

    Parameters
    ----------
    devices : sequence of jax devices, optional
        Default ``jax.devices()``.

    Returns
    -------
    jax.sharding.Mesh
    """
    return Mesh(np.array(_devices(devices)), (BATCH_AXIS,))


def batch_sharding(devices=None) -> NamedSharding:
    """Sharding that splits the first axis of an array into one block per device.

    Parameters
    ----------
    devices : sequence of jax devices, optional
        Block ``k`` goes to ``devices[k]`` (default ``jax.devices()``).

    Returns
    -------
    jax.sharding.NamedSharding
        Over :func:`batch_mesh`, the first axis along :data:`BATCH_AXIS`.
    """
    return NamedSharding(batch_mesh(devices), PartitionSpec(BATCH_AXIS))


def pad_to_power_of_two(idx, size=None):
    """``idx`` padded to ``size`` entries (default: the next power of two) by repeating its last.

    Batches of nearby sizes then share one compiled program; results are valid in ``[:len(idx)]``.

    Parameters
    ----------
    idx : array_like (n,), n >= 1
        Indices of the batch's items.
    size : int, optional
        The padded length (>= n).

    Returns
    -------
    numpy.ndarray

    Examples
    --------
    >>> from matfit.parallel import pad_to_power_of_two
    >>> pad_to_power_of_two([4, 7, 9]).tolist(), pad_to_power_of_two([4], 3).tolist()
    ([4, 7, 9, 9], [4, 4, 4])
    """
    idx = np.asarray(idx)
    size = 1 << int(idx.size - 1).bit_length() if size is None else int(size)
    return np.concatenate([idx, np.repeat(idx[-1:], size - idx.size)])


def shard_batch(tree, devices=None, fill=None):
    """Pad the first axis of every array in ``tree`` to a multiple of the device count and split it.

    Parameters
    ----------
    tree : pytree of arrays
        All leaves share the same first-axis length ``n``.
    devices : sequence of jax devices, optional
        Default: every device of the default backend.
    fill : pytree like ``tree`` of scalars, optional
        Value of the padding rows per leaf (default: a copy of the last row, so padded rows are
        valid inputs and never produce NaN).

    Returns
    -------
    sharded_tree : pytree of jax.Array
        The padded arrays, placed with :func:`batch_sharding`.
    n : int
        The original length: results computed from them are valid in ``[:n]``.

    Raises
    ------
    MatfitError
        No arrays, an empty batch, or leaves of different first-axis lengths.
    """
    leaves, treedef = jax.tree_util.tree_flatten(tree)
    if not leaves:
        raise MatfitError("shard_batch: no arrays given")
    ns = {int(np.shape(x)[0]) if np.ndim(x) else -1 for x in leaves}
    if len(ns) != 1 or -1 in ns:
        raise MatfitError(f"shard_batch: every array needs the same first-axis length, found {sorted(ns)}")
    n = ns.pop()
    if n == 0:
        raise MatfitError("shard_batch: empty batch")
    nd = device_count(devices)
    pad = (-n) % nd
    fills = [None] * len(leaves) if fill is None else jax.tree_util.tree_leaves(fill)
    out = []
    sh = batch_sharding(devices)
    for x, f in zip(leaves, fills):
        x = jnp.asarray(x) if not isinstance(x, np.ndarray) else x
        if pad:
            tail = x[-1:] if f is None else np.full((1,) + x.shape[1:], f, dtype=x.dtype)
            x = np.concatenate([np.asarray(x), np.repeat(np.asarray(tail), pad, axis=0)])
        out.append(jax.device_put(x, sh))
    return jax.tree_util.tree_unflatten(treedef, out), n
