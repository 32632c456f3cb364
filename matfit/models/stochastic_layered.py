"""StochasticLayered: the accuracy reference for coated stacks, by a position-free random walk."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

from .._math import COS_EPS, refract, up_like
from ..errors import ParameterError
from ..fresnel import fresnel_dielectric
from ._base import AbstractBSDF
from ._coat import coat_reflection, is_smooth
from ._pairs import valid_reflection
from ._params import as_channels, as_param, check_directions, check_range
from .rough_dielectric import RoughDielectric
from .smooth_dielectric import SmoothDielectric

__all__ = ["StochasticLayered"]


class StochasticLayered(AbstractBSDF):
    r"""Monte Carlo reference for a coat over a base: an unbiased ``eval`` estimate.

    The layer between a dielectric coat (:class:`SmoothDielectric` or :class:`RoughDielectric`)
    and a base model is a non-scattering medium of thickness :math:`d` with absorption
    :math:`\sigma_a` per channel. After Guo, Hašan and Zhao (2018), transport in the layer is a
    random walk over directions only (the slab is laterally infinite and homogeneous):

    1. the coat's reflection lobe at (wo, wi) is added exactly (zero for a smooth coat's delta);
    2. a path enters through the coat by sampling it at ``wo`` (weight :math:`f|\cos|/p`);
    3. each crossing of the layer attenuates the throughput by :math:`e^{-\sigma_a d/|\cos\theta|}`;
    4. at the base it is connected to the light: for a smooth coat deterministically through the
       refracted light direction (:math:`(1 - F(\mu_i))\,f_{base}(\omega', \omega_i')\,\mu_i`),
       for a rough coat by two strategies combined by multiple importance sampling (balance
       heuristic): the coat's BTDF :math:`f_{coat}(-\omega_b, \omega_i)\mu_i` at the
       base-sampled direction :math:`\omega_b`, and the coat sampled from the light side,
       :math:`\omega = -\omega_l`, with :math:`f_{coat}(\omega_l, \omega_i) = \eta^2
       f_{coat}(\omega_i, \omega_l)` (generalized reciprocity);
    5. the walk continues by sampling the base and the coat from inside, up to ``max_depth``
       base bounces; paths that leave through the coat end.

    The estimate is unbiased up to the truncation at ``max_depth`` (each extra bounce is damped
    by the base albedo times the coat's internal reflectance: the bias falls geometrically); its
    standard error falls as :math:`1/\sqrt{n}` with ``n_samples``. ``eval`` and
    ``eval_with_error`` take an optional ``key`` (default ``PRNGKey(0)``: a deterministic
    estimate). There is no closed-form pdf: ``pdf`` and ``sample`` raise
    ``NotImplementedError`` (sample with :class:`Layered` or :class:`Plastic`); ``albedo`` is
    the energy of the walks' paths that leave the layer.

    Parameters
    ----------
    coat : SmoothDielectric or RoughDielectric; differentiable (its array leaves)
        The coat, seen from outside.
    base : AbstractBSDF; no Dirac lobe; differentiable (its array leaves)
        The model under the coat, evaluated and sampled inside the layer.
    thickness : array_like, scalar or (...), default 0.0; >= 0; differentiable
        Layer thickness d, in the units of ``1 / sigma_a``.
    sigma_a : array_like, scalar or (..., C), default 0.0; >= 0; differentiable
        Absorption coefficient of the layer per colour channel.
    n_samples : int, default 1024; >= 1; static, not differentiable
        Random walks per evaluation; the standard error falls as ``1 / sqrt(n_samples)``.
    max_depth : int, default 16; >= 1; static, not differentiable
        Base bounces per walk (the truncation of the series).

    References
    ----------
    - Y. Guo, M. Hašan, S. Zhao, "Position-Free Monte Carlo Simulation for Arbitrary Layered
      BSDFs", ACM ToG 37(6), 2018.

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.models import StochasticLayered, SmoothDielectric, Lambert
    >>> ref = StochasticLayered(SmoothDielectric(1.5), Lambert(1.0), n_samples=4096, max_depth=32)
    >>> e = ref.albedo(jnp.array([0.0, 0.0, 1.0]))  # a white base under a lossless coat
    >>> bool(abs(float(e[0]) - 1.0) < 0.02)
    True
    """

    coat: AbstractBSDF
    base: AbstractBSDF
    thickness: jnp.ndarray
    sigma_a: jnp.ndarray = eqx.field(converter=as_channels)
    n_samples: int = eqx.field(static=True)
    max_depth: int = eqx.field(static=True)

    def __init__(self, coat, base, thickness=0.0, sigma_a=0.0, n_samples=1024, max_depth=16):
        if not isinstance(coat, (SmoothDielectric, RoughDielectric)):
            raise ParameterError(f"StochasticLayered: coat must be a SmoothDielectric or RoughDielectric, got {type(coat).__name__}")
        if not isinstance(base, AbstractBSDF) or base.has_delta_lobe:
            raise ParameterError(f"StochasticLayered: base must be a matfit model without Dirac lobes, got {type(base).__name__}")
        check_range("StochasticLayered", "thickness", thickness, 0.0)
        check_range("StochasticLayered", "sigma_a", sigma_a, 0.0)
        if int(n_samples) < 1 or int(max_depth) < 1:
            raise ParameterError(f"StochasticLayered: n_samples and max_depth must be >= 1, got {n_samples}, {max_depth}")
        self.coat = coat
        self.base = base
        self.thickness = as_param(thickness)
        self.sigma_a = sigma_a
        self.n_samples = int(n_samples)
        self.max_depth = int(max_depth)

    @property
    def channels(self):
        return max(self.base.channels, self.sigma_a.shape[-1])

    @property
    def has_delta_lobe(self):
        return is_smooth(self.coat)

    def _atten(self, w):
        return jnp.exp(-(self.sigma_a * self.thickness) / jnp.maximum(jnp.abs(w[..., 2]), COS_EPS)[..., None])

    def _walk(self, wo, wi, key, energy):
        """Per-walk contributions, shape (n_samples, ..., C): f|cos_i| (eval) or exiting energy."""
        coat, base = self.coat, self.base
        smooth = is_smooth(coat)
        shape = (self.n_samples,) + jnp.broadcast_shapes(wo.shape, wi.shape if wi is not None else wo.shape)[:-1]
        C = self.channels
        wo = jnp.broadcast_to(wo, shape + (3,))
        dtype = wo.dtype
        k0, k_loop = jax.random.split(key)
        total = jnp.zeros(shape + (C,), dtype)
        u = jax.random.uniform(k0, shape + (3,), dtype)
        w_c, wt, pc = coat.sample(wo, u)
        up = w_c[..., 2] > 0
        light_in = conn = mu_i = None
        if energy:  # reflected at the entry: counts as leaving energy
            total = total + jnp.where((up & (pc > 0))[..., None], wt, 0)
        else:
            wi = jnp.broadcast_to(wi, shape + (3,))
            mu_i = jnp.abs(wi[..., 2])
            total = total + (coat_reflection(coat, wo, wi) * mu_i)[..., None]
            if smooth:
                n = up_like(wi)
                t_l, ok_l = refract(wi, n, coat.eta)
                light_in = -t_l
                conn = (1 - fresnel_dielectric(wi[..., 2], coat.eta)) * mu_i
                conn = jnp.where(ok_l & (wi[..., 2] > COS_EPS), conn, 0)[..., None] * self._atten(light_in)
        alive = (pc > 0) & ~up
        beta = jnp.where(alive[..., None], wt, 0) * jnp.ones((C,), dtype)

        def bounce(carry, k):
            total, beta, alive, w_down = carry
            k_b, k_l, k_c = jax.random.split(k, 3)
            beta = beta * self._atten(w_down)
            wo_base = -w_down
            if not energy and smooth:
                total = total + beta * base.eval(wo_base, light_in) * conn
            wi_b, wb, pb = base.sample(wo_base, jax.random.uniform(k_b, shape + (3,), dtype))
            beta_v = beta
            alive = alive & (pb > 0) & (wi_b[..., 2] > COS_EPS)
            beta = jnp.where(alive[..., None], beta * wb * self._atten(wi_b), 0)
            if not energy and not smooth:
                total = total + self._connect_rough(wo_base, wi, mu_i, wi_b, beta, beta_v, k_l, shape, dtype)
            w_c, wc, pcc = coat.sample(-wi_b, jax.random.uniform(k_c, shape + (3,), dtype))
            out = alive & (pcc > 0) & (w_c[..., 2] > 0)
            if energy:
                total = total + jnp.where(out[..., None], beta * wc, 0)
            alive = alive & (pcc > 0) & (w_c[..., 2] < 0)
            beta = jnp.where(alive[..., None], beta * wc, 0)
            return (total, beta, alive, w_c), None

        keys = jax.random.split(k_loop, self.max_depth)
        (total, _, _, _), _ = jax.lax.scan(bounce, (total, beta, alive, w_c), keys)
        return total

    def _connect_rough(self, wo_base, wi, mu_i, wi_b, beta, beta_v, key, shape, dtype):
        """Light connection through a rough coat: base sampling and coat sampling from the light
        side, combined by multiple importance sampling (balance heuristic)."""
        coat, base = self.coat, self.base
        eta2 = coat.eta**2
        # (a) the base-sampled direction, evaluating the coat's BTDF toward the light.
        p_a = base.pdf(wo_base, wi_b)
        p_b = coat.pdf(wi, -wi_b)
        mis_a = jnp.where(p_a > 0, p_a / (p_a + p_b), 0)
        c_a = beta * (coat.eval(-wi_b, wi)[..., 0] * mu_i * mis_a)[..., None]
        # (b) a direction sampled through the coat from the light; by generalized reciprocity
        # f_coat(w_l, wi) = eta^2 f_coat(wi, w_l).
        w_l, W_l, p_l = coat.sample(wi, jax.random.uniform(key, shape + (3,), dtype))
        om = -w_l
        ok_l = (p_l > 0) & (om[..., 2] > COS_EPS)
        p_a2 = base.pdf(wo_base, om)
        mis_b = jnp.where(ok_l, p_l / (p_a2 + p_l), 0)
        c_b = beta_v * base.eval(wo_base, om) * self._atten(om) * (eta2 * mu_i * mis_b)[..., None] * W_l
        return c_a + jnp.where(ok_l[..., None], c_b, 0)

    def _walks(self, owner, wo, wi, key):
        """The walks' ``f cos`` samples ``(n_samples, ..., C)``, the valid-pair mask ``(..., 1)`` and
        ``cos(theta_i)`` (1 where invalid)."""
        check_directions(owner, wo=wo, wi=wi)
        key = jax.random.PRNGKey(0) if key is None else key
        wo = jnp.asarray(wo)
        wi = jnp.asarray(wi)
        ok = valid_reflection(wo, wi)[..., None]
        return self._walk(wo, wi, key, energy=False), ok, jnp.where(ok, wi[..., 2:3], 1)

    def eval(self, wo, wi, key=None):
        """Unbiased estimate of ``f`` from ``n_samples`` walks (0 unless a reflection pair above the surface)."""
        c, ok, mu_i = self._walks("StochasticLayered.eval", wo, wi, key)
        return jnp.where(ok, jnp.mean(c, axis=0) / mu_i, 0)

    def eval_with_error(self, wo, wi, key=None):
        """``(estimate, stderr)``: the estimate of :meth:`eval` and its standard error, ``(..., C)`` each
        (both 0 unless a reflection pair above the surface)."""
        c, ok, mu_i = self._walks("StochasticLayered.eval_with_error", wo, wi, key)
        return (jnp.where(ok, jnp.mean(c, axis=0) / mu_i, 0),
                jnp.where(ok, jnp.std(c, axis=0) / jnp.sqrt(self.n_samples) / mu_i, 0))

    def albedo(self, wo, method="mc", n=None, key=None):
        """Directional albedo by the walk; ``method`` and ``n`` are not read (the count is ``n_samples``)."""
        wo = jnp.asarray(wo)
        key = jax.random.PRNGKey(0) if key is None else key
        e = jnp.mean(self._walk(wo, None, key, energy=True), axis=0)
        return jnp.where((wo[..., 2] > COS_EPS)[..., None], e, 0)

    def pdf(self, wo, wi):
        """Raises ``NotImplementedError``: the walk has no closed-form density."""
        raise NotImplementedError("StochasticLayered has no closed-form pdf; use Layered or Plastic for sampling and MIS")

    def sample(self, wo, u):
        """Raises ``NotImplementedError``: the model is an evaluation reference."""
        raise NotImplementedError("StochasticLayered is an evaluation reference; sample with Layered or Plastic")
