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
    """Raise a ParameterError naming ``owner`` unless ``model`` is a matfit model."""
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
    """Raise a ParameterError when ``model`` is or holds a TabulatedMicrofacet, which ``target`` cannot
    represent: the message names the nearest analytic model (GGX or Beckmann width of least misfit to
    the tabulated D, :func:`~matfit.microfacet.nearest_analytic`, with its eta and k).
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
    """Three plain numbers for a colour of 1 (repeated) or 3 channels; a ParameterError naming ``owner`` else."""
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
    >>> from matfit.export import to_pbrt
    >>> from matfit.models import Lambert
    >>> r = to_pbrt(Lambert([0.5, 0.4, 0.3]))
    >>> r.target, r.exact, r.fidelity
    ('pbrt', True, None)
    >>> print(r.summary())
    export to pbrt: exact
      reflectance = [0.5, 0.4, 0.3]              <- albedo           exact
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
        """The document as text (JSON for dict targets)."""
        return self.content if isinstance(self.content, str) else json.dumps(self.content, indent=2)

    def write(self, path):
        """Write :meth:`text` to ``path``, ending with a newline (parent folders are created); returns the :class:`pathlib.Path`."""
        p = Path(path)
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(self.text() + ("" if self.text().endswith("\n") else "\n"))
        return p

    def summary(self) -> str:
        """One line per parameter (target name, value, source, exact or why not), then the fidelity and the notes."""
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
        """JSON-ready ``target``, ``exact``, ``mapping`` (a dict per parameter), ``fidelity`` (dict or None) and ``notes``; not the document."""
        return {"target": self.target, "exact": self.exact,
                "mapping": [m.__dict__ for m in self.mapping],
                "fidelity": None if self.fidelity is None else self.fidelity.__dict__, "notes": list(self.notes)}
