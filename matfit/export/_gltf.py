"""glTF 2.0: a material of the metallic-roughness model with KHR_materials_ior,
KHR_materials_specular, KHR_materials_clearcoat, KHR_materials_iridescence and
KHR_materials_anisotropy.

A glTF material is :class:`~matfit.models.GltfPBR`. A Lambertian model maps exactly (metallic 0,
specular factor 0); a :class:`~matfit.models.GltfPBR` maps exactly; every other model is
approximated by fitting a GltfPBR to it over the hemisphere (:func:`~matfit.export.fit_target`):
a conductor by a metal (F0 colour and roughness: Schlick's Fresnel cannot follow a complex
index), a plastic by a dielectric (base colour, roughness, ior), a coated metal by a metal under
the clear coat, a model with a thin-film lobe (:class:`~matfit.models.MultiLobe`) by an
iridescent dielectric (base colour, roughness, ior, the film's index and thickness, started from
the film lobe's), an anisotropic conductor turned by an angle (:class:`~matfit.models.Rotated`)
by an anisotropic metal (F0 colour, roughness, ``anisotropyStrength`` and ``anisotropyRotation``,
started from ``alpha_b`` the narrow width and ``alpha_t = alpha_b + (1 - alpha_b) strength^2``
the wide one, rotated to the wide axis), anything else by the general metallic-roughness
material. A
:class:`~matfit.models.Sheen` is KHR_materials_sheen over its base's glTF material: the sheen
maps exactly (colour, ``sheenRoughnessFactor = sqrt(alpha)``; approximately below alpha ~ 0.06,
where matfit normalizes the lobe and the extension does not), the base as it does alone.

Roughness: ``roughnessFactor = sqrt(alpha)`` (glTF squares it), likewise for the clear coat.
"""

from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np

from ..errors import ParameterError
from ..fresnel import FILM_ETA_RANGE, FILM_THICKNESS_RANGE, fresnel_conductor
from ..models import GltfPBR, Lambert, Layered, MultiLobe, Plastic, Rotated, RoughConductor, Sheen, SmoothConductor
from ._model_file import plain_numbers
from ._fidelity import fit_target, measure
from ._result import ExportResult, ParamMapping, check_model, rgb

EXTENSIONS = ("KHR_materials_ior", "KHR_materials_specular", "KHR_materials_clearcoat", "KHR_materials_iridescence",
              "KHR_materials_sheen", "KHR_materials_anisotropy")


def _rgb(x):
    return rgb("to_gltf", x)


def _f(x):
    return plain_numbers(np.asarray(x).ravel()[0])


@functools.lru_cache(maxsize=None)
def families():
    """The GltfPBR families the exporter fits: ``metal``, ``dielectric``, ``coated_metal``, ``general``."""
    from ..fitting import Family, Param

    col = Param("base_color", 0.0, 1.0, True, "base colour")
    a = Param("alpha", 2e-3, 1.0, False, "GGX width (roughnessFactor^2)")
    return {
        "metal": Family("gltf_metal", (col, a), lambda p, C: GltfPBR(p["base_color"], 1.0, p["alpha"]),
                        "glTF metal"),
        "dielectric": Family("gltf_dielectric", (col, a, Param("ior", 1.05, 3.0, False, "index of refraction")),
                             lambda p, C: GltfPBR(p["base_color"], 0.0, p["alpha"], p["ior"]), "glTF dielectric"),
        "coated_metal": Family("gltf_coated_metal", (col, a, Param("clearcoat_alpha", 2e-3, 1.0, False, "coat width")),
                               lambda p, C: GltfPBR(p["base_color"], 1.0, p["alpha"], clearcoat=1.0,
                                                    clearcoat_alpha=p["clearcoat_alpha"]), "glTF metal under a clear coat"),
        "iridescent": Family("gltf_iridescent", (col, a, Param("ior", 1.05, 3.0, False, "index under the film"),
                                                 Param("iridescence_ior", *FILM_ETA_RANGE, False, "film index"),
                                                 Param("iridescence_thickness", *FILM_THICKNESS_RANGE, False, "film (nm)")),
                             lambda p, C: GltfPBR(p["base_color"], 0.0, p["alpha"], p["ior"], iridescence=1.0,
                                                  iridescence_ior=p["iridescence_ior"],
                                                  iridescence_thickness=p["iridescence_thickness"]),
                             "glTF iridescent dielectric"),
        "anisotropic_metal": Family(
            "gltf_anisotropic_metal", (col, a, Param("anisotropy", 0.0, 1.0, False, "anisotropyStrength"),
                                       Param("anisotropy_rotation", -np.pi, np.pi, False, "anisotropyRotation (rad)")),
            lambda p, C: GltfPBR(p["base_color"], 1.0, p["alpha"], anisotropy=p["anisotropy"],
                                 anisotropy_rotation=p["anisotropy_rotation"]), "glTF anisotropic metal"),
        "general": Family("gltf_general", (col, Param("metallic", 0.0, 1.0, False, "metallic"), a),
                          lambda p, C: GltfPBR(p["base_color"], p["metallic"], p["alpha"]), "glTF metallic-roughness"),
    }


