"""pbrt-v4: ``MakeNamedMaterial "matfit"`` scene lines (use it with ``NamedMaterial "matfit"``).

=================  ======================================================  ==========================
matfit model       pbrt-v4 material                                        mapping
=================  ======================================================  ==========================
Lambert            ``diffuse`` (reflectance)                               exact
RoughConductor     ``conductor`` (roughness = alpha, remaproughness false)  exact for GGX with height-
                                                                           correlated masking; else a
                                                                           fitted height-correlated GGX
SmoothConductor    ``conductor`` (roughness 0)                             exact
Rough/Smooth-      ``dielectric`` (eta, roughness)                         exact for GGX height-
Dielectric                                                                 correlated or smooth
Plastic            ``coateddiffuse`` (reflectance, roughness, eta)         approximate: pbrt simulates
                                                                           the layer by random walks
Layered over a     ``coatedconductor`` (interface.*, conductor.*)          approximate (random walks)
RoughConductor
Blend              ``mix`` (materials [a b], amount = weight)              exact when both parts are
=================  ======================================================  ==========================

Roughness: pbrt-v4 remaps ``roughness`` by ``sqrt`` unless ``"bool remaproughness" false``;
matfit always writes ``false`` and ``roughness = alpha``. pbrt has only the Trowbridge-Reitz
(GGX) distribution, with the height-correlated Smith masking. Colours are written as ``rgb``
(pbrt-v4 upsamples them to spectra; ``eta``/``k`` as unbounded RGB spectra).
"""

from __future__ import annotations

import functools

import numpy as np

from ..errors import ParameterError
from ..models import (Blend, Lambert, Layered, Plastic, RoughConductor, RoughDielectric, SmoothConductor,
                      SmoothDielectric)
from ._fidelity import fit_target, measure, relative_rmse
from ._model_file import plain_numbers
from ._result import ExportResult, ParamMapping, check_model, reject_tabulated, rgb


def _vals(x):
    a = np.asarray(x)
    v = plain_numbers(a.ravel())
    return v


def _rgb(name, x):
    v = rgb("to_pbrt", x)
    return f'"rgb {name}" [ {" ".join(repr(t) for t in v)} ]'


def _float(name, x):
    return f'"float {name}" [ {plain_numbers(np.asarray(x).ravel()[0])!r} ]'


def _rough(m, prefix=""):
    if m.alpha_y is None:
        return [_float(prefix + "roughness", m.alpha)]
    return [_float(prefix + "uroughness", m.alpha), _float(prefix + "vroughness", m.alpha_y)]


def _pbrt_exact(m):
    return m.distribution == "ggx" and m.masking == "height_correlated"


@functools.lru_cache(maxsize=None)
def conductor_family():
    """The family fitted when pbrt cannot take a conductor as it is: GGX, height-correlated Smith."""
    from ..fitting import METAL_ETA_RANGE, METAL_K_RANGE, Family, Param

    return Family("pbrt_conductor", (
        Param("alpha", 1e-3, 1.5, False, "GGX width"), Param("eta", *METAL_ETA_RANGE, True, "real index"),
        Param("k", *METAL_K_RANGE, True, "extinction", physical=(True, False))),
        lambda p, C: RoughConductor(p["alpha"], p["eta"], p["k"], masking="height_correlated"),
        "pbrt-v4 conductor (Trowbridge-Reitz, height-correlated Smith)")


