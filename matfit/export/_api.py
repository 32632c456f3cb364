"""The exporters and their registry."""

from __future__ import annotations

from ..errors import ParameterError
from . import _mitsuba
from ._fidelity import fit_target, measure
from ._gltf import to_gltf
from ._materialx import to_materialx, to_openpbr
from ._pbrt import to_pbrt
from ._usd import to_usd
from ._result import ExportResult, ParamMapping, check_model, reject_tabulated


def _approx(owner, model, plan, supported):
    if plan is None:
        raise ParameterError(f"{owner}: {type(model).__name__} has no mapping to this target; it exports {supported}")
    family, init = plan
    return fit_target(model, family, init=init)


def to_mitsuba(model) -> ExportResult:
    """A Mitsuba 3 ``load_dict`` dictionary of ``model``'s BSDF.

    Parameters
    ----------
    model : matfit.models.AbstractBSDF
        Lambert, the conductors, the dielectrics, Plastic and Blend map to Mitsuba's plugins
        one to one; a MultiLobe of conductor or dielectric lobes (separable masking, albedo
        plus weights at most 1) maps exactly to nested ``blendbsdf`` (a MultiLobe with Schlick
        lobes has no Mitsuba form and raises); Layered over a RoughConductor is written as a
        ``blendbsdf`` of two ``roughconductor`` lobes fitted to it over the hemisphere.

    Returns
    -------
    ExportResult
        ``content`` is the dict (``mitsuba.load_dict(result.content)`` loads it).

    Raises
    ------
    ParameterError
        Not a matfit model, or one with neither a plugin nor an approximation (for a
        :class:`~matfit.models.TabulatedMicrofacet` the message names the nearest analytic model).

    Examples
    --------
    >>> from matfit.models import RoughConductor
    >>> r = to_mitsuba(RoughConductor(0.2, [0.2, 0.9, 1.1], [3.9, 2.4, 2.2]))
    >>> r.content["type"], r.content["alpha"], r.exact
    ('roughconductor', 0.2, True)
    """
    check_model("to_mitsuba", model)
    reject_tabulated("to_mitsuba", model, "Mitsuba 3")
    got = _mitsuba.exact_mitsuba(model)
    fid, target, notes = None, model, []
    if got is None:
        target = _approx("to_mitsuba", model, _mitsuba.approximate_mitsuba(model), _mitsuba.SUPPORTED)
        got = _mitsuba.exact_mitsuba(target)
        got = (got[0], [ParamMapping(m.target, m.value, "fitted", False, "fitted to the model over the hemisphere")
                        for m in got[1]])
        fid = measure(model, target)
        notes.append(f"Mitsuba 3 has no plugin for {type(model).__name__}: a {type(target).__name__} fitted to it")
    elif not all(m.exact for m in got[1]):
        notes.append("mapped one to one; Mitsuba evaluates its own form of the terms marked approximate")
    return ExportResult("mitsuba", got[0], got[1], target, fid, notes)


def to_mitsuba_xml(model) -> ExportResult:
    """:func:`to_mitsuba` as Mitsuba scene XML: ``content`` is a ``<bsdf id="matfit">`` element.

    Parameters
    ----------
    model : matfit.models.AbstractBSDF
        As for :func:`to_mitsuba`.

    Returns
    -------
    ExportResult
        Mapping, model and fidelity are those of :func:`to_mitsuba`.

    Examples
    --------
    >>> from matfit.models import Lambert
    >>> print(to_mitsuba_xml(Lambert([0.5, 0.4, 0.3])).content)
    <bsdf version="3.0.0" type="diffuse" id="matfit">
        <rgb name="reflectance" value="0.5, 0.4, 0.3"/>
    </bsdf>
    """
    r = to_mitsuba(model)
    return ExportResult("mitsuba-xml", _mitsuba.to_xml(r.content, 0, "matfit"), r.mapping, r.model, r.fidelity, r.notes)


#: Target name -> exporter.
EXPORTERS = {"mitsuba": to_mitsuba, "mitsuba-xml": to_mitsuba_xml, "pbrt": to_pbrt, "gltf": to_gltf,
             "mtlx": to_materialx, "openpbr": to_openpbr, "usd": to_usd}


def export(model, to) -> ExportResult:
    """Export ``model`` to the target ``to`` with its exporter in :data:`EXPORTERS`.

    Parameters
    ----------
    model : matfit.models.AbstractBSDF
    to : {"mitsuba", "mitsuba-xml", "pbrt", "gltf", "mtlx", "openpbr", "usd"}

    Returns
    -------
    ExportResult

    Raises
    ------
    ParameterError
        An unknown target, or a model the target cannot take.
    """
    if to not in EXPORTERS:
        raise ParameterError(f"export: target must be one of {sorted(EXPORTERS)}, got {to!r}")
    return EXPORTERS[to](model)