def _f0(eta, k):
    return np.clip(np.asarray(fresnel_conductor(jnp.ones(()), jnp.asarray(eta), jnp.asarray(k))), 0.01, 0.99)


def _anisotropic_start(alpha, alpha_y, angle):
    """glTF's alpha (the narrow width), strength and rotation (of the wide axis) of GGX widths
    ``alpha`` along the lobe's x axis at azimuth ``angle`` and ``alpha_y`` across it."""
    a_t, a_b, rot = (alpha, alpha_y, angle) if alpha >= alpha_y else (alpha_y, alpha, angle + np.pi / 2)
    a_b = float(np.clip(a_b, 3e-3, 0.99))
    strength = float(np.sqrt(np.clip((min(a_t, 1.0) - a_b) / (1 - a_b), 1e-4, 0.999)))
    return a_b, strength, float(np.angle(np.exp(1j * rot)))  # rotation in (-pi, pi]


def _plan(model):
    fam = families()
    if isinstance(model, Rotated) and isinstance(model.base, RoughConductor):
        c = model.base
        a_b, s, r = _anisotropic_start(_f(c.alpha), _f(c.alpha if c.alpha_y is None else c.alpha_y), _f(model.angle))
        return fam["anisotropic_metal"], {"base_color": _f0(c.eta, c.k), "alpha": a_b, "anisotropy": s,
                                          "anisotropy_rotation": r}
    if isinstance(model, RoughConductor):
        return fam["metal"], {"base_color": _f0(model.eta, model.k), "alpha": float(np.clip(np.asarray(model.alpha), 3e-3, 0.99))}
    if isinstance(model, Plastic):
        a = float(np.clip(np.asarray(getattr(model.coat, "alpha", 0.003)), 3e-3, 0.99))
        return fam["dielectric"], {"base_color": np.clip(np.asarray(model.reflectance), 0.01, 0.99), "alpha": a,
                                   "ior": float(np.clip(np.asarray(model.eta), 1.06, 2.9))}
    if isinstance(model, Layered) and isinstance(model.base, RoughConductor):
        eta_c = float(np.asarray(model.coat.eta))
        a_c = float(np.clip(np.asarray(getattr(model.coat, "alpha", 0.003)), 3e-3, 0.99))
        return fam["coated_metal"], {"base_color": _f0(np.asarray(model.base.eta) * eta_c, np.asarray(model.base.k) * eta_c),
                                     "alpha": float(np.clip(np.asarray(model.base.alpha), 3e-3, 0.99)),
                                     "clearcoat_alpha": a_c}
    films = [lb for lb in model.lobes if lb.fresnel == "thin_film"] if isinstance(model, MultiLobe) else []
    if films:
        lb = films[0]
        return fam["iridescent"], {"base_color": np.clip(np.broadcast_to(np.asarray(model.diffuse), (3,)), 0.01, 0.99),
                                   "alpha": float(np.clip(_f(lb.alpha), 3e-3, 0.99)),
                                   "ior": float(np.clip(_f(lb.eta), 1.06, 2.9)),
                                   "iridescence_ior": float(np.clip(_f(lb.film_eta), *FILM_ETA_RANGE)),
                                   "iridescence_thickness": float(np.clip(_f(lb.thickness), *FILM_THICKNESS_RANGE))}
    if model.has_delta_lobe or model.transmits:
        return None
    return fam["general"], None


