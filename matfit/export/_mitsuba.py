"""Mitsuba 3: a ``mitsuba.load_dict`` dictionary, or the same material as scene XML.

=================  ===========================================================  ==========
matfit model       Mitsuba 3 plugin                                             mapping
=================  ===========================================================  ==========
Lambert            ``diffuse`` (reflectance)                                    exact
RoughConductor     ``roughconductor`` (alpha / alpha_u, alpha_v; eta, k)        exact (GGX, separable Smith);
                                                                                Beckmann approximate
SmoothConductor    ``conductor`` (eta, k)                                       exact
RoughDielectric    ``roughdielectric`` (alpha, int_ior = eta, ext_ior = 1)      exact (GGX)
SmoothDielectric   ``dielectric`` (int_ior = eta, ext_ior = 1)                  exact
Plastic            ``plastic`` / ``roughplastic`` (diffuse_reflectance, alpha,  approximate: Mitsuba's own
                   int_ior, nonlinear = true)                                   internal-reflectance terms
Blend              ``blendbsdf`` (weight; weight 0 is the first model)          exact when both parts are
MultiLobe          nested ``blendbsdf`` of ``diffuse`` and ``roughconductor``   exact for conductor and
                   lobes (``specular_reflectance`` = the lobe's weight over     dielectric (k = 0, eta > 1)
                   its blend probability)                                       lobes, GGX, separable masking,
                                                                                albedo + sum of weights <= 1;
                                                                                Schlick lobes: none
Layered, others    fitted: ``blendbsdf`` of two ``roughconductor`` lobes         approximate (fitted)
=================  ===========================================================  ==========

Roughness: Mitsuba's ``alpha`` is the distribution's own width, as matfit's (no remapping).
Colours: one channel is written as a float, three as ``{"type": "rgb"}`` (exact in Mitsuba's
RGB variants; spectral variants upsample the RGB values).
"""

from __future__ import annotations

import functools

import numpy as np

from ..models import (Blend, Lambert, Layered, MultiLobe, Plastic, RoughConductor, RoughDielectric, SmoothConductor,
                      SmoothDielectric)
from ._model_file import plain_numbers
from ._result import ParamMapping, rgb

_DISTRIBUTIONS = {"ggx": "ggx", "beckmann": "beckmann"}


def _num(x):
    a = np.asarray(x)
    return plain_numbers(a.ravel()[0] if a.size == 1 else a.ravel())


def _colour(x):
    v = _num(x)
    return v if isinstance(v, float) else {"type": "rgb", "value": rgb("to_mitsuba", v)}


def _alpha(d, m, where, mapping, exact=True, note=""):
    if m.distribution not in _DISTRIBUTIONS:
        return False
    d["distribution"] = _DISTRIBUTIONS[m.distribution]
    if m.distribution == "beckmann" and exact:
        exact, note = False, "Mitsuba's Beckmann masking is a rational approximation of Smith's (differences up to ~0.5 %)"
    if m.alpha_y is None:
        d["alpha"] = _num(m.alpha)
        mapping.append(ParamMapping(f"{where}alpha", d["alpha"], "alpha", exact, note))
    else:
        d["alpha_u"], d["alpha_v"] = _num(m.alpha), _num(m.alpha_y)
        mapping.append(ParamMapping(f"{where}alpha_u", d["alpha_u"], "alpha", exact, note))
        mapping.append(ParamMapping(f"{where}alpha_v", d["alpha_v"], "alpha_y", exact, note))
    return True


