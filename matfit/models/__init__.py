"""BSDF models: one model per file, each an equinox Module with eval, pdf, sample and albedo."""

from ._base import AbstractBSDF
from ._microfacet import AbstractMicrofacetBSDF
from ._pairs import SoAPairs, half_vector, valid_reflection
from ._registry import MODEL_USES, MODELS, models_for
from .blend import Blend
from .diffuse_specular import DiffuseSpecular
from .gltf_pbr import GltfPBR
from .lambert import Lambert
from .layered import CoatedConductor, Layered
from .measured import MeasuredMERL, MeasuredRGL, measured_model
from .multi_lobe import MultiLobe, SpecularLobe
from .plastic import Plastic
from .rough_conductor import RoughConductor
from .rough_dielectric import RoughDielectric
from .rotated import Rotated
from .sheen import Sheen, sheen_albedo
from .smooth_conductor import SmoothConductor
from .smooth_dielectric import SmoothDielectric
from .stochastic_layered import StochasticLayered
from .tabulated_microfacet import TabulatedMicrofacet

__all__ = [
    "AbstractBSDF",
    "AbstractMicrofacetBSDF",
    "SoAPairs",
    "half_vector",
    "valid_reflection",
    "StochasticLayered",
    "Lambert",
    "Plastic",
    "Layered",
    "CoatedConductor",
    "Blend",
    "Rotated",
    "DiffuseSpecular",
    "GltfPBR",
    "MeasuredMERL",
    "MeasuredRGL",
    "measured_model",
    "MultiLobe",
    "SpecularLobe",
    "RoughConductor",
    "RoughDielectric",
    "Sheen",
    "sheen_albedo",
    "SmoothConductor",
    "SmoothDielectric",
    "TabulatedMicrofacet",
    "MODELS",
    "MODEL_USES",
    "models_for",
]