def gltf_parameters(m):
    """The glTF material dict of a :class:`~matfit.models.GltfPBR`, or of a
    :class:`~matfit.models.Sheen` over one (KHR_materials_sheen), exact."""
    if isinstance(m, Sheen):
        mat = gltf_parameters(m.base)
        mat["extensions"]["KHR_materials_sheen"] = {"sheenColorFactor": _rgb(m.color),
                                                    "sheenRoughnessFactor": float(np.sqrt(_f(m.alpha)))}
        return mat
    pbr = {"baseColorFactor": _rgb(m.base_color) + [1.0], "metallicFactor": _f(m.metallic),
           "roughnessFactor": float(np.sqrt(_f(m.alpha)))}
    ext = {"KHR_materials_ior": {"ior": _f(m.ior)},
           "KHR_materials_specular": {"specularFactor": _f(m.specular), "specularColorFactor": _rgb(m.specular_color)}}
    if _f(m.clearcoat) > 0:
        ext["KHR_materials_clearcoat"] = {"clearcoatFactor": _f(m.clearcoat),
                                          "clearcoatRoughnessFactor": float(np.sqrt(_f(m.clearcoat_alpha)))}
    if _f(m.iridescence) > 0:
        d = _f(m.iridescence_thickness)
        ext["KHR_materials_iridescence"] = {"iridescenceFactor": _f(m.iridescence), "iridescenceIor": _f(m.iridescence_ior),
                                            "iridescenceThicknessMinimum": d, "iridescenceThicknessMaximum": d}
    if m.has_anisotropy and _f(m.anisotropy) > 0:
        ext["KHR_materials_anisotropy"] = {"anisotropyStrength": _f(m.anisotropy),
                                           "anisotropyRotation": _f(m.anisotropy_rotation)}
    return {"name": "matfit", "pbrMetallicRoughness": pbr, "extensions": ext}


def _mapping(mat, source, exact, note=""):
    pbr, ext = mat["pbrMetallicRoughness"], mat["extensions"]
    out = [ParamMapping("baseColorFactor", pbr["baseColorFactor"], source.get("base", "base_color"), exact, note),
           ParamMapping("metallicFactor", pbr["metallicFactor"], source.get("metallic", "metallic"), exact, note),
           ParamMapping("roughnessFactor", pbr["roughnessFactor"], source.get("alpha", "sqrt(alpha)"), exact, note),
           ParamMapping("KHR_materials_ior.ior", ext["KHR_materials_ior"]["ior"], source.get("ior", "ior"), exact, note),
           ParamMapping("KHR_materials_specular.specularFactor", ext["KHR_materials_specular"]["specularFactor"],
                        source.get("specular", "specular"), exact, note)]
    if "KHR_materials_clearcoat" in ext:
        c = ext["KHR_materials_clearcoat"]
        out += [ParamMapping("KHR_materials_clearcoat.clearcoatFactor", c["clearcoatFactor"], "clearcoat", exact, note),
                ParamMapping("KHR_materials_clearcoat.clearcoatRoughnessFactor", c["clearcoatRoughnessFactor"],
                             "sqrt(clearcoat_alpha)", exact, note)]
    if "KHR_materials_iridescence" in ext:
        c = ext["KHR_materials_iridescence"]
        out += [ParamMapping("KHR_materials_iridescence.iridescenceFactor", c["iridescenceFactor"], "iridescence", exact,
                             note),
                ParamMapping("KHR_materials_iridescence.iridescenceIor", c["iridescenceIor"],
                             source.get("iridescence_ior", "iridescence_ior"), exact, note),
                ParamMapping("KHR_materials_iridescence.iridescenceThicknessMaximum", c["iridescenceThicknessMaximum"],
                             source.get("iridescence_thickness", "iridescence_thickness (nm; minimum the same)"),
                             exact, note)]
    if "KHR_materials_anisotropy" in ext:
        c = ext["KHR_materials_anisotropy"]
        out += [ParamMapping("KHR_materials_anisotropy.anisotropyStrength", c["anisotropyStrength"],
                             source.get("anisotropy", "anisotropy"), exact, note),
                ParamMapping("KHR_materials_anisotropy.anisotropyRotation", c["anisotropyRotation"],
                             source.get("anisotropy_rotation", "anisotropy_rotation (rad)"), exact, note)]
    if "KHR_materials_sheen" in ext:
        c = ext["KHR_materials_sheen"]
        out += [ParamMapping("KHR_materials_sheen.sheenColorFactor", c["sheenColorFactor"], "sheen color", exact, note),
                ParamMapping("KHR_materials_sheen.sheenRoughnessFactor", c["sheenRoughnessFactor"], "sqrt(sheen alpha)",
                             exact, note)]
    return out


