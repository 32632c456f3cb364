"""Export a fitted model to a renderer: Mitsuba 3, pbrt-v4, glTF 2.0, MaterialX (standard_surface, OpenPBR), USD.

Every exporter returns an :class:`ExportResult`: the document, a per-parameter
:class:`ParamMapping` saying whether the target reproduces the model exactly, and, where it
does not, a :class:`Fidelity` measured against the model. Where a target cannot express a model
(a conductor's complex index in glTF's F0, a coated metal in Mitsuba), the target's own BRDF,
written as a matfit model, is fitted to the model over the hemisphere with matfit's fitter
(:func:`fit_target`) and that fit is what gets written.
"""

from ._api import EXPORTERS, export, to_gltf, to_materialx, to_mitsuba, to_mitsuba_xml, to_openpbr, to_pbrt, to_usd
from ._fidelity import fit_target, hemisphere_pairs, measure, relative_rmse
from ._model_file import describe_model, load_model, model_from_description, save_model
from ._result import ExportResult, Fidelity, ParamMapping

__all__ = [
    "EXPORTERS", "export", "to_mitsuba", "to_mitsuba_xml", "to_pbrt", "to_gltf", "to_materialx", "to_openpbr", "to_usd",
    "ExportResult", "Fidelity", "ParamMapping", "fit_target", "hemisphere_pairs", "measure", "relative_rmse",
    "describe_model", "model_from_description", "save_model", "load_model",
]
