"""The synthetic gonioreflectometer: scene -> :class:`matfit.Table` with its ground truth.

Pipeline (each step only when the scene asks for it):

1. geometry -> nominal ``(wo, wi)`` pairs and the grid's ``valid`` mask (only reflection pairs,
   only transmission pairs, or both, as declared);
2. jitter -> the directions actually measured (kept on the nominal side of the surface);
3. evaluation of the model on the valid rows only, point-wise or averaged over the aperture cone
   (cone directions that fall on the other side of the surface are not evaluated and count 0);
4. spectral scenes: per-wavelength values -> linear sRGB (or kept as a spectrum);
5. gain, Poisson and relative Gaussian noise, outliers; ``sigma`` from the declared noise model.

The table's ``provenance["ground_truth"]`` holds the model name, its parameters, the effects, the seed
and the realized gain / outlier rows. Evaluation runs in float64.
"""
from __future__ import annotations

import os
import time

import equinox as eqx
import jax
import numpy as np

from matfit import __version__ as _matfit_version
from matfit.table import Table

from . import effects as _fx
from . import geometry as _geo
from . import spectral
from .scene import Scene, load_scene

CHUNK = 1 << 16


class EvalCounter:
    """Records every call the synthesizer makes to ``model.eval`` (pass as ``counter=``).

    Attributes: ``calls`` (eval invocations), ``pairs`` (direction pairs evaluated), ``transmission_pairs``
    (pairs with ``wo`` and ``wi`` on opposite sides), ``reflection_pairs``, ``aperture_rules`` (cone
    quadratures built) and ``log`` (one ``(n_pairs, n_transmission, purpose)`` per call).
    """

    def __init__(self):
        self.calls = self.pairs = self.transmission_pairs = self.reflection_pairs = self.aperture_rules = 0
        self.log = []

    def record(self, wo, wi, purpose):
        t = int(np.count_nonzero(wo[:, 2] * wi[:, 2] < 0))
        self.calls += 1
        self.pairs += len(wo)
        self.transmission_pairs += t
        self.reflection_pairs += len(wo) - t
        self.log.append((len(wo), t, purpose))


@eqx.filter_jit
def _eval(model, wo, wi):
    return model.eval(wo, wi)


def evaluate(model, wo, wi, counter=None, purpose="point"):
    """``model.eval`` on (N, 3) numpy pairs in float64, in chunks of CHUNK (padded: one compile per size)."""
    n = len(wo)
    if counter is not None:
        counter.record(wo, wi, purpose)
    if n == 0:
        return np.zeros((0, model.channels))
    out = []
    size = min(n, CHUNK)
    for s in range(0, n, size):
        a, b = wo[s:s + size], wi[s:s + size]
        m = len(a)
        if m < size:  # pad with a harmless valid pair
            a = np.concatenate([a, np.tile([[0.0, 0.0, 1.0]], (size - m, 1))])
            b = np.concatenate([b, np.tile([[0.0, 0.0, 1.0]], (size - m, 1))])
        out.append(np.asarray(_eval(model, a, b))[:m])
    return np.concatenate(out).astype(np.float64)


def _same_side(w, nominal):
    return (w[:, 2] * nominal[:, 2] > 0) & (np.abs(w[:, 2]) > 1e-7)


def _keep_side(w, nominal):
    """Directions mirrored back through the surface where jitter carried them to the other side."""
    w = np.array(w, copy=True)
    flip = ~_same_side(w, nominal)
    w[flip, 2] = np.where(nominal[flip, 2] >= 0, 1.0, -1.0) * np.maximum(np.abs(w[flip, 2]), 1e-6)
    return w / np.linalg.norm(w, axis=-1, keepdims=True)


def build_geometry(scene: Scene):
    g = dict(scene.geometry)
    kind = g.pop("kind")
    if kind == "sparse":
        g["views"] = [tuple(v) for v in g["views"]]
    return _geo.BUILDERS[kind](**g)


