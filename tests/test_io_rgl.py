"""RGL .bsdf tensor files: container, warps, evaluation of the 7 shared measurements."""
import numpy as np
import pytest

from testdata import rgl_path
from matfit.io import load, read_rgl, read_tensor_file, write_tensor_file
from matfit.io.rgl import RglBRDF, _Warp2D

NAMES = ["cc_ibiza_sunset", "cc_iris_purple_gem", "cg_sunflower", "colodur_napoli_4f", "paper_white",
         "satin_rosaline", "vch_golden_yellow"]


_cache = {}


def brdf(name) -> RglBRDF:
    if name not in _cache:
        _cache[name] = read_rgl(rgl_path(name))
    return _cache[name]


# ---------------------------------------------------------------------------------- warps (no data needed)
@pytest.mark.check
def test_warp_sample_invert_consistent():
    rng = np.random.default_rng(0)
    p0, p1 = np.array([0.0, 0.5, 1.2]), np.array([-1.0, 2.0])
    data = rng.uniform(0.05, 1.0, size=(3, 2, 9, 13))
    w = _Warp2D(data, (p0, p1))
    n = 4000
    u = rng.uniform(0, 1, size=(n, 2))
    par = (rng.uniform(-0.2, 1.4, n), rng.uniform(-1.5, 2.5, n))
    pos, pdf = w.sample(u, par)
    assert ((pos >= 0) & (pos <= 1)).all()
    back, pdf2 = w.invert(pos, par)
    # exact up to the loader's own shortcut: where a patch's density is constant to 1e-4 the forward
    # warp inverts the linear CDF by its constant-density approximation (as powitacq does)
    np.testing.assert_allclose(back, np.clip(u, 6e-8, 1 - 6e-8), atol=1e-5)
    assert np.median(np.abs(back - u)) < 1e-12
    np.testing.assert_allclose(pdf2, pdf, rtol=1e-4)
    np.testing.assert_allclose(w.eval(pos, par), pdf2, rtol=1e-9)
    # the density integrates to one over the unit square (bilinear patches: trapezoid rule is exact)
    g = np.linspace(0, 1, 97)
    X, Y = np.meshgrid(g, g, indexing="xy")
    pts = np.stack([X.ravel(), Y.ravel()], 1)
    vals = w.eval(pts, (np.full(len(pts), 0.5), np.full(len(pts), 2.0))).reshape(97, 97)
    assert abs(np.trapezoid(np.trapezoid(vals, g, axis=1), g) - 1.0) < 1e-3


def test_tensor_file_round_trip(tmp_path):
    fields = {"a": np.arange(12, dtype=np.float32).reshape(3, 4), "b": np.array([1, 0], dtype=np.uint8),
              "name": np.frombuffer(b"hello", dtype=np.uint8), "c": np.arange(5, dtype=np.int64)}
    write_tensor_file(tmp_path / "t.bsdf", fields)
    tf = read_tensor_file(tmp_path / "t.bsdf")
    assert set(tf.fields) == set(fields)
    for k, v in fields.items():
        np.testing.assert_array_equal(tf[k], v)
        assert tf[k].dtype == v.dtype.newbyteorder("<") or tf[k].dtype == v.dtype
    assert tf.dtype_codes == {"a": 10, "b": 1, "name": 1, "c": 8}


# ---------------------------------------------------------------------------------- the shared files
@pytest.mark.parametrize("name", NAMES)
def test_file_evaluates_and_matches_stored_samples(name):
    b = brdf(name)
    assert b.channels == "rgb" and b.isotropic and b.jacobian
    t = b.to_table(use_file_valid=False)
    assert len(t) == 8 * b.grid_shape[0] * b.grid_shape[1]
    assert np.isfinite(t.values).all() and (t.values >= 0).all()
    v = t.valid
    assert v.mean() > 0.6
    # values at the measured directions agree with the file's own stored samples
    ev = b.eval(t.wo[v], t.wi[v])
    rel = np.abs(ev - t.values[v]) / np.maximum(t.values[v], 1e-3)
    assert rel.max() < 1e-3, rel.max()
    assert np.median(rel) < 1e-9
    # finite and non-negative at arbitrary directions, zero below the horizon
    rng = np.random.default_rng(0)
    d = rng.normal(size=(2, 3000, 3))
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    f = b.eval(d[0], d[1])
    assert np.isfinite(f).all() and (f >= 0).all()
    below = (d[0][:, 2] <= 0) | (d[1][:, 2] <= 0)
    assert (f[below] == 0).all() and (f[~below].max(axis=1) > 0).mean() > 0.99


