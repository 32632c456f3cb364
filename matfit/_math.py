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
    """Unit vector along ``v`` (..., 3) or :class:`Vec3`; vectors shorter than the dtype's
    machine epsilon (a half vector of nearly opposite unit directions) map to ``(0, 0, 1)`` with
    finite grads (the derivative of ``v/|v|`` grows as ``1/|v|``)."""
    n2 = dot(v, v)
    ok = n2 > jnp.finfo(jnp.result_type(n2)).eps ** 2
    inv = jnp.where(ok, jax.lax.rsqrt(jnp.where(ok, n2, 1)), 0)
    if isinstance(v, Vec3):
        return where_up(ok, Vec3(v.x * inv, v.y * inv, v.z * inv))
    return where_up(ok, v * inv[..., None])


def where_up(ok, v):
    """``v`` where ``ok``, else the normal ``(0, 0, 1)``: the first half of the double-where
    pattern for directions, for ``(..., 3)`` arrays, :class:`Vec3` and :class:`IsoDir` alike."""
    if isinstance(v, Vec3):
        return Vec3(jnp.where(ok, v.x, 0), jnp.where(ok, v.y, 0), jnp.where(ok, v.z, 1))
    if isinstance(v, IsoDir):
        return IsoDir(jnp.where(ok, v.z, 1), jnp.where(ok, v.t2, 0))
    z = jnp.zeros_like(v).at[..., 2].set(1)
    return jnp.where(ok[..., None], v, z)


@jax.tree_util.register_pytree_node_class
class Vec3:
    """Directions as a structure of arrays: three arrays ``x, y, z`` of one shape ``(...)``.

    A stand-in for a ``(..., 3)`` array wherever a formula reads a vector only through its
    components ``v[..., 0]``, ``v[..., 1]``, ``v[..., 2]`` (and ``+``, ``-``, :func:`dot`,
    :func:`normalize`): the microfacet distributions (``D``, ``Lambda``, ``G1``, ``G2``) and the
    models' ``eval`` that are listed in :mod:`matfit.fast`. XLA then keeps one array per component
    instead of an interleaved ``(..., 3)`` layout, which it fuses far better on CPUs. ``shape``
    is that of the equivalent ``(..., 3)`` array, so shape checks work unchanged.

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit._math import Vec3, dot
    >>> v = Vec3.from_array(jnp.array([[0.0, 0.6, 0.8]]))
    >>> v.shape, float(dot(v, v)[0])
    ((1, 3), 1.0)
    """

    __slots__ = ("x", "y", "z")

    def __init__(self, x, y, z):
        self.x, self.y, self.z = x, y, z

    @classmethod
    def from_array(cls, v):
        """Split a ``(..., 3)`` array into its components."""
        v = jnp.asarray(v)
        return cls(v[..., 0], v[..., 1], v[..., 2])

    def to_array(self):
        """The equivalent ``(..., 3)`` array (a copy into the interleaved layout)."""
        return jnp.stack([self.x, self.y, self.z], axis=-1)

    @property
    def shape(self):
        return tuple(jnp.broadcast_shapes(jnp.shape(self.x), jnp.shape(self.y), jnp.shape(self.z))) + (3,)

    @property
    def dtype(self):
        return jnp.result_type(self.x, self.y, self.z)

    def __getitem__(self, idx):
        if not (isinstance(idx, tuple) and len(idx) == 2 and idx[0] is Ellipsis and isinstance(idx[1], int)):
            raise TypeError(f"Vec3 only supports component access v[..., i], got {idx!r}")
        return (self.x, self.y, self.z)[idx[1]]

    def __add__(self, o):
        return Vec3(self.x + o.x, self.y + o.y, self.z + o.z)

    def __sub__(self, o):
        return Vec3(self.x - o.x, self.y - o.y, self.z - o.z)

    def __neg__(self):
        return Vec3(-self.x, -self.y, -self.z)

    def tree_flatten(self):
        return (self.x, self.y, self.z), None

    @classmethod
    def tree_unflatten(cls, aux, children):
        return cls(*children)


@jax.tree_util.register_pytree_node_class
class IsoDir:
    r"""A direction known only by its polar angle: ``z`` = :math:`\cos\theta` and ``t2`` =
    :math:`\sin^2\theta = x^2 + y^2`, without an azimuth.

    What an isotropic microfacet distribution reads of a direction (``D``, ``Lambda``, ``G1``,
    ``G2`` of :mod:`matfit.microfacet`, which accept it in place of a ``(..., 3)`` array; they use
    ``alpha_x`` and so must be isotropic). It carries no azimuth, so Smith's visibility indicator
    :math:`\chi^+((v\cdot m)(v\cdot n))` becomes :math:`v_z > 0`: exact where ``m`` is the
    reflection half vector of ``v`` and another direction above the surface (there
    :math:`v\cdot m = \lVert v + w\rVert / 2 > 0`), the only place :mod:`matfit.fast` builds
    it. A kernel then reads one or two arrays per direction instead of three, and computes no
    dot products (``docs/performance.md``). Only ``v[..., 2]`` is defined.

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit._math import IsoDir
    >>> from matfit.microfacet import GGX
    >>> m = jnp.array([0.6, 0.0, 0.8])
    >>> bool(jnp.isclose(GGX(0.3).D(IsoDir(m[2], 0.36)), GGX(0.3).D(m)))
    True
    """

    __slots__ = ("z", "t2")

    def __init__(self, z, t2):
        self.z, self.t2 = z, t2

    @classmethod
    def from_cos(cls, z):
        """The direction of cosine ``z`` (a unit vector): ``t2 = 1 - z^2``, clamped at 0. Accurate
        in absolute terms only (for ``z`` near 1 in float32, ``t2`` is off by ~1e-7), enough
        where ``t2`` is scaled by ``alpha^2`` and added to ``z^2`` (``Lambda``, ``G1``), not for
        the half vector of ``D``, whose ``t2`` is divided by ``alpha^2``."""
        return cls(z, jnp.maximum(1 - z * z, 0))

    @property
    def shape(self):
        return tuple(jnp.broadcast_shapes(jnp.shape(self.z), jnp.shape(self.t2))) + (3,)

    @property
    def dtype(self):
        return jnp.result_type(self.z, self.t2)

    def __getitem__(self, idx):
        if not (isinstance(idx, tuple) and len(idx) == 2 and idx[0] is Ellipsis and idx[1] in (2, -1)):
            raise TypeError(f"IsoDir only supports the cosine v[..., 2], got {idx!r}")
        return self.z

    def tree_flatten(self):
        return (self.z, self.t2), None

    @classmethod
    def tree_unflatten(cls, aux, children):
        return cls(*children)


def tan_sq(v, sx=1.0, sy=1.0):
    """``(v_x s_x)^2 + (v_y s_y)^2`` of a ``(..., 3)`` array, :class:`Vec3` or :class:`IsoDir`
    (there ``t2 s_x^2``: isotropic scales only): the tangential part of the stretched squared
    length that every microfacet distribution reads."""
    if isinstance(v, IsoDir):
        return v.t2 * sq(sx)
    return sq(v[..., 0] * sx) + sq(v[..., 1] * sy)


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
