r"""Which family: cheap cues of the data pick the candidates, the rendered images pick the winner.

:func:`choose_family` is what ``fit(table)`` and ``matfit fit FILE`` run when no family is named:

1. **Cues** (:func:`appearance_cues`), from the table alone, in the half/difference angles
   :math:`\theta_h, \theta_d`: the specular ratio (the 90th percentile near the mirror,
   :math:`\theta_h < 5°, \theta_d < 30°`, or the ten rows closest to the mirror, over the floor,
   the lower decile off it, :math:`\theta_h > 30°`, both angles below 70°); a coloured highlight
   (the saturation of the near-mirror excess over the floor's colour, where the specular ratio
   is above 2); a colour change with angle (the spread of that excess's chromaticity over the
   bands :math:`\theta_d` 0-20-40-60-90°); an excess at grazing angles (off-mirror rows with
   both angles past 70° over the floor, where the floor is diffuse: specular ratio below 10; a
   sheen lobe only where the backward rows, both directions on one side, show it too); a second
   lobe (the RMS, in log, of the peak's excess over the floor about the best single GGX shape in
   :math:`\theta_h`); an azimuthal dependence (the spread of log values over the half vector's
   azimuth in cells of :math:`\theta_h, \theta_d`, about a plane in those angles).
2. **Candidates**: ``lambert``, ``plastic``, ``lobes1`` and ``lobes2`` always; ``lobes3`` with a
   second lobe; ``car_paint`` with a coloured highlight or a colour change; ``film`` (a thin-film
   lobe) with a colour change; ``sheen`` with a grazing excess that the backward rows show too;
   ``conductor`` with a coloured highlight or a dark floor (specular ratio above 50);
   ``conductor_aniso`` (brushed metal) with an azimuthal dependence over a dark floor, measured in
   two planes of incidence or more.
3. **Judge**: every candidate is fitted, rendered beside the measurement under each lighting of
   :data:`~matfit.appearance.JUDGE_LIGHTS` and scored by
   :math:`s = \max_\text{lights}\max(\text{FLIP}/0.05,\ \text{CIEDE2000}/1.5)`: :math:`s \le 1`
   is the line under which the two look alike. The chosen family is the one of fewest
   parameters whose score is within :data:`SCORE_TOL` (10 %) of the best; the runner-up is the
   best of the others. Without a reference to render (a table from no file, no truth; or
   channels other than 1 or 3), the families are compared on a held-out split instead
   (:func:`~matfit.fitting.compare_models`).
"""

from __future__ import annotations

import functools
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from ..errors import ParameterError
from ..table import Table
from ._film_guess import BANDS, NEAR_DEGREES
from ._result import FitError
from .fit import fit as _fit_named

#: Families every choice tries; the cues add others.
BASE_CANDIDATES = ("lambert", "plastic", "lobes1", "lobes2")
#: The loss of a fit chosen by appearance (E2 gave the lowest image error on the RGL files:
#: docs/fitting.md, "Choosing the family").
CHOICE_LOSS = "e2"
#: A candidate within this relative margin of the best score counts as as good.
SCORE_TOL = 0.10
#: Cue thresholds (see the module docstring).
CUE_LINES = {"second_lobe": 0.25, "coloured_highlight": 0.15, "colour_shift": 0.1, "grazing_excess": 1.5,
             "azimuthal": 0.1, "dark_floor": 50.0}


def _angles(table):
    wo, wi = np.asarray(table.wo, float), np.asarray(table.wi, float)
    h = wo + wi
    h /= np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-12)
    th_h = np.degrees(np.arccos(np.clip(h[:, 2], -1, 1)))
    th_d = np.degrees(np.arccos(np.clip(np.sum(wi * h, 1), -1, 1)))
    ph_h = np.degrees(np.arctan2(h[:, 1], h[:, 0]))
    return th_h, th_d, ph_h, np.degrees(np.arccos(np.clip(wi[:, 2], -1, 1))), np.degrees(
        np.arccos(np.clip(wo[:, 2], -1, 1)))


