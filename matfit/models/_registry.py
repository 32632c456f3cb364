"""The model registry: every public model of :mod:`matfit.models` by name, in one place.

:data:`MODELS` maps a model's name (its class's or factory's ``__name__``) to the class or
factory; :data:`MODEL_USES` says what each entry is declared for, and :func:`models_for` selects
the entries of one use:

* ``"document"``: a model document (the JSON model file of :mod:`matfit.export`) may name it, a
  class whose fields are numbers, names and nested models, rebuilt from those fields;
* ``"scene"``: a synthetic scene (``data_synth``) may build it from its keyword arguments.

The model-file reader, data_synth and the tests take their names from here, so a new model is
named once.
"""

from __future__ import annotations

from ..errors import ParameterError
from .blend import Blend
from .diffuse_specular import DiffuseSpecular
from .gltf_pbr import GltfPBR
from .lambert import Lambert
from .layered import CoatedConductor, Layered
from .measured import MeasuredMERL, MeasuredRGL
from .multi_lobe import MultiLobe, SpecularLobe
from .plastic import Plastic
from .rough_conductor import RoughConductor
from .rough_dielectric import RoughDielectric
from .rotated import Rotated
from .sheen import Sheen
from .smooth_conductor import SmoothConductor
from .smooth_dielectric import SmoothDielectric
from .stochastic_layered import StochasticLayered
from .tabulated_microfacet import TabulatedMicrofacet

_DOC, _SCENE = "document", "scene"
#: The uses an entry may declare.
USES = (_DOC, _SCENE)

_ENTRIES = (
    (Lambert, (_DOC, _SCENE)),
    (RoughConductor, (_DOC, _SCENE)),
    (SmoothConductor, (_DOC, _SCENE)),
    (RoughDielectric, (_DOC, _SCENE)),
    (SmoothDielectric, (_DOC, _SCENE)),
    (Plastic, (_DOC, _SCENE)),
    (Layered, (_DOC, _SCENE)),
    (CoatedConductor, (_SCENE,)),  # a factory of a Layered, which a document holds as such
    (Blend, (_DOC, _SCENE)),
    (Rotated, (_DOC, _SCENE)),
    (StochasticLayered, (_DOC,)),
    (GltfPBR, (_DOC,)),
    (DiffuseSpecular, (_DOC,)),
    (TabulatedMicrofacet, (_DOC,)),
    (MultiLobe, (_DOC,)),
    (SpecularLobe, (_DOC,)),
    (Sheen, (_DOC,)),
    (MeasuredRGL, ()),  # measured tables: read from their files, not written as numbers
    (MeasuredMERL, ()),
)

#: Every public model by name: the class, or the factory (``CoatedConductor``).
MODELS = {obj.__name__: obj for obj, _ in _ENTRIES}
#: The uses each entry of :data:`MODELS` is declared for (a subset of :data:`USES`).
MODEL_USES = {obj.__name__: frozenset(uses) for obj, uses in _ENTRIES}


def models_for(use):
    """The entries of :data:`MODELS` declared for one use, in registry order.

    Parameters
    ----------
    use : {"document", "scene"}
        A model document may name the entry (``"document"``) or a synthetic scene may build it
        (``"scene"``).

    Returns
    -------
    dict
        Name -> class or factory.
    """
    if use not in USES:
        raise ParameterError(f"models_for: use must be one of {list(USES)}, found {use!r}")
    return {name: obj for name, obj in MODELS.items() if use in MODEL_USES[name]}
