"""A model as a JSON document: what ``matfit fit`` writes next to its report and what
``matfit export`` and ``matfit render`` read.

The document is ``{"matfit_model": 1, "model": {"type": <class name>, <field>: <value>, ...}}``:
array fields as (nested) lists of numbers (the shortest decimals that read back as the same
values: a float32 0.4 is written 0.4), static fields as they are, nested models as nested
objects, a sequence of nested models (:class:`~matfit.models.MultiLobe`'s ``lobes``) as a list
of them. It holds numbers and names only (no pickles) and is read back by rebuilding each
class from its fields, so every value is checked against the class's declared fields. A
tabulated distribution of normals (:class:`~matfit.microfacet.TabulatedNDF`, the ``ndf`` of a
:class:`~matfit.models.TabulatedMicrofacet`) is written as ``{"type": "TabulatedNDF", "theta",
"d", "n_lambda"}``, its constructor's arguments, and rebuilt (and checked) by its constructor.

Errors: writing a class outside :data:`MODEL_CLASSES` or non-finite values raises
:class:`~matfit.errors.ParameterError`; reading raises :class:`~matfit.errors.DataFormatError`
naming the file (or source) and field: a missing file, not JSON, no ``model`` field, an unknown
``type``, missing or unexpected fields, values that are not (finite) numbers, a table the
TabulatedNDF constructor rejects.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from ..errors import DataFormatError, ParameterError
from .. import models as _models
from ..microfacet import TabulatedNDF

FORMAT_VERSION = 1

#: The classes a model document may name: the registry's entries declared for ``"document"``.
MODEL_CLASSES = _models.models_for("document")
#: The fields of a tabulated distribution's description (:class:`~matfit.microfacet.TabulatedNDF`'s arguments).
NDF_FIELDS = ("theta", "d", "n_lambda")


def plain_numbers(a):
    """Python floats (nested lists for arrays) of the shortest decimal strings that read back as the same values."""
    a = np.asarray(a)
    if a.dtype.kind != "f":
        return a.astype(float).tolist()
    if a.ndim == 0:
        return float(np.format_float_positional(a[()], unique=True, trim="-"))
    flat = [float(np.format_float_positional(x, unique=True, trim="-")) for x in a.ravel()]
    return np.asarray(flat).reshape(a.shape).tolist()


def describe_model(model) -> dict:
    """The model's fields as a JSON-ready dict ``{"type": class name, field: value, ...}`` (the module's format).

    Parameters
    ----------
    model : matfit.models.AbstractBSDF
        Of a class in :data:`MODEL_CLASSES`, with concrete (not traced) parameters.

    Returns
    -------
    dict
    """
    cls = type(model)
    if MODEL_CLASSES.get(cls.__name__) is not cls:
        raise ParameterError(f"describe_model: {cls.__name__} is not a model class matfit can write; "
                             f"expected one of {sorted(MODEL_CLASSES)}")
    out = {"type": cls.__name__}
    for f in dataclasses.fields(model):
        v = getattr(model, f.name)
        if v is None or isinstance(v, (str, bool, int, float)):
            out[f.name] = v
        elif isinstance(v, _models.AbstractBSDF):
            out[f.name] = describe_model(v)
        elif isinstance(v, (tuple, list)) and v and all(isinstance(x, _models.AbstractBSDF) for x in v):
            out[f.name] = [describe_model(x) for x in v]  # a sequence of models (MultiLobe's lobes)
        elif isinstance(v, TabulatedNDF):
            out[f.name] = describe_ndf(v)
        else:
            a = np.asarray(v)
            if not np.all(np.isfinite(a)):
                raise ParameterError(f"describe_model: {cls.__name__}.{f.name} has non-finite values {a.tolist()}")
            out[f.name] = plain_numbers(a)
    return out


def describe_ndf(ndf) -> dict:
    r"""A TabulatedNDF as its constructor's arguments: node angles (from the stored sin^2 theta), the normalized D, the masking table's size."""
    x = np.clip(np.asarray(ndf.x_nodes, np.float64), 0.0, 1.0)
    d = np.asarray(ndf.d_nodes)
    if not np.all(np.isfinite(d)):
        raise ParameterError(f"describe_model: TabulatedNDF.d_nodes has non-finite values {d.tolist()}")
    return {"type": "TabulatedNDF", "theta": plain_numbers(np.arcsin(np.sqrt(x))), "d": plain_numbers(d),
            "n_lambda": int(np.asarray(ndf.b_nodes).shape[0])}


def ndf_from_description(d, where="model description"):
    """Rebuild a TabulatedNDF from :func:`describe_ndf`'s dict (its constructor checks the table); errors name ``where``."""
    fields = set(d) - {"type"}
    if fields != set(NDF_FIELDS):
        raise DataFormatError(f"{where}: TabulatedNDF expects fields {list(NDF_FIELDS)}; missing "
                              f"{sorted(set(NDF_FIELDS) - fields)}, unexpected {sorted(fields - set(NDF_FIELDS))}")
    n_lambda = d["n_lambda"]
    if isinstance(n_lambda, bool) or not isinstance(n_lambda, int):
        raise DataFormatError(f"{where}: TabulatedNDF.n_lambda: expected an integer, found {n_lambda!r}")
    arrays = {}
    for name in ("theta", "d"):
        try:
            arrays[name] = np.asarray(d[name], dtype=float)
        except (TypeError, ValueError):
            raise DataFormatError(f"{where}: TabulatedNDF.{name}: expected a list of numbers, found {d[name]!r}") from None
    try:
        return TabulatedNDF(arrays["theta"], arrays["d"].astype(jnp.result_type(float)), n_lambda)
    except ParameterError as exc:
        raise DataFormatError(f"{where}: {exc}") from None


