"""Synthetic gonioreflectometer (data_synth): geometry, effects, ground truth, scene errors, CLI."""
from __future__ import annotations

import copy
import json

import jax
import numpy as np
import pytest

from data_synth import (EvalCounter, MissingKeyError, SceneError, SceneSyntaxError, SceneTypeError,
                        SceneValueError, UnknownKeyError, UnknownModelError, UnknownParameterError, load_scene,
                        parse_scene, shipped_scenes, synthesize)
from data_synth import effects as fx
from data_synth import geometry as geo
from data_synth.spectral import metal_nk, rgb_matrix
from data_synth.synth import evaluate
from matfit.errors import MatfitError
from matfit.models import Lambert, RoughConductor, RoughDielectric


def _scene(**over):
    """A small Lambert in-plane scene as a dict, with sections replaced by ``over``."""
    d = {"scene": {"name": "t", "seed": 0},
         "geometry": {"kind": "inplane", "theta_i": [0.0, 40.0], "theta_o_step": 10.0},
         "material": {"model": "Lambert", "albedo": [0.5, 0.3, 0.2]}}
    d.update(copy.deepcopy(over))
    return d


# ------------------------------------------------------------------ geometry
@pytest.mark.parametrize("kind,kw", [("inplane", {}), ("hemisphere", {"n_theta": 3, "n_phi": 4}),
                                     ("merl", {"n_theta_h": 4, "n_theta_d": 4, "n_phi_d": 6}),
                                     ("random", {"n": 50}), ("stratified", {"n": 50}), ("sparse", {})])
def test_geometries_are_unit_and_reflection_only(kind, kw):
    wo, wi, valid, info = geo.BUILDERS[kind](**kw)
    assert wo.shape == wi.shape and wo.shape[1] == 3 and valid.shape == (len(wo),)
    np.testing.assert_allclose(np.linalg.norm(wo, axis=1), 1, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(wi, axis=1), 1, atol=1e-12)
    assert (wi[valid, 2] > 0).all() and (wo[valid, 2] > 0).all()
    json.dumps(info)


def test_merl_grid_matches_matfit_reader_geometry():
    from matfit.io import dirs_to_half_diff
    from matfit.io.merl import cell_index
    wo, wi, valid, _ = geo.merl_grid(6, 6, 12)
    th, _, td, pd = dirs_to_half_diff(wo, wi)
    exp_th = ((np.arange(6) + 0.5) / 6) ** 2 * np.pi / 2
    np.testing.assert_allclose(np.unique(np.round(th, 9)), np.round(exp_th, 9), atol=1e-8)
    # the full-resolution grid lands in its own MERL cells (same rule as MerlBRDF.lookup)
    wo, wi, valid, _ = geo.merl_grid()
    sel = np.arange(0, len(wo), 997)
    ih, idd, ip = cell_index(*np.delete(np.array(dirs_to_half_diff(wo[sel], wi[sel])), 1, axis=0))
    np.testing.assert_array_equal(ih * 90 * 180 + idd * 180 + ip, sel)


def test_stratified_marginals_are_stratified():
    wo, wi, _, _ = geo.stratified_pairs(n=64, seed=3)
    u = 1 - wi[:, 2]  # uniform-in-solid-angle: cos theta is uniform, one sample per stratum
    np.testing.assert_array_equal(np.sort(np.floor(u * 64)), np.arange(64))


# ------------------------------------------------------------------ effects
def test_aperture_converges_to_point_value():
    jax.config.update("jax_enable_x64", True)
    m = RoughConductor(0.15, np.array([0.2, 0.5, 1.4]), np.array([3.9, 2.4, 1.6]))
    wo = geo.sph([10.0, 35.0, 60.0], [0.0, 0.0, 20.0])
    wi = geo.sph([30.0, 35.0, 50.0], [180.0, 180.0, 180.0])
    point = evaluate(m, wo, wi)
    errs = []
    for g in (4.0, 2.0, 1.0, 0.5, 0.01):
        d, w = fx.cone_directions(wo, g, 6, 12)
        f = evaluate(m, d.reshape(-1, 3), np.repeat(wi, d.shape[1], 0)).reshape(3, d.shape[1], 3)
        errs.append(np.max(np.abs(np.einsum("nqc,q->nc", f, w) / point - 1)))
    assert errs[-1] < 1e-6
    # second order: halving the half-angle divides the error by ~4
    for a, b in zip(errs[:3], errs[1:4]):
        assert 2.5 < a / b < 5.5, errs
    # the rule is normalized and averages a constant exactly
    assert abs(fx.cone_rule(3.0, 3, 5)[2].sum() - 1) < 1e-14


