"""Rusinkiewicz half/difference angles (as used by MERL and ALTA), in numpy float64.

Convention (MERL's BRDFRead.cpp): the half vector ``h = normalize(wi + wo)`` has angles
``(theta_h, phi_h)``; the difference vector is ``wi`` rotated by ``-phi_h`` about the normal (z) and then
by ``-theta_h`` about the binormal (y), with angles ``(theta_d, phi_d)``. ``wi`` is the light direction.
"""
from __future__ import annotations

import numpy as np


def _rot_z(v, a):
    c, s = np.cos(a), np.sin(a)
    return np.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1], v[..., 2]], -1)


def _rot_y(v, a):
    c, s = np.cos(a), np.sin(a)
    return np.stack([c * v[..., 0] + s * v[..., 2], v[..., 1], -s * v[..., 0] + c * v[..., 2]], -1)


def dirs_to_half_diff(wo, wi):
    """Rusinkiewicz's (1998) half/difference angles of direction pairs; phi in (-pi, pi].

    Parameters
    ----------
    wo, wi : array_like, (..., 3)
        Unit directions to the viewer and to the light.

    Returns
    -------
    theta_h, phi_h, theta_d, phi_d : numpy.ndarray, (...,) float64
        Radians.

    Examples
    --------
    >>> import numpy as np
    >>> from matfit.io import dirs_to_half_diff
    >>> th, ph, td, pd = dirs_to_half_diff([0.0, 0.6, 0.8], [0.0, -0.6, 0.8])  # mirror pair: h = n
    >>> round(float(th), 6), round(float(np.cos(td)), 6)
    (0.0, 0.8)
    """
    wo = np.asarray(wo, dtype=np.float64)
    wi = np.asarray(wi, dtype=np.float64)
    h = wi + wo
    n = np.linalg.norm(h, axis=-1, keepdims=True)
    h = h / np.where(n > 0, n, 1.0)
    theta_h = np.arccos(np.clip(h[..., 2], -1.0, 1.0))
    phi_h = np.arctan2(h[..., 1], h[..., 0])
    d = _rot_y(_rot_z(wi, -phi_h), -theta_h)
    theta_d = np.arccos(np.clip(d[..., 2], -1.0, 1.0))
    phi_d = np.arctan2(d[..., 1], d[..., 0])
    return theta_h, phi_h, theta_d, phi_d


def half_diff_to_dirs(theta_h, theta_d, phi_d, phi_h=0.0):
    """The inverse of :func:`dirs_to_half_diff`: unit ``(wo, wi)`` for half/difference angles.

    Parameters
    ----------
    theta_h, theta_d, phi_d : array_like
        Radians, broadcast together.
    phi_h : array_like, default 0
        Azimuth of the half vector.

    Returns
    -------
    wo, wi : numpy.ndarray, (..., 3) float64
    """
    theta_h, theta_d, phi_d, phi_h = np.broadcast_arrays(*(np.asarray(x, dtype=np.float64)
                                                           for x in (theta_h, theta_d, phi_d, phi_h)))
    d = np.stack([np.sin(theta_d) * np.cos(phi_d), np.sin(theta_d) * np.sin(phi_d), np.cos(theta_d)], -1)
    wi = _rot_z(_rot_y(d, theta_h), phi_h)
    h = np.stack([np.sin(theta_h) * np.cos(phi_h), np.sin(theta_h) * np.sin(phi_h), np.cos(theta_h)], -1)
    wo = 2.0 * np.sum(wi * h, -1, keepdims=True) * h - wi
    # renormalize against rounding so the Table's unit-vector check never trips
    wi = wi / np.linalg.norm(wi, axis=-1, keepdims=True)
    wo = wo / np.linalg.norm(wo, axis=-1, keepdims=True)
    return wo, wi
