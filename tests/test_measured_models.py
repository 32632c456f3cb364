"""Measured tables as models (matfit.models.MeasuredMERL, MeasuredRGL).

* RGL: ``eval`` equals the reader (:class:`matfit.io.RglBRDF`) at the file's stored samples and
  everywhere else; between the samples it agrees with Mitsuba 3's ``measured`` plugin (scalar_rgb,
  the file's incidence at our ``wi``) over random, near-mirror and grazing directions; ``pdf``
  agrees with the plugin's ``pdf`` (its ``si.wi`` at our ``wo``, the sampler's incidence).
* MERL: ``eval`` equals an independent numpy trilinear interpolation of the cell centres
  (written here from the formula), equals the stored cells at their centres, is reciprocal, and
  approximates the analytic BRDF the table was made from.
* Sampling (both): chi-square of ``sample`` against ``pdf`` on a grid of half vectors (quadrature
  of the pdf over each cell, tests/chi2.py), int pdf = fraction of valid samples, weight =
  f cos / pdf; energy: the directional albedo (quadrature and mean weight) is at most 1.
* Previews: render_sphere of the measured models is finite and close to a render of a fitted
  model of the same table (the RGL paper's least-squares Lambert fit, under the furnace; for the
  MERL table, under the sky with MIS, the conductor it was made of, which is what a fit of it
  returns).
* The tables are constants (zero gradients), a jitted function compiles once, bad input raises.
"""
from __future__ import annotations

import os
import sys
import zlib

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import chi2 as c2  # noqa: E402
from testdata import rgl_path  # noqa: E402

from matfit.errors import DataFormatError, ParameterError  # noqa: E402
from matfit.io import MerlBRDF, read_rgl  # noqa: E402
from matfit.io import dirs_to_half_diff, half_diff_to_dirs  # noqa: E402
from matfit.io.merl import cell_centres  # noqa: E402
from matfit.models import MeasuredMERL, MeasuredRGL, RoughConductor  # noqa: E402
from matfit.models import Lambert  # noqa: E402
from matfit.render import render_sphere  # noqa: E402

MI_FILES = ["cg_sunflower", "vch_golden_yellow", "cc_ibiza_sunset"]
GOLD = (jnp.array([0.143, 0.374, 1.442]), jnp.array([3.983, 2.385, 1.603]))
CHUNK = 1 << 13


_cache = {}


def rgl(name):
    if name not in _cache:
        p = rgl_path(name)
        _cache[name] = (read_rgl(p), MeasuredRGL.from_file(p))
    return _cache[name]


def _sph(theta, phi):
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], -1)


def _upper(rng, n, cos_min=0.02):
    return _sph(np.arccos(rng.uniform(cos_min, 1, n)), rng.uniform(-np.pi, np.pi, n))


def _seed(*parts):
    return zlib.crc32("|".join(map(str, parts)).encode())


@eqx.filter_jit
def _eval_j(m, wo, wi):
    return m.eval(wo, wi)


@eqx.filter_jit
def _eval_cos_j(m, wo, wi):
    return m.eval_cos(wo, wi)


@eqx.filter_jit
def _pdf_j(m, wo, wi):
    return m.pdf(wo, wi)


@eqx.filter_jit
def _sample_all(m, wo, u):
    wi, weight, pdf = m.sample(wo, u)
    return wi, weight, pdf, m.pdf(wo, wi), m.eval(wo, wi)


def chunked(fn, m, *arrays):
    """``fn(m, *arrays)`` over (n, 3) arrays in fixed-size chunks (one compilation per model
    structure), as float64 numpy; a (3,) array is broadcast to every row."""
    n = max(len(a) for a in arrays if np.ndim(a) == 2)
    arrays = [np.broadcast_to(np.asarray(a, np.float64), (n, 3)) for a in arrays]
    outs = []
    for s in range(0, n, CHUNK):
        blk = [a[s:s + CHUNK] for a in arrays]
        k = len(blk[0])
        if k < CHUNK:
            blk = [np.concatenate([b, np.tile([[0.0, 0.0, 1.0]], (CHUNK - k, 1))]) for b in blk]
        res = fn(m, *(jnp.asarray(b) for b in blk))
        res = res if isinstance(res, tuple) else (res,)
        outs.append([np.asarray(r, np.float64)[:k] for r in res])
    out = [np.concatenate([o[i] for o in outs]) for i in range(len(outs[0]))]
    return out if len(out) > 1 else out[0]


def _eval(m, wo, wi):
    return chunked(_eval_j, m, wo, wi)