def highlight_hues(table, model=None):
    """The hue (degrees, HSV) of the highlight per band of difference angle (``BANDS`` of
    ``_film_guess.py``): the mean RGB of the rows within ``NEAR_DEGREES`` of the mirror direction.
    A thin film shows in data as a hue that turns from band to band; a fit that carries the film
    turns with it.

    Parameters
    ----------
    table : matfit.Table
        An RGB table.
    model : matfit.models.AbstractBSDF, optional
        A model evaluated on the table's rows instead of the values.

    Returns
    -------
    numpy.ndarray (4,)
        Hue per band (NaN where a band has no rows or no colour).

    Examples
    --------
    >>> import numpy as np
    >>> from matfit import Table
    >>> from matfit.fitting import highlight_hues
    >>> wo = np.array([[0.0, 0.1, 0.99]]); wo /= np.linalg.norm(wo)
    >>> highlight_hues(Table(wo=wo, wi=wo * [1, -1, 1], values=[[1.0, 0.5, 0.0]])).round(1).tolist()  # orange
    [30.0, nan, nan, nan]
    """
    import colorsys

    import jax.numpy as jnp

    th_h, th_d = _angles(table)[:2]
    v = np.asarray(table.values, float) if model is None else np.asarray(
        model.eval(jnp.asarray(table.wo), jnp.asarray(table.wi)))
    out = np.full(len(BANDS), np.nan)
    for i, (lo, hi) in enumerate(BANDS):
        m = (th_h < NEAR_DEGREES) & (th_d >= lo) & (th_d < hi) & np.all(np.isfinite(v), axis=-1)
        mean = v[m].mean(0) if m.any() else np.zeros(3)
        if mean.max() > 0 and mean.max() > mean.min():
            out[i] = colorsys.rgb_to_hsv(*(np.clip(mean, 0, None) / mean.max()))[0] * 360
    return out


def _chroma(v):
    v = np.clip(v, 0, None)
    return v / max(float(v.sum()), 1e-12)


_PROFILE_EDGES = np.array([0, 0.5, 1, 1.5, 2, 3, 4, 5, 6, 8, 10, 12.5, 15, 20, 25, 30, 40, 50, 60, 75])


def _lobe_misfit(th_h, lum, floor):
    """RMS (natural log) of the near-mirror excess over the floor about the best single GGX shape
    ``1 / (cos^4 (alpha^2 + tan^2))^2`` (alpha on a grid, amplitude free); NaN without a peak."""
    if not np.isfinite(floor) or th_h.size < 20:
        return float("nan")
    idx = np.digitize(th_h, _PROFILE_EDGES) - 1
    cen, ex = [], []
    for b in range(len(_PROFILE_EDGES) - 1):
        m = idx == b
        if m.sum() >= 2:
            cen.append(np.radians(np.median(th_h[m])))
            ex.append(np.median(lum[m]) - floor)
    cen, ex = np.array(cen), np.array(ex)
    if ex.size < 4 or ex[0] <= 0.5 * max(floor, 1e-12):
        return float("nan")
    keep = ex > 0.03 * ex[0]  # below, the floor's own variation (a coat's Fresnel) dominates
    cen, lex = cen[keep], np.log(ex[keep])
    if cen.size < 4:
        return float("nan")
    best = np.inf
    for a in np.geomspace(0.005, 1.0, 80):
        shape = -np.log(np.cos(cen) ** 4 * (a * a + np.tan(cen) ** 2) ** 2)
        best = min(best, float(np.std(lex - shape)))
    return best