def gltf_target(model):
    """``(GltfPBR or Sheen over one, exact, fidelity, notes)``: the glTF BRDF that stands for ``model``."""
    if isinstance(model, GltfPBR):
        return model, True, None, []
    if isinstance(model, Sheen):
        # KHR_materials_sheen is this model over the glTF BRDF: the sheen maps exactly, the base
        # as the base does
        base, exact, _, notes = gltf_target(model.base)
        # the extension's own formula (no normalization): what a viewer renders, measured below
        t = Sheen(base, model.color, model.alpha, normalize=False)
        if model.normalized():
            # the extension's formula does not normalize the lobe (it creates energy at grazing there)
            exact = False
            notes = notes + ["a sheen narrower than alpha ~ 0.06: KHR_materials_sheen's lobe reflects more than it "
                             "receives at grazing there, where matfit's is normalized; the sheen maps approximately"]
        return t, exact, None if exact else measure(model, t), notes
    if isinstance(model, Lambert):
        return GltfPBR(_rgb(model.reflectance), 0.0, 1.0, specular=0.0), True, None, []
    if isinstance(model, SmoothConductor):
        t = GltfPBR(_f0(model.eta, model.k), 1.0, 1e-4)
        return t, False, None, ["a mirror: baseColor is the normal-incidence Fresnel reflectance (Schlick "
                                "approximates the conductor's curve); not measured (a delta lobe)"]
    plan = _plan(model)
    if plan is None:
        why = "has a Dirac lobe" if model.has_delta_lobe else "transmits light"
        raise ParameterError(f"to_gltf: {type(model).__name__} {why}, which the glTF metallic-roughness model "
                             "cannot represent; exports Lambert, GltfPBR, conductors, Plastic, Layered over a "
                             "conductor and blends of rough reflective models")
    fam, init = plan
    t = fit_target(model, fam, init=init, channels=3)
    fid = measure(model, t)
    return t, False, fid, [f"{type(model).__name__} approximated by the glTF BRDF fitted to it ({fam.doc})"]


def to_gltf(model) -> ExportResult:
    """A glTF 2.0 document holding one material for ``model``.

    Parameters
    ----------
    model : matfit.models.AbstractBSDF
        Lambert and GltfPBR map exactly; conductors, Plastic, Layered over a conductor and
        blends of rough reflective models are approximated by the glTF BRDF fitted to them.

    Returns
    -------
    ExportResult
        ``content`` is the glTF JSON as a dict (``pygltflib.GLTF2().from_dict`` reads it);
        ``model`` is the glTF BRDF as a :class:`~matfit.models.GltfPBR`.

    Raises
    ------
    ParameterError
        ``model`` is not a matfit model, has a Dirac lobe or transmits light.

    Examples
    --------
    >>> from matfit.models import Lambert
    >>> r = to_gltf(Lambert([0.5, 0.4, 0.3]))
    >>> r.content["materials"][0]["pbrMetallicRoughness"]["baseColorFactor"], r.exact
    ([0.5, 0.4, 0.3, 1.0], True)
    """
    check_model("to_gltf", model)
    t, exact, fid, notes = gltf_target(model)
    mat = gltf_parameters(t)
    used = sorted(mat["extensions"])
    doc = {"asset": {"version": "2.0", "generator": "matfit"}, "extensionsUsed": used, "materials": [mat]}
    lambert = isinstance(model, Lambert) or (isinstance(model, Sheen) and isinstance(model.base, Lambert))
    src = {"base": "albedo", "metallic": "0", "specular": "0 (no specular layer)"} if lambert else (
        {} if exact else {k: "fitted" for k in ("base", "metallic", "alpha", "ior", "specular", "iridescence_ior",
                                                "iridescence_thickness", "anisotropy", "anisotropy_rotation")})
    mapping = _mapping(mat, src, exact, "" if exact else "fitted to the model over the hemisphere")
    return ExportResult("gltf", doc, mapping, t, fid, notes)
