"""MaterialX: a document with a ``standard_surface`` shader and its ``surfacematerial``, built
and written with the ``materialx`` package (pip ``materialx``).

A Lambertian model maps exactly (``base`` 1, ``base_color`` = albedo, ``specular`` 0,
``diffuse_roughness`` 0). Every other model goes through the glTF BRDF fitted to it
(:mod:`matfit.export._gltf`), whose parameters standard_surface shares: ``base_color``,
``metalness``, ``specular``, ``specular_color``, ``specular_roughness = sqrt(alpha)``,
``specular_IOR``, ``coat``, ``coat_roughness``, ``coat_IOR = 1.5``. standard_surface layers its
lobes with its own energy-conserving albedo scaling and its metal Fresnel from the artistic
(F0, edge colour) parametrization, so those mappings are approximate; the fidelity reported is
that of the glTF BRDF.
"""

from __future__ import annotations

import numpy as np

from ..errors import MatfitError
from ..models import GltfPBR, Lambert
from ._gltf import gltf_target
from ._model_file import plain_numbers
from ._result import ExportResult, ParamMapping, check_model, rgb


def _mx():
    try:
        import MaterialX as mx
    except ImportError:
        raise MatfitError("to_materialx needs the materialx package: pip install materialx") from None
    return mx


def standard_library():
    """The MaterialX standard libraries, loaded (for validating documents).

    Returns
    -------
    MaterialX.Document
        A document holding the standard data libraries.

    Examples
    --------
    >>> lib = standard_library()
    >>> lib.getNodeDef("ND_standard_surface_surfaceshader") is not None
    True
    """
    mx = _mx()
    lib = mx.createDocument()
    mx.loadLibraries(mx.getDefaultDataLibraryFolders(), mx.getDefaultDataSearchPath(), lib)
    return lib


def to_materialx(model) -> ExportResult:
    """A MaterialX document (text) with the ``standard_surface`` of ``model``.

    Parameters
    ----------
    model : matfit.models.AbstractBSDF
        Lambert maps exactly; every model :func:`~matfit.export.to_gltf` takes is written
        through the glTF BRDF fitted to it, whose parameters ``standard_surface`` shares.

    Returns
    -------
    ExportResult
        ``content`` is the ``.mtlx`` XML text; the material node is ``matfit``.

    Raises
    ------
    MatfitError
        The ``materialx`` package is missing; a :class:`~matfit.errors.ParameterError` for a
        model glTF cannot represent.

    Examples
    --------
    >>> from matfit.models import Lambert
    >>> r = to_materialx(Lambert([0.5, 0.4, 0.3]))
    >>> 'standard_surface' in r.content, r.exact
    (True, True)
    """
    check_model("to_materialx", model)
    mx = _mx()
    doc = mx.createDocument()
    ss = doc.addNode("standard_surface", "matfit_shader", "surfaceshader")
    mapping, notes, fid = [], [], None

    def put(name, value, source, exact, note=""):
        v = plain_numbers(np.asarray(value))
        if isinstance(v, list):
            ss.setInputValue(name, mx.Color3(*v))
        else:
            ss.setInputValue(name, float(v))
        mapping.append(ParamMapping(name, v, source, exact, note))

    if isinstance(model, Lambert):
        put("base", 1.0, "1", True)
        put("base_color", rgb("to_materialx", model.reflectance), "albedo", True)
        put("diffuse_roughness", 0.0, "0 (Lambert)", True)
        put("specular", 0.0, "0 (no specular layer)", True)
    else:
        t, exact, fid, notes = gltf_target(model)
        note = "standard_surface's layering and metal Fresnel differ from the glTF BRDF fitted to the model"
        if isinstance(model, GltfPBR):
            note = "standard_surface's layering and metal Fresnel differ from the glTF BRDF"
        put("base", 1.0, "1", False, note)
        put("base_color", rgb("to_materialx", t.base_color), "base_color", False, note)
        put("metalness", t.metallic, "metallic", False, note)
        put("specular", t.specular, "specular", False, note)
        put("specular_color", rgb("to_materialx", t.specular_color), "specular_color", False, note)
        put("specular_roughness", np.sqrt(np.asarray(t.alpha, float)), "sqrt(alpha)", False, note)
        put("specular_IOR", t.ior, "ior", False, note)
        if float(np.asarray(t.clearcoat)) > 0:
            put("coat", t.clearcoat, "clearcoat", False, note)
            put("coat_roughness", np.sqrt(np.asarray(t.clearcoat_alpha, float)), "sqrt(clearcoat_alpha)", False, note)
            put("coat_IOR", 1.5, "1.5", False, note)
        notes = list(notes) + ["fidelity measured on the glTF BRDF that standard_surface approximates"] if fid else notes
    doc.addMaterialNode("matfit", ss)
    lib = standard_library()
    vdoc = mx.createDocument()
    vdoc.copyContentFrom(doc)
    vdoc.importLibrary(lib)
    ok, msg = vdoc.validate()
    if not ok:  # a bug of this exporter, never the user's: say so
        raise MatfitError(f"to_materialx: the document failed MaterialX validation: {msg}")
    return ExportResult("mtlx", mx.writeToXmlString(doc), mapping, model if isinstance(model, Lambert) else t, fid, notes)