def appearance_cues(table):
    """The cues of :func:`choose_family` for ``table`` (see the module docstring).

    Parameters
    ----------
    table : matfit.Table

    Returns
    -------
    dict
        Each cue's value (``specular_ratio``, ``highlight_saturation``, ``colour_spread``,
        ``grazing_ratio``, ``grazing_back_ratio`` (over the backward grazing rows only),
        ``lobe_misfit``, ``azimuthal_spread``; NaN where the table has too few rows for it),
        ``incidence_planes`` (planes of incidence with rows: 15-degree bins of the light's azimuth) and the
        booleans ``second_lobe``, ``coloured_highlight``, ``colour_shift``, ``grazing_excess``,
        ``azimuthal``, ``dark_floor``.

    Examples
    --------
    >>> import numpy as np
    >>> from matfit import Table
    >>> wo = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, 0.6, 0.8]]); wi = wo[[1, 2, 0]]
    >>> sorted(k for k, v in appearance_cues(Table(wo=wo, wi=wi, values=np.ones((3, 3)))).items() if v is True)
    []
    """
    if not isinstance(table, Table):
        raise ParameterError(f"appearance_cues: expected a matfit.Table, got {type(table).__name__}")
    ok = np.asarray(table.valid, bool) & np.all(np.isfinite(table.values), axis=1)
    y = np.asarray(table.values, float)
    th_h, th_d, ph_h, th_i, th_o = _angles(table)
    lum = y @ np.array([0.2126, 0.7152, 0.0722]) if y.shape[1] == 3 else y.mean(axis=1)
    # near the mirror: th_h < 5 deg, or the ten rows closest to it (a rough material's table may
    # hold none that close); off it: th_h > 30 deg in range, or the farthest tenth of the rows
    d30 = ok & (th_d < 30)
    lim = max(5.0, float(np.sort(th_h[d30])[min(9, d30.sum() - 1)])) if d30.any() else 5.0
    near = d30 & (th_h <= lim)
    inrange = ok & (th_i < 70) & (th_o < 70)
    off = inrange & (th_h > 30)
    if off.sum() < 3 and ok.sum() >= 30:
        off = ok & (th_h >= np.percentile(th_h[ok], 90))
    nan = float("nan")
    c = {k: nan for k in ("specular_ratio", "highlight_saturation", "colour_spread", "grazing_ratio",
                          "grazing_back_ratio", "lobe_misfit", "azimuthal_spread")}
    # the floor: the lower decile of the in-range rows off the mirror (a diffuse level, ~0 for a metal)
    floor = float(np.percentile(lum[off], 10)) if off.sum() >= 3 else nan
    if near.sum() >= 3 and off.sum() >= 3:
        peak = float(np.percentile(lum[near], 90))
        c["specular_ratio"] = peak / max(floor, 1e-12)
        if y.shape[1] == 3 and c["specular_ratio"] > 2:
            # the highlight's own colour: the excess over the floor's colour (a white coat's
            # highlight on a red paint is white), overall and per band of th_d
            base = np.percentile(y[off], 10, axis=0)
            spec = np.median(y[near], 0) - base
            c["highlight_saturation"] = float((spec.max() - max(spec.min(), 0)) / spec.max())
            mirror = ok & (th_h <= lim)
            chrom = []
            for a, b in BANDS:
                m = mirror & (th_d >= a) & (th_d < b)
                if m.sum() >= 3:
                    ex = np.median(y[m], 0) - base
                    if ex.sum() > 0.5 * base.sum():
                        chrom.append(_chroma(ex))
            if len(chrom) >= 2:
                c["colour_spread"] = float(max(np.abs(p - q).max() for p in chrom for q in chrom))
        band = ok & (th_d < 30) & (th_h > 30) & (th_h < 45)
        local = float(np.median(lum[band])) if band.sum() >= 3 else floor
        c["lobe_misfit"] = _lobe_misfit(th_h[ok & (th_d < 30)], lum[ok & (th_d < 30)], local)
    graz = ok & (th_i > 70) & (th_o > 70) & (th_h > 30)
    if graz.sum() >= 3 and np.isfinite(floor) and not c["specular_ratio"] >= 10:  # a diffuse floor
        c["grazing_ratio"] = float(np.median(lum[graz]) / max(floor, 1e-12))
        # backward: the two directions on the same side of the normal (a sheen lobe lifts these
        # too; a grazing Fresnel rise or a wide forward lobe lifts only the forward ones)
        wo, wi = np.asarray(table.wo, float), np.asarray(table.wi, float)
        back = graz & (wo[:, 0] * wi[:, 0] + wo[:, 1] * wi[:, 1] > 0)
        if back.sum() >= 3:
            c["grazing_back_ratio"] = float(np.median(lum[back]) / max(floor, 1e-12))
    # azimuthal dependence: in (th_h, th_d) cells, the spread of log values about a plane in
    # (th_h, th_d) (the lobe's own slope removed) over rows of different half-vector azimuth
    spreads = []
    for a in np.arange(5, 30, 2.5):
        for b in range(0, 60, 10):
            m = ok & (th_h >= a) & (th_h < a + 2.5) & (th_d >= b) & (th_d < b + 10) & (lum > 0)
            if m.sum() >= 8 and np.ptp(ph_h[m]) > 90:
                X = np.stack([np.ones(m.sum()), th_h[m], th_d[m]], 1)
                q = np.log(lum[m])
                res = q - X @ np.linalg.lstsq(X, q, rcond=None)[0]
                spreads.append(float(np.std(res)))
    if spreads:
        c["azimuthal_spread"] = float(np.median(spreads))
    # planes of incidence (15-degree bins of the light's azimuth, modulo 180, with 3 rows or more):
    # a table measured in one plane (an isotropic RGL file's) cannot tell an anisotropic lobe from
    # masking narrowing an isotropic one along that plane
    wi = np.asarray(table.wi, float)[ok]
    tilted = wi[:, 2] < 0.99
    az = np.degrees(np.arctan2(wi[tilted, 1], wi[tilted, 0]))
    bins = np.mod(np.floor((np.mod(az, 180.0) + 7.5) / 15.0), 12).astype(int)  # 0 and 180 deg: one bin
    c["incidence_planes"] = int(np.sum(np.bincount(bins, minlength=12) >= 3)) if bins.size else 0
    L = CUE_LINES
    c.update(second_lobe=bool(c["lobe_misfit"] > L["second_lobe"]),
             coloured_highlight=bool(c["highlight_saturation"] > L["coloured_highlight"]),
             colour_shift=bool(c["colour_spread"] > L["colour_shift"]),
             grazing_excess=bool(c["grazing_ratio"] > L["grazing_excess"]),
             azimuthal=bool(c["azimuthal_spread"] > L["azimuthal"]),
             dark_floor=bool(c["specular_ratio"] > L["dark_floor"]))
    return c


