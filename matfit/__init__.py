"""matfit: differentiable physically based material fitting in JAX.

Conventions: local shading frame with the normal along +z; ``wo`` points to the viewer, ``wi``
to the light, both away from the surface; ``f(wo, wi)`` in 1/sr without the cosine; colour
channels on the last axis.

The public API is flat: ``matfit.fit``, ``matfit.fit_batch``, ``matfit.load``, ``matfit.save``,
``matfit.sample_posterior``, ``matfit.compare_models``, ``matfit.fit_map`` and the packages
``matfit.export``, ``matfit.render``, ``matfit.maps`` (each loaded on first use, so that
``import matfit`` stays quick).

Examples
--------
>>> import numpy as np, matfit
>>> wo = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, 0.6, 0.8]]); wi = wo[[1, 2, 0]]
>>> r = matfit.fit(matfit.Table(wo=wo, wi=wi, values=np.full((3, 3), 0.1)), model="lambert", starts=1)
>>> round(float(r.params["albedo"][0]), 4)
0.3142
"""

import importlib

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
    "fit",
    "fit_batch",
    "load",
    "save",
    "sample_posterior",
    "compare_models",
    "fit_map",
    "export",
    "render",
    "maps",
]

#: Top-level names loaded on first use: name -> (module, attribute or None for the module).
_LAZY = {
    "fit": ("matfit.fitting", "fit"),
    "fit_batch": ("matfit.fitting", "fit_batch"),
    "sample_posterior": ("matfit.fitting", "sample_posterior"),
    "compare_models": ("matfit.fitting", "compare_models"),
    "load": ("matfit.io", "load"),
    "save": ("matfit.io", "save"),
    "fit_map": ("matfit.maps", "fit_map"),
    "export": ("matfit.export", None),
    "render": ("matfit.render", None),
    "maps": ("matfit.maps", None),
}


def __getattr__(name):
    if name in _LAZY:
        module, attr = _LAZY[name]
        mod = importlib.import_module(module)
        return mod if attr is None else getattr(mod, attr)
    raise AttributeError(f"module 'matfit' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))
