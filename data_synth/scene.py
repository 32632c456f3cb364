"""Scene files: a TOML description of a synthetic measurement, parsed and validated.

See docs/data.md ("Synthetic data: scene files") for every key. ``load_scene(path)`` (or
``parse_scene(dict, file=None)``) returns a :class:`Scene` whose ``geometry``, ``material`` and
``effects`` are plain, fully defaulted, JSON-able dicts, and whose :meth:`Scene.build_model`
returns the matfit model. All problems raise :mod:`data_synth.errors` exceptions (subclasses of
:class:`matfit.errors.MatfitError`) naming the file and the dotted key, expected vs found.
"""
from __future__ import annotations

import copy
import inspect
import math
import os
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from matfit import models as _models
from matfit.errors import ParameterError

from . import spectral
from .errors import (MissingKeyError, SceneSyntaxError, SceneTypeError, SceneValueError, UnknownKeyError,
                     UnknownModelError, UnknownParameterError)
from .geometry import DEFAULT_SPARSE_VIEWS

SCENE_DIR = Path(__file__).with_name("scenes")

#: The models a scene may build: the registry's entries declared for ``"scene"`` (:data:`matfit.models.MODELS`).
MODELS = _models.models_for("scene")
#: Parameters that hold a nested model (an inline table with its own ``model`` key).
MODEL_PARAMS = {"coat", "base", "a", "b"}
#: Parameters that may carry a colour-channel axis (a list); every other numeric parameter is a scalar.
CHANNEL_PARAMS = {"albedo", "k", "eta_base", "k_base", "sigma_a"}
CONDUCTORS_ETA = {"RoughConductor", "SmoothConductor"}
#: Models that accept ``metal = "<name>"`` and the (eta, k) parameters it sets.
METAL_KEYS = {"RoughConductor": ("eta", "k"), "SmoothConductor": ("eta", "k"), "CoatedConductor": ("eta_base", "k_base")}

GEOMETRY_KEYS = {
    "inplane": {"theta_i", "theta_o_step", "theta_o_max", "phi_i"},
    "hemisphere": {"theta_i", "n_theta", "n_phi", "theta_o_max", "phi_i"},
    "merl": {"n_theta_h", "n_theta_d", "n_phi_d"},
    "random": {"n", "distribution", "seed"},
    "stratified": {"n", "distribution", "seed"},
    "sparse": {"views"},
}

_REQ = object()


def _tname(v):
    if isinstance(v, bool):
        return f"a boolean ({v!r})"
    if isinstance(v, int):
        return f"an integer ({v!r})"
    if isinstance(v, float):
        return f"a float ({v!r})"
    if isinstance(v, str):
        return f"a string ({v!r})"
    if isinstance(v, list):
        return f"an array of {len(v)}"
    if isinstance(v, dict):
        return "a table"
    return type(v).__name__


def _is_num(v):
    return isinstance(v, (int, float)) and not isinstance(v, bool)