def candidates_for(cues):
    """The candidate families for ``cues`` (from :func:`appearance_cues`), and why each is there.

    Parameters
    ----------
    cues : dict

    Returns
    -------
    dict
        ``{family: reason}``, in order of parameter count.

    Examples
    --------
    >>> list(candidates_for({"second_lobe": True}))
    ['lambert', 'plastic', 'lobes1', 'lobes2', 'lobes3']
    """
    out = {f: "always tried" for f in BASE_CANDIDATES}
    if cues.get("second_lobe"):
        out["lobes3"] = "the peak has a second width"
    if cues.get("coloured_highlight") or cues.get("colour_shift"):
        out["car_paint"] = "a coloured highlight" if cues.get("coloured_highlight") else "colour changes with angle"
    if cues.get("colour_shift"):
        out["film"] = "the highlight's hue turns with angle (a thin film)"
    if _backward_grazing(cues):
        out["sheen"] = "an excess at grazing angles, backward as well as forward (a sheen)"
    if cues.get("dark_floor") or cues.get("coloured_highlight"):
        out["conductor"] = "a dark floor under a strong peak" if cues.get("dark_floor") else "a coloured highlight"
    if _anisotropic_metal(cues):
        out["conductor_aniso"] = "an azimuthal dependence under a dark floor (a brushed metal)"
    from .families import FAMILIES
    from .params import Parametrization

    return dict(sorted(out.items(), key=lambda kv: Parametrization(kv[0], 3).size if kv[0] in FAMILIES else 0))


#: What a cue says no registered family carries (a grazing excess backward as well as forward
#: is the sheen family's).
_MISSING = {"grazing_excess": "", "azimuthal": "an azimuthal dependence (anisotropy)"}
#: An azimuthal dependence in a table measured in one plane of incidence (an isotropic RGL file).
_ONE_PLANE = ("an azimuthal dependence in one plane of incidence (anisotropy, or masking narrowing an isotropic "
              "lobe along that plane: the table cannot tell them apart)")
#: The grazing excess when the backward grazing rows show none, or the table holds none.
_FORWARD_GRAZING = {
    "none": "an excess at forward grazing angles only (a grazing Fresnel rise or a wide forward lobe; no backward "
            "excess, so not a sheen lobe)",
    "unknown": "an excess at forward grazing angles (a grazing Fresnel rise, a wide forward lobe or a sheen lobe: "
               "the table holds no backward grazing rows to tell them apart)"}


def _anisotropic_metal(cues):
    """An azimuthal dependence of a peak over a dark floor: the anisotropic conductor's."""
    return bool(cues.get("azimuthal")) and bool(cues.get("dark_floor")) and cues.get("incidence_planes", 0) >= 2


def _backward_grazing(cues):
    """A grazing excess that the backward grazing rows show too: a sheen."""
    return bool(cues.get("grazing_excess")) and cues.get("grazing_back_ratio", np.nan) > CUE_LINES["grazing_excess"]


def _missing(cues):
    """What the cues see that no registered family carries (one phrase each)."""
    out = []
    for k, text in _MISSING.items():
        if not cues.get(k):
            continue
        if k == "grazing_excess":
            if _backward_grazing(cues):
                continue  # the sheen family carries it
            back = cues.get("grazing_back_ratio", np.nan)
            text = _FORWARD_GRAZING["none" if np.isfinite(back) else "unknown"]
        elif k == "azimuthal" and _anisotropic_metal(cues):
            continue  # the anisotropic conductor carries it
        elif k == "azimuthal" and cues.get("incidence_planes", 2) < 2:
            text = _ONE_PLANE
        out.append(text)
    return out


