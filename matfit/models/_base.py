"""The abstract BSDF: the interface every model implements, and the directional albedo."""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._math import COS_EPS, safe_div
from ..errors import ParameterError
from ._pairs import SoAPairs
from ._params import channel_count, check_complex_index, check_directions


class AbstractBSDF(eqx.Module):
    r"""A BSDF in the local shading frame (normal +z): the contract every model implements.

    Directions ``wo`` (to the viewer) and ``wi`` (to the light) are unit vectors ``(..., 3)``
    pointing away from the surface; batch shapes broadcast. ``C`` is :attr:`channels`.

    - ``eval(wo, wi)``: :math:`f(\omega_o, \omega_i)` in 1/sr without the cosine, ``(..., C)``
      (the radiance BTDF for a transmitted pair); 0 outside the model's domain (``wi`` below the
      horizon for a reflection-only model, directions within ``COS_EPS`` of grazing).
    - ``pdf(wo, wi)``: the solid-angle density of ``sample``, ``(...)``, in 1/sr. A Dirac lobe
      has none: a delta model's pdf is 0 everywhere, a model with a delta lobe gives its other
      lobes' density.
    - ``sample(wo, u)``: ``(wi, weight, pdf)`` for uniform ``u`` in [0, 1) of shape ``(..., 3)``
      (``u[..., 0]`` picks a lobe, ``u[..., 1:3]`` the direction), with
      :math:`\mathrm{weight} = f\,|\cos\theta_i| / p` (``(..., C)``) and ``pdf`` the density
      (the discrete probability for a Dirac lobe). An invalid sample has ``weight == 0`` and
      ``pdf == 0``, its ``wi`` finite but arbitrary.
    - ``eval_pairs(pairs)``: ``eval`` on prepared :class:`~matfit.models.SoAPairs`, the
      direction-only quantities read from them. The default rebuilds the ``(..., 3)`` arrays;
      models with :attr:`pair_kernels` override it, and their ``eval`` is
      ``eval_pairs(SoAPairs.of(wo, wi))``.
    - ``energy_factor(wo, wi)``: turns :math:`f\,|\cos\theta_i|` into transported energy,
      :math:`\eta_p^2` for a transmitted pair of a radiance BTDF, 1 otherwise; ``(...)``.
    - ``delta_albedo(wo)``: the energy carried by the Dirac lobes, ``(..., C)``.
    - ``albedo(wo)``: the directional albedo, reflected plus transmitted,

      .. math:: E(\omega_o) = \int_{S^2} f(\omega_o, \omega_i)\,|\cos\theta_i|\,
                \eta_p^2\,d\omega_i + E_\delta(\omega_o)

    A model is an equinox Module: its array fields are the differentiable parameters (pytree
    leaves), its string and integer options static fields. Each concrete model documents its
    constructor arguments in its own ``Parameters`` section (the tables of ``docs/models.md``
    are generated from them).

    Attributes
    ----------
    is_delta : bool
        True for models made only of Dirac lobes (``eval`` and ``pdf`` zero everywhere); a class
        attribute.
    pair_kernels : bool
        True for models whose ``eval_pairs`` evaluates prepared pairs channel by channel on
        component arrays (the kernels of :mod:`matfit.fast`); others rebuild ``(N, 3)`` arrays.
        A class attribute (a property of composite models).

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.models import Lambert
    >>> m, up = Lambert(0.5), jnp.array([0.0, 0.0, 1.0])
    >>> wi, weight, pdf = m.sample(up, jnp.array([0.0, 0.3, 0.7]))
    >>> round(float(weight[0]), 6), round(float(m.albedo(up)[0]), 6)  # cosine sampling: weight = albedo
    (0.5, 0.5)
    """

    is_delta: ClassVar[bool] = False

    @property
    def transmits(self) -> bool:
        """True when the model transmits light (``eval`` can be non-zero for ``wi`` below the surface)."""
        return False

    @property
    def has_delta_lobe(self) -> bool:
        """True when some of the model's energy is in a Dirac lobe (sampled, never evaluated)."""
        return self.is_delta

    @abc.abstractmethod
    def eval(self, wo, wi):
        r"""The BSDF value :math:`f(\omega_o, \omega_i)` in 1/sr, without the cosine factor."""

    pair_kernels: ClassVar[bool] = False

    def eval_pairs(self, pairs):
        """:meth:`eval` on prepared direction pairs (default: rebuilds the arrays and calls it)."""
        return self.eval(pairs.wo.to_array(), pairs.wi.to_array())

    @abc.abstractmethod
    def pdf(self, wo, wi):
        """Solid-angle density of :meth:`sample` choosing ``wi`` given ``wo``."""

    @abc.abstractmethod
    def sample(self, wo, u):
        """Importance-sample an incident direction for ``wo``: ``(wi, weight, pdf)``."""

    @property
    @abc.abstractmethod
    def channels(self) -> int:
        """Number of colour channels ``C`` of :meth:`eval`."""

    def energy_factor(self, wo, wi):
        r"""Factor turning :math:`f\,|\cos\theta_i|` into transported energy (:math:`\eta_p^2` or 1)."""
        return jnp.ones(jnp.broadcast_shapes(wo.shape, wi.shape)[:-1], wo.dtype)

    def delta_albedo(self, wo):
        """Energy carried by the model's Dirac lobes for ``wo`` (zero for a model without any)."""
        return jnp.zeros(wo.shape[:-1] + (self.channels,), wo.dtype)

    def _weighted(self, wo, wi, above=False):
        """``(wi, weight, pdf)`` of sampled directions ``wi``: ``weight = f |cos theta_i| / pdf``;
        both 0 unless ``pdf > 0`` (and, with ``above``, both directions above ``COS_EPS``)."""
        pdf = self.pdf(wo, wi)
        ok = pdf > 0
        if above:
            ok = ok & (wi[..., 2] > COS_EPS) & (wo[..., 2] > COS_EPS)
        weight = safe_div(self.eval(wo, wi) * jnp.abs(wi[..., 2])[..., None], pdf[..., None])
        return wi, jnp.where(ok[..., None], weight, 0), jnp.where(ok, pdf, 0)

    def albedo(self, wo, method="quadrature", n=None, key=None):
        r"""Directional albedo :math:`E(\omega_o)` (class docstring), ``(..., C)``.

        ``method="quadrature"``: Gauss-Legendre in cos(theta) on each hemisphere times a uniform
        rule in phi, order ``n`` (default 96), accurate for lobes wider than ~pi/n.
        ``method="mc"``: the mean of ``n`` importance-sampled weights (default 2**16, ``key``
        default ``PRNGKey(0)``), unbiased for every model, delta models included.
        """
        owner = f"{type(self).__name__}.albedo"
        check_directions(owner, wo=wo)
        wo = jnp.asarray(wo)
        if method not in ("quadrature", "mc"):
            raise ParameterError(f"{owner}: method must be 'quadrature' or 'mc', got {method!r}")
        if n is not None and not (isinstance(n, (int, np.integer)) and not isinstance(n, bool) and n > 0):
            raise ParameterError(f"{owner}: n must be a positive integer, got {n!r}")
        if method == "mc":
            n = 2**16 if n is None else int(n)
            key = jax.random.PRNGKey(0) if key is None else key
            u = jax.random.uniform(key, (n,) + wo.shape[:-1] + (3,), dtype=wo.dtype)
            wob = jnp.broadcast_to(wo, u.shape)
            wi, weight, pdf = self.sample(wob, u)
            e = weight * self.energy_factor(wob, wi)[..., None]
            return jnp.mean(e, axis=0)
        n = 96 if n is None else int(n)
        x, w = np.polynomial.legendre.leggauss(n)
        mu = np.concatenate([-0.5 * (x + 1), 0.5 * (x + 1)])
        wmu = np.concatenate([0.5 * w, 0.5 * w])
        phi = (np.arange(2 * n) + 0.5) * (np.pi / n)
        s = np.sqrt(1 - mu**2)
        wi = np.stack(np.broadcast_arrays(s[:, None] * np.cos(phi), s[:, None] * np.sin(phi), mu[:, None]), -1)
        wi = jnp.asarray(wi.reshape(-1, 3), wo.dtype)
        wts = jnp.asarray(np.repeat(wmu * np.abs(mu), 2 * n) * (np.pi / n), wo.dtype)

        def one(w1):
            wob = jnp.broadcast_to(w1, wi.shape)
            f = self.eval(wob, wi) * self.energy_factor(wob, wi)[..., None]
            return jnp.sum(f * wts[:, None], axis=0)

        flat = wo.reshape(-1, 3)
        e = jax.lax.map(one, flat).reshape(wo.shape[:-1] + (self.channels,))
        return e + self.delta_albedo(wo)