def exact_mitsuba(model, where=""):
    """``(dict, mapping)`` when Mitsuba has a plugin for ``model`` (exact or one-to-one), else None."""
    mp = []
    if isinstance(model, Lambert):
        d = {"type": "diffuse", "reflectance": _colour(model.reflectance)}
        mp.append(ParamMapping(f"{where}reflectance", _num(model.reflectance), "albedo", True))
        return d, mp
    if isinstance(model, RoughConductor):
        if model.masking != "separable":
            return None
        d = {"type": "roughconductor"}
        if not _alpha(d, model, where, mp):
            return None
        d.update(eta=_colour(model.eta), k=_colour(model.k), sample_visible=True)
        mp += [ParamMapping(f"{where}eta", _num(model.eta), "eta", True), ParamMapping(f"{where}k", _num(model.k), "k", True)]
        return d, mp
    if isinstance(model, SmoothConductor):
        d = {"type": "conductor", "eta": _colour(model.eta), "k": _colour(model.k)}
        mp += [ParamMapping(f"{where}eta", _num(model.eta), "eta", True), ParamMapping(f"{where}k", _num(model.k), "k", True)]
        return d, mp
    if isinstance(model, (RoughDielectric, SmoothDielectric)):
        eta = _num(model.eta)
        if not isinstance(eta, float):
            return None
        d = {"type": "dielectric", "int_ior": eta, "ext_ior": 1.0}
        if isinstance(model, RoughDielectric):
            if model.masking != "separable":
                return None
            d["type"] = "roughdielectric"
            if not _alpha(d, model, where, mp):
                return None
            d["sample_visible"] = True
        mp.append(ParamMapping(f"{where}int_ior", eta, "eta (ext_ior = 1)", True))
        return d, mp
    if isinstance(model, Plastic):
        coat = model.coat
        eta = _num(coat.eta)
        note = ("Mitsuba's plastic computes the internal reflectance with its own approximation; the "
                "diffuse term differs slightly" if model.internal_reflection else
                "Mitsuba's plastic always includes internal reflections (matfit's internal_reflection=False omits them)")
        d = {"type": "plastic", "diffuse_reflectance": _colour(model.reflectance), "int_ior": eta, "ext_ior": 1.0,
             "nonlinear": True}
        if isinstance(coat, RoughDielectric):
            if coat.masking != "separable" or coat.alpha_y is not None:
                return None
            d["type"] = "roughplastic"
            if not _alpha(d, coat, where, mp):
                return None
        mp.append(ParamMapping(f"{where}diffuse_reflectance", _num(model.reflectance), "albedo", False, note))
        mp.append(ParamMapping(f"{where}int_ior", eta, "eta (ext_ior = 1)", True))
        return d, mp
    if isinstance(model, Blend):
        a = exact_mitsuba(model.a, where + "bsdf_0.")
        b = exact_mitsuba(model.b, where + "bsdf_1.")
        if a is None or b is None or np.asarray(model.weight).size != 1:
            return None
        w = _num(model.weight)
        d = {"type": "blendbsdf", "weight": w, "bsdf_0": a[0], "bsdf_1": b[0]}
        return d, a[1] + b[1] + [ParamMapping(f"{where}weight", w, "weight", True)]
    if isinstance(model, MultiLobe):
        return _multi_lobe(model, where)
    return None


def _multi_lobe(model, where):
    """A :class:`~matfit.models.MultiLobe` as nested ``blendbsdf``: the sum ``sum_i c_i f_i`` of
    its components (the diffuse base, the lobes with their weights ``c_i`` per channel) is the
    convex combination ``sum_i p_i (c_i / p_i) f_i`` with ``p_i`` proportional to ``max c_i``; the
    scales ``c_i / p_i`` (at most ``S = sum_i max c_i``) go into the diffuse reflectance and the
    lobes' ``specular_reflectance``. Exact only where every lobe is a Mitsuba ``roughconductor``
    (a conductor, or a dielectric of index > 1 as a conductor with k = 0) and ``S <= 1`` (a
    reflectance above 1 is not a valid Mitsuba reflectance); else None."""
    if np.asarray(model.diffuse).ndim > 1:
        return None  # one value per pixel
    parts = []  # (mitsuba model, its weight c per channel, where, kind)
    albedo = np.asarray(model.diffuse, float)
    if np.any(albedo > 0):
        parts.append((Lambert(np.broadcast_to(albedo, (model.channels,))), albedo, "diffuse.", "lambert"))
    for i, lobe in enumerate(model.lobes):
        w = np.asarray(lobe.weight, float)
        if lobe.fresnel == "schlick" or w.ndim > 1:
            return None
        if lobe.fresnel == "dielectric" and not np.all(np.asarray(lobe.eta) > 1):
            return None
        k = lobe.k if lobe.fresnel == "conductor" else np.zeros_like(np.asarray(lobe.eta))
        if np.any(w > 0):
            parts.append((RoughConductor(lobe.alpha, lobe.eta, k, distribution=lobe.distribution, masking=lobe.masking,
                                         alpha_y=lobe.alpha_y), w, f"lobes[{i}].", lobe.fresnel))
    peaks = np.array([float(np.max(c)) for _, c, _, _ in parts])
    total = float(peaks.sum())
    if not parts or total > 1.0:
        return None
    probs = peaks / total
    dicts, mapping = [], []
    for (m, c, name, kind), p in zip(parts, probs):
        got = exact_mitsuba(m, where + name)
        if got is None:
            return None
        d, mp = got
        scale = c / p
        if isinstance(m, Lambert):
            d["reflectance"] = _colour(np.broadcast_to(scale, (model.channels,)))
            mp = [ParamMapping(f"{where}{name}reflectance", _num(scale), "albedo / blend probability", True)]
        else:
            d["specular_reflectance"] = _colour(scale)
            mp.append(ParamMapping(f"{where}{name}specular_reflectance", _num(scale), "weight / blend probability", True))
            if kind == "dielectric":  # the dielectric Fresnel of eta > 1 is the conductor's of k = 0
                mp = [ParamMapping(x.target, x.value, "0 (dielectric lobe)", True) if x.target.endswith(".k") else x
                      for x in mp]
        dicts.append(d)
        mapping += mp
    # nested blends: bsdf_0 is the first component, bsdf_1 the blend of the others
    out, rest = dicts[-1], probs[-1]
    for d, p in zip(dicts[-2::-1], probs[-2::-1]):
        w = float(rest / (rest + p))
        out = {"type": "blendbsdf", "weight": w, "bsdf_0": d, "bsdf_1": out}
        rest = rest + p
    mapping.append(ParamMapping(f"{where}weight", [plain_numbers(p) for p in probs], "blend probabilities "
                                "max(c_i) / sum max(c_j) of the components", True))
    return out, mapping