ALB = {}


def albedo(name, deg=30.0):
    if (name, deg) not in ALB:
        ALB[(name, deg)] = brdf(name).albedo(np.radians(deg), n=48)
    return ALB[(name, deg)]


@pytest.mark.check
@pytest.mark.parametrize("name", NAMES)
def test_albedo_bounded(name):
    for deg in (0.0, 30.0, 60.0):
        a = albedo(name, deg)
        assert (a > 0.005).all() and (a < 1.05).all(), (deg, a)


def test_albedo_white_paper_and_red_paint():
    a = albedo("paper_white")
    assert 0.6 < a.mean() < 0.95 and (a > 0.6).all() and (a < 1.05).all(), a
    assert a[2] > a[0]  # optical brighteners: blue-ish white
    # Colodur "Napoli 4F" is a red wall paint (R ~ 0.26, G, B ~ 0.065), not a white one
    c = albedo("colodur_napoli_4f")
    assert 0.15 < c[0] < 0.4 and c[1] < 0.5 * c[0] and c[2] < 0.5 * c[0], c


@pytest.mark.parametrize("name", ["cc_ibiza_sunset", "cc_iris_purple_gem", "cg_sunflower", "vch_golden_yellow"])
def test_vinyl_films_coloured(name):
    a = albedo(name)
    assert a.max() / a.min() > 1.5, a


def test_albedo_quadrature_matches_angular_grid():
    b = brdf("satin_rosaline")
    n = 120
    th = (np.arange(n) + 0.5) / n * np.pi / 2
    ph = (np.arange(2 * n) + 0.5) / (2 * n) * 2 * np.pi - np.pi
    T, P = np.meshgrid(th, ph, indexing="ij")
    wo = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(-1, 3)
    ti = np.radians(30.0)
    wi = np.broadcast_to([np.sin(ti), 0.0, np.cos(ti)], wo.shape)
    brute = (b.eval_cos(wo, wi) * np.sin(T).reshape(-1, 1)).sum(0) * (np.pi / 2 / n) * (np.pi / n)
    np.testing.assert_allclose(albedo("satin_rosaline"), brute, rtol=0.01)


def test_load_dispatch_and_file_valid_mask():
    p = rgl_path("paper_white")
    t, native = load(p, return_native=True)
    assert isinstance(native, RglBRDF) and t.provenance["material"] == "White A4 paper (160 gsm)"
    assert t.n_valid < native.to_table(use_file_valid=False).n_valid
    nodes = np.tile(native.node_valid.ravel(), len(native.theta_i))  # rows: incidence-major, then nodes
    assert not t.valid[~nodes].any()


def test_spectral_variant(tmp_path):
    """A 'spectra' + 'wavelengths' file (Mitsuba's spectral layout) evaluates like the RGB one."""
    tf = read_tensor_file(rgl_path("cc_ibiza_sunset"))
    fields = dict(tf.fields)
    fields["spectra"] = fields.pop("rgb")
    fields["wavelengths"] = np.array([450.0, 550.0, 650.0], dtype=np.float32)
    write_tensor_file(tmp_path / "spec.bsdf", fields)
    s = read_rgl(tmp_path / "spec.bsdf")
    assert s.channels == (450.0, 550.0, 650.0)
    b = brdf("cc_ibiza_sunset")
    rng = np.random.default_rng(5)
    d = rng.normal(size=(2, 500, 3))
    d[..., 2] = np.abs(d[..., 2])
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    np.testing.assert_allclose(s.eval(d[0], d[1]), b.eval(d[0], d[1]), rtol=1e-12)