def test_noise_statistics_match_declared_model():
    rng = np.random.default_rng(0)
    n, v0 = 40000, 0.7
    v = np.full((n, 1), v0)
    valid = np.ones(n, bool)
    noisy, clean, _ = fx.apply_noise(v, valid, rng, relative=0.05)
    r = noisy[:, 0] / v0 - 1
    assert abs(r.mean()) < 4 * 0.05 / np.sqrt(n) and abs(r.std() / 0.05 - 1) < 0.02
    # Poisson: counts have mean = variance = lambda
    noisy, _, _ = fx.apply_noise(v, valid, rng, photons=200.0, reference=1.0)
    counts = noisy[:, 0] * 200.0
    lam = v0 * 200.0
    assert np.allclose(counts, np.round(counts))
    assert abs(counts.mean() / lam - 1) < 0.005 and abs(counts.var() / lam - 1) < 0.03
    np.testing.assert_allclose(fx.predicted_sigma(v0, photons=200.0), np.sqrt(lam) / 200.0)
    # gain: channel means move by the recorded factors
    noisy, clean, rec = fx.apply_noise(np.full((n, 3), v0), valid, rng, gain=0.05, relative=0.01)
    np.testing.assert_allclose(noisy.mean(0) / v0, rec["gain"], rtol=3e-4)
    # outliers: the recorded rows, and only them, are off by the scale
    noisy, clean, rec = fx.apply_noise(v[:1000], valid[:1000], rng, outliers=0.02, outlier_scale=4.0)
    off = np.flatnonzero(~np.isclose(noisy[:, 0], v0))
    np.testing.assert_array_equal(off, rec["outlier_rows"])
    assert len(off) == 20 and np.allclose(np.sort(np.unique(np.round(noisy[off, 0] / v0, 9))), [0.25, 4.0])


def test_jitter_angle_distribution():
    rng = np.random.default_rng(1)
    w = np.tile(geo.sph(30.0, 40.0), (20000, 1))
    j = fx.jitter_directions(w, 0.5, rng)
    ang = np.degrees(np.arccos(np.clip(np.sum(j * w, 1), -1, 1)))
    # Rayleigh with sigma 0.5 deg: E[angle^2] = 2 sigma^2
    assert abs(np.mean(ang**2) / (2 * 0.25) - 1) < 0.03


def test_scene_noise_sigma_and_statistics():
    d = _scene(geometry={"kind": "random", "n": 4000}, effects={"noise": {"relative": 0.1}})
    t = synthesize(parse_scene(d))
    clean = synthesize(parse_scene(_scene(geometry={"kind": "random", "n": 4000})))
    z = (t.values - clean.values) / t.sigma
    assert abs(z.std() - 1) < 0.03 and abs(z.mean()) < 0.05
    assert clean.sigma is None


# ------------------------------------------------------------------ colour
def test_spectral_gold_is_yellow_and_white_is_white():
    M = rgb_matrix(380.0, 780.0, 10.0, "D65")
    np.testing.assert_allclose(np.ones(41) @ M, [1, 1, 1], atol=2e-3)
    d = {"geometry": {"kind": "sparse", "views": [[0.0, 0.0, 0.0, 0.0], [30.0, 180.0, 30.0, 0.0]]},
         "material": {"model": "RoughConductor", "metal": "gold", "alpha": 0.3}}
    d["effects"] = {"colour": {"mode": "spectral"}}
    t = synthesize(parse_scene(d))
    r, g, b = t.values[0]
    assert r > g > b > 0 and r / b > 1.8, t.values
    # normal-incidence Fresnel reflectance rendered the same way: gold is yellow, R > G > B
    wl = np.arange(380.0, 781.0, 10.0)
    n, k = metal_nk("gold", wl)
    F0 = ((n - 1) ** 2 + k**2) / ((n + 1) ** 2 + k**2)
    R, G, B = F0 @ M
    assert R > G > B and 0.9 < R < 1.1 and B < 0.6
    # spectrum output keeps wavelengths as channels
    d["effects"]["colour"]["output"] = "spectrum"
    ts = synthesize(parse_scene(d))
    assert ts.channels == tuple(wl) and ts.values.shape == (2, 41)