class AbstractDeltaBSDF(AbstractBSDF):
    """A model made only of Dirac lobes (:class:`~matfit.models.SmoothConductor`,
    :class:`~matfit.models.SmoothDielectric`): ``eval`` and ``pdf`` are zero everywhere (the
    zeros take the dtype of its ``eta`` field); subclasses define ``sample`` and ``delta_albedo``."""

    is_delta: ClassVar[bool] = True
    eta: eqx.AbstractVar[jax.Array]

    def eval(self, wo, wi):
        check_directions(f"{type(self).__name__}.eval", wo=wo, wi=wi)
        shape = jnp.broadcast_shapes(wo.shape, wi.shape)[:-1] + (self.channels,)
        return jnp.zeros(shape, jnp.result_type(wo, self.eta))

    def pdf(self, wo, wi):
        check_directions(f"{type(self).__name__}.pdf", wo=wo, wi=wi)
        return jnp.zeros(jnp.broadcast_shapes(wo.shape, wi.shape)[:-1], jnp.result_type(wo))


class AbstractPairBSDF(AbstractBSDF):
    """A model evaluated on prepared direction pairs: it defines ``eval_pairs``, and its ``eval``
    is ``eval_pairs(SoAPairs.of(wo, wi))`` after the directions' checks; :attr:`pair_kernels`
    unless the model says otherwise."""

    pair_kernels: ClassVar[bool] = True

    def eval(self, wo, wi):
        check_directions(f"{type(self).__name__}.eval", wo=wo, wi=wi)
        return self.eval_pairs(SoAPairs.of(wo, wi))

    @abc.abstractmethod
    def eval_pairs(self, pairs):
        """:meth:`eval` on prepared direction pairs."""


