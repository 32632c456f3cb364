r"""Rotated: a model turned about the normal, the orientation of an anisotropic lobe.

An anisotropic lobe (``alpha_y`` differs from ``alpha``) is stretched along the frame's own x
and y axes. A brushed metal's grooves run at some azimuth :math:`\varphi` of the surface's
tangent frame: the lobe's x axis lies at that azimuth. With :math:`R_\varphi` the rotation by
:math:`\varphi` about the normal,

.. math::

    f(\omega_o, \omega_i) = f_b(R_{-\varphi}\,\omega_o,\; R_{-\varphi}\,\omega_i), \qquad
    p(\omega_o, \omega_i) = p_b(R_{-\varphi}\,\omega_o,\; R_{-\varphi}\,\omega_i),

and a sample of the base for :math:`R_{-\varphi}\omega_o` is turned back by :math:`R_\varphi`
(its weight and density unchanged: a rotation keeps solid angle). Albedo, energy and
reciprocity are the base's. An isotropic base is unchanged by any angle, and an anisotropic
one is unchanged by :math:`\varphi + \pi` (its lobe is symmetric under :math:`(x, y) \to
(-x, -y)`); swapping ``alpha`` and ``alpha_y`` is the same as :math:`\varphi + \pi/2`.

The exporters map a rotated anisotropic lobe to glTF's ``KHR_materials_anisotropy``
(strength and rotation) and to OpenPBR's ``specular_roughness_anisotropy`` with a rotated
tangent (docs/export.md).
"""

from __future__ import annotations

import jax.numpy as jnp

from .._math import turn_about_z
from ._base import AbstractBSDF
from ._params import as_param, check_directions, check_range, check_u
from ..errors import ParameterError

__all__ = ["Rotated"]


class Rotated(AbstractBSDF):
    r"""A model turned about the normal by ``angle`` (module docstring: the math).

    Parameters
    ----------
    base : AbstractBSDF; differentiable (its array leaves)
        The model in its own frame, typically an anisotropic lobe (``alpha_y`` set).
    angle : array_like, scalar or (...); radians, any value; differentiable
        The azimuth of the base's x axis in the shading frame.

    Examples
    --------
    >>> import numpy as np, jax.numpy as jnp
    >>> from matfit.models import Rotated, RoughConductor
    >>> brushed = RoughConductor(0.05, 0.2, 3.0, alpha_y=0.4)  # wide along y
    >>> wo, wi = jnp.array([0.5, 0.0, 0.866]), jnp.array([-0.5, 0.0, 0.866])
    >>> bool(jnp.allclose(Rotated(brushed, np.pi / 2).eval(wo, wi),
    ...                   RoughConductor(0.4, 0.2, 3.0, alpha_y=0.05).eval(wo, wi)))
    True
    """

    base: AbstractBSDF
    angle: jnp.ndarray

    def __init__(self, base, angle):
        if not isinstance(base, AbstractBSDF):
            raise ParameterError(f"Rotated: base must be a matfit model, got {type(base).__name__}")
        check_range("Rotated", "angle", angle)  # finite (radians), any value
        self.base = base
        self.angle = as_param(angle)

    @property
    def channels(self):
        return self.base.channels

    @property
    def transmits(self):
        return self.base.transmits

    @property
    def has_delta_lobe(self):
        return self.base.has_delta_lobe

    @property
    def is_delta(self):
        """The base's (a rotated Dirac lobe is one)."""
        return self.base.is_delta

    def _into(self, w):
        """``w`` in the base's frame (turned by ``-angle``)."""
        return turn_about_z(w, jnp.cos(self.angle), -jnp.sin(self.angle))

    def eval(self, wo, wi):
        check_directions("Rotated.eval", wo=wo, wi=wi)
        return self.base.eval(self._into(wo), self._into(wi))

    def pdf(self, wo, wi):
        check_directions("Rotated.pdf", wo=wo, wi=wi)
        return self.base.pdf(self._into(wo), self._into(wi))

    def sample(self, wo, u):
        check_directions("Rotated.sample", wo=wo)
        check_u("Rotated.sample", u, 3)
        wi, weight, pdf = self.base.sample(self._into(wo), u)
        return turn_about_z(wi, jnp.cos(self.angle), jnp.sin(self.angle)), weight, pdf

    def energy_factor(self, wo, wi):
        return self.base.energy_factor(self._into(wo), self._into(wi))

    def delta_albedo(self, wo):
        return self.base.delta_albedo(self._into(wo))

    def albedo(self, wo, **options):
        """The base's directional albedo (its own ``options``) at ``wo`` seen in its frame."""
        check_directions("Rotated.albedo", wo=wo)
        return self.base.albedo(self._into(wo), **options)
