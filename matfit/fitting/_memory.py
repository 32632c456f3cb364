"""The memory a fit needs, and the refusal before allocating when the machine does not have it."""

from __future__ import annotations

import os

import jax.numpy as jnp
import numpy as np

from ._result import FitError

__all__ = ["available_memory", "memory_estimate", "check_memory", "BYTES_PER_ROW"]


#: Bytes of working memory a fit needs per table row and value, in units of the float size: the
#: table's device copy, its structure-of-arrays layout and prepared targets, and per parameter
#: group one difference column (``lm_fd`` keeps ``J`` compressed and streams ``J^T J``).
BYTES_PER_ROW = (16, 8, 2)  # (per row, per value, per value and parameter group)


def available_memory():
    """Bytes of memory the system can give this process now (``MemAvailable`` of
    ``/proc/meminfo``, else the physical memory), or None when unknown."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def memory_estimate(rows, channels, groups, dtype=None):
    """Estimated peak working memory (bytes) of :func:`~matfit.fitting.fit` on a table.

    Parameters
    ----------
    rows, channels, groups : int
        Rows with a nonzero weight, colour channels, column groups of the Jacobian (parameter
        names; :func:`~matfit.fitting.lm.column_groups`).
    dtype : dtype, optional
        The fit's floating type (default: JAX's default float).

    Returns
    -------
    int
        Bytes: :data:`BYTES_PER_ROW` per row, value and value-and-group, times the float size.

    Examples
    --------
    >>> from matfit.fitting.fit import memory_estimate
    >>> round(memory_estimate(1_458_000, 3, 3, "float32") / 2**20)  # a full MERL table, conductor
    323
    """
    size = np.dtype(dtype or jnp.result_type(float)).itemsize
    a, b, c = BYTES_PER_ROW
    return int(rows * size * (a + channels * (b + c * groups)))


def check_memory(where, rows, channels, groups, dtype=None):
    """Raise :class:`FitError` before allocating when a fit of ``rows`` rows would need more
    memory than the system has available (row count, estimate and availability in the message)."""
    need = memory_estimate(rows, channels, groups, dtype)
    have = available_memory()
    if have is not None and need > have:
        size = lambda b: f"{b / 2**30:.1f} GiB" if b >= 2**30 else f"{b / 2**20:.1f} MiB"  # noqa: E731
        raise FitError(f"{where}: a table of {rows} rows x {channels} channels needs about {size(need)} of working "
                       f"memory ({np.dtype(dtype or jnp.result_type(float)).name}), and {size(have)} are "
                       "available; fit a subsample (Table.subsample or matfit fit --subsample N) or use a machine "
                       "with more memory")
