"""The abstract BSDF: the interface every model implements, and the directional albedo."""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._math import dot
from ..errors import ParameterError
from ._params import check_directions


class AbstractBSDF(eqx.Module):
    """A BSDF in the local shading frame (normal = +z).

    ``eval(wo, wi)`` is ``f`` in 1/sr without the cosine (radiance BTDF for transmission),
    ``pdf(wo, wi)`` the density of :meth:`sample` in solid angle, and ``sample(wo, u)`` returns
    ``(wi, weight, pdf)`` with ``weight = f |cos theta_i| / pdf``. Directions have shape
    ``(..., 3)``, ``u`` shape ``(..., 3)`` (``u[..., 0]`` picks a lobe, ``u[..., 1:]`` the
    direction). Invalid samples have ``pdf == 0`` and ``weight == 0``.
    """

    #: True for models made only of Dirac lobes (eval and pdf are zero everywhere).
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
        """BSDF value ``(..., C)`` for directions ``(..., 3)``."""

    #: True for models whose :meth:`eval_pairs` evaluates prepared pairs channel by channel on
    #: component arrays (the kernels of :mod:`matfit.fast`); others rebuild ``(N, 3)`` arrays.
    pair_kernels: ClassVar[bool] = False

    def eval_pairs(self, pairs):
        """:meth:`eval` on prepared direction pairs (:class:`~matfit.models.SoAPairs`): the
        quantities that depend only on the directions are taken from ``pairs`` instead of being
        derived again. The default rebuilds the ``(..., 3)`` arrays and calls :meth:`eval`;
        models with :attr:`pair_kernels` override it, and their :meth:`eval` is
        ``eval_pairs(SoAPairs.of(wo, wi))``.

        Examples
        --------
        >>> import jax.numpy as jnp
        >>> from matfit.models import Lambert, SoAPairs
        >>> up = jnp.array([[0.0, 0.0, 1.0]])
        >>> Lambert(0.5).eval_pairs(SoAPairs.of(up, up)).shape
        (1, 1)
        """
        return self.eval(pairs.wo.to_array(), pairs.wi.to_array())

    @abc.abstractmethod
    def pdf(self, wo, wi):
        """Solid-angle density ``(...)`` of sampling ``wi`` given ``wo``."""

    @abc.abstractmethod
    def sample(self, wo, u):
        """Importance-sample ``wi``: returns ``(wi, weight, pdf)``."""

    @property
    @abc.abstractmethod
    def channels(self) -> int:
        """Number of colour channels ``C`` of :meth:`eval`."""

    def energy_factor(self, wo, wi):
        """Factor turning ``f |cos|`` into transported energy (``etap^2`` for radiance BTDFs)."""
        return jnp.ones(jnp.broadcast_shapes(wo.shape, wi.shape)[:-1], wo.dtype)

    def delta_albedo(self, wo):
        """Energy carried by Dirac lobes for ``wo`` ``(..., C)``; zero for non-delta models."""
        return jnp.zeros(wo.shape[:-1] + (self.channels,), wo.dtype)

    def albedo(self, wo, method="quadrature", n=None, key=None):
        r"""Directional albedo: the fraction of energy reflected plus transmitted for ``wo``.

        .. math:: E(\omega_o) = \int_{S^2} f(\omega_o, \omega_i)\,|\cos\theta_i|\,
                  \eta_p^2\,d\omega_i + E_\delta(\omega_o)

        where :math:`\eta_p^2` undoes the radiance scaling of transmission.

        Parameters
        ----------
        wo : array_like, shape (..., 3)
            Outgoing directions.
        method : {"quadrature", "mc"}
            ``"quadrature"``: Gauss-Legendre in cos(theta) on each hemisphere times a uniform
            rule in phi (order ``n``, default 96), accurate for lobes wider than ~pi/n.
            ``"mc"``: mean of the importance-sampled weights (``n`` samples, default 2**16),
            unbiased for every model, delta models included.
        n : int, optional
            Quadrature order or sample count.
        key : jax.random.PRNGKey, optional
            Random key for ``"mc"`` (default ``PRNGKey(0)``).

        Returns
        -------
        jax.Array, shape (..., C)

        Examples
        --------
        >>> import jax.numpy as jnp
        >>> from matfit.models import Lambert
        >>> e = Lambert(0.5).albedo(jnp.array([0.0, 0.0, 1.0]))
        >>> round(float(e[0]), 6)
        0.5
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


def dielectric_energy_factor(wo, wi, eta):
    """``etap^2`` for a transmitted pair (1 for reflection): undoes the radiance BTDF's scaling.

    ``etap`` is ``eta`` when ``wo`` is outside and ``1/eta`` when it is inside.
    """
    refl = wo[..., 2] * wi[..., 2] > 0
    etap = jnp.where(wo[..., 2] > 0, eta, 1 / eta)
    return jnp.where(refl, 1.0, etap * etap) * jnp.ones_like(wo[..., 2])


def cos_theta(w):
    return w[..., 2]


__all__ = ["AbstractBSDF", "dot", "cos_theta"]