def model_from_description(d, source="model description"):
    """Rebuild a model from :func:`describe_model`'s dict.

    Parameters
    ----------
    d : dict
        ``{"type": ..., fields...}``.
    source : str
        Named in error messages (e.g. the file it came from).

    Returns
    -------
    matfit.models.AbstractBSDF
    """
    if not isinstance(d, dict) or "type" not in d:
        raise DataFormatError(f"{source}: a model must be an object with a 'type' field, found {type(d).__name__}")
    cls = MODEL_CLASSES.get(d["type"])
    if cls is None:
        raise DataFormatError(f"{source}: field 'type': expected one of {sorted(MODEL_CLASSES)}, found {d['type']!r}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    missing = sorted(set(fields) - set(d))
    extra = sorted(set(d) - set(fields) - {"type"})
    if missing or extra:
        raise DataFormatError(f"{source}: {cls.__name__} expects fields {sorted(fields)}; missing {missing}, "
                              f"unexpected {extra}")
    obj = object.__new__(cls)
    for name, f in fields.items():
        v = d[name]
        where = f"{source}: {cls.__name__}.{name}"
        if isinstance(v, dict) and v.get("type") == "TabulatedNDF":
            v = ndf_from_description(v, where)
        elif isinstance(v, dict):
            v = model_from_description(v, source)
        elif isinstance(v, list) and v and any(isinstance(x, dict) for x in v):
            if not all(isinstance(x, dict) for x in v):
                raise DataFormatError(f"{where}: expected a list of models (objects with a 'type' field), found {v!r}")
            v = tuple(model_from_description(x, source) for x in v)
        elif f.metadata.get("static", False) or isinstance(v, (str, bool)) or v is None:
            pass
        else:
            try:
                a = np.asarray(v, dtype=float)
            except (TypeError, ValueError):
                raise DataFormatError(f"{where}: expected numbers, found {v!r}") from None
            if not np.all(np.isfinite(a)):
                raise DataFormatError(f"{where}: expected finite numbers, found {a.tolist()}")
            v = jnp.asarray(a)
        object.__setattr__(obj, name, v)
    return obj


def save_model(path, model, **extra) -> None:
    """Write ``model`` as a model document (JSON) at ``path``, parent folders created.

    Parameters
    ----------
    path : str or PathLike
    model : matfit.models.AbstractBSDF
        As for :func:`describe_model`.
    **extra
        JSON-serializable values stored at the top level beside ``model`` (e.g. ``family``).

    Examples
    --------
    >>> import json, os, tempfile
    >>> from matfit.models import Lambert
    >>> with tempfile.TemporaryDirectory() as d:
    ...     save_model(os.path.join(d, "m.json"), Lambert(0.5), family="lambert")
    ...     with open(os.path.join(d, "m.json")) as fh:
    ...         doc = json.load(fh)
    >>> doc["matfit_model"], doc["family"], doc["model"]["type"]
    (1, 'lambert', 'Lambert')
    """
    doc = {"matfit_model": FORMAT_VERSION, "model": describe_model(model), **extra}
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w") as fh:
        json.dump(doc, fh, indent=2)


def load_model(path):
    """Read a model from a model document or a ``report.json`` (:func:`matfit.report.write_report`).

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    matfit.models.AbstractBSDF
    """
    p = Path(path)
    if not p.exists():
        raise DataFormatError(f"{p}: no such file")
    try:
        with open(p) as fh:
            doc = json.load(fh)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DataFormatError(f"{p}: not a JSON document ({exc})") from None
    if not isinstance(doc, dict) or "model" not in doc:
        raise DataFormatError(f"{p}: field 'model': expected a model document (matfit fit --save-model, or a "
                              "report.json), found no 'model' field")
    return model_from_description(doc["model"], str(p))
