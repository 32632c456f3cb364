"""Writing parameter maps: 16-bit PNG and float EXR per parameter, and a textured glTF material.

Layout of the output folder (``maps.json`` indexes it):

================================  =====================================================
``<name>.exr``                    the map in float32 (RGB for per-channel parameters, Y else)
``<name>.png``                    16-bit linear PNG of ``value / scale`` (``scale`` in maps.json:
                                  1 for parameters in [0, 1], else the parameter's upper bound)
``<name>_stderr.exr``             its standard errors
``fitted.png``, ``converged.png``  8-bit masks (255: yes)
``rel_rmse.exr``                  relative RMS residual per texel
``material.gltf`` + textures      glTF 2.0: a unit quad with the material (``baseColorTexture``
                                  sRGB, ``metallicRoughnessTexture`` with roughness = sqrt(alpha)
                                  in G and metallic in B, KHR_materials_specular for F0)
================================  =====================================================

Texels that were not fitted hold 0 in the images (``fitted.png`` tells which).

glTF per family (texture values per texel, factors per map):

- ``diffuse_specular``: base colour = albedo, metallic 0, roughness = sqrt(alpha),
  ``KHR_materials_ior`` ior chosen so that its F0 is the map's largest F0 and
  ``specularColorTexture`` = F0 / F0(ior). Approximate: glTF weights the diffuse part by
  ``1 - max(F)``, the model does not.
- ``conductor``, ``conductor_beckmann``: base colour = the normal-incidence Fresnel reflectance of
  (eta, k), metallic 1, roughness = sqrt(alpha). Approximate: Schlick's curve instead of the
  complex-index Fresnel.
- ``lambert``: base colour = albedo, metallic 0, specular factor 0. Exact.
- ``plastic``: base colour = albedo, metallic 0, roughness = sqrt(alpha), ior = the map's median
  eta (glTF has no ior texture). Approximate.
"""

from __future__ import annotations

import base64
import json
from pathlib import Path

import numpy as np

from ..errors import ParameterError
from ..fitting import get_family
from ..render import srgb_encode
from ._fit_map import MapResult
from ._images import write_exr, write_png

FORMATS = ("png", "exr", "gltf")


def _clean(a):
    return np.where(np.isfinite(a), a, 0.0).astype(np.float32)


def _quad_buffer():
    """A unit quad in the xy plane facing +z with texture coordinates (glTF's v runs down)."""
    pos = np.array([[-0.5, -0.5, 0], [0.5, -0.5, 0], [0.5, 0.5, 0], [-0.5, 0.5, 0]], np.float32)
    nrm = np.tile(np.array([0, 0, 1], np.float32), (4, 1))
    uv = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], np.float32)
    idx = np.array([0, 1, 2, 0, 2, 3], np.uint16)
    blobs = [pos.tobytes(), nrm.tobytes(), uv.tobytes(), idx.tobytes()]
    return blobs, pos


def _gltf_document(material, textures):
    blobs, pos = _quad_buffer()
    data = b"".join(blobs)
    offsets = np.cumsum([0] + [len(b) for b in blobs[:-1]]).tolist()
    views = [{"buffer": 0, "byteOffset": o, "byteLength": len(b), "target": 34963 if i == 3 else 34962}
             for i, (o, b) in enumerate(zip(offsets, blobs))]
    accessors = [
        {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": pos.min(0).tolist(),
         "max": pos.max(0).tolist()},
        {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC3"},
        {"bufferView": 2, "componentType": 5126, "count": 4, "type": "VEC2"},
        {"bufferView": 3, "componentType": 5123, "count": 6, "type": "SCALAR"},
    ]
    return {
        "asset": {"version": "2.0", "generator": "matfit fit-map"},
        "extensionsUsed": sorted(material.get("extensions", {})),
        "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0, "name": "sample"}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2}, "indices": 3,
                                     "material": 0}]}],
        "buffers": [{"byteLength": len(data),
                     "uri": "data:application/octet-stream;base64," + base64.b64encode(data).decode()}],
        "bufferViews": views, "accessors": accessors,
        "samplers": [{"magFilter": 9729, "minFilter": 9987, "wrapS": 33071, "wrapT": 33071}],
        "images": [{"uri": name} for name in textures],
        "textures": [{"sampler": 0, "source": i} for i in range(len(textures))],
        "materials": [material],
    }


