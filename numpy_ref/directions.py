"""Random and structured direction sets (float64 unit vectors, last axis x, y, z)."""

from __future__ import annotations

import numpy as np

from ._array import f64, flip_up, normalize

__all__ = ["random_directions", "random_normals_near_z", "generalized_half_vector"]


def random_directions(rng, n, hemisphere="upper", min_abs_cos=0.0):
    """n uniformly distributed unit vectors (float64, shape (n, 3)).

    hemisphere: "upper" (z > 0), "lower" (z < 0) or "both". Directions with |z| < min_abs_cos are
    redrawn (use it to stay away from grazing angles).
    """
    out = np.empty((0, 3))
    while out.shape[0] < n:
        v = rng.normal(size=(2 * n + 8, 3))
        v /= np.linalg.norm(v, axis=-1, keepdims=True)
        if hemisphere == "upper":
            v[:, 2] = np.abs(v[:, 2])
        elif hemisphere == "lower":
            v[:, 2] = -np.abs(v[:, 2])
        else:
            assert hemisphere == "both", hemisphere
        v = v[np.abs(v[:, 2]) > max(min_abs_cos, 1e-6)]
        out = np.concatenate([out, v])
    return out[:n]


def random_normals_near_z(rng, n, alpha_x, alpha_y=None, spread=3.0):
    """Unit vectors in the upper hemisphere concentrated where a distribution of roughness alpha
    has its mass: tan(theta) ~ alpha(phi) * U(0, spread)."""
    alpha_y = alpha_x if alpha_y is None else alpha_y
    phi = rng.uniform(0, 2 * np.pi, n)
    r = rng.uniform(0, spread, n)
    tx = r * alpha_x * np.cos(phi)
    ty = r * alpha_y * np.sin(phi)
    v = np.stack([tx, ty, np.ones(n)], axis=-1)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def generalized_half_vector(wo, wi, eta):
    """``(m, |etap wi + wo|)``: the generalized half vector ``normalize(etap wi + wo)`` oriented to
    ``m_z >= 0``, with ``etap`` 1 for a reflection pair, ``eta`` when wo is outside (z > 0) and wi
    inside, ``1 / eta`` the other way round (a zero vector stays zero)."""
    wo, wi = f64(wo), f64(wi)
    co, ci = wo[..., 2], wi[..., 2]
    etap = np.where(co * ci > 0, 1.0, np.where(co > 0, eta, 1 / eta))
    m = etap[..., None] * wi + wo
    return flip_up(normalize(m)), np.linalg.norm(m, axis=-1)