def _material(name, m, mapping, notes, fids, where=""):
    """Lines of ``MakeNamedMaterial name`` for ``m`` (and its parts first, for ``mix``); appends to
    ``mapping``, ``notes`` and ``fids`` (the fidelity of a fitted top-level conductor)."""
    if isinstance(m, Lambert):
        mapping.append(ParamMapping(where + "reflectance", _vals(m.reflectance), "albedo", True))
        return [f'MakeNamedMaterial "{name}" "string type" "diffuse" {_rgb("reflectance", m.reflectance)}']
    if isinstance(m, SmoothConductor):
        mapping += [ParamMapping(where + "eta", _vals(m.eta), "eta", True), ParamMapping(where + "k", _vals(m.k), "k", True)]
        return [f'MakeNamedMaterial "{name}" "string type" "conductor" {_rgb("eta", m.eta)} {_rgb("k", m.k)} '
                f'"float roughness" [ 0.0 ]']
    if isinstance(m, RoughConductor):
        exact = _pbrt_exact(m)
        src = m
        if not exact:
            src = fit_target(m, conductor_family(), init={
                "alpha": float(np.clip(np.asarray(m.alpha), 2e-3, 1.4)), "eta": np.clip(np.asarray(m.eta), 0.06, 7.9),
                "k": np.clip(np.asarray(m.k), 0.0, 11.9)}) if m.alpha_y is None else RoughConductor(
                m.alpha, m.eta, m.k, masking="height_correlated", alpha_y=m.alpha_y)
            err = relative_rmse(m, src)
            if m.alpha_y is None and not where:
                fids.append(measure(m, src, err=err))
            notes.append(f"pbrt's conductor is GGX with height-correlated masking; the model ({m.distribution}, "
                         f"{m.masking}) was {'fitted by one' if m.alpha_y is None else 'mapped to one'}: relative RMSE "
                         f"{err:.3%}")
        how, note = ("alpha", "") if exact else ("fitted", "fitted height-correlated GGX")
        mapping += [ParamMapping(where + "roughness", _vals(src.alpha)[0], how, exact, note),
                    ParamMapping(where + "eta", _vals(src.eta), how.replace("alpha", "eta"), exact, note),
                    ParamMapping(where + "k", _vals(src.k), how.replace("alpha", "k"), exact, note)]
        return [f'MakeNamedMaterial "{name}" "string type" "conductor" {_rgb("eta", src.eta)} {_rgb("k", src.k)} '
                + " ".join(_rough(src)) + ' "bool remaproughness" false']
    if isinstance(m, (SmoothDielectric, RoughDielectric)):
        eta = _vals(m.eta)
        if len(eta) != 1:
            raise ParameterError("to_pbrt: a dielectric with one eta per pixel cannot be written as one material")
        rough = isinstance(m, RoughDielectric)
        exact = (not rough) or _pbrt_exact(m)
        note = "" if exact else f"pbrt uses GGX with height-correlated masking (model: {m.distribution}, {m.masking})"
        mapping.append(ParamMapping(where + "eta", eta[0], "eta", True))
        if rough:
            mapping.append(ParamMapping(where + "roughness", _vals(m.alpha)[0], "alpha", exact, note))
        return [f'MakeNamedMaterial "{name}" "string type" "dielectric" {_float("eta", eta[0])} '
                + (" ".join(_rough(m)) if rough else '"float roughness" [ 0.0 ]') + ' "bool remaproughness" false']
    if isinstance(m, Plastic):
        coat = m.coat
        a = getattr(coat, "alpha", 0.0)
        note = "pbrt's coateddiffuse simulates the coat-base interreflection by random walks (thickness 0.01, no medium)"
        mapping += [ParamMapping(where + "reflectance", _vals(m.reflectance), "albedo", False, note),
                    ParamMapping(where + "roughness", _vals(a)[0], "alpha", False, note),
                    ParamMapping(where + "eta", _vals(coat.eta)[0], "eta", False, note)]
        return [f'MakeNamedMaterial "{name}" "string type" "coateddiffuse" {_rgb("reflectance", m.reflectance)} '
                f'{_float("roughness", a)} {_float("eta", coat.eta)} "float thickness" [ 0.01 ] "bool remaproughness" false']
    if isinstance(m, Layered) and isinstance(m.base, RoughConductor):
        coat, base = m.coat, m.base
        eta_c = float(np.asarray(coat.eta))
        a = getattr(coat, "alpha", 0.0)
        note = "pbrt's coatedconductor simulates the layer by random walks"
        # matfit's base index is relative to the coat; pbrt's conductor.eta/k are relative to the outside
        mapping += [ParamMapping(where + "interface.roughness", _vals(a)[0], "coat alpha", False, note),
                    ParamMapping(where + "interface.eta", eta_c, "coat eta", False, note),
                    ParamMapping(where + "conductor.eta", _vals(np.asarray(base.eta) * eta_c), "base eta * coat eta", False, note),
                    ParamMapping(where + "conductor.k", _vals(np.asarray(base.k) * eta_c), "base k * coat eta", False, note),
                    ParamMapping(where + "conductor.roughness", _vals(base.alpha)[0], "base alpha", False, note)]
        return [f'MakeNamedMaterial "{name}" "string type" "coatedconductor" {_float("interface.roughness", a)} '
                f'{_float("interface.eta", eta_c)} {_rgb("conductor.eta", np.asarray(base.eta) * eta_c)} '
                f'{_rgb("conductor.k", np.asarray(base.k) * eta_c)} {_float("conductor.roughness", base.alpha)} '
                '"bool remaproughness" false']
    if isinstance(m, Blend):
        if np.asarray(m.weight).size != 1:
            raise ParameterError("to_pbrt: a Blend with one weight per pixel cannot be written as one material")
        lines = (_material(name + "_a", m.a, mapping, notes, fids, where + "a.")
                 + _material(name + "_b", m.b, mapping, notes, fids, where + "b."))
        mapping.append(ParamMapping(where + "amount", _vals(m.weight)[0], "weight", True))
        return lines + [f'MakeNamedMaterial "{name}" "string type" "mix" "string materials" [ "{name}_a" "{name}_b" ] '
                        f'{_float("amount", m.weight)}']
    raise ParameterError(f"to_pbrt: {type(m).__name__} has no pbrt-v4 material; exports Lambert, RoughConductor, "
                         "SmoothConductor, RoughDielectric, SmoothDielectric, Plastic, Layered over a RoughConductor "
                         "and Blend of those")


def to_pbrt(model) -> ExportResult:
    """pbrt-v4 scene lines defining the named material ``"matfit"`` for ``model``.

    Parameters
    ----------
    model : matfit.models.AbstractBSDF
        Lambert, a conductor, a dielectric, Plastic, Layered over a RoughConductor, or a Blend
        of those (the table in the module docstring); a conductor pbrt cannot evaluate exactly
        is written as a height-correlated GGX conductor fitted to it.

    Returns
    -------
    ExportResult
        ``content`` is the text; include it in a scene and select it with ``NamedMaterial "matfit"``.

    Raises
    ------
    ParameterError
        ``model`` is not a matfit model or has no pbrt-v4 material (a
        :class:`~matfit.models.TabulatedMicrofacet`: the message names the nearest analytic model).

    Examples
    --------
    >>> from matfit.models import Lambert
    >>> print(to_pbrt(Lambert([0.5, 0.4, 0.3])).content, end="")
    # matfit export: Lambert (exact)
    MakeNamedMaterial "matfit" "string type" "diffuse" "rgb reflectance" [ 0.5 0.4 0.3 ]
    """
    check_model("to_pbrt", model)
    reject_tabulated("to_pbrt", model, "pbrt-v4")
    mapping, notes, fids = [], [], []
    lines = _material("matfit", model, mapping, notes, fids)
    exact = all(p.exact for p in mapping)
    text = "\n".join([f"# matfit export: {type(model).__name__} ({'exact' if exact else 'approximate'})"] + lines) + "\n"
    return ExportResult("pbrt", text, mapping, model, fids[0] if fids else None, notes)