def _pdf(m, wo, wi):
    return chunked(_pdf_j, m, wo, wi)


# ------------------------------------------------------------------------------------------------
# A MERL table made from an analytic BRDF (no MERL file is shared)
# ------------------------------------------------------------------------------------------------
def _cells():
    th, td, pd = cell_centres()
    TH, TD, PD = np.meshgrid(th, td, pd, indexing="ij")
    wo, wi = half_diff_to_dirs(TH.ravel(), TD.ravel(), PD.ravel())
    return wo, wi


@pytest.fixture(scope="module")
def merl_gold():
    """(truth, MerlBRDF, MeasuredMERL): a rough gold conductor (GGX 0.2) at MERL's cell centres."""
    truth = RoughConductor(0.2, *GOLD)
    wo, wi = _cells()
    valid = (wo[:, 2] > 0) & (wi[:, 2] > 0)
    f = np.asarray(jax.jit(lambda a, b: truth.eval(a, b))(jnp.asarray(wo), jnp.asarray(wi)))
    table = MerlBRDF.from_values(f.T.reshape(3, 90, 90, 180), valid.reshape(90, 90, 180))
    return truth, table, MeasuredMERL(table, n_theta_o=16)


def merl_reference(table, wo, wi):
    """Trilinear interpolation of the cell centres written from the formula (numpy): coordinates
    sqrt(theta_h / (pi/2)) * 90 - 1/2, theta_d / (pi/2) * 90 - 1/2 (clamped), (phi_d mod pi) / pi * 180
    - 1/2 (periodic); invalid cells drop out and the remaining weights are renormalized."""
    th, _, td, pd = dirs_to_half_diff(wo, wi)
    x = [np.clip(np.sqrt(th / (np.pi / 2)) * 90 - 0.5, 0, 89), np.clip(td / (np.pi / 2) * 90 - 0.5, 0, 89),
         np.mod(pd, np.pi) / np.pi * 180 - 0.5]
    vals = np.moveaxis(table.values, 0, -1)
    valid = table.valid
    num = np.zeros((len(wo), 3))
    den = np.zeros(len(wo))
    i0 = [np.minimum(np.floor(x[0]), 88).astype(int), np.minimum(np.floor(x[1]), 88).astype(int),
          np.floor(x[2]).astype(int)]
    t = [x[k] - i0[k] for k in range(3)]
    for a in (0, 1):
        for b in (0, 1):
            for c in (0, 1):
                ia, ib, ic = i0[0] + a, i0[1] + b, (i0[2] + c) % 180
                w = (t[0] if a else 1 - t[0]) * (t[1] if b else 1 - t[1]) * (t[2] if c else 1 - t[2])
                w = w * valid[ia, ib, ic]
                num += w[:, None] * vals[ia, ib, ic]
                den += w
    out = np.where(den[:, None] > 0, num / np.where(den > 0, den, 1)[:, None], 0)
    return np.where(((wo[:, 2] > 0) & (wi[:, 2] > 0))[:, None], out, 0)


def test_merl_eval_interpolates_cell_centres(merl_gold):
    truth, table, m = merl_gold
    rng = np.random.default_rng(1)
    wo, wi = _upper(rng, 4000, 0.01), _upper(rng, 4000, 0.01)
    got = _eval(m, wo, wi)
    np.testing.assert_allclose(got, merl_reference(table, wo, wi), rtol=1e-9, atol=1e-12)
    # at the cell centres: the stored cells (MERL's own lookup rule)
    cwo, cwi = _cells()
    sel = rng.choice(np.flatnonzero(table.valid.ravel()), 3000, replace=False)
    stored, ok = table.lookup(cwo[sel], cwi[sel])
    assert ok.all()
    np.testing.assert_allclose(_eval(m, cwo[sel], cwi[sel]), stored,
                               rtol=1e-9)
    # between them: close to the analytic BRDF the table was made from
    ref = _eval(truth, wo, wi)
    rel = np.abs(got - ref) / np.maximum(ref, 1e-3)
    assert np.median(rel) < 3e-3 and np.quantile(rel, 0.9) < 2e-2, np.quantile(rel, [0.5, 0.9])


def test_merl_reciprocal_and_one_sided(merl_gold):
    _, _, m = merl_gold
    rng = np.random.default_rng(2)
    wo, wi = _upper(rng, 3000, 0.0), _upper(rng, 3000, 0.0)
    a = _eval(m, wo, wi)
    b = _eval(m, wi, wo)
    np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-14)
    below = wi * np.array([1, 1, -1])
    assert np.all(_eval(m, wo, below) == 0)
    assert np.all(_pdf(m, wo, below) == 0)


