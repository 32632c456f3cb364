"""MaterialX: a document with a ``standard_surface`` (or OpenPBR's ``open_pbr_surface``) shader
and its ``surfacematerial``, built and written with the ``materialx`` package (pip ``materialx``).

A Lambertian model maps exactly (``base`` 1, ``base_color`` = albedo, ``specular`` 0,
``diffuse_roughness`` 0). Every other model goes through the glTF BRDF fitted to it
(:mod:`matfit.export._gltf`), whose parameters standard_surface shares: ``base_color``,
``metalness``, ``specular``, ``specular_color``, ``specular_roughness = sqrt(alpha)``,
``specular_IOR``, ``coat``, ``coat_roughness``, ``coat_IOR = 1.5``, for a thin film
``thin_film_thickness`` (nm) and ``thin_film_IOR``, for an anisotropic lobe
``specular_anisotropy`` and ``specular_rotation`` (:func:`anisotropic_roughness`; OpenPBR:
``specular_roughness_anisotropy``, its rotation left to the tangent), and for a :class:`~matfit.models.Sheen`
``sheen`` 1, ``sheen_color``, ``sheen_roughness = sqrt(alpha)`` (OpenPBR: ``fuzz_*``). standard_surface layers its
lobes with its own energy-conserving albedo scaling and its metal Fresnel from the artistic
(F0, edge colour) parametrization, so those mappings are approximate; the fidelity reported is
that of the glTF BRDF.
"""

from __future__ import annotations

import numpy as np

from ..errors import MatfitError
from ..models import GltfPBR, Lambert, Sheen
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
    """A MaterialX document holding the standard data libraries (for validating documents)."""
    mx = _mx()
    lib = mx.createDocument()
    mx.loadLibraries(mx.getDefaultDataLibraryFolders(), mx.getDefaultDataSearchPath(), lib)
    return lib


#: The inputs of each surface shader the exporter writes: matfit's name -> the shader's name, and
#: the thin film's thickness unit (per nm).
SURFACES = {
    "standard_surface": dict(base="base", base_color="base_color", diffuse_roughness="diffuse_roughness",
                             metalness="metalness", specular="specular", specular_color="specular_color",
                             specular_roughness="specular_roughness", specular_ior="specular_IOR", coat="coat",
                             coat_roughness="coat_roughness", coat_ior="coat_IOR", thin_film_weight=None,
                             thin_film_thickness="thin_film_thickness", thin_film_ior="thin_film_IOR", per_nm=1.0,
                             sheen="sheen", sheen_color="sheen_color", sheen_roughness="sheen_roughness",
                             specular_anisotropy="specular_anisotropy", specular_rotation="specular_rotation"),
    "open_pbr_surface": dict(base="base_weight", base_color="base_color", diffuse_roughness="base_diffuse_roughness",
                             metalness="base_metalness", specular="specular_weight", specular_color="specular_color",
                             specular_roughness="specular_roughness", specular_ior="specular_ior", coat="coat_weight",
                             coat_roughness="coat_roughness", coat_ior="coat_ior", thin_film_weight="thin_film_weight",
                             thin_film_thickness="thin_film_thickness", thin_film_ior="thin_film_ior", per_nm=1e-3,
                             sheen="fuzz_weight", sheen_color="fuzz_color", sheen_roughness="fuzz_roughness",
                             specular_anisotropy="specular_roughness_anisotropy", specular_rotation=None),
}


def anisotropic_roughness(surface, alpha_t, alpha_b):
    """The ``(specular_roughness, anisotropy)`` of ``surface`` whose lobe has GGX widths
    ``alpha_t`` along the tangent and ``alpha_b <= alpha_t`` across it: standard_surface's
    ``alpha_t = r^2 / sqrt(1 - a)``, ``alpha_b = r^2 sqrt(1 - a)`` (MaterialX's
    ``mx_roughness_anisotropy``); OpenPBR's ``alpha_t = r^2 sqrt(2 / (1 + (1 - a)^2))``,
    ``alpha_b = (1 - a) alpha_t``.

    Parameters
    ----------
    surface : {"standard_surface", "open_pbr_surface"}
    alpha_t, alpha_b : float

    Returns
    -------
    tuple of float
    """
    a = 1.0 - alpha_b / alpha_t
    if surface == "standard_surface":
        return float((alpha_t * alpha_b) ** 0.25), float(a)
    return float(np.sqrt(alpha_t / np.sqrt(2.0 / (1.0 + (1.0 - a) ** 2)))), float(a)



