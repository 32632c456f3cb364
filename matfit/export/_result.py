"""What an exporter returns: the target's document, how each parameter was mapped, and how
close the target comes to the model when the mapping is approximate."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import ParameterError
from ..microfacet import nearest_analytic
from ..models import AbstractBSDF, TabulatedMicrofacet
from ._model_file import plain_numbers


def check_model(owner, model) -> None:
    """A :class:`~matfit.errors.ParameterError` naming ``owner`` unless ``model`` is a matfit model.

    Parameters
    ----------
    owner : str
        The exporter, named in the message.
    model : object

    Raises
    ------
    ParameterError
        ``model`` is not a :class:`~matfit.models.AbstractBSDF`.

    Examples
    --------
    >>> check_model("to_pbrt", "lambert")
    Traceback (most recent call last):
    ...
    matfit.errors.ParameterError: to_pbrt: model must be a matfit model, got str
    """
    if not isinstance(model, AbstractBSDF):
        raise ParameterError(f"{owner}: model must be a matfit model, got {type(model).__name__}")


def _tabulated_parts(model):
    """The :class:`~matfit.models.TabulatedMicrofacet` models in ``model`` (itself or nested)."""
    if isinstance(model, TabulatedMicrofacet):
        return [model]
    found = []
    for f in dataclasses.fields(model):
        v = getattr(model, f.name)
        if isinstance(v, AbstractBSDF):
            found += _tabulated_parts(v)
    return found


def reject_tabulated(owner, model, target) -> None:
    """A :class:`~matfit.errors.ParameterError` when ``model`` is (or holds) a
    :class:`~matfit.models.TabulatedMicrofacet`, which ``target`` cannot represent: the message
    names the model and suggests the nearest analytic model (the GGX or Beckmann width of least
    misfit to its tabulated D, :func:`~matfit.microfacet.nearest_analytic`, with its eta and k).

    Parameters
    ----------
    owner : str
        The exporter, named in the message.
    model : matfit.models.AbstractBSDF
        The model to export.
    target : str
        The renderer, named in the message.

    Raises
    ------
    ParameterError
        ``model`` holds a tabulated distribution of normals.

    Examples
    --------
    >>> from matfit.microfacet import GGX, TabulatedNDF
    >>> from matfit.models import Lambert, TabulatedMicrofacet
    >>> reject_tabulated("to_pbrt", Lambert(0.5), "pbrt-v4")  # nothing tabulated: no error
    >>> tab = TabulatedMicrofacet(TabulatedNDF.from_distribution(GGX(0.2)), 1.0, 3.0)
    >>> reject_tabulated("to_pbrt", tab, "pbrt-v4")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    matfit.errors.ParameterError: to_pbrt: TabulatedMicrofacet ... RoughConductor(alpha=0.2, ...
    """
    parts = _tabulated_parts(model)
    if not parts:
        return
    m = parts[0]
    near = min((nearest_analytic(m.ndf, d) for d in ("ggx", "beckmann")), key=lambda r: r["misfit"])
    eta, k = (np.round(np.asarray(a, float), 4).tolist() for a in (m.eta, m.k))
    raise ParameterError(
        f"{owner}: TabulatedMicrofacet (a rough conductor on a tabulated distribution of normals) cannot be written "
        f"for {target}, which has no tabulated microfacet distribution; the nearest analytic model is "
        f"RoughConductor(alpha={near['alpha']:.4g}, eta={eta}, k={k}, distribution={near['distribution']!r}, "
        f"masking={m.masking!r}) (relative misfit of D {near['misfit']:.2%}): export that "
        "(matfit.models.RoughConductor), or fit model='conductor' to the measured table")


def rgb(owner, x):
    """Three plain numbers for a colour of 1 (repeated) or 3 channels; an error naming ``owner`` else.

    Parameters
    ----------
    owner : str
        The exporter, named in the message.
    x : array_like
        A colour of 1 or 3 channels.

    Returns
    -------
    list of float

    Examples
    --------
    >>> import numpy as np
    >>> rgb("to_gltf", np.float32(0.4)), rgb("to_gltf", [0.1, 0.2, 0.3])
    ([0.4, 0.4, 0.4], [0.1, 0.2, 0.3])
    """
    a = np.asarray(x).ravel()
    if a.size not in (1, 3):
        raise ParameterError(f"{owner}: colours have 3 channels, the model has {a.size}")
    return plain_numbers(np.repeat(a, 3) if a.size == 1 else a)


@dataclass(frozen=True)
class ParamMapping:
    """One parameter of the target document.

    Attributes
    ----------
    target : str
        The target's parameter name (``"alpha"``, ``"roughnessFactor"``, ``"interface.roughness"``).
    value : object
        The value written (numbers or lists of numbers).
    source : str
        Where it comes from in matfit's model (``"alpha"``, ``"sqrt(alpha)"``, ``"fitted"``).
    exact : bool
        True when the target reproduces the model's dependence on this parameter exactly.
    note : str
        Why it is approximate, when it is.

    Examples
    --------
    >>> from matfit.export import to_pbrt
    >>> from matfit.models import Lambert
    >>> to_pbrt(Lambert([0.5, 0.4, 0.3])).mapping
    [ParamMapping(target='reflectance', value=[0.5, 0.4, 0.3], source='albedo', exact=True, note='')]
    """

    target: str
    value: object
    source: str
    exact: bool
    note: str = ""


@dataclass(frozen=True)
class Fidelity:
    """How close an approximate export comes to the source model.

    Attributes
    ----------
    relative_rmse : float
        ``sqrt(sum w (f_t - f_s)^2 / sum w f_s^2)`` over held-out direction pairs of the upper
        hemisphere, ``w = cos(theta_o) cos(theta_i)`` (the error of reflected radiance under
        uniform light), ``f_s`` the source model and ``f_t`` the target's BRDF.
    n_pairs : int
        Direction pairs the error was measured on.
    method : str
        How the target's parameters were found: ``"fitted"`` (matfit's fitter, the target's
        BRDF as a matfit model fitted to the source) or ``"mapped"`` (one-to-one).
    ciede2000 : float or None
        Mean CIEDE2000 over the pixels of spheres of the source and the target rendered
        noise-free under the sky lighting (:func:`matfit.appearance.render_lit`), when measured.

    Examples
    --------
    >>> from matfit.export import Fidelity, relative_rmse
    >>> from matfit.models import Lambert
    >>> f = Fidelity(relative_rmse(Lambert(0.5), Lambert(0.55)), n_pairs=4096, method="mapped")
    >>> round(f.relative_rmse, 3), f.ciede2000   # measure() would also compare rendered spheres
    (0.1, None)
    """

    relative_rmse: float
    n_pairs: int
    method: str
    ciede2000: float | None = None


@dataclass
class ExportResult:
    """A model exported to a renderer's format.

    Attributes
    ----------
    target : str
        ``"mitsuba"``, ``"mitsuba-xml"``, ``"pbrt"``, ``"gltf"``, ``"mtlx"`` or ``"openpbr"``.
    content : dict or str
        The document: a Mitsuba ``load_dict`` dict, a glTF JSON dict, or text (Mitsuba XML,
        pbrt-v4 scene lines, a MaterialX document).
    mapping : list of ParamMapping
        One entry per parameter written.
    model : matfit.models.AbstractBSDF
        The BRDF the target renders, as a matfit model (the source itself when exact).
    fidelity : Fidelity or None
        None when every parameter is exact.
    notes : list of str
        What the target does differently, in words.

    Examples
    --------
    >>> from matfit.export import to_mitsuba
    >>> from matfit.models import Lambert
    >>> r = to_mitsuba(Lambert([0.5, 0.4, 0.3]))
    >>> r.target, r.exact, r.fidelity, r.content["reflectance"]
    ('mitsuba', True, None, {'type': 'rgb', 'value': [0.5, 0.4, 0.3]})
    """

    target: str
    content: object
    mapping: list
    model: object = field(repr=False)
    fidelity: Fidelity | None = None
    notes: list = field(default_factory=list)

    @property
    def exact(self) -> bool:
        """True when every parameter is represented exactly."""
        return all(m.exact for m in self.mapping)

    def text(self) -> str:
        """The document as text (JSON for dict targets).

        Returns
        -------
        str

        Examples
        --------
        >>> import json
        >>> from matfit.export import to_gltf
        >>> from matfit.models import Lambert
        >>> json.loads(to_gltf(Lambert(0.5)).text())["asset"]["version"]
        '2.0'
        """
        return self.content if isinstance(self.content, str) else json.dumps(self.content, indent=2)

    def write(self, path):
        """Write :meth:`text` to ``path`` (parent folders are created).

        The file ends with a newline.

        Parameters
        ----------
        path : str or PathLike

        Returns
        -------
        Path
            ``path``, as a :class:`pathlib.Path`.

        Examples
        --------
        >>> import tempfile
        >>> from matfit.export import to_pbrt
        >>> from matfit.models import Lambert
        >>> with tempfile.TemporaryDirectory() as d:
        ...     p = to_pbrt(Lambert(0.5)).write(f"{d}/scene/material.pbrt")
        ...     p.name, p.read_text().splitlines()[0]
        ('material.pbrt', '# matfit export: Lambert (exact)')
        """
        p = Path(path)
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(self.text() + ("" if self.text().endswith("\n") else "\n"))
        return p

    def summary(self) -> str:
        """A table of the mapping, then the fidelity when approximate.

        Returns
        -------
        str
            One line per parameter (target name, value, source, exact or why not), then the
            fidelity and the notes.

        Examples
        --------
        >>> from matfit.export import to_pbrt
        >>> from matfit.models import Lambert
        >>> print(to_pbrt(Lambert([0.5, 0.4, 0.3])).summary())
        export to pbrt: exact
          reflectance = [0.5, 0.4, 0.3]              <- albedo           exact
        """
        lines = [f"export to {self.target}: {'exact' if self.exact else 'approximate'}"]
        w = max([len(m.target) for m in self.mapping] + [9])
        for m in self.mapping:
            v = json.dumps(m.value) if not isinstance(m.value, str) else m.value
            lines.append(f"  {m.target:{w}s} = {v:28s} <- {m.source:16s} {'exact' if m.exact else 'approx: ' + m.note}")
        if self.fidelity is not None:
            f = self.fidelity
            cd = f", CIEDE2000 {f.ciede2000:.2f}" if f.ciede2000 is not None else ""
            lines.append(f"  fidelity ({f.method}): relative RMSE {f.relative_rmse:.3%} over {f.n_pairs} pairs{cd}")
        lines += [f"  note: {n}" for n in self.notes]
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """JSON-ready description (the mapping and the fidelity, not the document).

        Returns
        -------
        dict
            ``target``, ``exact``, ``mapping`` (a dict per parameter), ``fidelity`` (a dict or
            None) and ``notes``.

        Examples
        --------
        >>> from matfit.export import to_pbrt
        >>> from matfit.models import Lambert
        >>> d = to_pbrt(Lambert(0.5)).to_dict()
        >>> d["exact"], d["mapping"][0]["target"], d["fidelity"]
        (True, 'reflectance', None)
        """
        return {"target": self.target, "exact": self.exact,
                "mapping": [m.__dict__ for m in self.mapping],
                "fidelity": None if self.fidelity is None else self.fidelity.__dict__, "notes": list(self.notes)}