@dataclass
class Choice:
    """How :func:`choose_family` chose.

    Attributes
    ----------
    chosen, runner_up : str, str or None
    reason : str
        One sentence: why the chosen family.
    judged_by : str
        ``"appearance"`` (rendered images) or ``"held-out error"``.
    rows : list of dict
        Per candidate: ``family``, ``p``, ``why`` (why a candidate), ``score``, the image means
        per lighting (``appearance``), ``objective``, or ``error``.
    cues : dict
        :func:`appearance_cues`.
    missing : list of str
        Effects the cues see that no registered family carries.

    Examples
    --------
    >>> c = Choice("lambert", None, "only candidate", "appearance")
    >>> c.summary(), c.to_dict()["chosen"]
    ('chose lambert by appearance: only candidate', 'lambert')
    """

    chosen: str
    runner_up: object
    reason: str
    judged_by: str
    rows: list = field(default_factory=list)
    cues: dict = field(default_factory=dict)
    missing: list = field(default_factory=list)

    def to_dict(self):
        """For JSON: everything but the fits and images."""
        return {"chosen": self.chosen, "runner_up": self.runner_up, "reason": self.reason,
                "judged_by": self.judged_by, "missing": list(self.missing),
                "cues": {k: (v if isinstance(v, bool) else (None if not np.isfinite(v) else float(v)))
                         for k, v in self.cues.items()},
                "candidates": [{k: v for k, v in r.items() if k not in ("result", "diff")} for r in self.rows]}

    def summary(self):
        """A few lines: the chosen family, why, and the candidates' scores."""
        lines = [f"chose {self.chosen} by {self.judged_by}: {self.reason}"]
        for r in self.rows:
            if "error" in r:
                lines.append(f"  {r['family']:14s} p={r['p']:2d}  failed: {r['error']}")
            elif "score" in r:
                lines.append(f"  {r['family']:14s} p={r['p']:2d}  score {r['score']:.2f}  " + "; ".join(
                    f"{k}: FLIP {m['flip']:.3f}, CIEDE2000 {m['ciede2000']:.2f}" for k, m in r["appearance"].items()))
            else:
                lines.append(f"  {r['family']:14s} p={r['p']:2d}  held-out RMSE {r['holdout_rmse']:.4g}")
        if self.missing:
            lines.append("  the data show effects no family here carries: " + "; ".join(self.missing))
        return "\n".join(lines)


def _score(diff):
    from ..appearance import CIEDE2000_LINE, FLIP_LINE

    return max(max(d.means["flip"] / FLIP_LINE, d.means["ciede2000"] / CIEDE2000_LINE) for d in diff.lights.values())


