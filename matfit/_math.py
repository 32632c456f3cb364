r"""Small numerical helpers shared by every model, and the direction types of the fast path.

Guarded operations use the "double where" pattern: the argument is replaced by a safe value
*before* the singular operation, so that both the value and the gradient stay finite at the
guarded points (a plain ``where`` after the fact still propagates NaN gradients).

A direction reaches the microfacet distributions in one of three forms: a ``(..., 3)`` array,
a :class:`Vec3` (its components as three arrays) or an :class:`IsoDir` (its cosine and squared
sine only). :func:`as_direction` is the one place that tells them apart: it hands a distribution
a direction object, and what differs between the forms (the stretched tangential length
:meth:`Vec3.tan_sq`, Smith's visibility indicator :meth:`Vec3.visible`, the azimuthal mix
:meth:`Vec3.along_azimuth`, the guard :meth:`Vec3.where_up`) is a method of each type.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

#: Smallest |cos theta| treated as non-grazing. Below it a direction is on the horizon and every
#: model returns exactly zero.
COS_EPS = 1e-7


def sq(x):
    """The square ``x * x``."""
    return x * x


def dot(a, b):
    """Dot product over the last axis, ``(..., 3), (..., 3) -> (...)``; reads only ``v[..., i]``, so a
    :class:`Vec3` works too."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def safe_sqrt(x):
    """``sqrt(max(x, 0))`` with a finite gradient at and below 0 (gradient 0 there)."""
    pos = x > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, x, 1)), 0)


def safe_atan2(y, x):
    """``atan2(y, x)``, the same values (``atan2(+-0, +-0)`` included), with a finite gradient at
    the origin (0 there, where the angle is undefined)."""
    ok = (x != 0) | (y != 0)
    return jnp.where(ok, jnp.arctan2(jnp.where(ok, y, 0), jnp.where(ok, x, 1)), jax.lax.stop_gradient(jnp.arctan2(y, x)))


def per_pair(x):
    """``x`` itself (bit for bit, gradient 1), ended by a division so that XLA computes it once per
    pair, in a loop of its own.

    A model's value is per-pair work (cosines, D, G, a scalar Fresnel) broadcast against its
    colour channels. XLA's CPU fusion copies cheap operations into the per-channel ``(..., C)``
    loop but not expensive ones (divisions, square roots): the expensive operands of the last
    cheap operation then become separate loops, each written out and read back (a smooth coat's
    two transmittances became eight loops). A quantity that ends in a division is computed whole
    in one loop, written once, and read by the per-channel loop. The divisor is 1 wherever
    ``x == x`` (0 where ``x`` is NaN, which stays NaN).
    """
    x = jnp.asarray(x)
    return x / jnp.where(x == x, 1, 0).astype(x.dtype)


def safe_div(num, den, fill=0.0):
    """``num / den`` where ``den != 0``, else ``fill``; gradients stay finite."""
    ok = den != 0
    return jnp.where(ok, num / jnp.where(ok, den, 1), fill)


def as_float(x):
    """``x`` as a floating JAX array: integer and boolean input becomes the default float type
    (float64 when x64 is on, else float32); floating input keeps its dtype."""
    x = jnp.asarray(x)
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.result_type(float))
    return x


