"""matfit: differentiable physically based material fitting in JAX.

Conventions: local shading frame with the normal along +z; ``wo`` points to the viewer, ``wi``
to the light, both away from the surface; ``f(wo, wi)`` in 1/sr without the cosine; colour
channels on the last axis.
"""

from . import fresnel, microfacet, models
from .errors import DataFormatError, MatfitError, ParameterError
from .table import Table
from .models import (
    Blend,
    CoatedConductor,
    Lambert,
    Layered,
    Plastic,
    RoughConductor,
    RoughDielectric,
    SmoothConductor,
    SmoothDielectric,
    StochasticLayered,
)

__version__ = "0.1.0"

__all__ = [
    "Table",
    "fresnel",
    "microfacet",
    "models",
    "MatfitError",
    "ParameterError",
    "DataFormatError",
    "Lambert",
    "RoughConductor",
    "RoughDielectric",
    "SmoothConductor",
    "SmoothDielectric",
    "Plastic",
    "Layered",
    "CoatedConductor",
    "Blend",
    "StochasticLayered",
]