def gltf_maps(result: MapResult):
    """The glTF texture images and material of a map (the module doc's mapping per family).

    Parameters
    ----------
    result : MapResult
        A map of a family in :data:`GLTF_FAMILIES` (else a ParameterError).

    Returns
    -------
    images : dict
        File name -> (H, W, 3) array in [0, 1], encoded as glTF reads it (sRGB for colour).
    material : dict
        The glTF material, with texture indices in the order of ``images``.
    notes : list of str
        What is approximate.
    """
    fam = result.family
    if fam not in GLTF_MAPPINGS:
        raise ParameterError(f"glTF maps: family {fam!r} has no glTF texture mapping; families with one: "
                             f"{list(GLTF_FAMILIES)} (its PNG and EXR maps are written all the same)")
    return GLTF_MAPPINGS[fam](result.params, result.fitted, f"matfit {fam} map")


def _textured(name, base, fitted, metallic=None, alpha=None):
    """``(images, material, notes)`` of a metallic-roughness material: the sRGB base colour texture and,
    given ``alpha``, the metallic-roughness texture (roughness = sqrt(alpha) in G, ``metallic`` in B).
    """
    base = np.where(fitted[..., None], np.clip(base, 0, 1), 0)
    images = {"base_color.png": srgb_encode(base)}
    pbr = {"baseColorFactor": [1.0, 1.0, 1.0, 1.0], "baseColorTexture": {"index": 0}, "metallicFactor": 0.0}
    material = {"name": name, "pbrMetallicRoughness": pbr, "extensions": {}}
    notes = []
    if alpha is not None:
        a = _clean(alpha)
        rough = np.where(fitted, np.sqrt(np.clip(a, 0, 1)), 1.0)
        images["metallic_roughness.png"] = np.stack([np.zeros_like(rough), rough, metallic], axis=-1)
        pbr.update({"metallicFactor": 1.0, "roughnessFactor": 1.0, "metallicRoughnessTexture": {"index": 1}})
        if np.any(a[fitted] > 1):
            notes.append("alpha > 1 clipped to roughness 1")
    return images, material, notes


def _gltf_lambert(p, fitted, name):
    images, material, notes = _textured(name, _clean(p["albedo"]), fitted)
    material["pbrMetallicRoughness"]["roughnessFactor"] = 1.0
    material["extensions"]["KHR_materials_specular"] = {"specularFactor": 0.0}
    return images, material, notes


def _gltf_conductor(p, fitted, name):
    import jax.numpy as jnp

    from ..fresnel import fresnel_conductor

    base = np.asarray(fresnel_conductor(jnp.ones(()), jnp.asarray(_clean(p["eta"])), jnp.asarray(_clean(p["k"]))))
    images, material, notes = _textured(name, base, fitted, np.ones(fitted.shape), p["alpha"])
    notes.append("base colour = normal-incidence Fresnel reflectance of (eta, k); glTF's Schlick curve replaces "
                 "the complex-index Fresnel")
    return images, material, notes


def _gltf_diffuse_specular(p, fitted, name):
    images, material, notes = _textured(name, _clean(p["albedo"]), fitted, np.zeros(fitted.shape), p["alpha"])
    f0 = np.where(fitted[..., None], np.clip(_clean(p["f0"]), 0, 1), 0)
    top = float(np.clip(f0.max(), 1e-4, 0.98))
    s = np.sqrt(top)
    images["specular_color.png"] = srgb_encode(np.clip(f0 / top, 0, 1))
    material["extensions"]["KHR_materials_ior"] = {"ior": float((1 + s) / (1 - s))}
    material["extensions"]["KHR_materials_specular"] = {"specularFactor": 1.0, "specularColorFactor": [1.0, 1.0, 1.0],
                                                        "specularColorTexture": {"index": 2}}
    notes.append("glTF weights the diffuse part by 1 - max(F); the fitted model adds it unweighted")
    return images, material, notes


def _gltf_plastic(p, fitted, name):
    images, material, notes = _textured(name, _clean(p["albedo"]), fitted, np.zeros(fitted.shape), p["alpha"])
    eta = float(np.nanmedian(p["eta"][fitted])) if fitted.any() else 1.5
    material["extensions"]["KHR_materials_ior"] = {"ior": eta}
    notes.append(f"ior = the map's median eta {eta:.4g} (glTF has no ior texture); the coat's Fresnel weighting of "
                 "the base is glTF's 1 - max(F)")
    return images, material, notes


#: glTF texture mapping per family: ``mapping(params, fitted, name) -> (images, material, notes)``
#: (the table in the module doc).
GLTF_MAPPINGS = {
    "diffuse_specular": _gltf_diffuse_specular,
    "conductor": _gltf_conductor,
    "conductor_beckmann": _gltf_conductor,
    "lambert": _gltf_lambert,
    "plastic": _gltf_plastic,
}
GLTF_FAMILIES = tuple(GLTF_MAPPINGS)