@jax.tree_util.register_pytree_node_class
class Vec3:
    """Directions as a structure of arrays: three arrays ``x, y, z`` of one (broadcastable) shape ``(...)``.

    A stand-in for a ``(..., 3)`` array wherever a formula reads a vector only through its
    components ``v[..., 0]``, ``v[..., 1]``, ``v[..., 2]`` (and ``+``, ``-``, :func:`dot`,
    :func:`normalize`): the microfacet distributions (``D``, ``Lambda``, ``G1``, ``G2``) and the
    models' :meth:`~matfit.models.AbstractBSDF.eval_pairs`. XLA then keeps one array per
    component instead of an interleaved ``(..., 3)`` layout, which it fuses far better on CPUs.
    ``shape`` is that of the equivalent ``(..., 3)`` array, so shape checks work unchanged.

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
        """Shape ``(..., 3)`` of the equivalent array."""
        return tuple(jnp.broadcast_shapes(jnp.shape(self.x), jnp.shape(self.y), jnp.shape(self.z))) + (3,)

    @property
    def dtype(self):
        """Common dtype of the components."""
        return jnp.result_type(self.x, self.y, self.z)

    def tan_sq(self, sx=1.0, sy=1.0):
        """``(v_x s_x)^2 + (v_y s_y)^2``: the tangential part of the stretched squared length that
        every microfacet distribution reads (with the default scales 1: the squared sine)."""
        return sq(self.x * sx) + sq(self.y * sy)

    def visible(self, m):
        r"""Smith's local visibility indicator :math:`\chi^+((v\cdot m)(v\cdot n))` of this
        direction ``v`` for microfacet normals ``m``."""
        return dot(self, m) * self.z > 0

    def along_azimuth(self, a_x, a_y):
        r"""``a_x cos^2 phi + a_y sin^2 phi`` at this direction's azimuth :math:`\phi`: a quantity that
        is ``a_x`` along x and ``a_y`` along y (Blinn-Phong's exponent).

        Within machine epsilon of the normal ``a_x`` is taken (the quotient's derivative
        ``-x^2 / (x^2 + y^2)^2`` would underflow to 0/0 there).
        """
        rxy2 = sq(self.x) + sq(self.y)
        big = rxy2 > jnp.finfo(jnp.result_type(rxy2)).eps ** 2
        c2 = jnp.where(big, sq(self.x) / jnp.where(big, rxy2, 1), 1.0)
        return a_x * c2 + a_y * (1 - c2)

    def where_up(self, ok):
        """This direction where ``ok``, else the normal ``(0, 0, 1)``: the first half of the
        double-where pattern for directions."""
        return Vec3(jnp.where(ok, self.x, 0), jnp.where(ok, self.y, 0), jnp.where(ok, self.z, 1))

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
        """Pytree children ``(x, y, z)``, no static data."""
        return (self.x, self.y, self.z), None

    @classmethod
    def tree_unflatten(cls, aux, children):
        """Rebuild from :meth:`tree_flatten`'s output."""
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
    :math:`v\cdot m = \lVert v + w\rVert / 2 > 0`), the only place
    :meth:`~matfit.models.SoAPairs.isotropic` builds it. A kernel then reads one or two arrays
    per direction instead of three, and computes no dot products (``docs/performance.md``).
    Only ``v[..., 2]`` is defined.

    Parameters
    ----------
    z : array_like
        Cosine of the polar angle.
    t2 : array_like
        Squared sine of the polar angle.

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
        """The direction of cosine ``z`` (a unit vector): ``t2 = 1 - z^2``, clamped at 0.

        Accurate in absolute terms only (for ``z`` near 1 in float32, ``t2`` is off by ~1e-7),
        enough where ``t2`` is scaled by ``alpha^2`` and added to ``z^2`` (``Lambda``, ``G1``),
        not for the half vector of ``D``, whose ``t2`` is divided by ``alpha^2``.
        """
        return cls(z, jnp.maximum(1 - z * z, 0))

    @property
    def shape(self):
        """Shape ``(..., 3)`` of the equivalent direction array."""
        return tuple(jnp.broadcast_shapes(jnp.shape(self.z), jnp.shape(self.t2))) + (3,)

    @property
    def dtype(self):
        """Common dtype of ``z`` and ``t2``."""
        return jnp.result_type(self.z, self.t2)

    def tan_sq(self, sx=1.0, sy=None):
        """``t2 s_x^2``: :meth:`Vec3.tan_sq` of an isotropic scale (``sy`` is not read)."""
        return self.t2 * sq(sx)

    def visible(self, m):
        """:meth:`Vec3.visible` without an azimuth: ``v_z > 0`` (``m``, not read, is this direction's
        reflection half vector with another direction above the surface, so ``v . m > 0``)."""
        return self.z > 0

    def along_azimuth(self, a_x, a_y):
        """``a_x``: an IsoDir belongs to an isotropic distribution, where ``a_x == a_y``."""
        return a_x

    def where_up(self, ok):
        """This direction where ``ok``, else the normal (``z = 1``, ``t2 = 0``)."""
        return IsoDir(jnp.where(ok, self.z, 1), jnp.where(ok, self.t2, 0))

    def __getitem__(self, idx):
        if not (isinstance(idx, tuple) and len(idx) == 2 and idx[0] is Ellipsis and idx[1] in (2, -1)):
            raise TypeError(f"IsoDir only supports the cosine v[..., 2], got {idx!r}")
        return self.z

    def tree_flatten(self):
        """Pytree children ``(z, t2)``, no static data."""
        return (self.z, self.t2), None

    @classmethod
    def tree_unflatten(cls, aux, children):
        """Rebuild from :meth:`tree_flatten`'s output."""
        return cls(*children)