class _Checker:
    def __init__(self, file):
        self.file = file

    def keys(self, tbl, path, allowed, required=()):
        if not isinstance(tbl, dict):
            raise SceneTypeError(self.file, path, "a table", _tname(tbl))
        for k in tbl:
            if k not in allowed:
                raise UnknownKeyError(self.file, _join(path, k), f"one of {sorted(allowed)}", repr(k))
        for k in required:
            if k not in tbl:
                raise MissingKeyError(self.file, _join(path, k), "a value (required)", "nothing")

    def _get(self, tbl, path, key, default):
        if key not in tbl:
            if default is _REQ:
                raise MissingKeyError(self.file, _join(path, key), "a value (required)", "nothing")
            return False, default
        return True, tbl[key]

    def number(self, tbl, path, key, default=_REQ, lo=None, hi=None, lo_open=False, hi_open=False, integer=False):
        present, v = self._get(tbl, path, key, default)
        if not present:
            return v
        return self.check_number(v, _join(path, key), lo, hi, lo_open, hi_open, integer)

    def check_number(self, v, key, lo=None, hi=None, lo_open=False, hi_open=False, integer=False):
        if integer:
            if not isinstance(v, int) or isinstance(v, bool):
                raise SceneTypeError(self.file, key, "an integer", _tname(v))
        elif not _is_num(v):
            raise SceneTypeError(self.file, key, "a number", _tname(v))
        if not math.isfinite(v):
            raise SceneValueError(self.file, key, "a finite number", repr(v))
        bad_lo = lo is not None and (v <= lo if lo_open else v < lo)
        bad_hi = hi is not None and (v >= hi if hi_open else v > hi)
        if bad_lo or bad_hi:
            lb = "-inf" if lo is None else f"{lo:g}"
            hb = "inf" if hi is None else f"{hi:g}"
            rng = f"{'(' if lo_open or lo is None else '['}{lb}, {hb}{')' if hi_open or hi is None else ']'}"
            raise SceneValueError(self.file, key, f"a value in {rng}", repr(v))
        return int(v) if integer else float(v)

    def string(self, tbl, path, key, default=_REQ, choices=None):
        present, v = self._get(tbl, path, key, default)
        if not present:
            return v
        if not isinstance(v, str):
            raise SceneTypeError(self.file, _join(path, key), "a string", _tname(v))
        if choices is not None and v not in choices:
            raise SceneValueError(self.file, _join(path, key), f"one of {sorted(choices)}", repr(v))
        return v

    def boolean(self, tbl, path, key, default=_REQ):
        present, v = self._get(tbl, path, key, default)
        if present and not isinstance(v, bool):
            raise SceneTypeError(self.file, _join(path, key), "a boolean (true / false)", _tname(v))
        return v

    def numbers(self, tbl, path, key, default=_REQ, lo=None, hi=None, lo_open=False, hi_open=False,
                lengths=None, allow_scalar=False):
        present, v = self._get(tbl, path, key, default)
        if not present:
            return v
        k = _join(path, key)
        if allow_scalar and _is_num(v):
            return self.check_number(v, k, lo, hi, lo_open, hi_open)
        if not isinstance(v, list) or not v:
            raise SceneTypeError(self.file, k, "a non-empty array of numbers" + (" or a number" if allow_scalar else ""),
                                 _tname(v))
        out = [self.check_number(x, f"{k}[{i}]", lo, hi, lo_open, hi_open) for i, x in enumerate(v)]
        if lengths is not None and len(out) not in lengths:
            raise SceneValueError(self.file, k, f"an array of length {' or '.join(map(str, sorted(lengths)))}",
                                  f"length {len(out)}")
        return out


def _join(path, key):
    return f"{path}.{key}" if path else str(key)


@dataclass
class Scene:
    """A validated scene. ``geometry``, ``material``, ``effects`` are JSON-able dicts with defaults filled."""

    name: str
    seed: int
    geometry: dict
    material: dict
    effects: dict
    description: str = ""
    file: str | None = None
    _model_cache: object = field(default=None, repr=False, compare=False)

    @property
    def spectral(self) -> bool:
        return self.effects["colour"]["mode"] == "spectral"

    def wavelengths(self):
        c = self.effects["colour"]
        return spectral.wavelength_grid(*c["wavelengths"]) if self.spectral else None

    def build_model(self):
        """The matfit model with the scene's true parameters (per wavelength in spectral scenes)."""
        return _build(_Checker(self.file), self.material, "material", self)

    def to_dict(self):
        return {"scene": {"name": self.name, "description": self.description, "seed": self.seed},
                "geometry": copy.deepcopy(self.geometry), "material": copy.deepcopy(self.material),
                "effects": copy.deepcopy(self.effects)}


def resolve_scene_path(path):
    """``path`` itself if it exists, else a shipped scene ``data_synth/scenes/<path>[.toml]``; else
    :class:`FileNotFoundError` naming the path and the shipped scenes."""
    p = Path(path)
    if p.exists():
        return p
    for cand in (SCENE_DIR / p.name, SCENE_DIR / (p.name + ".toml")):
        if cand.exists():
            return cand
    names = ", ".join(q.stem for q in shipped_scenes())
    raise FileNotFoundError(f"{os.fspath(path)}: no such scene file, nor a shipped scene of that name ({names})")


def shipped_scenes():
    return sorted(SCENE_DIR.glob("*.toml"))


