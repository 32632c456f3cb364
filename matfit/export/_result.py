"""What an exporter returns: the target's document, how each parameter was mapped, and how
close the target comes to the model when the mapping is approximate."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import ParameterError
from ..models import AbstractBSDF
from ._model_file import plain_numbers


def check_model(owner, model):
    """A :class:`~matfit.errors.ParameterError` naming ``owner`` unless ``model`` is a matfit model."""
    if not isinstance(model, AbstractBSDF):
        raise ParameterError(f"{owner}: model must be a matfit model, got {type(model).__name__}")


def rgb(owner, x):
    """Three plain numbers for a colour of 1 (repeated) or 3 channels; an error naming ``owner`` else."""
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
        Mean CIEDE2000 between spheres of the source and the target rendered under the built-in
        sky (:func:`matfit.render.render_sphere`), when measured.
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
        ``"mitsuba"``, ``"mitsuba-xml"``, ``"pbrt"``, ``"gltf"`` or ``"mtlx"``.
    content : dict or str
        The document: a Mitsuba ``load_dict`` dict, a glTF JSON dict, or text (Mitsuba XML,
        pbrt-v4 scene lines, a MaterialX document).
    mapping : list of ParamMapping
    model : matfit.models.AbstractBSDF
        The BRDF the target renders, as a matfit model (the source itself when exact).
    fidelity : Fidelity or None
        None when every parameter is exact.
    notes : list of str
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
        """Write :meth:`text` to ``path`` (parent folders are created)."""
        p = Path(path)
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(self.text() + ("" if self.text().endswith("\n") else "\n"))
        return p

    def summary(self) -> str:
        """A table of the mapping, then the fidelity when approximate."""
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
        """JSON-ready description (the mapping and the fidelity, not the document)."""
        return {"target": self.target, "exact": self.exact,
                "mapping": [m.__dict__ for m in self.mapping],
                "fidelity": None if self.fidelity is None else self.fidelity.__dict__, "notes": list(self.notes)}