def as_direction(v):
    """The direction object of ``v``: a :class:`Vec3` or :class:`IsoDir` as it is, a ``(..., 3)``
    array as the :class:`Vec3` of its components (views ``v[..., i]``, no conversion, so that the
    arithmetic on them is that on the array).

    The one place that tells the direction forms apart: the distributions call the methods of
    what it returns and never test a type.
    """
    if isinstance(v, (Vec3, IsoDir)):
        return v
    return Vec3(v[..., 0], v[..., 1], v[..., 2])


def normalize(v):
    """Unit vector along ``v`` (an array or a :class:`Vec3`, returned in its form); vectors shorter
    than the dtype's machine epsilon (a half vector of nearly opposite unit directions) map to
    ``(0, 0, 1)`` with finite gradients (the derivative of ``v/|v|`` grows as ``1/|v|``)."""
    n2 = dot(v, v)
    ok = n2 > jnp.finfo(jnp.result_type(n2)).eps ** 2
    inv = jnp.where(ok, jax.lax.rsqrt(jnp.where(ok, n2, 1)), 0)
    d = as_direction(v)
    if d is v:  # a direction object: scaled component by component
        return Vec3(d.x * inv, d.y * inv, d.z * inv).where_up(ok)
    # an array keeps its interleaved layout: one product and one select over (..., 3)
    u = v * inv[..., None]
    return jnp.where(ok[..., None], u, up_like(u))


def up_like(v):
    """The normal ``(0, 0, 1)`` in the shape and dtype of the direction array ``v``."""
    return jnp.zeros_like(v).at[..., 2].set(1)


def turn_about_z(w, c, s):
    """``w`` (..., 3) turned about +z by the angle of cosine ``c`` and sine ``s`` (batch shapes broadcast)."""
    x, y = w[..., 0], w[..., 1]
    return jnp.stack(jnp.broadcast_arrays(c * x - s * y, s * x + c * y, w[..., 2]), axis=-1)


def mirror(w):
    """``(-w_x, -w_y, w_z)``: ``w`` reflected about the normal ``(0, 0, 1)``, a perfect mirror's direction."""
    return w * jnp.array([-1, -1, 1], w.dtype)


def reflect(wo, m):
    """``2 (wo.m) m - wo``: ``wo`` mirrored about the unit normal ``m``."""
    return 2 * dot(wo, m)[..., None] * m - wo