def _build_coated(p, C):
    coat = RoughConductor(p["alpha_coat"], p["eta_coat"], 0.0)
    metal = RoughConductor(p["alpha"], p["eta"], p["k"])
    return Blend(coat, metal, p["weight"])


@functools.lru_cache(maxsize=None)
def coated_metal_family():
    """The family fitted to a coated conductor for Mitsuba (which has no coated-conductor plugin):
    a ``blendbsdf`` of a clear-coat lobe (a ``roughconductor`` with the coat's real index and
    k = 0, i.e. the dielectric Fresnel) and a metal lobe."""
    from ..fitting import METAL_ETA_RANGE, METAL_K_RANGE, Family, Param

    return Family("mitsuba_coated_metal", (
        Param("alpha_coat", 1e-3, 1.0, False, "coat lobe GGX width"), Param("eta_coat", 1.05, 2.5, False, "coat index"),
        Param("alpha", 1e-3, 1.5, False, "metal GGX width"), Param("eta", *METAL_ETA_RANGE, True, "metal index"),
        Param("k", *METAL_K_RANGE, True, "metal extinction", physical=(True, False)),
        Param("weight", 0.0, 1.0, False, "metal lobe weight", physical=(True, True))),
        _build_coated, "blend of a clear-coat lobe and a metal lobe (Mitsuba roughconductor x 2)")


def approximate_mitsuba(model):
    """``(family, init)`` of the Mitsuba-expressible family fitted to ``model``, or None."""
    if isinstance(model, Layered) and isinstance(model.base, RoughConductor):
        coat = model.coat
        a_c = float(np.max(np.asarray(getattr(coat, "alpha", 0.01)))) or 0.01
        eta_c = float(np.asarray(coat.eta))
        init = {"alpha_coat": min(max(a_c, 0.002), 0.99), "eta_coat": min(max(eta_c, 1.06), 2.4),
                "alpha": float(np.clip(np.asarray(model.base.alpha), 0.002, 1.4)),
                "eta": np.clip(np.asarray(model.base.eta) * eta_c, 0.06, 7.9),
                "k": np.clip(np.asarray(model.base.k) * eta_c, 0.0, 11.9), "weight": 0.8}
        return coated_metal_family(), init
    return None


def to_xml(d, indent=1, name=None):
    """Mitsuba scene XML for a ``load_dict`` dict of a BSDF."""
    pad = "    " * indent
    head = (f'{pad}<bsdf' + (' version="3.0.0"' if indent == 0 else "") + f' type="{d["type"]}"'
            + (f' id="{name}"' if name else "") + ">")
    lines = [head]
    for k, v in d.items():
        if k == "type":
            continue
        if isinstance(v, dict) and v.get("type") == "rgb":
            lines.append(f'{pad}    <rgb name="{k}" value="{", ".join(f"{x:.9g}" for x in v["value"])}"/>')
        elif isinstance(v, dict):
            lines += to_xml(v, indent + 1).splitlines()
        elif isinstance(v, bool):
            lines.append(f'{pad}    <boolean name="{k}" value="{str(v).lower()}"/>')
        elif isinstance(v, str):
            lines.append(f'{pad}    <string name="{k}" value="{v}"/>')
        else:
            lines.append(f'{pad}    <float name="{k}" value="{float(v):.9g}"/>')
    lines.append(f"{pad}</bsdf>")
    return "\n".join(lines)



#: What the Mitsuba exporter accepts (named in its error message).
SUPPORTED = ("Lambert, RoughConductor and RoughDielectric (GGX, Beckmann, separable masking), SmoothConductor, "
             "SmoothDielectric, Plastic, Blend of those, Layered over a RoughConductor (fitted), MultiLobe of "
             "conductor or dielectric lobes (separable masking, albedo + sum of weights <= 1; no Schlick lobes)")
