"""USD: a ``UsdShade`` material holding two surfaces, written with usd-core (pip ``usd-core``).

* ``outputs:surface``: a ``UsdPreviewSurface``, which every USD renderer reads. A Lambertian
  model maps exactly (``useSpecularWorkflow`` 1, ``specularColor`` 0, ``diffuseColor`` the
  albedo: the preview surface's diffuse is Lambertian). Every other model goes through the glTF
  BRDF fitted to it (:mod:`matfit.export._gltf`): ``diffuseColor`` = ``base_color``,
  ``metallic``, ``roughness = sqrt(alpha)`` (the preview surface squares it for its GGX lobe),
  ``ior``, ``clearcoat`` and ``clearcoatRoughness = sqrt(clearcoat_alpha)``: approximate (the
  preview surface has its own layering and Fresnel, and no specular factor, thin film, sheen or
  anisotropy; a note names what it drops).
* ``outputs:mtlx:surface``: OpenPBR's ``open_pbr_surface`` as a MaterialX shader
  (``info:id = ND_open_pbr_surface_surfaceshader``), with exactly the inputs and values of
  :func:`~matfit.export.to_openpbr` (the anisotropy, thin film and fuzz included).

``content`` is the layer as ``.usda`` text; the fidelity is the glTF stand-in's, as for MaterialX.
"""

from __future__ import annotations

import numpy as np

from ..errors import MatfitError, ParameterError
from ..models import GltfPBR, Lambert, Sheen
from ._materialx import to_openpbr
from ._result import ExportResult, ParamMapping, check_model, rgb

#: The prim paths of the material and its two shaders.
MATERIAL_PATH = "/matfit/Material"
PREVIEW_PATH = MATERIAL_PATH + "/PreviewSurface"
OPENPBR_PATH = MATERIAL_PATH + "/OpenPBR"
#: The MaterialX node definition of OpenPBR's surface.
OPENPBR_ID = "ND_open_pbr_surface_surfaceshader"


def _pxr():
    try:
        from pxr import Gf, Sdf, Usd, UsdShade
    except ImportError:
        raise MatfitError("to_usd needs the usd-core package: pip install usd-core") from None
    return Gf, Sdf, Usd, UsdShade


def _preview_inputs(t):
    """``[(input, value, source, exact)]`` of the UsdPreviewSurface standing for ``t`` (the model
    to_openpbr wrote: a Lambert, a Sheen, or the glTF stand-in), and the notes."""
    if isinstance(t, Sheen):
        rows, notes = _preview_inputs(t.base)
        return [(n, v, s, False) for n, v, s, _ in rows], notes + [
            "UsdPreviewSurface has no sheen lobe: its surface is the base's (the OpenPBR shader carries the fuzz)"]
    if isinstance(t, Lambert):
        return [("useSpecularWorkflow", 1, "1", True), ("specularColor", [0.0, 0.0, 0.0], "0 (no specular lobe)", True),
                ("diffuseColor", rgb("to_usd", t.reflectance), "albedo", True)], []
    if not isinstance(t, GltfPBR):  # what to_openpbr writes is one of the three
        raise MatfitError(f"to_usd: unexpected stand-in {type(t).__name__} (a bug of this exporter)")
    rows = [("useSpecularWorkflow", 0, "0 (metalness)", False), ("diffuseColor", rgb("to_usd", t.base_color),
                                                                   "base_color", False),
            ("metallic", float(np.asarray(t.metallic)), "metallic", False),
            ("roughness", float(np.sqrt(np.asarray(t.alpha))), "sqrt(alpha)", False),
            ("ior", float(np.asarray(t.ior)), "ior", False)]
    if float(np.asarray(t.clearcoat)) > 0:
        rows += [("clearcoat", float(np.asarray(t.clearcoat)), "clearcoat", False),
                 ("clearcoatRoughness", float(np.sqrt(np.asarray(t.clearcoat_alpha))), "sqrt(clearcoat_alpha)", False)]
    dropped = [what for what, on in (("specular factor", float(np.asarray(t.specular)) < 1),
                                     ("thin film", t.has_film and float(np.asarray(t.iridescence)) > 0),
                                     ("anisotropy", t.has_anisotropy and float(np.asarray(t.anisotropy)) > 0)) if on]
    notes = [f"UsdPreviewSurface has no {' or '.join(dropped)}: the OpenPBR shader carries "
             f"{'them' if len(dropped) > 1 else 'it'}"] if dropped else []
    return rows, notes


def to_usd(model) -> ExportResult:
    """A USD layer with one material for ``model``: a UsdPreviewSurface and OpenPBR (module docstring).

    Parameters
    ----------
    model : matfit.models.AbstractBSDF
        What :func:`~matfit.export.to_openpbr` takes.

    Returns
    -------
    ExportResult
        ``content`` is the ``.usda`` text (``Usd.Stage.Open`` of the written file reads it);
        ``mapping`` holds the preview surface's inputs (``preview:<name>``) and the OpenPBR
        shader's (``openpbr:<name>``); ``model`` is the stand-in.

    Raises
    ------
    ParameterError
        ``model`` is not a matfit model, or one OpenPBR's exporter cannot take.
    MatfitError
        usd-core or materialx is not installed.

    Examples
    --------
    >>> from matfit.models import Lambert
    >>> r = to_usd(Lambert([0.5, 0.4, 0.3]))
    >>> "UsdPreviewSurface" in r.content, r.exact
    (True, True)
    """
    check_model("to_usd", model)
    Gf, Sdf, Usd, UsdShade = _pxr()
    try:
        pbr = to_openpbr(model)
    except ParameterError as e:  # the stand-in's exporter names itself: say which call failed
        raise ParameterError(f"to_usd, through OpenPBR's glTF stand-in: {e}") from None
    rows, notes = _preview_inputs(pbr.model)
    stage = Usd.Stage.CreateInMemory()
    stage.SetDefaultPrim(stage.DefinePrim("/matfit", "Scope"))
    material = UsdShade.Material.Define(stage, MATERIAL_PATH)

    def put(shader, name, value):
        if isinstance(value, list):
            shader.CreateInput(name, Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*[float(x) for x in value]))
        elif isinstance(value, int):
            shader.CreateInput(name, Sdf.ValueTypeNames.Int).Set(value)
        else:
            shader.CreateInput(name, Sdf.ValueTypeNames.Float).Set(float(value))

    preview = UsdShade.Shader.Define(stage, PREVIEW_PATH)
    preview.CreateIdAttr("UsdPreviewSurface")
    mapping = []
    for name, value, source, exact in rows:
        put(preview, name, value)
        mapping.append(ParamMapping(f"preview:{name}", value, source, exact,
                                    "" if exact else "UsdPreviewSurface's own layering and Fresnel"))
    material.CreateSurfaceOutput().ConnectToSource(preview.ConnectableAPI(), "surface")
    shader = UsdShade.Shader.Define(stage, OPENPBR_PATH)
    shader.CreateIdAttr(OPENPBR_ID)
    for m in pbr.mapping:
        put(shader, m.target, m.value)
        mapping.append(ParamMapping(f"openpbr:{m.target}", m.value, m.source, m.exact, m.note))
    material.CreateSurfaceOutput("mtlx").ConnectToSource(shader.ConnectableAPI(), "out")
    text = stage.GetRootLayer().ExportToString()
    return ExportResult("usd", text, mapping, pbr.model, pbr.fidelity, list(pbr.notes) + notes)