# ------------------------------------------------------------------ only what is asked is computed
def test_reflection_only_never_evaluates_transmission():
    base = {"geometry": {"kind": "inplane", "theta_i": [0.0, 50.0], "theta_o_step": 5.0, "theta_o_max": 89.0},
            "material": {"model": "RoughDielectric", "alpha": 0.3, "eta": 1.5}}
    for geom in (base["geometry"], {"kind": "random", "n": 300}, {"kind": "hemisphere", "n_theta": 4, "n_phi": 6}):
        d = dict(base, geometry=geom, effects={"aperture": {"half_angle": 3.0}, "noise": {"jitter": 2.0}})
        c = EvalCounter()
        t = synthesize(parse_scene(d), counter=c)
        assert c.calls == 1 and c.transmission_pairs == 0 and c.reflection_pairs == c.pairs > 0
    d = dict(base, effects={"transmission": True})
    c = EvalCounter()
    t = synthesize(parse_scene(d), counter=c)
    assert c.transmission_pairs == c.reflection_pairs == len(t) // 2
    d = dict(base, effects={"reflection": False, "transmission": True})
    c = EvalCounter()
    synthesize(parse_scene(d), counter=c)
    assert c.reflection_pairs == 0 and c.transmission_pairs > 0


def test_no_aperture_no_quadrature_and_invalid_rows_skipped():
    c = EvalCounter()
    t = synthesize(parse_scene(_scene()), counter=c)
    assert c.aperture_rules == 0 and c.pairs == len(t) and c.log[0][2] == "point"
    c = EvalCounter()
    synthesize(parse_scene(_scene(effects={"aperture": {"half_angle": 1.0, "n_polar": 2, "n_azimuth": 3}})),
               counter=c)
    assert c.aperture_rules == 1 and c.pairs == 6 * len(t) and c.log[0][2] == "aperture"
    c = EvalCounter()
    t = synthesize(parse_scene(_scene(geometry={"kind": "merl", "n_theta_h": 5, "n_theta_d": 5, "n_phi_d": 8})),
                   counter=c)
    assert c.pairs == t.n_valid < len(t) and (t.values[~t.valid] == 0).all()


# ------------------------------------------------------------------ ground truth
def test_ground_truth_in_provenance_and_values_exact():
    jax.config.update("jax_enable_x64", True)
    t = synthesize(load_scene("demo"))
    gt = t.provenance["ground_truth"]
    assert gt["model"] == "RoughConductor" and gt["params"]["alpha"] == 0.2 and gt["params"]["metal"] == "gold"
    assert gt["seed"] == 1 and gt["effects"]["noise"]["relative"] == 0.02
    assert len(gt["metal_nk"]["gold"][0]) == 3
    assert t.provenance["scene"] == "demo" and t.sigma is not None
    # noise-free scene: values equal the true model
    d = _scene(material={"model": "RoughConductor", "alpha": 0.25, "eta": [0.2, 0.5, 1.4], "k": [3.9, 2.4, 1.6]})
    t = synthesize(parse_scene(d))
    gt = t.provenance["ground_truth"]["params"]
    m = RoughConductor(gt["alpha"], np.array(gt["eta"]), np.array(gt["k"]))
    np.testing.assert_allclose(t.values, evaluate(m, t.wo, t.wi), rtol=1e-12)
    assert t.sigma is None and t.channels == "rgb"


@pytest.mark.check
def test_shipped_scenes_parse():
    names = {p.stem for p in shipped_scenes()}
    assert {"demo", "gold_ggx_inplane", "red_plastic_hemi", "frosted_glass_transmission",
            "car_paint_merlgrid"} <= names
    for p in shipped_scenes():
        s = load_scene(p)
        assert s.name == p.stem