def load_scene(path) -> Scene:
    """Read and validate a scene TOML file (a shipped scene may be named without its folder)."""
    p = resolve_scene_path(path)
    with open(p, "rb") as fh:
        raw = fh.read()
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except UnicodeDecodeError as e:
        raise SceneSyntaxError(os.fspath(p), None, "UTF-8 text", f"undecodable bytes at byte {e.start}") from None
    except tomllib.TOMLDecodeError as e:
        raise SceneSyntaxError(os.fspath(p), None, "valid TOML", f"a syntax error ({e})") from None
    return parse_scene(data, file=os.fspath(p))


def parse_scene(data: dict, file=None) -> Scene:
    """Validate a scene given as a dict (the parsed TOML)."""
    ck = _Checker(file)
    ck.keys(data, "", {"scene", "geometry", "material", "effects"}, required=("geometry", "material"))
    meta = data.get("scene", {})
    ck.keys(meta, "scene", {"name", "description", "seed"})
    default_name = Path(file).stem if file else "scene"
    name = ck.string(meta, "scene", "name", default_name)
    description = ck.string(meta, "scene", "description", "")
    seed = ck.number(meta, "scene", "seed", 0, lo=0, integer=True)
    effects = _parse_effects(ck, data.get("effects", {}))
    geometry = _parse_geometry(ck, data["geometry"], effects, seed)
    scene = Scene(name=name, seed=seed, geometry=geometry, material={}, effects=effects, description=description,
                  file=file)
    scene.material = _parse_material(ck, data["material"], "material", scene)
    scene.build_model()  # raises range errors now, naming the key
    return scene


# ---------------------------------------------------------------- effects
def _parse_effects(ck, eff):
    ck.keys(eff, "effects", {"reflection", "transmission", "aperture", "noise", "colour"})
    out = {"reflection": ck.boolean(eff, "effects", "reflection", True),
           "transmission": ck.boolean(eff, "effects", "transmission", False)}
    if not (out["reflection"] or out["transmission"]):
        raise SceneValueError(ck.file, "effects.reflection", "reflection and/or transmission to be true",
                              "both false")
    out["aperture"] = None
    if "aperture" in eff:
        a, p = eff["aperture"], "effects.aperture"
        ck.keys(a, p, {"half_angle", "n_polar", "n_azimuth"}, required=("half_angle",))
        out["aperture"] = {"half_angle": ck.number(a, p, "half_angle", lo=0.0, hi=20.0, lo_open=True),
                           "n_polar": ck.number(a, p, "n_polar", 4, lo=1, hi=32, integer=True),
                           "n_azimuth": ck.number(a, p, "n_azimuth", 8, lo=1, hi=64, integer=True)}
    out["noise"] = None
    if "noise" in eff:
        n, p = eff["noise"], "effects.noise"
        ck.keys(n, p, {"relative", "photons", "reference", "gain", "jitter", "outliers", "outlier_scale",
                       "sigma_floor"})
        out["noise"] = {
            "relative": ck.number(n, p, "relative", 0.0, lo=0.0, hi=1.0),
            "photons": ck.number(n, p, "photons", None, lo=0.0, lo_open=True),
            "reference": ck.number(n, p, "reference", 1.0, lo=0.0, lo_open=True),
            "gain": ck.numbers(n, p, "gain", None, lo=0.0, lo_open=True, allow_scalar=True),
            "jitter": ck.number(n, p, "jitter", 0.0, lo=0.0, hi=10.0),
            "outliers": ck.number(n, p, "outliers", 0.0, lo=0.0, hi=0.5),
            "outlier_scale": ck.number(n, p, "outlier_scale", 5.0, lo=1.0, lo_open=True),
            "sigma_floor": ck.number(n, p, "sigma_floor", 1e-6, lo=0.0),
        }
        if isinstance(out["noise"]["gain"], float) and out["noise"]["gain"] > 0.5:
            raise SceneValueError(ck.file, "effects.noise.gain", "a standard deviation in (0, 0.5] or a list of "
                                  "per-channel factors", repr(out["noise"]["gain"]))
    c, p = eff.get("colour", {}), "effects.colour"
    ck.keys(c, p, {"mode", "wavelengths", "illuminant", "observer", "output"})
    mode = ck.string(c, p, "mode", "rgb", choices={"rgb", "spectral"})
    col = {"mode": mode}
    if mode == "rgb":
        for k in ("wavelengths", "illuminant", "observer", "output"):
            if k in c:
                raise SceneValueError(ck.file, _join(p, k), "no value unless mode = 'spectral'", repr(c[k]))
    else:
        wl = ck.numbers(c, p, "wavelengths", [380.0, 780.0, 10.0], lengths={3})
        if not (300.0 <= wl[0] < wl[1] <= 900.0 and 0 < wl[2] <= (wl[1] - wl[0])):
            raise SceneValueError(ck.file, _join(p, "wavelengths"),
                                  "[start, stop, step] in nm with 300 <= start < stop <= 900, 0 < step <= stop - start",
                                  repr(wl))
        col.update(wavelengths=wl,
                   illuminant=ck.string(c, p, "illuminant", "D65", choices=set(spectral.illuminants())),
                   observer=ck.string(c, p, "observer", spectral.DEFAULT_OBSERVER, choices=set(spectral.observers())),
                   output=ck.string(c, p, "output", "rgb", choices={"rgb", "spectrum"}))
    out["colour"] = col
    return out


