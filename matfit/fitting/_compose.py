"""Families of a Lambertian base plus microfacet lobes, declared in a few lines.

:func:`~matfit.fitting.compose_family` turns a list of :class:`Lobe` specifications into a
:class:`~matfit.fitting.Family` of :class:`~matfit.models.MultiLobe` models (its docstring
tables the parameters: names, bounds, meaning). This module holds what does not need the
:class:`~matfit.fitting.Param` class: the specification, the layout of the parameters (names,
bounds, generic starts), the build of the model from the parameters' values and the data-driven
start (a variable projection: for a few candidate widths and Fresnel levels, the lobes'
amplitudes and the diffuse albedo by weighted non-negative least squares, the best candidate
kept). Lobes are numbered from 1; a parameter shared by the lobes has no suffix.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Optional

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import ParameterError
from ..fresnel import FILM_ETA_RANGE, FILM_THICKNESS_RANGE, fresnel_dielectric, fresnel_thin_film
from ..microfacet import DISTRIBUTIONS, MASKING_FORMS
from ..models import Layered, MultiLobe, RoughDielectric, SoAPairs, SpecularLobe
from ..models.multi_lobe import FRESNEL_KINDS, FRESNEL_PARAMS
from ._film_guess import FILM_GENERIC, film_candidates

__all__ = ["Lobe", "Slot", "LobeSpec", "LobeRefine", "lobe_layout", "WEIGHT_MODES", "SHAREABLE", "METAL_ETA_RANGE",
           "METAL_K_RANGE", "COAT_SLOTS"]

#: How the lobes are weighted: a per-channel weight each, a mixture (weights summing to 1), or 1.
WEIGHT_MODES = ("channels", "mixture", "none")
#: The Fresnel parameters that lobes may share (one parameter for every lobe that has it).
SHAREABLE = ("f0", "eta", "k", "thickness", "film_eta")
#: Widths of lobes 1, 2, 3, ... at the generic start: narrow, medium, wide (factor 4 apart).
GENERIC_ALPHA, GENERIC_RATIO = 0.05, 4.0
#: The ranges a fitted metal's real index and extinction take: range limits of the fit (a
#: tabulated metal reaches k ~ 10 in the visible), except k = 0, a dielectric's Fresnel.
METAL_ETA_RANGE, METAL_K_RANGE = (0.05, 8.0), (0.0, 12.0)
#: Bounds of a width ratio of ordered lobes.
RATIO_BOUNDS = (1.0, 100.0)
#: The data-driven start's candidate widths: the first lobe at these factors of the peak's half
#: width, each next lobe these ratios wider than the previous one.
WIDTH_FACTORS, WIDTH_RATIOS = (0.4, 0.7, 1.0, 1.5, 2.5, 4.0), (3.0, 6.0, 12.0)
#: The data-driven start's candidate Schlick F0.
F0_CANDIDATES = (0.04, 0.25, 0.9)
#: How many candidate films (:func:`film_candidates`) a thin-film lobe's start tries.
FILM_CANDIDATES = 3
#: Rows a single large table's start is read from (a fixed random subset).
MAX_ROWS = 4096


@dataclass(frozen=True)
class Lobe:
    """One microfacet lobe of a composed family (:func:`~matfit.fitting.compose_family`).

    Parameters
    ----------
    distribution : {"ggx", "beckmann", "blinn_phong"}, default "ggx"
        The microfacet distribution.
    fresnel : {"schlick", "dielectric", "conductor", "thin_film"}, default "schlick"
        The lobe's Fresnel term (:class:`~matfit.models.SpecularLobe`).
    masking : {"separable", "height_correlated"}, default "separable"
        Smith masking form.

    Examples
    --------
    >>> from matfit.fitting import Lobe
    >>> Lobe("beckmann", fresnel="conductor").fresnel
    'conductor'
    """

    distribution: str = "ggx"
    fresnel: str = "schlick"
    masking: str = "separable"

    def __post_init__(self):
        for name, value, choices in (("distribution", self.distribution, tuple(DISTRIBUTIONS)),
                                     ("fresnel", self.fresnel, FRESNEL_KINDS), ("masking", self.masking, MASKING_FORMS)):
            if not isinstance(value, str) or value not in choices:
                raise ParameterError(f"Lobe: {name} must be one of {list(choices)}, got {value!r}")

    @property
    def alpha_upper(self) -> float:
        """The largest width a fit gives the lobe: 1 for Blinn-Phong (its exponent is negative
        beyond), 1.5 otherwise."""
        return 1.0 if self.distribution == "blinn_phong" else 1.5

    @property
    def fresnel_params(self) -> tuple:
        """The Fresnel parameters of the lobe: ``("f0",)``, ``("eta",)``, ``("eta", "k")`` or
        ``("thickness", "film_eta", "eta")``."""
        return FRESNEL_PARAMS[self.fresnel]


@dataclass(frozen=True)
class Slot:
    """One parameter of a composed family, what a :class:`~matfit.fitting.Param` is made from:
    ``name``, ``kind`` (``"albedo"``, ``"alpha"``, ``"ratio"``, ``"ks"``, ``"mix"`` or a Fresnel
    parameter), the 0-based ``lobes`` that read it (none for the albedo), bounds, ``per_channel``,
    a report line ``doc`` and the ``generic`` start.
    """

    name: str
    kind: str
    lobes: tuple
    lower: float
    upper: float
    per_channel: bool
    doc: str
    generic: float


def _fresnel_slot(kind, lobe, fresnel, per_channel, name, lobes):
    if kind == "f0":
        return Slot(name, kind, lobes, 0.0, 1.0, per_channel, "Schlick F0 (normal-incidence reflectance)", 0.04)
    if kind == "eta" and fresnel == "dielectric":
        return Slot(name, kind, lobes, 1.01, 4.0, per_channel, "dielectric index", 1.5)
    if kind == "eta" and fresnel == "thin_film":
        return Slot(name, kind, lobes, 1.01, 3.0, per_channel, "index under the film", FILM_GENERIC["eta"])
    if kind == "thickness":
        return Slot(name, kind, lobes, *FILM_THICKNESS_RANGE, per_channel, "film thickness (nm)",
                    FILM_GENERIC["thickness"])
    if kind == "film_eta":
        return Slot(name, kind, lobes, *FILM_ETA_RANGE, per_channel, "film index", FILM_GENERIC["film_eta"])
    if kind == "eta":
        return Slot(name, kind, lobes, *METAL_ETA_RANGE, per_channel, "conductor real index", 1.0)
    return Slot(name, kind, lobes, *METAL_K_RANGE, per_channel, "conductor extinction", 3.0)


#: A coat's slots: (name, bounds, generic start, doc).
COAT_SLOTS = (("alpha_coat", (1e-3, 1.0), 0.1, "coat GGX width"), ("eta_coat", (1.05, 2.5), 1.5, "coat index"))


def lobe_layout(base, lobes, weights, ordered, share, tied, coat=False):
    """The :class:`Slot` of every parameter of a composed family, in the order of the unconstrained
    vector (the arguments are :func:`~matfit.fitting.compose_family`'s). Raises ParameterError for
    an unknown option, a shared parameter of lobes with different Fresnel terms or of one lobe only.
    """
    owner = "compose_family"
    if not isinstance(coat, bool):
        raise ParameterError(f"{owner}: coat must be True or False, got {coat!r}")
    if base not in ("lambert", None):
        raise ParameterError(f"{owner}: base must be 'lambert' or None, got {base!r}")
    if weights not in WEIGHT_MODES:
        raise ParameterError(f"{owner}: weights must be one of {list(WEIGHT_MODES)}, got {weights!r}")
    for n in share:
        if n not in SHAREABLE:
            raise ParameterError(f"{owner}: share takes Fresnel parameter names {list(SHAREABLE)}, got {n!r}")
        users = [i + 1 for i, lb in enumerate(lobes) if n in lb.fresnel_params]
        kinds = {lb.fresnel for lb in lobes if n in lb.fresnel_params}
        if not kinds:
            raise ParameterError(f"{owner}: share {n!r}: no lobe has that parameter")
        if len(users) == 1 and len(lobes) > 1:
            # sharing is between lobes: with several lobes and one user it is a mistake
            raise ParameterError(f"{owner}: share {n!r}: only lobe {users[0]} has that parameter, there is nothing "
                                 f"to share it with")
        if len(kinds) > 1:
            raise ParameterError(f"{owner}: share {n!r}: the lobes that have it must have the same Fresnel term, "
                                 f"found {sorted(kinds)}")
    slots = []
    if base == "lambert":
        slots.append(Slot("albedo", "albedo", (), 0.0, 1.0, True, "diffuse albedo", 0.5))
    done = set()
    for j, lb in enumerate(lobes):
        i = j + 1
        if j == 0 or not ordered:
            generic = min(GENERIC_ALPHA * GENERIC_RATIO**j, 0.9 * lb.alpha_upper)
            slots.append(Slot(f"alpha_{i}", "alpha", (j,), 1e-3, lb.alpha_upper, False,
                              f"lobe {i} {lb.distribution} width", generic))
        else:
            slots.append(Slot(f"ratio_{i}", "ratio", (j,), *RATIO_BOUNDS, False, f"alpha_{i} / alpha_{i - 1}",
                              GENERIC_RATIO))
        if weights == "channels":
            slots.append(Slot(f"ks_{i}", "ks", (j,), 0.0, 1.0, True, f"lobe {i} weight", 0.5))
        elif weights == "mixture" and j > 0:
            slots.append(Slot(f"mix_{i}", "mix", (j,), 0.0, 1.0, False, f"lobe {i}'s share of lobes 1..{i}", 0.3))
        for kind in lb.fresnel_params:
            # the weight carries a Schlick lobe's colour when there is one (Löw's k_s): F0 is one value then
            per_channel = {"f0": weights != "channels", "eta": lb.fresnel == "conductor", "k": True,
                           "thickness": False, "film_eta": False}[kind]
            if kind in share:
                if kind in done:
                    continue
                done.add(kind)
                name, users = kind, tuple(m for m, other in enumerate(lobes) if kind in other.fresnel_params)
            else:
                name, users = f"{kind}_{i}", (j,)
            slots.append(_fresnel_slot(kind, lb, lb.fresnel, per_channel, name, users))
    if coat:
        slots += [Slot(n, n, (), lo, hi, False, doc, g) for n, (lo, hi), g, doc in COAT_SLOTS]
    names = [s.name for s in slots]
    for n in tied:
        if n not in names:
            raise ParameterError(f"{owner}: tied names {n!r}, which is not a parameter; the parameters are {names}")
    return tuple(Slot(s.name, s.kind, s.lobes, s.lower, s.upper, s.per_channel and s.name not in tied, s.doc, s.generic)
                 for s in slots)


def _k_from_reflectance(r0):
    """``k`` of a conductor with ``eta = 1`` and normal-incidence reflectance ``r0``:
    ``F(1) = k^2 / (4 + k^2)``."""
    r0 = np.clip(r0, 0.02, 0.95)
    return 2 * np.sqrt(r0 / (1 - r0))


def _eta_from_reflectance(r0):
    """The dielectric index of normal-incidence reflectance ``r0``."""
    s = np.sqrt(np.clip(r0, 1e-4, 0.3))
    return (1 + s) / (1 - s)


@dataclass(frozen=True)
class LobeSpec:
    """Everything a composed family knows (its base, lobes, weights, ordering, every parameter's
    :class:`Slot`, the ``(name, values)`` pairs it holds fixed and whether a rough dielectric coat
    lies over the lobes): the family's ``build`` (a call gives the :class:`~matfit.models.MultiLobe`
    of ``values``, C channels, or the :class:`~matfit.models.Layered` of the coat over it) and its
    data-driven start (the coat's width and index start at the generic guess: the lobes' start
    reads the peak as theirs).
    """

    base: Optional[str]
    lobes: tuple
    weights: str
    ordered: bool
    slots: tuple
    fixed: tuple = ()
    coat: bool = False

    def _slot(self, kind, j):
        return next(s for s in self.slots if s.kind == kind and j in s.lobes)

    def lobe_names(self, j):
        """``{kind: name}`` of the parameters lobe ``j`` (0-based) reads: ``"width"`` (``alpha_j``, or
        ``ratio_j`` of an ordered lobe after the first), ``"ks"`` or ``"mix"`` (a weight of its own)
        and its Fresnel parameters.
        """
        width = "ratio" if (self.ordered and j > 0) else "alpha"
        out = {"width": self._slot(width, j).name}
        if self.weights == "channels":
            out["ks"] = self._slot("ks", j).name
        elif self.weights == "mixture" and j > 0:
            out["mix"] = self._slot("mix", j).name
        for kind in self.lobes[j].fresnel_params:
            out[kind] = self._slot(kind, j).name
        return out

    def widths(self, values):
        """The lobes' widths from ``{name: value}`` (fixed ones may be left out): ratios multiplied
        out, an ordered Blinn-Phong lobe capped at 1 (its exponent is negative beyond).
        """
        p = {**{n: jnp.asarray(v) for n, v in self.fixed}, **values}
        out = []
        for j, lb in enumerate(self.lobes):
            names = self.lobe_names(j)
            a = p[names["width"]] * out[-1] if (self.ordered and j > 0) else p[names["width"]]
            out.append(jnp.minimum(a, 1.0) if lb.distribution == "blinn_phong" and self.ordered and j > 0 else a)
        return out

    def lobe_weights(self, values):
        """The lobes' weights from ``{name: value}``: ``ks_j``, the stick-breaking weights of ``mix_j``
        (lobe j takes the share ``mix_j`` of lobes 1..j, so that the weights sum to 1), or 1.
        """
        p = {**{n: jnp.asarray(v) for n, v in self.fixed}, **values}
        K = len(self.lobes)
        if self.weights == "channels":
            return [p[self.lobe_names(j)["ks"]] for j in range(K)]
        if self.weights == "none":
            return [1.0] * K
        out, rest = [None] * K, 1.0
        for j in range(K - 1, 0, -1):
            m = p[self.lobe_names(j)["mix"]]
            out[j] = m * rest
            rest = rest * (1 - m)
        out[0] = rest
        return out

    def __call__(self, values, C):
        """The :class:`~matfit.models.MultiLobe` of the free parameters' ``values`` (per channel: (C,))."""
        p = {**{n: jnp.asarray(v) for n, v in self.fixed}, **values}
        alphas, weights = self.widths(p), self.lobe_weights(p)
        lobes = []
        for j, lb in enumerate(self.lobes):
            names = self.lobe_names(j)
            fres = {kind: p[names[kind]] for kind in lb.fresnel_params}
            w = weights[j]
            lobes.append(SpecularLobe(alphas[j], lb.fresnel, w if self.weights == "channels" else jnp.asarray(w)[..., None],
                                      distribution=lb.distribution, masking=lb.masking, **fres))
        albedo = p["albedo"] if self.base == "lambert" else 0.0
        if self.coat:
            return Layered(RoughDielectric(p["alpha_coat"], p["eta_coat"]), MultiLobe(albedo, lobes))
        return MultiLobe(albedo, lobes)

    # ---------------------------------------------------------------------------------------------
    # The data-driven start
    # ---------------------------------------------------------------------------------------------
    def refine(self, WO, WI, V, M, guess, family) -> None:
        """The family's data-driven start (its :attr:`~matfit.fitting.Family.refine` hook): updates
        ``guess`` in place for the stack of tables ``WO, WI`` (B, N, 3), ``V`` (B, N, C), valid rows
        ``M``, with every parameter of ``family`` that is not a constant start.

        For every candidate of a small grid (the first lobe's width at :data:`WIDTH_FACTORS` of the
        peak's half width ``guess["alpha"]``, each next lobe :data:`WIDTH_RATIOS` times wider; a
        Schlick lobe's F0 at :data:`F0_CANDIDATES`; a thin film's :data:`FILM_CANDIDATES` best films),
        the diffuse albedo and the lobes' amplitudes per channel solve a non-negative weighted
        least-squares problem on the table's rows (the diffuse level read where the lobes are small,
        their heights near the mirror direction; weights ``1 / (f + median f)^2``, relative near the
        peak and absolute in the tail). The candidate with the smallest residual gives every start:
        widths, amplitudes (the weights ``ks_j``, the mixture shares, or the Fresnel level where the
        lobes are not weighted) and the Fresnel parameters (a conductor's ``k`` at ``eta = 1`` from its
        normal-incidence reflectance). A single table of more than :data:`MAX_ROWS` rows is read on a
        fixed random subset of them.
        """
        B, N, C = V.shape
        if B == 1 and N > MAX_ROWS:  # a large table: a fixed random subset of its valid rows
            rows = np.flatnonzero(M[0])
            if rows.size > MAX_ROWS:
                rows = np.sort(np.random.default_rng(0).choice(rows, MAX_ROWS, replace=False))
            WO, WI, V, M = WO[:, rows], WI[:, rows], V[:, rows], M[:, rows]
            N = V.shape[1]  # the subset's rows: the shapes below are the subset's
        V = np.asarray(V, float)
        ok = M & (WO[..., 2] > 1e-3) & (WI[..., 2] > 1e-3) & np.all(np.isfinite(V), axis=-1)
        y = np.where(ok[..., None], V, 0.0)
        ybar = y.mean(axis=-1)
        med = np.array([np.median(ybar[b][ok[b]]) if ok[b].any() else 0.0 for b in range(B)])
        W = np.where(ok, 1.0 / (ybar + med[:, None] + 1e-12) ** 2, 0.0)  # (B, N)
        h = WO + WI
        h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-12)
        cos_d = np.clip(np.sum(WO * h, axis=-1), 0.0, 1.0)
        fixed = {n: np.asarray(v, float) for n, v in self.fixed}
        free = {p.name for p in family.params} - set(family.starts)
        bounds = {p.name: (p.lower, p.upper) for p in family.params}

        diffuse_known = None
        if self.base == "lambert" and "albedo" in fixed:
            diffuse_known = np.broadcast_to(fixed["albedo"], (C,))
        if self.base is None:
            diffuse_known = np.zeros(C)
        target = y - (0.0 if diffuse_known is None else np.where(ok[..., None], diffuse_known / np.pi, 0.0))

        alpha0 = np.asarray(guess.get("alpha", np.full(B, 0.1)), float).reshape(B)
        K = len(self.lobes)
        cands, xs, ress = [], [], []
        width_sets = self._width_candidates(alpha0, fixed)
        # D G2 / (4 cos cos) of every lobe at every candidate width: (G, B, N) per lobe
        dgs = [self._microfacet_factor(WO, WI, np.stack([ws[j] for ws in width_sets]), j) for j in range(K)]
        film_levels = self._film_candidates(h, V, ok, cos_d, fixed)
        for g, width_set in enumerate(width_sets):
            dg = [d[g] for d in dgs]
            for level in self._fresnel_candidates(fixed, film_levels):
                cols = [] if diffuse_known is not None else [np.broadcast_to(np.where(ok, 1 / np.pi, 0.0)[..., None],
                                                                             (B, N, C))]
                cols += [dg[j][..., None] * self._fresnel_basis(j, level, cos_d, C) for j in range(K)]
                x, res = _nnls_channels(np.stack(cols, axis=-1), target, W)  # columns (B, N, C, P)
                cands.append((width_set, level))
                xs.append(x)
                ress.append(res)
        pick = np.argmin(np.stack(ress, axis=1), axis=1)  # the best candidate per table
        x = np.stack(xs, axis=1)[np.arange(B), pick]  # (B, C, P)
        width_set = [np.array([cands[g][0][j][b] for b, g in enumerate(pick)]) for j in range(K)]
        # a candidate level is one value for every table (F0) or one per table (a film's)
        level = {n: np.array([float(np.broadcast_to(cands[g][1][n], (B,))[b]) for b, g in enumerate(pick)])
                 for n in cands[0][1]}
        off = 0 if diffuse_known is not None else 1
        amps = [x[..., off + j] for j in range(K)]  # (B, C) each
        out = {}
        if off:
            out["albedo"] = x[..., 0]
        # widths
        for j in range(K):
            name = self.lobe_names(j)["width"]
            out[name] = width_set[j] / width_set[j - 1] if (self.ordered and j > 0) else width_set[j]
        # amplitudes -> weights and Fresnel levels
        levels = self._levels_from_amplitudes(amps, level, C, B)
        if self.weights == "channels":
            for j in range(K):
                out[self.lobe_names(j)["ks"]] = levels["ks"][j]
        elif self.weights == "mixture":
            shares = np.stack([a.sum(axis=-1) for a in amps], axis=-1)  # (B, K)
            shares = shares / np.maximum(shares.sum(axis=-1, keepdims=True), 1e-12)
            shares = np.where(np.all(shares == 0, axis=-1, keepdims=True), 1.0 / K, shares)
            rest = np.ones(B)
            for j in range(K - 1, 0, -1):
                # stick-breaking backwards: lobe j's share of lobes 1..j
                out[self.lobe_names(j)["mix"]] = np.clip(shares[:, j] / np.maximum(rest, 1e-12), 0, 1)
                rest = rest - shares[:, j]
        for j, lb in enumerate(self.lobes):
            for kind in lb.fresnel_params:
                name = self.lobe_names(j)[kind]
                val = levels[kind][j]
                out.setdefault(name, []).append(val)
        by_name = {s.name: s for s in self.slots}
        for name, val in out.items():
            if name not in free:
                continue
            if isinstance(val, list):  # a Fresnel parameter of one or several lobes: their mean
                val = np.mean(np.stack(val), axis=0)
            val = np.asarray(val, float)
            if by_name[name].per_channel:
                val = np.broadcast_to(val.reshape((B, -1)), (B, C)).copy()
            else:
                val = val.reshape((B, -1)).mean(axis=1)
            lo, hi = bounds[name]
            guess[name] = np.clip(val, lo, hi)

    def _width_candidates(self, alpha0, fixed):
        """Candidate widths of every lobe: ``[(B,) per lobe]`` per candidate."""
        out = []
        for m1 in WIDTH_FACTORS:
            for ratio in WIDTH_RATIOS:
                ws = []
                for j, lb in enumerate(self.lobes):
                    name = self.lobe_names(j)["width"]
                    if name in fixed:
                        a = float(fixed[name]) * (ws[-1] if (self.ordered and j > 0) else 1.0)
                    elif j == 0:
                        a = np.clip(alpha0 * m1, 2e-3, 0.9 * lb.alpha_upper)
                    else:
                        a = ws[-1] * ratio
                    ws.append(np.minimum(np.broadcast_to(a, alpha0.shape), lb.alpha_upper))
                out.append(ws)
        return out

    def _film_candidates(self, h, V, ok, cos_d, fixed):
        """The thin-film lobes' candidate films (:func:`film_candidates`) from the rows' unit half
        vectors ``h``: a list of dicts ``{parameter name: (B,)}``, or ``[{}]`` without a thin-film
        lobe (or with its film fixed)."""
        films = [j for j, lb in enumerate(self.lobes) if lb.fresnel == "thin_film"]
        if not films or V.shape[-1] != 3:
            return [{}]
        th_h = np.degrees(np.arccos(np.clip(h[..., 2], -1, 1)))
        out = []
        for c in film_candidates(th_h, cos_d, V, ok, n=FILM_CANDIDATES):
            level = {}
            for j in films:
                names = self.lobe_names(j)
                for kind in ("thickness", "film_eta", "eta"):
                    if names[kind] not in fixed:
                        level[names[kind]] = c[kind]
            out.append(level)
        return out

    def _fresnel_candidates(self, fixed, films=({},)):
        """Candidate Fresnel levels: dicts ``{parameter name: value}``, one per candidate (Schlick
        F0 levels crossed with the candidate films ``films``)."""
        f0_names = sorted({self.lobe_names(j)["f0"] for j, lb in enumerate(self.lobes) if lb.fresnel == "schlick"})
        free_f0 = [n for n in f0_names if n not in fixed]
        f0s = [{n: np.asarray(v) for n in free_f0} for v in F0_CANDIDATES] if free_f0 else [{}]
        return [{**a, **b} for a in f0s for b in films]

    def _fresnel_basis(self, j, level, cos_d, C):
        """Lobe ``j``'s Fresnel factor of the basis, ``(B, N, C)``: Schlick's of the candidate (or
        fixed) F0, the dielectric Fresnel of the fixed index or 1.5, and 1 for a conductor (its
        level is the amplitude)."""
        lb = self.lobes[j]
        names = self.lobe_names(j)
        fixed = dict(self.fixed)
        if lb.fresnel == "schlick":
            f0 = np.asarray(level[names["f0"]] if names["f0"] in level else fixed.get(names["f0"], 0.04), float)
            F = f0 + (1 - f0) * (1 - cos_d[..., None]) ** 5
        elif lb.fresnel == "dielectric":
            eta = np.asarray(fixed.get(names["eta"], 1.5), float)
            F = np.asarray(fresnel_dielectric(jnp.asarray(cos_d[..., None]), jnp.asarray(eta)), float)
        elif lb.fresnel == "thin_film":
            B = cos_d.shape[0]

            def per_table(kind):
                v = level[names[kind]] if names[kind] in level else fixed.get(names[kind], FILM_GENERIC[kind])
                return jnp.asarray(np.broadcast_to(np.asarray(v, float), (B,))[:, None])

            F = np.asarray(_film_rgb(jnp.asarray(cos_d), per_table("thickness"), per_table("film_eta"),
                                     per_table("eta")), float)
        else:
            F = np.ones(cos_d.shape + (1,))
        return np.broadcast_to(F, cos_d.shape + (C,))

    def _levels_from_amplitudes(self, amps, level, C, B):
        """The weights and Fresnel parameters of the lobes from their amplitudes ``(B, C)``."""
        fixed = dict(self.fixed)
        K = len(self.lobes)
        total = sum(amps)  # (B, C)
        out = {"ks": [None] * K, "f0": [None] * K, "eta": [None] * K, "k": [None] * K, "thickness": [None] * K,
               "film_eta": [None] * K}
        for j, lb in enumerate(self.lobes):
            names = self.lobe_names(j)
            a = amps[j]
            # the Fresnel level a lobe's amplitude stands for: its own (weights none), the
            # lobes' total (a mixture), or none (per-channel weights carry it)
            scale = {"channels": None, "mixture": total, "none": a}[self.weights]
            if lb.fresnel == "schlick":
                f0 = np.asarray(level.get(names["f0"], fixed.get(names["f0"], 0.04)), float)
                f0 = np.broadcast_to(f0.reshape((B, -1)) if f0.ndim else f0, (B, C))
                out["f0"][j] = f0 if scale is None else np.clip(scale * f0, 0.005, 0.99)
                out["ks"][j] = a
            elif lb.fresnel == "thin_film":
                # the film of the candidate; its level is the weight's (the film is not scaled)
                for kind, default in FILM_GENERIC.items():
                    v = level.get(names[kind], fixed.get(names[kind], default))
                    out[kind][j] = np.broadcast_to(np.asarray(v, float).reshape((-1, 1)), (B, C))
                out["ks"][j] = a if scale is None else np.clip(a / np.maximum(scale, 1e-12), 0.0, 1.0)
            elif lb.fresnel == "dielectric":
                eta = float(np.mean(fixed.get(names["eta"], 1.5)))
                r0 = ((eta - 1) / (eta + 1)) ** 2
                out["eta"][j] = np.full((B, C), eta) if scale is None else _eta_from_reflectance(scale * r0)
                out["ks"][j] = a
            else:
                r0 = a / 0.9 if scale is None else scale
                out["eta"][j] = np.ones((B, C))
                out["k"][j] = _k_from_reflectance(r0)
                out["ks"][j] = np.full((B, C), 0.9) if scale is None else a
        return out

    def _microfacet_factor(self, WO, WI, alpha, j):
        """``D G2 / (4 cos cos)`` of lobe ``j`` at the widths ``alpha`` (G, B) on the rows: (G, B, N),
        in chunks of candidates (a texel map's stack of tables holds many rows)."""
        lb = self.lobes[j]
        G, B = alpha.shape
        step = max(1, int(2**21 // max(WO.shape[0] * WO.shape[1], 1)))
        out = [np.asarray(_lobe_factor(jnp.asarray(alpha[g:g + step, :, None]), jnp.asarray(WO[None]),
                                       jnp.asarray(WI[None]), lb.distribution, lb.masking), float)
               for g in range(0, G, step)]
        return np.concatenate(out)


_film_rgb = jax.jit(fresnel_thin_film)


@functools.partial(jax.jit, static_argnums=(3, 4))
def _lobe_factor(alpha, wo, wi, distribution, masking):
    """The Fresnel-free lobe of widths ``alpha`` (G, B, 1) on directions (1, B, N, 3)."""
    lobe = SpecularLobe(alpha, "schlick", 1.0, f0=1.0, distribution=distribution, masking=masking)
    return lobe.eval_pairs(SoAPairs.of(wo, wi))[..., 0]


def _nnls_channels(A, y, W):
    """Non-negative weighted least squares per table and channel (two active-set passes).

    ``A`` (B, N, C, P), ``y`` (B, N, C), ``W`` (B, N): returns the amplitudes ``x`` (B, C, P) and
    the weighted residual summed over the channels (B,)."""
    P = A.shape[-1]
    G = np.einsum("bn,bncp,bncq->bcpq", W, A, A)
    r = np.einsum("bn,bncp,bnc->bcp", W, A, y)
    scale = np.maximum(np.einsum("bcpp->bcp", G), 1e-300)
    eye = np.eye(P)
    active = np.ones(G.shape[:-1], bool)
    x = np.zeros(r.shape)
    for _ in range(3):
        mask = active[..., :, None] & active[..., None, :]
        Gm = np.where(mask, G, 0.0) + np.where(active, 0.0, 1.0)[..., None] * eye + 1e-10 * scale[..., None] * eye
        x = np.linalg.solve(Gm, np.where(active, r, 0.0)[..., None])[..., 0]
        x = np.where(active, x, 0.0)
        if np.all(x >= 0):
            break
        active = active & (x > 0)
    x = np.maximum(x, 0.0)
    res = np.einsum("bn,bnc->b", W, (y - np.einsum("bncp,bcp->bnc", A, x)) ** 2)
    return x, res


@dataclass(frozen=True)
class LobeRefine:
    """The :attr:`~matfit.fitting.Family.refine` hook of a composed family: :meth:`LobeSpec.refine` as
    a value (two families composed alike compare equal, hooks included).
    """

    spec: LobeSpec

    def __call__(self, WO, WI, V, M, guess, family) -> None:
        """Refine ``guess`` in place (:meth:`LobeSpec.refine`)."""
        self.spec.refine(WO, WI, V, M, guess, family)