# ------------------------------------------------------------------ scene errors
ERROR_CASES = [
    ("unknown top-level key", lambda d: d.update(geometri={}), UnknownKeyError, "geometri"),
    ("unknown effects key", lambda d: d.update(effects={"apperture": {}}), UnknownKeyError, "effects.apperture"),
    ("missing section", lambda d: d.pop("material"), MissingKeyError, "material"),
    ("missing model param", lambda d: d.update(material={"model": "RoughConductor", "alpha": 0.1, "eta": 1.5}),
     MissingKeyError, "material.k"),
    ("missing aperture angle", lambda d: d.update(effects={"aperture": {"n_polar": 3}}), MissingKeyError,
     "effects.aperture.half_angle"),
    ("wrong type", lambda d: d["geometry"].update(theta_o_step="5"), SceneTypeError, "geometry.theta_o_step"),
    ("wrong type bool", lambda d: d.update(effects={"transmission": "yes"}), SceneTypeError, "effects.transmission"),
    ("unknown model", lambda d: d.update(material={"model": "Phong"}), UnknownModelError, "material.model"),
    ("unknown parameter", lambda d: d["material"].update(roughness=0.2), UnknownParameterError, "material.roughness"),
    ("out of range (model)", lambda d: d.update(material={"model": "Lambert", "albedo": 1.5}), SceneValueError,
     "material.albedo"),
    ("out of range (scene)", lambda d: d["geometry"].update(theta_i=[0.0, 95.0]), SceneValueError,
     "geometry.theta_i[1]"),
    ("bad choice", lambda d: d["geometry"].update(kind="hemisfere"), SceneValueError, "geometry.kind"),
    ("wrong channel count", lambda d: d["material"].update(albedo=[0.1, 0.2]), SceneValueError, "material.albedo"),
    ("merl with transmission", lambda d: d.update(geometry={"kind": "merl"}, effects={"transmission": True}),
     SceneValueError, "effects.transmission"),
    ("nested model error", lambda d: d.update(material={"model": "Blend", "weight": 0.5, "a": {"model": "Lambert",
     "albedo": 0.5}, "b": {"model": "Lambert", "albdo": 0.5}}), UnknownParameterError, "material.b.albdo"),
    ("metal and eta", lambda d: d.update(material={"model": "RoughConductor", "alpha": 0.1, "metal": "gold",
     "eta": 1.0}), SceneValueError, "material.eta"),
    ("unknown metal", lambda d: d.update(material={"model": "RoughConductor", "alpha": 0.1, "metal": "silver"}),
     SceneValueError, "material.metal"),
    ("unknown illuminant", lambda d: d.update(effects={"colour": {"mode": "spectral", "illuminant": "D66"}}),
     SceneValueError, "effects.colour.illuminant"),
]


@pytest.mark.parametrize("what,mutate,exc,key", ERROR_CASES, ids=[c[0] for c in ERROR_CASES])
def test_scene_errors(tmp_path, what, mutate, exc, key):
    d = _scene()
    mutate(d)
    with pytest.raises(exc) as ei:
        parse_scene(d, file="bad.toml")
    e = ei.value
    assert isinstance(e, SceneError) and isinstance(e, MatfitError)
    assert e.key == key and e.file == "bad.toml"
    msg = str(e)
    assert msg.startswith(f"bad.toml: key '{key}'") and "expected" in msg and "found" in msg and "\n" not in msg


def test_toml_syntax_error_names_file(tmp_path):
    p = tmp_path / "s.toml"
    p.write_text("[geometry\nkind = 'inplane'\n")
    with pytest.raises(SceneSyntaxError, match="s.toml"):
        load_scene(p)


# ------------------------------------------------------------------ CLI
@pytest.mark.check
def test_cli_synth_info_roundtrip(tmp_path, capsys):
    from matfit.cli import main
    from matfit.io import load

    scene = tmp_path / "tiny.toml"
    scene.write_text('[scene]\nseed = 4\n[geometry]\nkind = "sparse"\n'
                     '[material]\nmodel = "Lambert"\nalbedo = [0.5, 0.4, 0.3]\n'
                     '[effects.noise]\nrelative = 0.01\n')
    out = tmp_path / "t.npz"
    assert main(["synth", str(scene), "-o", str(out)]) == 0
    t = load(out)
    assert len(t) == 10 and t.provenance["ground_truth"]["seed"] == 4
    assert t.provenance["ground_truth"]["params"] == {"model": "Lambert", "albedo": [0.5, 0.4, 0.3]}
    capsys.readouterr()
    assert main(["info", str(out)]) == 0
    text = capsys.readouterr().out
    assert "10 samples" in text and "ground truth: Lambert" in text and "scene: tiny" in text
    csv_out = tmp_path / "t.csv"
    assert main(["synth", str(scene), "-o", str(csv_out), "--seed", "9"]) == 0
    assert load(csv_out).provenance["ground_truth"]["seed"] == 9
    # errors: one line on stderr, exit status 2
    bad = tmp_path / "bad.toml"
    bad.write_text('[geometry]\nkind = "inplane"\n[material]\nmodel = "Lambert"\nalbedo = 0.5\ncolor = 1\n')
    capsys.readouterr()
    assert main(["synth", str(bad), "-o", str(tmp_path / "x.npz")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "bad.toml" in err and "material.color" in err
    assert main(["info", str(tmp_path / "missing.npz")]) == 2
