r"""Fast evaluation of a model on many direction pairs: structure of arrays, one kernel per channel,
split over every device.

``model.eval(wo, wi)`` on ``(N, 3)`` arrays is the general path. When the same directions are
evaluated many times (a fit, a benchmark, rendering a table), :func:`soa_pairs` lays them out once
as a structure of arrays (:class:`matfit._math.Vec3`: separate ``x``, ``y``, ``z`` arrays), split
along the batch over every device (:mod:`matfit.parallel`), and :func:`eval_soa` evaluates each
colour channel as its own single-output XLA kernel. On a CPU this is what XLA compiles into one
tight vectorized loop; three outputs of one loop, an interleaved ``(N, 3)`` layout or a
``jnp.stack`` of channels run several times slower (see ``docs/performance.md``).

The kernels are the models' own ``eval`` — the same formula functions (:mod:`matfit.fresnel`,
:mod:`matfit.microfacet`) called on component arrays — applied to the one-channel model of each
channel (:func:`channel_model`). Models whose ``eval`` reads directions only through components
(:data:`SOA_MODELS`, and a :class:`~matfit.models.Blend` of them) take this path; any other model
is evaluated by its ``eval`` on the rebuilt ``(N, 3)`` arrays, still split over every device.

Compilation happens once per model structure (class, static options, parameter shapes) and pair
count: new parameter values, or new directions of the same count, reuse the compiled kernels.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._math import IsoDir, Vec3, dot, normalize, tan_sq, where_up
from .errors import ParameterError
from .fresnel import FresnelAngle, clamp_cos
from .models import Blend, Lambert, Plastic, RoughConductor
from .models._base import AbstractBSDF
from .models._coat import is_smooth
from .parallel import shard_batch

__all__ = ["SoAPairs", "soa_pairs", "eval_soa", "eval_channel", "half_vector", "channel_model", "supports_soa", "SOA_MODELS"]

#: Model classes whose ``eval`` accepts :class:`~matfit._math.Vec3` directions (Plastic: smooth coat only).
SOA_MODELS = (Lambert, RoughConductor, Plastic)


class SoAPairs(eqx.Module):
    """Direction pairs as structures of arrays, padded and split over devices (see :func:`soa_pairs`).

    Attributes
    ----------
    wo, wi : Vec3
        Components of shape ``(n_padded,)`` each, sharded along the batch.
    h : Vec3
        Reflection half vector ``normalize(wo + wi)`` (depends only on the directions).
    cos_d : jax.Array
        ``wo . h``, the cosine that the Fresnel term of a reflection lobe takes, as
        :func:`~matfit.fresnel.clamp_cos` of it (once per pair instead of once per channel and
        parameter value); :meth:`fresnel_angle` gives its :class:`~matfit.fresnel.FresnelAngle`.
    iso : tuple of jax.Array
        What :meth:`isotropic` hands an isotropic lobe, computed once: the pairs' validity
        (:meth:`~matfit.models.RoughConductor.valid_pair`), the cosines of ``wo``, ``wi``, ``h``
        and ``h``'s squared sine ``h_x^2 + h_y^2`` (from its components: ``1 - h_z^2`` would lose
        it to rounding near the normal, where ``D`` divides it by ``alpha^2``), with invalid
        pairs already mapped to the normal.
    n : int
        Number of valid pairs (the first ``n`` entries); static.
    """

    wo: Vec3
    wi: Vec3
    h: Vec3
    cos_d: jax.Array
    iso: tuple
    n: int = eqx.field(static=True)

    @classmethod
    def from_directions(cls, wo: Vec3, wi: Vec3, n: int) -> "SoAPairs":
        """The pairs of component directions ``wo``, ``wi`` (already padded and placed), with
        their direction-only quantities computed once."""
        h, cos_d = half_vector(wo, wi)
        return cls(wo, wi, h, _clamp_cos(cos_d), _iso_terms(wo, wi, h), int(n))

    @property
    def n_padded(self):
        return int(self.wo.x.shape[0])

    def isotropic(self):
        """``(wo, wi, h, ok)``: the directions as :class:`~matfit._math.IsoDir` (what an isotropic
        microfacet lobe reads of them: cosines, and ``h``'s squared sine),
        already mapped to the normal where ``ok`` (the pairs' validity) is False, as the
        ``ok`` argument of :meth:`~matfit.models.RoughConductor.eval_half` expects. Computed
        once per table: a kernel then repeats none of these per-pair guards for every parameter
        value."""
        ok, oz, iz, hz, ht2 = self.iso
        return IsoDir.from_cos(oz), IsoDir.from_cos(iz), IsoDir(hz, ht2), ok

    def fresnel_angle(self):
        """:class:`~matfit.fresnel.FresnelAngle` of :attr:`cos_d`."""
        return FresnelAngle.of_clamped(self.cos_d)


def soa_pairs(wo, wi, dtype=None, devices=None) -> SoAPairs:
    """Lay out direction pairs for :func:`eval_soa`: split into components, pad, shard.

    Parameters
    ----------
    wo, wi : array_like, shape (N, 3)
        Outgoing and incident unit directions (local frame, normal +z). Broadcast against each
        other.
    dtype : dtype, optional
        Floating type of the components (default: that of ``wo``; float32 unless x64 is on).
    devices : sequence of jax devices, optional
        Devices to split the batch over (default: every device of the default backend; see
        :func:`matfit.parallel.use_host_devices` for the CPU cores).

    Examples
    --------
    >>> import numpy as np
    >>> from matfit.fast import soa_pairs
    >>> p = soa_pairs(np.array([[0.0, 0.0, 1.0]]), np.array([[0.6, 0.0, 0.8]]))
    >>> p.n
    1
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


@jax.jit
def half_vector(wo, wi):
    """``(h, cos_d)``: the reflection half vector ``normalize(wo + wi)`` and ``wo . h``, the two
    direction-only quantities :class:`SoAPairs` carries (for :class:`~matfit._math.Vec3` or
    ``(..., 3)`` directions).

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.fast import half_vector
    >>> h, cos_d = half_vector(jnp.array([0.6, 0.0, 0.8]), jnp.array([-0.6, 0.0, 0.8]))
    >>> h.tolist(), round(float(cos_d), 6)
    ([0.0, 0.0, 1.0], 0.8)
    """
    h = normalize(wo + wi)
    return h, dot(wo, h)


_clamp_cos = jax.jit(clamp_cos)


@jax.jit
def _iso_terms(wo, wi, h):
    ok = RoughConductor.valid_pair(wo, wi)
    # wo and wi keep only their cosines (1 where invalid; isotropic() rebuilds their sines,
    # cheaper than reading them for a million pairs); h keeps its exact squared sine
    h = where_up(ok, IsoDir(h.z, tan_sq(h)))
    return ok, jnp.where(ok, wo.z, 1), jnp.where(ok, wi.z, 1), h.z, h.t2


def supports_soa(model) -> bool:
    """True when ``model.eval`` can run on :class:`~matfit._math.Vec3` directions channel by channel."""
    if isinstance(model, Blend):
        return supports_soa(model.a) and supports_soa(model.b)
    if isinstance(model, Plastic):  # a rough coat builds its transmittance table from (N, 3) samples
        return is_smooth(model.coat)
    return isinstance(model, SOA_MODELS)


def channel_model(model: AbstractBSDF, c: int) -> AbstractBSDF:
    """The one-channel model of channel ``c``: every per-channel parameter sliced to ``[..., c:c+1]``.

    Per-channel parameters are the array leaves whose last axis has the model's channel count
    ``C`` (> 1); scalar and batch parameters are kept. Every model's channels are independent in
    ``eval``, so ``channel_model(m, c).eval(wo, wi)[..., 0] == m.eval(wo, wi)[..., c]``.

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.models import Lambert
    >>> from matfit.fast import channel_model
    >>> channel_model(Lambert(jnp.array([0.8, 0.5, 0.2])), 1).reflectance.tolist()
    [0.5]
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
    """Channel ``c`` of ``model.eval`` on SoA pairs, shape ``(n,)``, with the direction-only
    quantities (half vector, Fresnel cosine) taken from ``pairs``. Only for models that
    :func:`supports_soa` accepts; traced alone it is one single-output loop.

    Examples
    --------
    >>> import numpy as np
    >>> from matfit.models import Lambert
    >>> from matfit.fast import soa_pairs, eval_channel
    >>> up = np.array([[0.0, 0.0, 1.0]])
    >>> round(float(eval_channel(Lambert(np.array([0.8, 0.5, 0.2])), soa_pairs(up, up), 1)[0]) * np.pi, 6)
    0.5
    """
    return _eval_pairs(channel_model(model, c), pairs)[..., 0]


def _eval_pairs(m, pairs):
    """``m.eval`` on the pairs, with their direction-only quantities: a rough conductor's lobe
    takes the precomputed half vector, an isotropic one reads only cosines (:meth:`SoAPairs.isotropic`),
    a blend evaluates its parts so."""
    if isinstance(m, Blend):
        return m.mix(_eval_pairs(m.a, pairs), _eval_pairs(m.b, pairs))
    if isinstance(m, RoughConductor):
        if m.alpha_y is None:
            wo, wi, h, ok = pairs.isotropic()
            return m.eval_half(wo, wi, h, pairs.fresnel_angle(), ok=ok)
        return m.eval_half(pairs.wo, pairs.wi, pairs.h, pairs.fresnel_angle())
    return m.eval(pairs.wo, pairs.wi)


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
        Any matfit model. :data:`SOA_MODELS` (and blends of them) run one single-output kernel
        per channel on the component arrays; others run their ``eval`` on the ``(N, 3)`` arrays.
    pairs : SoAPairs
        From :func:`soa_pairs`.
    stack : bool
        False (default): return a tuple of ``C`` arrays of shape ``(N,)`` (no copy). True: one
        ``(N, C)`` array like ``model.eval`` (costs one interleaving copy).

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