def synthesize(scene, counter: EvalCounter | None = None) -> Table:
    """Render a scene (a :class:`Scene` or a path to a TOML file) into a Table."""
    if not isinstance(scene, (Scene, str, os.PathLike)):
        raise TypeError(f"synthesize: scene must be a data_synth Scene or a path to a TOML scene file, "
                        f"got {type(scene).__name__} (use data_synth.scene.parse_scene for a dict)")
    if not isinstance(scene, Scene):
        scene = load_scene(scene)
    t0 = time.perf_counter()
    with jax.enable_x64(True):
        model = scene.build_model()
        wo, wi, valid, ginfo = build_geometry(scene)
        fx = scene.effects
        noise = fx["noise"] or {}
        rng = np.random.default_rng(scene.seed)
        idx = np.flatnonzero(valid)
        wo_m, wi_m = wo[idx], wi[idx]
        if noise.get("jitter"):
            wo_m = _keep_side(_fx.jitter_directions(wo_m, noise["jitter"], rng), wo[idx])
            wi_m = _keep_side(_fx.jitter_directions(wi_m, noise["jitter"], rng), wi[idx])
        ap = fx["aperture"]
        if ap is None:
            f = evaluate(model, wo_m, wi_m, counter)
        else:
            if counter is not None:
                counter.aperture_rules += 1
            d, w = _fx.cone_directions(wo_m, ap["half_angle"], ap["n_polar"], ap["n_azimuth"])
            q = d.shape[1]
            d = d.reshape(-1, 3)
            wi_rep = np.repeat(wi_m, q, axis=0)
            ok = _same_side(d, np.repeat(wo_m, q, axis=0))
            f_all = np.zeros((len(d), model.channels))
            f_all[ok] = evaluate(model, d[ok], wi_rep[ok], counter, purpose="aperture")
            f = np.einsum("nqc,q->nc", f_all.reshape(len(wo_m), q, -1), w)
        col = fx["colour"]
        if col["mode"] == "spectral":
            wl = scene.wavelengths()
            f = np.broadcast_to(f, (len(f), len(wl)))
            if col["output"] == "rgb":
                f = f @ spectral.rgb_matrix(*col["wavelengths"], col["illuminant"], col["observer"])
                channels = "rgb"
            else:
                channels = tuple(float(x) for x in wl)
        else:
            channels = {1: "mono", 3: "rgb"}.get(f.shape[1])
            if channels is None:  # pragma: no cover - the parser only allows 1 or 3 channels
                raise ValueError(f"unexpected channel count {f.shape[1]}")
        values = np.zeros((len(wo), f.shape[1]))
        values[idx] = f
    record = {}
    sigma = None
    if noise:
        values, clean, record = _fx.apply_noise(values, valid, rng, gain=noise["gain"], photons=noise["photons"],
                                                reference=noise["reference"], relative=noise["relative"],
                                                outliers=noise["outliers"], outlier_scale=noise["outlier_scale"])
        sigma = _fx.predicted_sigma(clean, noise["relative"], noise["photons"], noise["reference"],
                                    noise["sigma_floor"])
        sigma = np.maximum(sigma, 1e-300)
        if noise["relative"] == 0 and not noise["photons"] and noise["sigma_floor"] == 0:
            sigma = None
    truth = {"model": scene.material["model"], "params": scene.material, "effects": fx, "seed": scene.seed,
             "geometry": scene.geometry, "matfit_version": _matfit_version, **record}
    if "metal" in _metal_specs(scene.material):
        wl = scene.wavelengths() if scene.spectral else np.asarray(spectral.RGB_WAVELENGTHS)
        truth["metal_wavelengths_nm"] = [float(x) for x in wl]
        truth["metal_nk"] = {m: [a.tolist() for a in spectral.metal_nk(m, wl)] for m in _metal_specs(scene.material)["metal"]}
        truth["metal_source"] = "data_synth/data/metals_nk.csv"
    prov = {"format": "matfit.synth/1", "source": scene.file, "scene": scene.name,
            "instrument": "data_synth synthetic gonioreflectometer", "material": _describe(scene.material),
            "geometry": ginfo, "ground_truth": truth,
            "synth_seconds": round(time.perf_counter() - t0, 4)}
    if scene.description:
        prov["description"] = scene.description
    return Table(wo=wo, wi=wi, values=values, sigma=sigma, valid=valid, channels=channels, provenance=prov)


def _metal_specs(spec, acc=None):
    acc = {} if acc is None else acc
    if "metal" in spec:
        acc.setdefault("metal", []).append(spec["metal"])
    for v in spec.values():
        if isinstance(v, dict):
            _metal_specs(v, acc)
    return acc


def _describe(spec):
    inner = []
    for k, v in spec.items():
        if k == "model":
            continue
        inner.append(f"{k}={_describe(v) if isinstance(v, dict) else v}")
    return f"{spec['model']}({', '.join(inner)})"