# ---------------------------------------------------------------- geometry
def _parse_geometry(ck, g, effects, seed):
    p = "geometry"
    if not isinstance(g, dict):
        raise SceneTypeError(ck.file, p, "a table", _tname(g))
    kind = ck.string(g, p, "kind", choices=set(GEOMETRY_KEYS))
    ck.keys(g, p, GEOMETRY_KEYS[kind] | {"kind"})
    refl, trans = effects["reflection"], effects["transmission"]
    out = {"kind": kind}
    if kind in ("inplane", "hemisphere"):
        out["theta_i"] = ck.numbers(g, p, "theta_i", [0.0, 30.0, 60.0], lo=0.0, hi=90.0, hi_open=True)
        out["theta_o_max"] = ck.number(g, p, "theta_o_max", 85.0, lo=0.0, hi=90.0, lo_open=True, hi_open=True)
        out["phi_i"] = ck.number(g, p, "phi_i", 0.0, lo=-360.0, hi=360.0)
        if kind == "inplane":
            out["theta_o_step"] = ck.number(g, p, "theta_o_step", 5.0, lo=0.0, hi=90.0, lo_open=True)
        else:
            out["n_theta"] = ck.number(g, p, "n_theta", 9, lo=1, hi=90, integer=True)
            out["n_phi"] = ck.number(g, p, "n_phi", 24, lo=1, hi=720, integer=True)
    elif kind == "merl":
        if trans:
            raise SceneValueError(ck.file, "effects.transmission", "false with geometry.kind = 'merl' "
                                  "(the MERL grid is reflection only)", "true")
        out["n_theta_h"] = ck.number(g, p, "n_theta_h", 90, lo=1, hi=90, integer=True)
        out["n_theta_d"] = ck.number(g, p, "n_theta_d", 90, lo=1, hi=90, integer=True)
        out["n_phi_d"] = ck.number(g, p, "n_phi_d", 180, lo=1, hi=180, integer=True)
    elif kind in ("random", "stratified"):
        out["n"] = ck.number(g, p, "n", 1000, lo=1, hi=10_000_000, integer=True)
        out["distribution"] = ck.string(g, p, "distribution", "uniform", choices={"uniform", "cosine"})
        out["seed"] = ck.number(g, p, "seed", seed, lo=0, integer=True)
    else:  # sparse
        views = g.get("views", [list(v) for v in DEFAULT_SPARSE_VIEWS])
        if not isinstance(views, list) or not views:
            raise SceneTypeError(ck.file, "geometry.views", "a non-empty array of [theta_i, phi_i, theta_o, phi_o]",
                                 _tname(views))
        vv = []
        for i, v in enumerate(views):
            k = f"geometry.views[{i}]"
            if not isinstance(v, list) or len(v) != 4:
                raise SceneTypeError(ck.file, k, "an array [theta_i, phi_i, theta_o, phi_o] of 4 numbers (degrees)",
                                     _tname(v))
            ti = ck.check_number(v[0], k + "[0]", 0.0, 90.0, hi_open=True)
            pi_ = ck.check_number(v[1], k + "[1]", -360.0, 360.0)
            to = ck.check_number(v[2], k + "[2]", 0.0, 180.0)
            po = ck.check_number(v[3], k + "[3]", -360.0, 360.0)
            if to < 90.0 and not refl or to > 90.0 and not trans or to == 90.0:
                want = "< 90 (reflection)" if refl else ""
                if trans:
                    want = (want + " or " if want else "") + "> 90 (transmission)"
                raise SceneValueError(ck.file, k + "[2]", f"theta_o {want} for the effects declared", repr(v[2]))
            vv.append([ti, pi_, to, po])
        out["views"] = vv
    out["reflection"], out["transmission"] = refl, trans
    return out


