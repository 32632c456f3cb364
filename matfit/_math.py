"""Small numerical helpers shared by every model.

Guarded operations use the "double where" pattern: the argument is replaced by a safe value
*before* the singular operation, so that both the value and the gradient stay finite at the
guarded points (a plain ``where`` after the fact still propagates NaN gradients).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

#: Smallest |cos theta| treated as non-grazing. Below it a direction is on the horizon and every
#: model returns exactly zero.
COS_EPS = 1e-7


def dot(a, b):
    """Dot product over the last axis: ``(..., 3), (..., 3) -> (...)``."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def safe_sqrt(x):
    """``sqrt(max(x, 0))`` with a finite gradient at and below 0 (gradient 0 there)."""
    pos = x > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, x, 1)), 0)


def safe_div(num, den, fill=0.0):
    """``num / den`` where ``den != 0``, else ``fill``; gradients stay finite."""
    ok = den != 0
    return jnp.where(ok, num / jnp.where(ok, den, 1), fill)


def normalize(v):
    """Unit vector along ``v`` (..., 3); the zero vector maps to ``(0, 0, 1)`` with finite grads."""
    n2 = dot(v, v)
    ok = n2 > 0
    inv = jnp.where(ok, jax.lax.rsqrt(jnp.where(ok, n2, 1)), 0)
    z = jnp.zeros_like(v).at[..., 2].set(1)
    return jnp.where(ok[..., None], v * inv[..., None], z)


def reflect(wo, m):
    """Mirror ``wo`` about the unit normal ``m``: ``2 (wo.m) m - wo``."""
    return 2 * dot(wo, m)[..., None] * m - wo


def refract(wi, n, eta):
    """Refract ``wi`` (pointing away from the surface) through the normal ``n``.

    ``eta`` is the relative index of the side the refracted ray enters over the side of ``wi``,
    after flipping ``n`` to ``wi``'s side (pbrt-v4 convention). Returns ``(wt, ok)`` with ``ok``
    false under total internal reflection (``wt`` is then an arbitrary unit vector).
    """
    cos_i = dot(n, wi)
    flip = cos_i < 0
    eta = jnp.where(flip, 1 / eta, eta)
    cos_i = jnp.abs(cos_i)
    n = jnp.where(flip[..., None], -n, n)
    # cos^2 theta_t = (eta^2 - 1 + cos_i^2) / eta^2: no cancellation near grazing or at eta ~ 1.
    cos2_t = (eta * eta - 1 + cos_i * cos_i) / (eta * eta)
    ok = cos2_t > 0
    cos_t = safe_sqrt(cos2_t)
    wt = -wi / eta[..., None] + (cos_i / eta - cos_t)[..., None] * n
    return wt, ok


def flip_up(v):
    """``v`` mirrored through the origin when it points below the surface (z < 0)."""
    return jnp.where((v[..., 2] < 0)[..., None], -v, v)


def sq(x):
    return x * x


def as_float(x, like=None):
    """``x`` as a floating JAX array (dtype of ``like`` when given)."""
    x = jnp.asarray(x)
    if like is not None:
        return x.astype(jnp.result_type(like))
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.result_type(float))
    return x


def uniform_to_disk(u1, u2):
    """Concentric (Shirley-Chiu) map of the unit square to the unit disk."""
    a = 2 * u1 - 1
    b = 2 * u2 - 1
    big_a = jnp.abs(a) > jnp.abs(b)
    r = jnp.where(big_a, a, b)
    phi = jnp.where(big_a, (jnp.pi / 4) * safe_div(b, a), jnp.pi / 2 - (jnp.pi / 4) * safe_div(a, b))
    return r * jnp.cos(phi), r * jnp.sin(phi)


def cosine_hemisphere(u1, u2):
    """Cosine-weighted direction on the upper hemisphere, pdf = cos(theta)/pi."""
    x, y = uniform_to_disk(u1, u2)
    z = safe_sqrt(1 - x * x - y * y)
    return jnp.stack([x, y, z], axis=-1)