def _surface_document(model, surface, owner, fmt):
    """The MaterialX document of ``model`` as a ``surface`` shader (a key of :data:`SURFACES`)."""
    check_model(owner, model)
    mx = _mx()
    names = SURFACES[surface]
    doc = mx.createDocument()
    ss = doc.addNode(surface, "matfit_shader", "surfaceshader")
    mapping, notes, fid = [], [], None

    def put(key, value, source, exact, note=""):
        v = plain_numbers(np.asarray(value))
        if isinstance(v, list):
            ss.setInputValue(names[key], mx.Color3(*v))
        else:
            ss.setInputValue(names[key], float(v))
        mapping.append(ParamMapping(names[key], v, source, exact, note))

    # a Sheen: the shader's sheen (OpenPBR: fuzz) over its base's mapping
    sheen = model if isinstance(model, Sheen) else None
    inner = model.base if sheen else model
    if isinstance(inner, Lambert):
        put("base", 1.0, "1", True)
        put("base_color", rgb(owner, inner.reflectance), "albedo", True)
        put("diffuse_roughness", 0.0, "0 (Lambert)", True)
        put("specular", 0.0, "0 (no specular layer)", True)
        t = model
    else:
        # the glTF stand-in of the whole model (a Sheen's: the sheen over its base's stand-in,
        # its fidelity measured whole); the shader's base inputs read the glTF BRDF
        t, _, fid, notes = gltf_target(model)
        g = t.base if sheen else t
        note = f"{surface}'s layering and metal Fresnel differ from the glTF BRDF fitted to the model"
        if isinstance(inner, GltfPBR):
            note = f"{surface}'s layering and metal Fresnel differ from the glTF BRDF"
        put("base", 1.0, "1", False, note)
        put("base_color", rgb(owner, g.base_color), "base_color", False, note)
        put("metalness", g.metallic, "metallic", False, note)
        put("specular", g.specular, "specular", False, note)
        put("specular_color", rgb(owner, g.specular_color), "specular_color", False, note)
        if g.has_anisotropy and float(np.asarray(g.anisotropy)) > 0:
            a_t, a_b = (float(np.asarray(w)) for w in g.anisotropic_widths())
            r, a = anisotropic_roughness(surface, a_t, a_b)
            put("specular_roughness", r, "from alpha_t, alpha_b (anisotropic_roughness)", False, note)
            put("specular_anisotropy", a, "1 - alpha_b / alpha_t", False, note)
            turn = float(np.asarray(g.anisotropy_rotation))
            if names["specular_rotation"]:
                put("specular_rotation", np.mod(turn / (2 * np.pi), 1.0), "anisotropy_rotation / 2 pi (turns)", False,
                    note)
            else:
                notes = list(notes) + [f"{surface} has no rotation input: turn its geometry_tangent by "
                                       f"{turn:.4f} rad about the normal for the wide axis"]
        else:
            put("specular_roughness", np.sqrt(np.asarray(g.alpha, float)), "sqrt(alpha)", False, note)
        put("specular_ior", g.ior, "ior", False, note)
        if float(np.asarray(g.clearcoat)) > 0:
            put("coat", g.clearcoat, "clearcoat", False, note)
            put("coat_roughness", np.sqrt(np.asarray(g.clearcoat_alpha, float)), "sqrt(clearcoat_alpha)", False, note)
            put("coat_ior", 1.5, "1.5", False, note)
        if float(np.asarray(g.iridescence)) > 0:
            # the shader's thin film over the specular layer: the glTF iridescence's film
            if names["thin_film_weight"]:
                put("thin_film_weight", g.iridescence, "iridescence", False, note)
            unit = "nm" if names["per_nm"] == 1.0 else "um"
            put("thin_film_thickness", np.asarray(g.iridescence_thickness) * names["per_nm"],
                f"iridescence_thickness ({unit})", False, note)
            put("thin_film_ior", g.iridescence_ior, "iridescence_ior", False, note)
        notes = list(notes) + [f"fidelity measured on the glTF BRDF that {surface} approximates"] if fid else notes
    if sheen is not None:
        note = (f"{surface}'s sheen is its own lobe (standard_surface: Estevez & Kulla's; OpenPBR's fuzz: an LTC "
                "fit, Zeltner et al. 2022), layered with its own albedo scaling")
        put("sheen", 1.0, "1", False, note)
        put("sheen_color", rgb(owner, sheen.color), "sheen color", False, note)
        put("sheen_roughness", np.sqrt(np.asarray(sheen.alpha, float)), "sqrt(sheen alpha)", False, note)
    doc.addMaterialNode("matfit", ss)
    lib = standard_library()
    vdoc = mx.createDocument()
    vdoc.copyContentFrom(doc)
    vdoc.importLibrary(lib)
    ok, msg = vdoc.validate()
    if not ok:  # a bug of this exporter, never the user's: say so
        raise MatfitError(f"{owner}: the document failed MaterialX validation: {msg}")
    return ExportResult(fmt, mx.writeToXmlString(doc), mapping, t, fid, notes)


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
    return _surface_document(model, "standard_surface", "to_materialx", "mtlx")


def to_openpbr(model) -> ExportResult:
    """A MaterialX document (text) with the ``open_pbr_surface`` (OpenPBR 1.1) of ``model``.

    The same mapping as :func:`to_materialx`, to OpenPBR's names (``base_weight``,
    ``base_metalness``, ``specular_weight``, ``specular_ior``, ``coat_weight``, ...); a thin film
    becomes ``thin_film_weight``, ``thin_film_thickness`` (in micrometres) and ``thin_film_ior``.

    Parameters
    ----------
    model : matfit.models.AbstractBSDF
        As for :func:`to_materialx` (which names the errors raised).

    Returns
    -------
    ExportResult
        ``content`` is the ``.mtlx`` XML text, validated against MaterialX's libraries.
    """
    return _surface_document(model, "open_pbr_surface", "to_openpbr", "openpbr")