# ------------------------------------------------------------------------------------------------
# RGL against the reader and against Mitsuba 3
# ------------------------------------------------------------------------------------------------
@pytest.mark.check
def test_rgl_eval_matches_the_reader():
    name = "cg_sunflower"
    brdf, m = rgl(name)
    t = brdf.to_table(use_file_valid=False)
    v = t.valid
    got = _eval(m, t.wo[v], t.wi[v])
    rel = np.abs(got - t.values[v]) / np.maximum(t.values[v], 1e-3)
    assert rel.max() < 1e-3 and np.median(rel) < 1e-9, (rel.max(), np.median(rel))
    rng = np.random.default_rng(3)
    wo, wi = _upper(rng, 3000, 0.0), _upper(rng, 3000, 0.0)
    np.testing.assert_allclose(_eval(m, wo, wi), brdf.eval(wo, wi),
                               rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(chunked(_eval_cos_j, m, wo, wi), brdf.eval_cos(wo, wi),
                               rtol=1e-9, atol=1e-12)


def _mitsuba():
    mi = pytest.importorskip("mitsuba", reason="Mitsuba 3 is not installed (pip install mitsuba)")
    if "scalar_rgb" not in mi.variants():
        pytest.skip("Mitsuba 3 has no scalar_rgb variant")
    mi.set_variant("scalar_rgb")
    return mi


def _mi_eval_pdf(mi, bsdf, wo, wi):
    """Mitsuba's eval (f cos(theta_o), without clipping) and pdf with its si.wi = our wi."""
    ctx = mi.BSDFContext()
    si = mi.SurfaceInteraction3f()
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    f = np.empty((len(wo), 3))
    p = np.empty(len(wo))
    for k in range(len(wo)):
        si.wi = mi.Vector3f(*wi[k])
        o = mi.Vector3f(*wo[k])
        v = bsdf.eval(ctx, si, o)
        f[k] = [v[0], v[1], v[2]]
        p[k] = bsdf.pdf(ctx, si, o)
    return f, p


def _direction_sets(rng, n):
    """Pairs (wo, wi) between the stored samples: random; near the mirror direction (half vector
    0.05..3 deg from the normal; the exact mirror is a singular point, see docs/data.md); grazing."""
    sets = {"random": (_upper(rng, n), _upper(rng, n))}
    wi = _sph(np.radians(rng.uniform(0, 85, n)), rng.uniform(-np.pi, np.pi, n))
    m = _sph(np.radians(10 ** rng.uniform(np.log10(0.05), np.log10(3), n)), rng.uniform(-np.pi, np.pi, n))
    wo = 2 * np.sum(wi * m, 1, keepdims=True) * m - wi
    ok = wo[:, 2] > 0.01
    sets["near mirror"] = (wo[ok], wi[ok])
    g = _sph(np.radians(rng.uniform(80, 89.5, n)), rng.uniform(-np.pi, np.pi, n))
    sets["grazing view"] = (g, _upper(rng, n))
    sets["grazing light"] = (_upper(rng, n), g)
    return sets


@pytest.mark.parametrize("name", MI_FILES)
def test_rgl_agrees_with_mitsuba_between_samples(name):
    """Eval (f cos) and pdf against Mitsuba 3.9's measured plugin (float32): figures in docs/data.md."""
    mi = _mitsuba()
    brdf, m = rgl(name)
    plugin = mi.load_dict({"type": "measured", "filename": str(rgl_path(name))})
    rng = np.random.default_rng(_seed(name))
    for label, (wo, wi) in _direction_sets(rng, 300).items():
        f_mi, _ = _mi_eval_pdf(mi, plugin, wo, wi)
        # Mitsuba keeps negative interpolated rgb values; the reader and the model clip them at 0
        neg = f_mi < 0
        ours = chunked(_eval_cos_j, m, wo, wi)
        assert np.all(ours[neg] == 0), label
        ref = np.maximum(f_mi, 0)
        rel = np.abs(ours - ref) / np.maximum(ref, 1e-3 * ref.max())
        assert np.median(rel) < 1e-5 and np.quantile(rel, 0.99) < 2e-4 and rel.max() < 2e-3, \
            (label, np.quantile(rel, [0.5, 0.99, 1.0]))
        np.testing.assert_allclose(brdf.eval_cos(wo, wi), ours, rtol=1e-9, atol=1e-12)
        # the sampler's pdf: our wo is the warp's incidence, i.e. Mitsuba's si.wi
        _, p_mi = _mi_eval_pdf(mi, plugin, wi, wo)
        p = _pdf(m, wo, wi)
        relp = np.abs(p - p_mi) / np.maximum(p_mi, 1e-6)
        assert np.quantile(relp, 0.99) < 2e-3 and relp.max() < 2e-2, (label, np.quantile(relp, [0.5, 0.99, 1.0]))


# ------------------------------------------------------------------------------------------------
# Sampling: chi-square on a grid of half vectors, int pdf, weights
# ------------------------------------------------------------------------------------------------
N_SAMPLES = 1 << 16
CASES = [("merl", 0.0), ("merl", 70.0), ("cc_ibiza_sunset", 30.0), ("vch_golden_yellow", 75.0)]
P_MIN = 0.01 / len(CASES)


def _model(kind, request):
    if kind == "merl":
        return request.getfixturevalue("merl_gold")[2]
    return rgl(kind)[1]


class HalfGrid:
    """Cells in (x, y) = (sqrt(theta_h / (pi/2)), azimuth of h relative to wo's) of the half
    vector h of a reflection pair: d omega_h = sin(theta_h) pi x dx dy. 32 x 32 cells, whose edges
    fall on the edges of both models' own tables (MERL's 64 x 64 half-vector cells, RGL's 128-node
    VNDF grids), so that a cell's pdf is smooth and the quadrature converges."""

    n = 32
    xedges = np.linspace(0.0, 1.0, n + 1)
    yedges = np.linspace(0.0, 2 * np.pi, n + 1)

    def __init__(self, phi_o):
        self.phi_o = phi_o

    def to_h(self, x, y):
        theta = x * x * (np.pi / 2)
        return _sph(theta, y + self.phi_o), np.sin(theta) * np.pi * x

    def from_h(self, h):
        theta = np.arctan2(np.hypot(h[:, 0], h[:, 1]), h[:, 2])
        return np.sqrt(theta / (np.pi / 2)), np.mod(np.arctan2(h[:, 1], h[:, 0]) - self.phi_o, 2 * np.pi)

    def describe(self, i, j):
        th = np.degrees(self.xedges[i:i + 2] ** 2 * (np.pi / 2))
        return f"theta_h in [{th[0]:.2f},{th[1]:.2f}] deg, relative phi_h cell {j}"


@pytest.mark.parametrize("kind,deg", CASES, ids=[f"{k}-{d:g}deg" for k, d in CASES])
def test_sampling_chi2_pdf_and_weights(kind, deg, request):
    m = _model(kind, request)
    phi_o = 0.4
    wo = _sph(np.radians(deg), phi_o)
    rng = np.random.default_rng(_seed(kind, deg))
    u = rng.random((N_SAMPLES, 3))
    wi, w, p, p_re, ev = chunked(_sample_all, m, wo, u)
    assert np.isfinite(wi).all() and np.isfinite(w).all() and np.isfinite(p).all()
    valid = p > 0
    assert np.all(w[~valid] == 0) and np.all(wi[valid, 2] > 0)
    # the returned pdf and weight against pdf() and eval() at the sampled direction
    rel_p = np.abs(p[valid] - p_re[valid]) / p_re[valid]
    assert np.quantile(rel_p, 0.999) < 1e-6, np.quantile(rel_p, [0.999, 1.0])
    w_ref = ev[valid] * wi[valid, 2:3] / p_re[valid, None]
    rel_w = (np.abs(w[valid] - w_ref) / np.maximum(w_ref, 1e-12)).max(-1)
    assert np.quantile(rel_w, 0.999) < 1e-6, np.quantile(rel_w, [0.999, 1.0])
    # the mean weight (the MC albedo) against a quadrature of f cos over the hemisphere
    # (Gauss-Legendre in theta_h^(1/2) x uniform in phi_h, the half-vector grid of HalfGrid)
    xg, wx = np.polynomial.legendre.leggauss(64)
    xg, wx = 0.5 * (xg + 1), 0.5 * wx
    yg = (np.arange(128) + 0.5) * (2 * np.pi / 128)
    X, Y = np.meshgrid(xg, yg, indexing="ij")
    h, jac = HalfGrid(phi_o).to_h(X.ravel(), Y.ravel())
    cos_oh = h @ wo
    wi_q = 2 * cos_oh[:, None] * h - wo
    fq = _eval(m, wo, wi_q) * np.clip(wi_q[:, 2:3], 0, None) * (jac * 4 * np.abs(cos_oh))[:, None]
    albedo_q = (fq * np.repeat(wx, 128)[:, None]).sum(0) * (2 * np.pi / 128)
    se = w.std(0) / np.sqrt(N_SAMPLES)
    assert np.all(np.abs(w.mean(0) - albedo_q) < 5 * se + 5e-3 * albedo_q), (w.mean(0), albedo_q, se)
    # energy: these tables are of passive, non-fluorescent materials (a conductor, vinyl films), so
    # the interpolated model reflects at most what arrives (the quadrature's error is below 5e-3)
    assert np.all(albedo_q <= 1.0 + 5e-3) and np.all(w.mean(0) <= 1.0 + 5 * se), (albedo_q, w.mean(0))
    # chi-square over half-vector cells; the pdf integrated over each cell (adaptive quadrature)
    g = HalfGrid(phi_o)

    def density(x, y):
        h, jac = g.to_h(x, y)
        cos_oh = h @ wo
        wi_h = 2 * cos_oh[:, None] * h - wo
        ok = (wi_h[:, 2] > 0) & (cos_oh > 0)
        v = np.zeros(len(x))
        v[ok] = _pdf(m, wo, wi_h[ok]) * (jac * 4 * cos_oh)[ok]
        return v

    P, unresolved = c2.cell_probabilities(density, g.xedges, g.yedges, n_samples=N_SAMPLES, max_depth=3)
    integral = float(P.sum())
    # int pdf d omega = the fraction of valid samples (the others leave below the horizon)
    assert integral <= 1.0 + 2e-3 and abs(integral - valid.mean()) < 5e-3 + unresolved, (integral, valid.mean())
    x, y = g.from_h(c2.half_vector_reflect(wo, wi[valid]))
    H, _, _ = np.histogram2d(x, y, [g.xedges, g.yedges])
    res = c2.chi2_test(np.concatenate([H.ravel(), [np.sum(~valid)]]),
                       N_SAMPLES * np.concatenate([P.ravel(), [max(0.0, 1 - integral)]]),
                       lambda k: g.describe(*divmod(k, g.n)) if k < P.size else "invalid samples")
    assert res.pvalue > P_MIN, res.summary()


# ------------------------------------------------------------------------------------------------
# Previews
# ------------------------------------------------------------------------------------------------
def test_rgl_render_close_to_a_fitted_lambert():
    brdf, m = rgl("paper_white")
    t = brdf.to_table()
    v = t.valid
    # least-squares Lambert fit of the table with Lambert's bound albedo <= 1 (closed form for one
    # parameter per channel: albedo / pi = mean of f, clipped; the blue channel of the paper, with its
    # optical brighteners, reaches the bound)
    fitted = Lambert(jnp.asarray(np.minimum(np.pi * t.values[v].mean(0), 1.0)))
    # under the furnace (BSDF sampling only; the MERL test below renders the sky with MIS)
    a = render_sphere(m, "furnace", size=20, spp=8)
    b = render_sphere(fitted, "furnace", size=20, spp=8)
    assert np.isfinite(a).all() and (a >= 0).all()
    rel = np.abs(a.mean((0, 1)) - b.mean((0, 1))) / b.mean((0, 1))
    assert rel.max() < 0.1, rel


def test_merl_render_close_to_its_conductor(merl_gold):
    truth, _, m = merl_gold
    a = render_sphere(m, "sky", size=20, spp=8)
    b = render_sphere(truth, "sky", size=20, spp=8)
    assert np.isfinite(a).all() and (a >= 0).all()
    rel = np.abs(a.mean((0, 1)) - b.mean((0, 1))) / b.mean((0, 1))
    assert rel.max() < 0.03, rel


# ------------------------------------------------------------------------------------------------
# Constants, compilation, bad input
# ------------------------------------------------------------------------------------------------
def test_tables_are_constants_and_jit_compiles_once():
    brdf, m = rgl("vch_golden_yellow")
    _, m2 = rgl("cc_ibiza_sunset")  # another file with tables of the same shapes
    traces = []

    @eqx.filter_jit
    def f(model, wo, wi):
        traces.append(1)
        return jnp.sum(model.eval(wo, wi))

    rng = np.random.default_rng(4)
    for model in (m, m, m2):
        f(model, jnp.asarray(_upper(rng, 64)), jnp.asarray(_upper(rng, 64)))
    assert len(traces) == 1
    g = eqx.filter_grad(f)(m, jnp.asarray(_upper(rng, 64)), jnp.asarray(_upper(rng, 64)))
    leaves = [x for x in jax.tree_util.tree_leaves(g) if eqx.is_inexact_array(x)]
    assert leaves and all(float(jnp.abs(x).max()) == 0 for x in leaves)
    # vmap over a batch of viewers (inside jit, as a renderer would call it)
    wo, wi = _upper(rng, 8), _upper(rng, 5)
    out = eqx.filter_jit(lambda model, o, i: jax.vmap(lambda o1: model.eval(o1, i))(o))(m, jnp.asarray(wo),
                                                                                         jnp.asarray(wi))
    assert out.shape == (8, 5, 3)
    np.testing.assert_allclose(np.asarray(out[3]), brdf.eval(np.broadcast_to(wo[3], (5, 3)), wi), rtol=1e-9)


@pytest.mark.check
def test_bad_input_raises_clear_errors(tmp_path):
    with pytest.raises(DataFormatError, match="no such file"):
        MeasuredRGL.from_file(tmp_path / "missing.bsdf")
    with pytest.raises(DataFormatError, match="no such file"):
        MeasuredMERL.from_file(tmp_path / "missing.binary")
    merl_file = tmp_path / "a.binary"
    merl_file.write_bytes(np.array([90, 90, 180], "<i4").tobytes() + b"\0" * 64)
    with pytest.raises(DataFormatError, match="a.binary.*truncated"):
        MeasuredMERL.from_file(merl_file)
    with pytest.raises(DataFormatError, match="a.binary.*magic"):
        MeasuredRGL.from_file(merl_file)  # a MERL file is no tensor file
    with pytest.raises(ParameterError, match="MeasuredRGL: brdf must be a matfit.io.RglBRDF"):
        MeasuredRGL("paper.bsdf")
    with pytest.raises(ParameterError, match="MeasuredMERL: table must be a matfit.io.MerlBRDF"):
        MeasuredMERL(np.zeros((3, 90, 90, 180)))
    grey = MerlBRDF.from_values(np.full((3, 90, 90, 180), 0.1))
    with pytest.raises(ParameterError, match="n_theta_o must be an integer >= 2"):
        MeasuredMERL(grey, n_theta_o=1)
    with pytest.raises(ParameterError, match=r"diffuse_fraction must be a number in \(0, 1\)"):
        MeasuredMERL(grey, diffuse_fraction=0.0)
    with pytest.raises(ParameterError, match="dtype must be float32 or float64"):
        MeasuredMERL(grey, dtype=np.int32)
    m = MeasuredMERL(grey, n_theta_o=2, n_theta_h=8, n_phi_h=8, dtype=np.float32)
    with pytest.raises(ParameterError, match="MeasuredMERL.eval: wo must have shape"):
        m.eval(jnp.zeros(2), jnp.zeros(3))
    up = jnp.array([0.0, 0.0, 1.0], jnp.float32)
    f = eqx.filter_jit(lambda model, a: model.eval(a, a))(m, up)
    assert f.dtype == jnp.float32 and abs(float(f[0]) - 0.1) < 1e-6


def test_report_of_a_measured_file_renders_the_measurement_beside_the_fit(tmp_path):
    """write_report reads the measured file the table came from as a model and renders it as the
    preview's reference, noise-free under each judging lighting: measured | fitted | FLIP, with the
    image means of matfit.appearance."""
    import json

    from matfit.fitting import fit
    from matfit.io import load
    from matfit.report import write_report

    path = rgl_path("paper_white")
    table = load(path)
    r = fit(table, model="lambert", starts=1)
    s = write_report(r, table, tmp_path / "a")
    assert s["preview"]["panels"] == ["measured", "fitted", "FLIP"]
    # the means are matfit.appearance's (tests/test_appearance.py checks them), here in range
    for k in ("sky", "studio"):
        m = s["preview"][k]["means"]
        assert 0 < m["flip"] < 1 and m["ciede2000"] > 0 and m["itp"] > 0
    # a Lambertian paper does not look like the paper: the poor-fit warning says so and where
    assert not s["preview"]["looks_alike"] and any(w.startswith("poor fit in appearance") for w in s["warnings"])
    assert json.loads((tmp_path / "a" / "report.json").read_text())["preview"]["panels"][0] == "measured"
    # without the measured model (or when the table names no readable file) the fitted sphere alone
    assert write_report(r, table, tmp_path / "b", measured=None)["preview"]["panels"] == ["fitted"]
