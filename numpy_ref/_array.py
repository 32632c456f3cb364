"""Array helpers shared by the reference modules (float64, last axis = x, y, z)."""

from __future__ import annotations

import numpy as np


def f64(x):
    """``x`` as a float64 array."""
    return np.asarray(x, dtype=np.float64)


def dot(a, b):
    """Dot product over the last axis (``a_x b_x + a_y b_y + a_z b_z``)."""
    a, b = f64(a), f64(b)
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def normalize(v):
    """``v / |v|`` over the last axis; a zero vector stays zero."""
    v = f64(v)
    n = np.sqrt(dot(v, v))
    return v / np.where(n > 0, n, 1.0)[..., None]


def flip_up(m):
    """``m`` or ``-m``, whichever has ``m_z >= 0``."""
    return np.where((m[..., 2] < 0)[..., None], -m, m)