# ---------------------------------------------------------------- material
def _signature(name):
    return inspect.signature(MODELS[name]).parameters


def _parse_material(ck, m, path, scene):
    if not isinstance(m, dict):
        raise SceneTypeError(ck.file, path, "a table with a 'model' key", _tname(m))
    model = ck.string(m, path, "model")
    if model not in MODELS:
        raise UnknownModelError(ck.file, _join(path, "model"), f"one of {sorted(MODELS)}", repr(model))
    params = _signature(model)
    allowed = set(params) | {"model"} | ({"metal"} if model in METAL_KEYS else set())
    for k in m:
        if k not in allowed:
            raise UnknownParameterError(ck.file, _join(path, k), f"a parameter of {model}: {sorted(allowed - {'model'})}",
                                        repr(k))
    out = {"model": model}
    metal_keys = ()
    if "metal" in m:
        metal = ck.string(m, path, "metal", choices=set(spectral.metals()))
        metal_keys = METAL_KEYS[model]
        for k in metal_keys:
            if k in m:
                raise SceneValueError(ck.file, _join(path, k), f"no value when 'metal' is given (metal sets {list(metal_keys)})",
                                      repr(m[k]))
        if scene.spectral:
            lo, hi = spectral.metal_range(metal)
            wl = scene.effects["colour"]["wavelengths"]
            if wl[0] < lo or wl[1] > hi:
                raise SceneValueError(ck.file, "effects.colour.wavelengths",
                                      f"a range inside the {metal} table [{lo:g}, {hi:g}] nm", repr(wl))
        out["metal"] = metal
    n_ch = len(scene.wavelengths()) if scene.spectral else 3
    for name, prm in params.items():
        if name in metal_keys:
            continue
        key = _join(path, name)
        if name not in m:
            if prm.default is inspect.Parameter.empty:
                hint = " (or 'metal')" if name in (METAL_KEYS.get(model) or ()) else ""
                raise MissingKeyError(ck.file, key, f"a value (required by {model}){hint}", "nothing")
            continue
        v = m[name]
        if name in MODEL_PARAMS:
            out[name] = _parse_material(ck, v, key, scene)
        elif isinstance(prm.default, bool):
            out[name] = ck.boolean(m, path, name)
        elif isinstance(prm.default, str):
            out[name] = ck.string(m, path, name)
        elif name in CHANNEL_PARAMS or (name == "eta" and model in CONDUCTORS_ETA):
            out[name] = ck.numbers(m, path, name, allow_scalar=True, lengths={1, n_ch})
        else:
            out[name] = ck.number(m, path, name)
    return out


def _build(ck, spec, path, scene):
    model = spec["model"]
    kw = {}
    for name, v in spec.items():
        if name in ("model", "metal"):
            continue
        if isinstance(v, dict):
            kw[name] = _build(ck, v, _join(path, name), scene)
        elif isinstance(v, list):
            kw[name] = np.asarray(v, dtype=np.float64)
        else:
            kw[name] = v
    if "metal" in spec:
        wl = scene.wavelengths() if scene.spectral else np.asarray(spectral.RGB_WAVELENGTHS)
        n, k = spectral.metal_nk(spec["metal"], wl)
        ke, kk = METAL_KEYS[model]
        kw[ke], kw[kk] = n, k
    try:
        return MODELS[model](**kw)
    except ParameterError as e:
        msg = str(e)
        m = re.search(r"parameter '(\w+)'", msg) or re.search(r": (\w+) must be", msg)
        name = m.group(1) if m else None
        exp = re.search(r"must be (.*?)(?:, (?:found|got) (.*))?$", msg)
        key = _join(path, name) if name and name in spec else path
        found = repr(spec.get(name)) if name in spec else (exp.group(2) if exp and exp.group(2) else None)
        raise SceneValueError(ck.file, key, exp.group(1) if exp else "a valid value", found,
                              detail=None if (name and name in spec) else msg) from None
