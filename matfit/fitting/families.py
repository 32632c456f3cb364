"""Every model family in one place: :class:`Family` (a model built from named, bounded
:class:`Param` s), the families themselves (:data:`FAMILIES`), :func:`compose_family` (a family of
microfacet lobes declared in a few lines, its layout in ``_compose.py``) and the lookups
(:func:`get_family`, :func:`family_describing`, :func:`reduced_family`). The metal bounds are
``METAL_ETA_RANGE`` and ``METAL_K_RANGE``; how a family's parameters are fitted is
:class:`~matfit.fitting.Parametrization`'s.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Callable, Optional

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import ParameterError
from ._compose import METAL_ETA_RANGE, METAL_K_RANGE, Lobe, LobeRefine, LobeSpec, lobe_layout
from ._conductor_guess import refine_conductor
from ._aniso_guess import refine_anisotropic
from ..models import CoatedConductor, DiffuseSpecular, Lambert, Plastic, Rotated, RoughConductor, RoughDielectric, Sheen

__all__ = ["Param", "TruthMap", "Family", "FAMILIES", "family_describing", "get_family", "Lobe", "compose_family",
           "reduced_family", "REDUCE_TOL", "check_param_value", "METAL_ETA_RANGE", "METAL_K_RANGE", "DEFAULT_FAMILY",
           "COMPARE_FAMILIES"]


@dataclass(frozen=True)
class Param:
    """One fittable parameter: its name, bounds and whether it has a colour-channel axis.

    Parameters
    ----------
    name : str
        The name: a key of a fit's ``params`` and of ``fixed`` / ``init`` / ``tied``.
    lower, upper : float
        The open range the parameter is fitted in (``upper = np.inf``: bounded below only).
    per_channel : bool, default False
        True when the parameter has a colour-channel axis (one value per channel unless tied).
    doc : str
        One line for reports and the docs.
    generic : float, optional
        The generic mid-range start :func:`~matfit.fitting.robust_fit` tries beside the
        data-driven guess (None: that guess's value).
    physical : (bool, bool), default (False, False)
        Whether the lower and the upper bound are physical limits (a weight or albedo of 0 or 1,
        an extinction of 0: the fit there says the data ask for none or all of the term) rather
        than range limits chosen for fitting (a width of 1e-3, a metal index of 8: the best fit
        may lie beyond). A fit's "at a bound" warning says which.

    Examples
    --------
    >>> from matfit.fitting import Param
    >>> p = Param("alpha", 1e-3, 1.5, doc="GGX width", generic=0.2)
    >>> round(float(p.from_unconstrained(p.to_unconstrained(0.3))), 6)
    0.3
    """

    name: str
    lower: float
    upper: float  # np.inf: bounded below only
    per_channel: bool = False
    doc: str = ""
    generic: Optional[float] = None
    physical: tuple = (False, False)

    def to_unconstrained(self, theta):
        """The ``z`` of ``theta``, clipped just inside the range (to [1e-9, 1 - 1e-9] of it; 1e-30 above ``lower``)."""
        theta = jnp.asarray(theta)
        if np.isinf(self.upper):
            return jnp.log(jnp.maximum(theta - self.lower, 1e-30))
        t = jnp.clip((theta - self.lower) / (self.upper - self.lower), 1e-9, 1 - 1e-9)
        return jnp.log(t) - jnp.log1p(-t)

    def from_unconstrained(self, z):
        """The value at ``z`` (the maps of the module docstring), inverse of :meth:`to_unconstrained`."""
        if np.isinf(self.upper):
            return self.lower + jnp.exp(z)
        return self.lower + (self.upper - self.lower) * jax.nn.sigmoid(z)

    def log_jacobian(self, z):
        """``log |d theta / d z|`` elementwise (for priors expressed on theta when sampling in z)."""
        if np.isinf(self.upper):
            return z
        return jnp.log(self.upper - self.lower) + jax.nn.log_sigmoid(z) + jax.nn.log_sigmoid(-z)


@dataclass(frozen=True)
class TruthMap:
    """Which true models of a synthetic table a family describes exactly.

    A data_synth scene records its material as ``{"model": <class name>, <parameter>: value, ...}``
    (``provenance["ground_truth"]["params"]``). The family describes it when the class name is
    ``model`` and every key of ``where`` holds one of the listed values (None: the key is absent).
    The parameters share the family's names.

    Parameters
    ----------
    model : str
        The matfit model class the scene names.
    where : mapping of str to tuple, optional
        Static options the true model must have, e.g. ``{"distribution": (None, "ggx")}``.

    Examples
    --------
    >>> from matfit.fitting import TruthMap
    >>> t = TruthMap("RoughConductor", {"distribution": (None, "ggx")})
    >>> t.matches({"model": "RoughConductor", "alpha": 0.2}), t.matches({"model": "RoughConductor", "distribution": "beckmann"})
    (True, False)
    """

    model: str
    where: Mapping = field(default_factory=dict)

    def __post_init__(self):
        # stored as sorted pairs, so that a TruthMap (and the Family holding it) stays hashable:
        # fits cache their compiled programs by family
        object.__setattr__(self, "where", tuple(sorted((k, tuple(v)) for k, v in dict(self.where).items())))

    def matches(self, spec) -> bool:
        """True when the material ``spec`` (a scene's material dict) belongs to the family."""
        return spec.get("model") == self.model and all(spec.get(k) in v for k, v in self.where)


@dataclass(frozen=True)
class Family:
    """A model family: its parameters, how to build the model from their values, and what it
    knows about starting a fit and about the synthetic tables it describes.

    Nothing outside a family's definition branches on its name: the starts, the refinement of
    the data-driven guess, the generic start and the truth mapping live here.

    Parameters
    ----------
    name : str
        The key of :data:`FAMILIES` (``fit(table, model=name)``).
    params : tuple of Param
        The parameters, in the order of the unconstrained vector.
    build : callable
        ``build(values, C) -> model`` from a dict of every parameter's value.
    doc : str
        One line for reports and the docs.
    starts : mapping, optional
        Constant starting values that replace the generic data-driven ones (e.g. a dielectric
        coat's ``eta`` 1.5).
    refine : callable, optional
        ``refine(WO, WI, V, M, guess, family)``: refines the data-driven guess of a stack of
        tables in place (the conductor families read eta and k off the Fresnel curve).
    truth : TruthMap, optional
        The true models of synthetic tables the family describes exactly (reports compare the
        fit with them).

    Examples
    --------
    >>> from matfit.fitting import Family, Param
    >>> from matfit.models import Lambert
    >>> fam = Family("grey", (Param("albedo", 0.0, 1.0),), lambda p, C: Lambert(p["albedo"]), starts={"albedo": 0.5})
    >>> fam.starts["albedo"], fam.has_channels
    (0.5, False)
    """

    name: str
    params: tuple[Param, ...]
    build: Callable[..., object]
    doc: str = ""
    starts: Mapping = field(default_factory=dict, compare=False)
    refine: Optional[Callable] = None
    truth: Optional[TruthMap] = None

    @property
    def has_channels(self) -> bool:
        """True when some parameter has a colour-channel axis (a mono table suits the family
        otherwise: ``dielectric``)."""
        return any(p.per_channel for p in self.params)

    def generic_start(self, guess, free=None) -> dict:
        """The generic start of the parameters ``free`` (default: all): each one's :attr:`Param.generic`,
        else its value in ``guess``.
        """
        names = [p.name for p in self.params] if free is None else list(free)
        by_name = {p.name: p for p in self.params}
        return {n: by_name[n].generic if by_name[n].generic is not None else guess.get(n) for n in names}

    def describes(self, spec) -> bool:
        """True when the family describes the true material ``spec`` of a synthetic table exactly."""
        return self.truth is not None and self.truth.matches(spec)


def family_describing(spec):
    """The registered family that describes the true material ``spec`` exactly, or None.

    Parameters
    ----------
    spec : mapping
        A scene's material (``{"model": name, ...}``, as data_synth records it).

    Returns
    -------
    Family or None

    Examples
    --------
    >>> from matfit.fitting import family_describing
    >>> family_describing({"model": "RoughConductor", "alpha": 0.2}).name
    'conductor'
    """
    return next((f for f in FAMILIES.values() if f.describes(spec)), None)


def compose_family(name, lobes, base="lambert", weights="channels", ordered=True, share=(), tied=(), fixed=None,
                   bounds=None, starts=None, doc="", coat=False) -> Family:
    """Declare a family of a Lambertian base plus microfacet lobes (:class:`~matfit.models.MultiLobe`).

    The family's parameters, their bounds, generic starts, report names, the build of the model
    and a data-driven start come from the lobes' description. Parameters are named after their
    lobe (``alpha_1``, ``ks_2``, ...; see the table below); the generic start gives the lobes
    distinct widths (narrow, medium, wide: 0.05, 0.2, 0.8), and with ``ordered`` (the default)
    lobe ``j >= 2``'s width is fitted as the ratio ``ratio_j = alpha_j / alpha_{j-1} > 1``, so
    that the lobes stay ordered from narrow to wide and a fit cannot swap them (equal lobes in
    another order are the same model). The data-driven start (:meth:`LobeSpec.refine
    <matfit.fitting._compose.LobeSpec.refine>`) solves for the diffuse albedo and the lobes'
    amplitudes by non-negative least squares over a small grid of widths and Fresnel levels.

    =============  ====================  ================================================================
    parameter      bounds                what (lobe ``j``), when
    =============  ====================  ================================================================
    albedo[C]      (0, 1)                the base's albedo (``base="lambert"``)
    alpha_j        (1e-3, 1.5)           the width (Blinn-Phong: up to 1): lobe 1, every lobe unordered
    ratio_j        (1, 100)              ``alpha_j / alpha_{j-1}``: lobes 2.. when ``ordered``
    ks_j[C]        (0, 1)                the weight (``weights="channels"``)
    mix_j          (0, 1)                the share of lobes 1..j (``weights="mixture"``, lobes 2..)
    f0_j           (0, 1)                Schlick normal-incidence reflectance (per channel unless
                                         the weights are per channel)
    eta_j          (1.01, 4)             a dielectric lobe's index; (1.01, 3): the index under a film
    eta_j[C]       (0.05, 8)             a conductor lobe's real index
    k_j[C]         (0, 12)               a conductor lobe's extinction
    thickness_j    (0, 1000)             a thin-film lobe's film thickness (nm)
    film_eta_j     (1, 2.6)              a thin-film lobe's film index
    alpha_coat     (1e-3, 1)             the coat's GGX width (``coat=True``)
    eta_coat       (1.05, 2.5)           the coat's index (``coat=True``)
    =============  ====================  ================================================================

    Parameters
    ----------
    name : str
        The family's name (``fit(table, model=family)``; add it to :data:`FAMILIES` to fit it
        by name).
    lobes : sequence of Lobe or str
        The lobes, one :class:`Lobe` each (a string is a distribution: ``"ggx"`` is
        ``Lobe("ggx")``, a Schlick lobe).
    base : {"lambert", None}, default "lambert"
        A Lambertian base (``albedo``), or none (the lobes alone: a metal).
    weights : {"channels", "mixture", "none"}, default "channels"
        ``"channels"``: lobe j is scaled by ``ks_j`` per channel (Löw's Cook-Torrance ``k_s``:
        the weight is the lobe's colour, a Schlick F0 one value); ``"mixture"``: the lobes'
        weights sum to 1 (``mix_j``: lobe j's share of lobes 1..j; one surface whose roughness
        has several scales); ``"none"``: every weight is 1 (the Fresnel term alone sets the
        level, a Schlick F0 is then per channel).
    ordered : bool, default True
        Fit the widths of lobes 2.. as ratios to the previous lobe's (``ratio_j > 1``).
    share : sequence of str, default ()
        Fresnel parameters (``"f0"``, ``"eta"``, ``"k"``) shared by every lobe that has one:
        one parameter without a lobe suffix (``share=("eta", "k")``: one metal).
    tied : sequence of str, default ()
        Per-channel parameters fitted as one value for every channel (``tied=("ks_1",)``: a
        white specular lobe). A fit's own ``tied`` does the same for one fit.
    fixed : mapping, optional
        Parameters held at given values by the family (not parameters of it any more).
    bounds : mapping, optional
        ``{name: (lower, upper)}`` replacing parameters' bounds.
    starts : mapping, optional
        Constant starting values replacing the data-driven ones (:attr:`Family.starts`).
    doc : str, default ""
        One line for reports (default: a description of the lobes).
    coat : bool, default False
        A rough dielectric coat over the base and lobes (:class:`~matfit.models.Layered`, Weidlich
        and Wilkie's single scattering): ``alpha_coat`` and ``eta_coat``; the lobes' indices are
        then relative to the coat.

    Returns
    -------
    Family
        With a :class:`~matfit.fitting._compose.LobeSpec` as its ``build`` (which also gives
        the lobes' widths and weights from parameter values) and the data-driven start as its
        ``refine`` hook.

    Raises
    ------
    matfit.ParameterError
        Naming the argument: an unknown option or parameter name, bounds out of order, fixed
        values or starts out of range or of the wrong size.

    Examples
    --------
    >>> from matfit.fitting import Lobe, Parametrization, compose_family
    >>> fam = compose_family("haze", [Lobe("ggx"), Lobe("beckmann", fresnel="dielectric")],
    ...                      tied=("ks_1",), fixed={"eta_2": 1.5})
    >>> [p.name for p in fam.params]
    ['albedo', 'alpha_1', 'ks_1', 'f0_1', 'ratio_2', 'ks_2']
    >>> Parametrization(fam, 3).labels[:4]
    ['albedo[0]', 'albedo[1]', 'albedo[2]', 'alpha_1']
    >>> fam == compose_family("haze", [Lobe("ggx"), Lobe("beckmann", fresnel="dielectric")],
    ...                       tied=("ks_1",), fixed={"eta_2": 1.5})
    True
    """
    owner = "compose_family"
    if not isinstance(name, str) or not name:
        raise ParameterError(f"{owner}: name must be a non-empty string, got {name!r}")
    if isinstance(lobes, (str, Lobe)) or not isinstance(lobes, (list, tuple)) or not lobes:
        raise ParameterError(f"{owner}: lobes must be a non-empty list of Lobe (or distribution names), got {lobes!r}")
    lobes = tuple(Lobe(lb) if isinstance(lb, str) else lb for lb in lobes)
    for i, lb in enumerate(lobes):
        if not isinstance(lb, Lobe):
            raise ParameterError(f"{owner}: lobes[{i}] must be a Lobe or a distribution name, got {type(lb).__name__}")
    for what, v in (("share", share), ("tied", tied)):
        if isinstance(v, str) or not isinstance(v, (list, tuple)):
            raise ParameterError(f"{owner}: {what} must be a sequence of parameter names, got {v!r}")
    if not isinstance(ordered, bool):
        raise ParameterError(f"{owner}: ordered must be True or False, got {ordered!r}")
    slots = lobe_layout(base, lobes, weights, ordered, tuple(share), tuple(tied), coat)
    by_name = {s.name: s for s in slots}
    for what, m in (("fixed", fixed), ("bounds", bounds), ("starts", starts)):
        if m is not None and not isinstance(m, Mapping):
            raise ParameterError(f"{owner}: {what} must be a dict keyed by parameter name, got {type(m).__name__}")
        for n in (m or {}):
            if n not in by_name:
                raise ParameterError(f"{owner}: {what} names {n!r}, which is not a parameter; the parameters are "
                                     f"{list(by_name)}")
    limits = {s.name: (s.lower, s.upper) for s in slots}
    for n, b in (bounds or {}).items():
        try:
            lo, hi = (float(x) for x in b)
        except (TypeError, ValueError):
            raise ParameterError(f"{owner}: bounds[{n!r}] must be a pair (lower, upper), got {b!r}") from None
        if not (np.isfinite(lo) and lo < hi and not np.isnan(hi)):
            raise ParameterError(f"{owner}: bounds[{n!r}] must be finite lower < upper, got {b!r}")
        limits[n] = (lo, hi)
    every = []
    for s in slots:
        lo, hi = limits[s.name]
        generic = float(np.clip(s.generic, lo + 1e-3 * (hi - lo), hi - 1e-3 * (hi - lo)))
        # bounds a caller set are ranges; the slots' own 0 and 1 of a weight (and k = 0) are physics
        physical = (False, False) if s.name in (bounds or {}) else _PHYSICAL_SLOTS.get(s.kind, (False, False))
        every.append(Param(s.name, lo, hi, s.per_channel, s.doc, generic=generic, physical=physical))
    # fixed values and constant starts are checked as a fit checks them (range, finite, channels),
    # on the family of every parameter; a per-channel value sets the channel count it is read with
    given = list((fixed or {}).values()) + list((starts or {}).values())
    channels = max([1] + [len(v) for v in given if isinstance(v, (list, tuple)) or np.ndim(v) == 1])
    every_by_name = {q.name: q for q in every}
    fixed_items = []
    try:
        for what, m in (("fixed", fixed), ("starts", starts)):
            for n, v in (m or {}).items():
                check_param_value(every_by_name[n], channels, what, v)
        for n, v in (fixed or {}).items():
            a = np.atleast_1d(np.asarray(v, dtype=float))
            fixed_items.append((n, tuple(a.tolist()) if a.size > 1 else float(a[0])))
    except ParameterError as e:
        raise ParameterError(f"{owner}: {e}") from None
    fixed_names = {n for n, _ in fixed_items}
    params = tuple(p for p in every if p.name not in fixed_names)
    spec = LobeSpec(base, lobes, weights, ordered, slots, tuple(sorted(fixed_items)), coat)
    if not doc:
        kinds = ", ".join(f"{lb.distribution}/{lb.fresnel}" for lb in lobes)
        doc = (f"{'Lambertian base plus ' if base else ''}{len(lobes)} microfacet lobe(s) ({kinds}), weights {weights}"
               f"{', under a rough coat' if coat else ''}")
    return Family(name, params, spec, doc, starts=dict(starts or {}), refine=LobeRefine(spec))


def _conductor(distribution):
    return lambda p, C: RoughConductor(p["alpha"], p["eta"], p["k"], distribution=distribution)


#: Which bounds of a composed family's slots are physical limits (see :class:`Param`).
_PHYSICAL_SLOTS = {"albedo": (True, True), "ks": (True, True), "mix": (True, True), "f0": (True, True),
                   "ratio": (True, False),  # ratio 1: two lobes of one width, one lobe
                   "k": (True, False),
                   # no film: a thickness of 0 or a film index of 1 (the film is the outside)
                   "thickness": (True, False), "film_eta": (True, False)}


def _alpha(what, lower=1e-3, upper=1.5, name="alpha", generic=0.2):
    return Param(name, lower, upper, False, what, generic=generic)


_METAL = (Param("eta", *METAL_ETA_RANGE, True, "real index", generic=1.0),
          Param("k", *METAL_K_RANGE, True, "extinction", generic=3.0, physical=(True, False)))
_ALBEDO = Param("albedo", 0.0, 1.0, True, "diffuse albedo", generic=0.5, physical=(True, True))

FAMILIES: dict[str, Family] = {
    "lambert": Family(
        "lambert", (_ALBEDO,), lambda p, C: Lambert(p["albedo"]), "Lambertian diffuse", truth=TruthMap("Lambert")),
    "conductor": Family(
        "conductor", (_alpha("GGX width"),) + _METAL,
        _conductor("ggx"), "rough conductor, GGX, separable Smith", refine=refine_conductor("ggx"),
        truth=TruthMap("RoughConductor", {"distribution": (None, "ggx")})),
    "conductor_beckmann": Family(
        "conductor_beckmann", (_alpha("Beckmann width"),) + _METAL,
        _conductor("beckmann"), "rough conductor, Beckmann, separable Smith", refine=refine_conductor("beckmann"),
        truth=TruthMap("RoughConductor", {"distribution": ("beckmann",)})),
    "dielectric": Family(
        "dielectric", (_alpha("GGX width"), Param("eta", 1.01, 4.0, False, "relative index", generic=1.5)),
        lambda p, C: RoughDielectric(p["alpha"], p["eta"]), "rough dielectric (reflection and transmission)",
        starts={"eta": 1.5}, truth=TruthMap("RoughDielectric", {"distribution": (None, "ggx")})),
    "plastic": Family(
        "plastic",
        (Param("albedo", 0.0, 1.0, True, "base albedo", generic=0.5, physical=(True, True)), _alpha("coat GGX width"),
         Param("eta", 1.05, 3.0, False, "coat index", generic=1.5)),
        lambda p, C: Plastic(p["albedo"], p["alpha"], p["eta"]), "Lambertian base under a rough coat",
        starts={"eta": 1.5}, truth=TruthMap("Plastic")),
    "car_paint": Family(
        "car_paint",
        (_alpha("metal GGX width", name="alpha_base"), Param("eta_base", *METAL_ETA_RANGE, True, "metal index", generic=1.0),
         Param("k_base", *METAL_K_RANGE, True, "metal extinction", generic=3.0, physical=(True, False)),
         _alpha("coat GGX width", upper=1.0, name="alpha_coat", generic=0.1),
         Param("eta_coat", 1.05, 2.5, False, "coat index", generic=1.5)),
        lambda p, C: CoatedConductor(p["alpha_base"], p["eta_base"], p["k_base"], p["alpha_coat"], p["eta_coat"]),
        "rough metal under a rough clear coat", truth=TruthMap("CoatedConductor")),
    "diffuse_specular": Family(
        "diffuse_specular",
        (_ALBEDO, Param("f0", 0.0, 1.0, True, "specular F0 (Schlick)", physical=(True, True)), _alpha("GGX width")),
        lambda p, C: DiffuseSpecular(p["albedo"], p["f0"], p["alpha"]),
        "Lambertian albedo plus a GGX lobe with Schlick's Fresnel (the texel model of captures)"),
}
def get_family(name) -> Family:
    """The family called ``name`` (see :data:`FAMILIES`).

    Parameters
    ----------
    name : str
        A key of :data:`FAMILIES`.

    Returns
    -------
    Family

    Raises
    ------
    matfit.ParameterError
        Naming the families, when there is none of that name.
    """
    if name not in FAMILIES:
        raise ParameterError(f"model must be one of {sorted(FAMILIES)}, got {name!r}")
    return FAMILIES[name]


#: A lobe's weight (every channel) at or below this is no lobe; a width ratio within it of 1 is
#: the previous lobe again (see :func:`reduced_family`).
REDUCE_TOL = 1e-3
#: The family of a batch fit or a posterior that names none (a single fit with none chooses; a map
#: fits diffuse_specular).
DEFAULT_FAMILY = "plastic"
#: The families :func:`~matfit.fitting.compare_models` and ``matfit compare`` compare by default.
COMPARE_FAMILIES = ("lambert", "conductor", "plastic")


def reduced_family(family, params, tol=REDUCE_TOL):
    """The smaller family a fit of ``family`` reduces to, where its extra terms ended unused.

    A lobe of ``lobesN`` whose weight ``ks_j`` is at most ``tol`` on every channel is absent, and
    a lobe whose width ratio ``ratio_j`` is within ``tol`` of 1 is the previous lobe again (the
    two share the Fresnel ``f0``: their weights add); ``metal2`` with its mixture weight at 0 or 1
    or its ratio at 1 is one ``conductor``. Model choice counts such a fit's parameters as the
    smaller family's.

    Parameters
    ----------
    family : str
        The fitted family.
    params : mapping
        Its parameter values (name -> scalar or per channel), as :attr:`FitResult.params`.
    tol : float
        The weight (and ratio) tolerance.

    Returns
    -------
    (str, str) or None
        The smaller family and why, or None when every term is used.

    Examples
    --------
    >>> from matfit.fitting import reduced_family
    >>> p = {"albedo": 0.5, "alpha_1": 0.1, "ks_1": 0.4, "f0": 0.04, "ratio_2": 3.0, "ks_2": [0.0, 0.0, 2e-4]}
    >>> reduced_family("lobes2", p)
    ('lobes1', 'ks_2 = 0 on every channel: lobe 2 is unused')
    >>> reduced_family("lobes2", dict(p, ks_2=0.2)) is None
    True
    """
    v = {k: np.asarray(x, float) for k, x in params.items()}
    why = []
    if family.startswith("lobes") and family[5:].isdigit():
        n = int(family[5:])
        if any(f"ks_{j}" not in v or (j > 1 and f"ratio_{j}" not in v) for j in range(1, n + 1)):
            return None  # a family of that name composed otherwise
        alive = n
        for j in range(1, n + 1):
            if np.all(v[f"ks_{j}"] <= tol):
                why.append(f"ks_{j} = 0 on every channel: lobe {j} is unused")
                alive -= 1
            elif j > 1 and np.all(np.abs(v[f"ratio_{j}"] - 1) <= tol):
                why.append(f"ratio_{j} = 1: lobe {j} has lobe {j - 1}'s width (their weights add)")
                alive -= 1
        if alive < n and alive >= 1:
            return f"lobes{alive}", "; ".join(why)
        return None
    if family == "metal2" and {"mix_2", "ratio_2"} <= set(v):
        if np.all(v["mix_2"] <= tol) or np.all(v["mix_2"] >= 1 - tol):
            return "conductor", "mix_2 at 0 or 1: one lobe is unused"
        if np.all(np.abs(v["ratio_2"] - 1) <= tol):
            return "conductor", "ratio_2 = 1: the two lobes have one width"
    return None


# Lambertian base plus 1, 2, 3 GGX lobes with a per-channel weight and one Schlick F0 shared by the
# lobes (one interface, several roughness scales: a sharp highlight, a haze), and a metal whose
# roughness has two scales (one complex index, mixture weights)
FAMILIES.update({
    f"lobes{K}": compose_family(
        f"lobes{K}", [Lobe("ggx", "schlick")] * K, share=("f0",),
        doc=f"Lambertian albedo plus {K} GGX lobe{'s' if K > 1 else ''} (per-channel weights ks, one Schlick F0"
            f"{', widths ordered' if K > 1 else ''})")
    for K in (1, 2, 3)})
# cloth and velvet: a Lambertian base under a Charlie sheen lobe
FAMILIES["sheen"] = Family(
    "sheen",
    (_ALBEDO, Param("sheen_color", 0.0, 1.0, True, "sheen colour", generic=0.5, physical=(True, True)),
     Param("sheen_alpha", 0.05, 1.0, False, "sheen width (Charlie)", generic=0.4)),
    lambda p, C: Sheen(Lambert(p["albedo"]), p["sheen_color"], p["sheen_alpha"]),
    "Lambertian albedo under a Charlie sheen lobe (cloth, velvet; the base scaled to keep energy)")
# a highlight whose hue turns with the angle: a GGX lobe whose Fresnel is a thin film (one weight,
# the colour is the film's) over a wide coloured GGX lobe (Schlick, per-channel weight) in place of a
# Lambertian base (the colour-shifting films of the RGL set are dark at grazing angles)
FAMILIES["film"] = compose_family(
    "film", [Lobe("ggx", "thin_film"), Lobe("ggx", "schlick")], base=None, tied=("ks_1",),
    doc="GGX lobe with a thin-film Fresnel (iridescence: thickness_1, film_eta_1 on eta_1) over a wide coloured "
        "GGX lobe (Schlick f0_2, per-channel ks_2)")
# brushed metal: an anisotropic GGX conductor turned about the normal (its widths and angle read
# from the shape of the measured peak, the index as the isotropic conductor's)
FAMILIES["conductor_aniso"] = Family(
    "conductor_aniso",
    (_alpha("GGX width along the lobe's x axis"), _alpha("GGX width along its y axis", name="alpha_y"),
     Param("angle", -np.pi, np.pi, False, "azimuth of the lobe's x axis (radians; + pi: the same lobe)", generic=0.0))
    + _METAL,
    lambda p, C: Rotated(RoughConductor(p["alpha"], p["eta"], p["k"], alpha_y=p["alpha_y"]), p["angle"]),
    "anisotropic rough conductor (GGX, separable Smith) turned by an angle: brushed metal",
    refine=refine_anisotropic(refine_conductor("ggx")))
FAMILIES["metal2"] = compose_family(
    "metal2", [Lobe("ggx", "conductor")] * 2, base=None, weights="mixture", share=("eta", "k"),
    doc="rough conductor with two GGX widths mixed (one complex index)")


def check_param_value(p, channels, what, v):
    """``v`` unchanged when it is a valid value of parameter ``p`` on ``channels`` colour channels
    (real, finite, inside the range, a scalar or, per channel, ``C`` values); else a
    ParameterError naming ``what`` it was for.

    Parameters
    ----------
    p : Param
    channels : int
    what : str
        What the value is for (``"fixed"``, ``"fit: init"``), named in errors.
    v : float or array_like

    Returns
    -------
    float or array_like
        ``v``.
    """
    where = f"{what} {p.name}={v!r}"
    try:
        a = np.asarray(v)
    except Exception:  # ragged sequences
        raise ParameterError(f"{where}: expected a number or an array of numbers") from None
    if a.dtype.kind not in "iuf":
        raise ParameterError(f"{where}: expected real numbers, found dtype {a.dtype}")
    a = a.astype(float)
    if not np.all(np.isfinite(a)):
        raise ParameterError(f"{where}: expected finite values")
    if np.any(a < p.lower) or np.any(a > p.upper):
        raise ParameterError(f"{where} is outside its range [{p.lower}, {p.upper}]")
    sizes = (1, channels) if p.per_channel else (1,)
    if a.ndim > 1 or a.size not in sizes:
        want = f"a scalar or {channels} values (one per channel)" if p.per_channel else "a scalar"
        raise ParameterError(f"{where}: expected {want}, found shape {a.shape}")
    return v


# lobes under a coat: a plastic whose base has a glossy lobe of its own (a varnish over a satin
# paint), and a car paint whose metal has two roughness scales
# (the base lobe's Schlick F0 is held at 1: under the coat the refracted directions stay inside the
# critical cone, where Schlick's term hardly varies, and a fit identifies only ks * F0)
FAMILIES["coated_lobes1"] = compose_family(
    "coated_lobes1", [Lobe("ggx", "schlick")], coat=True, fixed={"f0_1": 1.0},
    doc="Lambertian albedo plus a GGX lobe (per-channel weight ks, no Fresnel of its own) under a rough clear coat")
FAMILIES["car_paint2"] = compose_family(
    "car_paint2", [Lobe("ggx", "conductor")] * 2, base=None, weights="mixture", share=("eta", "k"), coat=True,
    doc="rough conductor with two GGX widths mixed (one complex index) under a rough clear coat")