def write_maps(result: MapResult, folder, formats=FORMATS):
    """Write the maps of ``result`` into ``folder`` (created; the files: the module doc).

    Parameters
    ----------
    result : MapResult
        What :func:`fit_map` returned.
    folder : str or Path
    formats : sequence of {"png", "exr", "gltf"}, default FORMATS
        The files to write (``fitted.png`` and ``converged.png`` always are); an unknown format,
        or ``"gltf"`` for a family without a glTF mapping, raises ParameterError.

    Returns
    -------
    dict
        The ``maps.json`` index as written.

    Examples
    --------
    >>> import tempfile, numpy as np
    >>> from matfit.maps import fit_map, write_maps
    >>> wo = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, 0.6, 0.8]]); wi = wo[[1, 2, 0]]
    >>> result = fit_map(wo, wi, np.full((2, 2, 3, 3), 0.1), model="lambert")
    >>> with tempfile.TemporaryDirectory() as d:
    ...     index = write_maps(result, d)
    >>> index["params"]["albedo"]["exr"], index["gltf"], index["texels_fitted"]
    ('albedo.exr', 'material.gltf', 4)
    """
    if isinstance(formats, str):
        formats = (formats,)
    bad = [f for f in formats if f not in FORMATS]
    if bad:
        raise ParameterError(f"write_maps: unknown format(s) {bad}; expected some of {list(FORMATS)}")
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    fam = get_family(result.family)
    index = {"format": "matfit-maps", "version": 1, "family": result.family, "shape": list(result.shape),
             "labels": result.labels, "texels_fitted": int(result.fitted.sum()),
             "converged": float(result.converged[result.fitted].mean()) if result.fitted.any() else 0.0,
             "params": {}, "diagnostics": {}}
    for q in fam.params:
        v = _clean(result.params[q.name])
        entry = {"per_channel": q.per_channel, "range": [q.lower, q.upper if np.isfinite(q.upper) else None]}
        scale = 1.0 if (q.lower >= 0 and q.upper <= 1) else float(q.upper if np.isfinite(q.upper) else max(v.max(), 1))
        if "exr" in formats:
            write_exr(out / f"{q.name}.exr", v)
            entry["exr"] = f"{q.name}.exr"
            if q.name in result.stderr:
                write_exr(out / f"{q.name}_stderr.exr", _clean(result.stderr[q.name]))
                entry["stderr_exr"] = f"{q.name}_stderr.exr"
        if "png" in formats:
            write_png(out / f"{q.name}.png", np.clip(v / scale, 0, 1), bit_depth=16)
            entry.update(png=f"{q.name}.png", png_scale=scale, png_encoding="linear, value = code / 65535 * png_scale")
        index["params"][q.name] = entry
    write_png(out / "fitted.png", result.fitted.astype(float), bit_depth=8)
    write_png(out / "converged.png", (result.converged & result.fitted).astype(float), bit_depth=8)
    index["diagnostics"] = {"fitted": "fitted.png", "converged": "converged.png"}
    if "exr" in formats:
        write_exr(out / "rel_rmse.exr", _clean(result.rel_rmse))
        index["diagnostics"]["rel_rmse"] = "rel_rmse.exr"
    if "gltf" in formats:
        images, material, notes = gltf_maps(result)
        for name, img in images.items():
            write_png(out / name, img, bit_depth=8)
        (out / "material.gltf").write_text(json.dumps(_gltf_document(material, list(images)), indent=1))
        index["gltf"] = "material.gltf"
        index["gltf_notes"] = notes
    (out / "maps.json").write_text(json.dumps(index, indent=1))
    return index


def read_maps(folder):
    """Read a folder written by :func:`write_maps` back from its EXR maps.

    Parameters
    ----------
    folder : str or Path
        Holding ``maps.json`` (else a ParameterError, as for a parameter without its EXR map).

    Returns
    -------
    dict
        Parameter name -> float32 map, ``(H, W, C)`` per channel, else ``(H, W)``.
    """
    from ._images import read_image

    folder = Path(folder)
    path = folder / "maps.json"
    if not path.is_file():
        raise ParameterError(f"{path}: not found (a folder written by matfit fit-map has a maps.json)")
    index = json.loads(path.read_text())
    out = {}
    for name, e in index["params"].items():
        if "exr" not in e:
            raise ParameterError(f"{path}: parameter {name!r} has no EXR map (written without 'exr')")
        a = read_image(folder / e["exr"])[0]
        out[name] = a if e["per_channel"] else a[..., 0]
    return out