def choose_family(table, reference="auto", candidates=None, loss=None, log=None, workers=2, **fit_kwargs):
    """Fit the candidate families and keep the one whose render looks most like the reference's.

    Parameters
    ----------
    table : matfit.Table
    reference : "auto", matfit model or None
        The material to look like: ``"auto"`` reads the file the table came from
        (:func:`~matfit.models.measured_model`); a model (e.g. a synthetic table's truth);
        None compares on a held-out split instead.
    candidates : sequence of str, optional
        Families to try (default: chosen by the cues, :func:`candidates_for`).
    loss : str, optional
        The fits' loss (default :data:`CHOICE_LOSS`).
    log : callable, optional
        Where a line per candidate goes.
    workers : int, default 2
        Candidates fitted and judged at once (threads; 1: one after the other).
    **fit_kwargs
        Passed to :func:`~matfit.fitting.robust_fit` (``method``, ``starts``, ``seed``, ...).

    Returns
    -------
    tuple
        The chosen :class:`~matfit.fitting.FitResult` (``choice`` set to the :class:`Choice`,
        ``appearance`` to its :class:`~matfit.appearance.AppearanceDiff`) and the :class:`Choice`
        (an example: ``docs/examples.md``).
    """
    from ..models import measured_model
    from .families import FAMILIES
    from .params import Parametrization
    from .select import compare_models, robust_fit

    if not isinstance(table, Table):
        raise ParameterError(f"choose_family: table must be a matfit.Table, got {type(table).__name__}")
    say = log or (lambda *a: None)
    loss = CHOICE_LOSS if loss is None else loss
    cues = appearance_cues(table)
    why = candidates_for(cues) if candidates is None else {f: "asked for" for f in candidates}
    unknown = [f for f in why if f not in FAMILIES]
    if unknown or not why:
        raise ParameterError(f"choose_family: unknown families {unknown}; expected some of {sorted(FAMILIES)}")
    missing = _missing(cues)
    ref = measured_model(table) if isinstance(reference, str) and reference == "auto" else reference
    C = table.n_channels
    if C not in (1, 3):
        ref = None  # spectral channels: no sRGB image to judge
    if ref is None:
        cmp = compare_models(table, models=list(why), loss=loss, **fit_kwargs)
        rows = [{"family": r["model"], "p": Parametrization(r["model"], C).size, "why": why[r["model"]],
                 **({"error": r["error"]} if "error" in r else {"holdout_rmse": float(r["holdout_rmse"])})}
                for r in cmp.rows]
        chosen = cmp.recommended
        result = robust_fit(table, chosen, loss=loss, **fit_kwargs)
        others = [r for r in rows if r["family"] != chosen and "holdout_rmse" in r]
        runner = min(others, key=lambda r: r["holdout_rmse"])["family"] if others else None
        choice = Choice(chosen, runner, "no measured file or truth to render: the fewest parameters within "
                        f"{cmp.tol:.0%} of the best held-out RMSE", "held-out error", rows, cues, missing)
        result.choice, result.appearance = choice, None
        return result, choice
    from ..appearance import render_references, appearance_difference

    refs = render_references(ref)
    def candidate(fam):
        row = {"family": fam, "p": Parametrization(fam, C).size, "why": why[fam]}
        try:
            r = robust_fit(table, fam, loss=loss, **fit_kwargs)
        except FitError as e:
            return dict(row, error=str(e))
        d = appearance_difference(r.model, refs)
        if r.reduces_to is not None:  # a lobe unused: the fit is the smaller family, and counts so
            row = dict(row, p=Parametrization(r.reduces_to, C).size, reduces_to=r.reduces_to)
        return dict(row, score=_score(d), objective=float(r.objective), result=r, diff=d,
                    appearance={k: {m: float(v) for m, v in x.means.items()} for k, x in d.lights.items()})

    # candidates in threads: their compilations (most of a first run's time) overlap on the cores
    if workers > 1 and len(why) > 1:
        with ThreadPoolExecutor(max_workers=workers) as ex:
            rows = list(ex.map(candidate, why))
    else:
        rows = [candidate(f) for f in why]
    for row in rows:
        if "score" in row:
            say(f"  {row['family']:14s} p={row['p']:2d}  score {row['score']:.2f}  ({row['diff'].summary()})")
    scored = [r for r in rows if "score" in r]
    if not scored:
        raise FitError(f"choose_family: every candidate failed ({'; '.join(r['error'] for r in rows)})")
    best = min(r["score"] for r in scored)
    within = [r for r in scored if r["score"] <= best * (1 + SCORE_TOL)]
    pick = min(within, key=lambda r: (r["p"], r["score"]))
    others = [r for r in scored if r is not pick]
    runner = min(others, key=lambda r: r["score"]) if others else None
    simplest = pick["score"] > best
    reason = (f"{'the fewest parameters within' if simplest else 'the best image score, and no simpler family within'} "
              f"{SCORE_TOL:.0%} of the best image score ({pick['score']:.2f}"
              + (f" against {best:.2f}" if simplest else "") + "; 1 is the look-alike line)"
              + (f"; runner-up {runner['family']} ({runner['score']:.2f})" if runner else ""))
    choice = Choice(pick["family"], runner["family"] if runner else None, reason, "appearance", rows, cues, missing)
    result = pick["result"]
    result.choice, result.appearance = choice, pick["diff"]
    w = pick["diff"].warning("measured" if isinstance(reference, str) else "reference")
    if w:
        result.warnings.append(w)
    return result, choice


@functools.wraps(_fit_named)
def fit(table, model=None, fixed=None, tied=(), init=None, **kwargs):
    if model is None:
        if fixed or tied or init is not None:
            raise ParameterError("fit: fixed, tied and init name parameters of one family: name the family (model=...)")
        return choose_family(table, **kwargs)[0]
    return _fit_named(table, model, fixed=fixed, tied=tied, init=init, **kwargs)