def refract(wi, n, eta):
    """Refract the unit direction ``wi`` (pointing away from the surface) through the unit normal
    ``n``; returns ``(wt, ok)``.

    ``n`` is flipped to ``wi``'s side first; ``eta`` is the index of the side the refracted ray
    enters over that of ``wi``, after that flip (pbrt-v4 convention). ``ok`` is False under total
    internal reflection, where ``wt`` is an arbitrary unit vector.
    """
    cos_i = dot(n, wi)
    flip = cos_i < 0
    eta = jnp.where(flip, 1 / eta, eta)
    cos_i = jnp.abs(cos_i)
    n = jnp.where(flip[..., None], -n, n)
    cos2_t = refracted_cos2(cos_i, eta, 1 / eta)
    ok = cos2_t > 0
    cos_t = safe_sqrt(cos2_t)
    # divisions by eta, correctly rounded: the sampled direction and the pdf recomputed from it
    # agree to float32 rounding even near eta = 1, where the transmission Jacobian amplifies them
    wt = -wi / eta[..., None] + (cos_i / eta - cos_t)[..., None] * n
    return wt, ok


def refracted_cos2(cos_i, eta, inv):
    """``cos^2 theta_t = (eta^2 - 1 + cos_i^2) / eta^2``, Snell's law for the transmitted
    cosine, with ``inv = 1 / eta`` given; negative under total internal reflection.

    Written so (not ``1 - (1 - cos_i^2) / eta^2``) it keeps its digits near grazing incidence and
    at eta ~ 1 (float32: ``1 - c^2`` rounds to 1 at c = 1e-4); for a scalar index it is a product
    per direction, not a division (XLA's CPU backend repeats a direction's divisions in every loop
    that reads it).
    """
    return (eta * eta - 1 + cos_i * cos_i) * (inv * inv)


def refract_into(w, eta):
    """A direction above the surface (``w_z > 0``) refracted through the flat interface into the
    medium below, of relative index ``eta`` (below over above), and mirrored back up: the direction
    inside a layer under a smooth coat, ``(w_x / eta, w_y / eta, cos theta_t)``. Returns
    ``(wt, ok)``, ``ok`` False under total internal reflection (``eta < 1``).

    :func:`refract` with the normal ``(0, 0, 1)``, written in components so that it takes a
    :class:`Vec3` as well as a ``(..., 3)`` array (and returns the same kind); ``eta`` a scalar
    or of the batch shape.
    """
    v = w if isinstance(w, Vec3) else Vec3.from_array(w)
    eta = jnp.asarray(eta)
    inv = 1 / eta
    cos2_t = refracted_cos2(v.z, eta, inv)
    t = Vec3(v.x * inv, v.y * inv, safe_sqrt(cos2_t))
    return (t if isinstance(w, Vec3) else t.to_array()), cos2_t > 0


def flip_up(v):
    """``v`` mirrored through the origin where it points below the surface (``z < 0``)."""
    return jnp.where((v[..., 2] < 0)[..., None], -v, v)


def uniform_to_disk(u1, u2):
    """Concentric map of the unit square (``u1, u2`` in [0, 1)) to a point ``(x, y)`` of the unit
    disk, uniform in area for uniform input (P. Shirley, K. Chiu, "A Low Distortion Map Between
    Disk and Square", JGT 2(3), 1997)."""
    a = 2 * u1 - 1
    b = 2 * u2 - 1
    big_a = jnp.abs(a) > jnp.abs(b)
    r = jnp.where(big_a, a, b)
    phi = jnp.where(big_a, (jnp.pi / 4) * safe_div(b, a), jnp.pi / 2 - (jnp.pi / 4) * safe_div(a, b))
    return r * jnp.cos(phi), r * jnp.sin(phi)


def cosine_hemisphere(u1, u2):
    """Cosine-weighted unit direction ``(..., 3)`` on the upper hemisphere from uniform ``u1, u2``
    (Malley's method: a disk point lifted to ``z >= 0``); pdf = cos(theta)/pi."""
    x, y = uniform_to_disk(u1, u2)
    z = safe_sqrt(1 - x * x - y * y)
    return jnp.stack([x, y, z], axis=-1)