class AbstractConductor(AbstractBSDF):
    """A model with a conductor's complex index ``eta + i k`` per colour channel: its fields
    ``eta`` and ``k`` (declared by the model), checked and set by :meth:`_init_index`; ``C`` is
    their channel count. (No abstract fields here: a field of a base comes first in the model's
    pytree, and the models keep their own order of leaves.)"""

    def _init_index(self, owner, eta, k):
        check_complex_index(owner, eta, k)
        self.eta = eta
        self.k = k

    @property
    def channels(self):
        return channel_count(self.eta, self.k)


def dielectric_energy_factor(wo, wi, eta):
    """``etap^2`` for a transmitted pair, 1 for reflection: undoes the radiance BTDF's scaling.

    ``eta`` is the relative index inside / outside; ``etap`` is ``eta`` when ``wo`` is outside,
    ``1/eta`` when it is inside. Returns shape ``(...)``.
    """
    refl = wo[..., 2] * wi[..., 2] > 0
    etap = jnp.where(wo[..., 2] > 0, eta, 1 / eta)
    return jnp.where(refl, 1.0, etap * etap) * jnp.ones_like(wo[..., 2])


__all__ = ["AbstractBSDF", "AbstractConductor", "AbstractDeltaBSDF", "AbstractPairBSDF", "dielectric_energy_factor"]
