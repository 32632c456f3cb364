"""The abstract BSDF: the interface every model implements, and the directional albedo."""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..errors import ParameterError
from ._params import check_directions


class AbstractBSDF(eqx.Module):
    r"""A BSDF in the local shading frame (normal = +z): the interface every model implements.

    ``eval(wo, wi)`` is ``f`` in 1/sr without the cosine (radiance BTDF for transmission),
    ``pdf(wo, wi)`` the density of :meth:`sample` in solid angle, and ``sample(wo, u)`` returns
    ``(wi, weight, pdf)`` with ``weight = f |cos theta_i| / pdf``. Directions have shape
    ``(..., 3)``, ``u`` shape ``(..., 3)`` (``u[..., 0]`` picks a lobe, ``u[..., 1:]`` the
    direction). Invalid samples have ``pdf == 0`` and ``weight == 0``.

    A model is an equinox Module: its array fields are the differentiable parameters (pytree
    leaves), its string and integer options static fields. Each concrete model documents its
    constructor arguments in its own ``Parameters`` section (the tables of ``docs/models.md``
    are generated from them).

    Attributes
    ----------
    is_delta : bool
        True for models made only of Dirac lobes (``eval`` and ``pdf`` are zero everywhere);
        a class attribute.
    pair_kernels : bool
        True for models whose :meth:`eval_pairs` evaluates prepared pairs channel by channel
        on component arrays (the kernels of :mod:`matfit.fast`); others rebuild ``(N, 3)``
        arrays. A class attribute (a property of composite models).

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.models import AbstractBSDF, Lambert
    >>> m = Lambert(0.5)
    >>> isinstance(m, AbstractBSDF), m.channels, m.is_delta
    (True, 1, False)
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
        r"""The BSDF value :math:`f(\omega_o, \omega_i)` in 1/sr, without the cosine factor.

        Parameters
        ----------
        wo, wi : array_like, shape (..., 3)
            Unit directions to the viewer and to the light, both pointing away from the
            surface (local frame, normal +z); batch shapes broadcast.

        Returns
        -------
        jax.Array, shape (..., C)
            The value per colour channel (radiance BTDF for a transmitted pair); 0 where the
            pair is outside the model's domain (a reflection-only model and ``wi`` below the
            horizon, grazing directions within ``COS_EPS``).

        Examples
        --------
        >>> import jax.numpy as jnp
        >>> from matfit.models import Lambert
        >>> up = jnp.array([0.0, 0.0, 1.0])
        >>> round(float(Lambert(0.5).eval(up, up)[0] * jnp.pi), 6)
        0.5
        """

    pair_kernels: ClassVar[bool] = False

    def eval_pairs(self, pairs):
        """:meth:`eval` on prepared direction pairs: the quantities that depend only on the
        directions are taken from ``pairs`` instead of being derived again.

        The default rebuilds the ``(..., 3)`` arrays and calls :meth:`eval`; models with
        :attr:`pair_kernels` override it, and their :meth:`eval` is
        ``eval_pairs(SoAPairs.of(wo, wi))``.

        Parameters
        ----------
        pairs : SoAPairs
            From :meth:`SoAPairs.of <matfit.models.SoAPairs.of>` or :func:`matfit.fast.soa_pairs`.

        Returns
        -------
        jax.Array, shape (..., C)
            Equal to ``eval(wo, wi)`` of the pairs' directions.

        Examples
        --------
        >>> import jax.numpy as jnp
        >>> from matfit.models import Lambert, SoAPairs
        >>> up = jnp.array([[0.0, 0.0, 1.0]])
        >>> m = Lambert(0.5)
        >>> bool(jnp.array_equal(m.eval_pairs(SoAPairs.of(up, up)), m.eval(up, up)))
        True
        """
        return self.eval(pairs.wo.to_array(), pairs.wi.to_array())

    @abc.abstractmethod
    def pdf(self, wo, wi):
        """Solid-angle density of :meth:`sample` choosing ``wi`` given ``wo``.

        Dirac lobes have no density: a delta model's pdf is zero everywhere, and a model with
        a delta lobe returns the density of its other lobes.

        Parameters
        ----------
        wo, wi : array_like, shape (..., 3)
            Unit directions (as in :meth:`eval`).

        Returns
        -------
        jax.Array, shape (...)
            Density in 1/sr.

        Examples
        --------
        >>> import jax.numpy as jnp
        >>> from matfit.models import Lambert
        >>> up = jnp.array([0.0, 0.0, 1.0])
        >>> round(float(Lambert(0.5).pdf(up, up) * jnp.pi), 6)  # cosine-weighted: cos / pi
        1.0
        """

    @abc.abstractmethod
    def sample(self, wo, u):
        r"""Importance-sample an incident direction for ``wo``.

        Parameters
        ----------
        wo : array_like, shape (..., 3)
            Unit directions to the viewer.
        u : array_like, shape (..., 3)
            Uniform numbers in [0, 1): ``u[..., 0]`` picks a lobe, ``u[..., 1:3]`` the direction.

        Returns
        -------
        wi : jax.Array, shape (..., 3)
            The sampled unit direction (arbitrary but finite for an invalid sample).
        weight : jax.Array, shape (..., C)
            :math:`f\,|\cos\theta_i| / p` (radiance; 0 for an invalid sample).
        pdf : jax.Array, shape (...)
            The density of ``wi`` (the discrete probability for a Dirac lobe; 0 when invalid).

        Examples
        --------
        >>> import jax.numpy as jnp
        >>> from matfit.models import Lambert
        >>> wi, weight, pdf = Lambert(0.5).sample(jnp.array([0.0, 0.0, 1.0]), jnp.array([0.0, 0.3, 0.7]))
        >>> bool(wi[2] > 0), round(float(weight[0]), 6)  # the weight of a cosine-sampled Lambert is its albedo
        (True, 0.5)
        """

    @property
    @abc.abstractmethod
    def channels(self) -> int:
        """Number of colour channels ``C`` of :meth:`eval`."""

    def energy_factor(self, wo, wi):
        r"""Factor turning :math:`f\,|\cos\theta_i|` into transported energy: :math:`\eta_p^2`
        for a transmitted pair of a radiance BTDF, 1 otherwise.

        Parameters
        ----------
        wo, wi : array_like, shape (..., 3)
            Unit directions.

        Returns
        -------
        jax.Array, shape (...)

        Examples
        --------
        >>> import jax.numpy as jnp
        >>> from matfit.models import Lambert, SmoothDielectric
        >>> wo = jnp.array([0.0, 0.0, 1.0])
        >>> float(Lambert(0.5).energy_factor(wo, wo)), float(SmoothDielectric(1.5).energy_factor(wo, -wo))
        (1.0, 2.25)
        """
        return jnp.ones(jnp.broadcast_shapes(wo.shape, wi.shape)[:-1], wo.dtype)

    def delta_albedo(self, wo):
        """Energy carried by the model's Dirac lobes for ``wo`` (zero for a model without any).

        Parameters
        ----------
        wo : array_like, shape (..., 3)
            Unit directions to the viewer.

        Returns
        -------
        jax.Array, shape (..., C)

        Examples
        --------
        >>> import jax.numpy as jnp
        >>> from matfit.models import Lambert, SmoothDielectric
        >>> wo = jnp.array([0.0, 0.0, 1.0])
        >>> float(Lambert(0.5).delta_albedo(wo)[0]), float(SmoothDielectric(1.5).delta_albedo(wo)[0])
        (0.0, 1.0)
        """
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


class AbstractDeltaBSDF(AbstractBSDF):
    """A model made only of Dirac lobes (:class:`~matfit.models.SmoothConductor`,
    :class:`~matfit.models.SmoothDielectric`): ``eval`` and ``pdf`` are zero everywhere, a Dirac
    lobe having no density; subclasses define :meth:`sample` and :meth:`delta_albedo`.

    Attributes
    ----------
    eta : jax.Array
        The interface's relative index (its dtype is that of ``eval``'s zeros).

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.models import SmoothConductor
    >>> up = jnp.array([0.0, 0.0, 1.0])
    >>> m = SmoothConductor(0.2, 3.9)
    >>> m.is_delta, float(m.eval(up, up)[0]), float(m.pdf(up, up))
    (True, 0.0, 0.0)
    """

    is_delta: ClassVar[bool] = True
    eta: eqx.AbstractVar[jax.Array]

    def eval(self, wo, wi):
        check_directions(f"{type(self).__name__}.eval", wo=wo, wi=wi)
        shape = jnp.broadcast_shapes(wo.shape, wi.shape)[:-1] + (self.channels,)
        return jnp.zeros(shape, jnp.result_type(wo, self.eta))

    def pdf(self, wo, wi):
        check_directions(f"{type(self).__name__}.pdf", wo=wo, wi=wi)
        return jnp.zeros(jnp.broadcast_shapes(wo.shape, wi.shape)[:-1], jnp.result_type(wo))


def dielectric_energy_factor(wo, wi, eta):
    """``etap^2`` for a transmitted pair (1 for reflection): undoes the radiance BTDF's scaling.

    ``etap`` is ``eta`` when ``wo`` is outside and ``1/eta`` when it is inside.

    Parameters
    ----------
    wo, wi : array_like, shape (..., 3)
        Unit directions.
    eta : array_like
        Relative index inside / outside of the interface.

    Returns
    -------
    jax.Array, shape (...)

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.models._base import dielectric_energy_factor
    >>> up = jnp.array([0.0, 0.0, 1.0])
    >>> float(dielectric_energy_factor(up, -up, 2.0)), float(dielectric_energy_factor(-up, up, 2.0))
    (4.0, 0.25)
    """
    refl = wo[..., 2] * wi[..., 2] > 0
    etap = jnp.where(wo[..., 2] > 0, eta, 1 / eta)
    return jnp.where(refl, 1.0, etap * etap) * jnp.ones_like(wo[..., 2])


__all__ = ["AbstractBSDF", "AbstractDeltaBSDF", "dielectric_energy_factor"]
