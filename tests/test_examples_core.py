"""Checks moved from docstring examples of matfit's core modules (``_math``, ``fresnel``, ``fast``,
``parallel``, ``cache``, ``_check``, ``_dataerr``, ``table``): each a small, fast assertion of a
value or behaviour that an example used to show."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from matfit._check import check_range, real_dtype
from matfit._dataerr import data_error, with_file
from matfit._math import (IsoDir, Vec3, as_direction, as_float, cosine_hemisphere, dot, flip_up, mirror, normalize,
                          per_pair, reflect, refract, refract_into, refracted_cos2, safe_div, safe_sqrt, sq,
                          uniform_to_disk, up_like)
from matfit.cache import cache_dir, enable_compilation_cache, loop_jit
from matfit.errors import DataFormatError, ParameterError
from matfit.fast import channel_model, eval_channel, soa_pairs, supports_soa
from matfit.fresnel import FresnelAngle, clamp_cos
from matfit.models import Lambert
from matfit.parallel import batch_mesh, batch_sharding, device_count, shard_batch
from matfit.table import Table


# ---------------------------------------------------------------------------- matfit._math
@pytest.mark.check
def test_math_scalar_helpers():
    assert sq(-3.0) == 9.0
    assert float(dot(jnp.array([1.0, 2.0, 3.0]), jnp.array([4.0, 5.0, 6.0]))) == 32.0
    assert [float(v) for v in safe_sqrt(jnp.array([4.0, -1.0]))] == [2.0, 0.0]
    assert float(jax.grad(safe_sqrt)(0.0)) == 0.0
    assert float(per_pair(jnp.float32(0.25))) == 0.25
    assert float(jax.grad(lambda t: per_pair(3 * t))(1.0)) == 3.0
    assert [float(v) for v in safe_div(jnp.array([1.0, 1.0]), jnp.array([4.0, 0.0]), fill=-1.0)] == [0.25, -1.0]
    assert jnp.issubdtype(as_float(2).dtype, jnp.floating) and as_float(jnp.float32(0.5)).dtype == jnp.float32


def test_vec3_methods():
    assert float(Vec3.from_array(jnp.array([0.0, 0.6, 0.8])).y) == pytest.approx(0.6)
    assert Vec3(0.0, 0.0, 1.0).to_array().tolist() == [0.0, 0.0, 1.0]
    assert float(Vec3(0.6, 0.0, 0.8).tan_sq(2.0, 1.0)) == pytest.approx(1.44)
    assert bool(Vec3(0.6, 0.0, 0.8).visible(Vec3(0.0, 0.0, 1.0)))
    assert float(Vec3(0.0, 0.6, 0.8).along_azimuth(2.0, 5.0)) == 5.0  # along y: a_y
    assert Vec3(0.6, 0.0, 0.8).where_up(jnp.array(False)).to_array().tolist() == [0.0, 0.0, 1.0]
    assert Vec3(1.0, 2.0, 3.0).tree_flatten() == ((1.0, 2.0, 3.0), None)
    assert float(Vec3.tree_unflatten(None, (1.0, 2.0, 3.0)).z) == 3.0


def test_isodir_methods():
    d = IsoDir(0.8, 0.36)
    assert float(IsoDir.from_cos(0.8).t2) == pytest.approx(0.36)
    assert float(d.tan_sq(2.0)) == pytest.approx(1.44)
    assert bool(d.visible(IsoDir(1.0, 0.0)))
    assert d.along_azimuth(2.0, 2.0) == 2.0
    up = d.where_up(jnp.array(False))
    assert (float(up.z), float(up.t2)) == (1.0, 0.0)
    assert d.tree_flatten() == ((0.8, 0.36), None)
    assert float(IsoDir.tree_unflatten(None, (0.8, 0.36)).z) == 0.8
    assert as_direction(d) is d
    assert type(as_direction(jnp.array([0.0, 0.6, 0.8]))) is Vec3


def test_direction_helpers():
    u = normalize(jnp.array([[3.0, 0.0, 4.0], [0.0, 0.0, 0.0]]))  # a zero vector maps to +z
    np.testing.assert_allclose(np.asarray(u), [[0.6, 0.0, 0.8], [0.0, 0.0, 1.0]], atol=1e-7)
    assert up_like(jnp.ones((2, 3))).tolist() == [[0.0, 0.0, 1.0]] * 2
    assert mirror(jnp.array([0.5, 0.25, 0.5])).tolist() == [-0.5, -0.25, 0.5]
    np.testing.assert_allclose(np.asarray(reflect(jnp.array([0.6, 0.0, 0.8]), jnp.array([0.0, 0.0, 1.0]))),
                               [-0.6, 0.0, 0.8], atol=1e-7)
    assert flip_up(jnp.array([0.5, 0.25, -0.5])).tolist() == [-0.5, -0.25, 0.5]


def test_refraction_obeys_snell():
    wt, ok = refract(jnp.array([0.6, 0.0, 0.8]), jnp.array([0.0, 0.0, 1.0]), jnp.array(1.5))
    assert float(wt[0]) == pytest.approx(-0.4) and bool(ok)  # sin theta_t = 0.6 / 1.5
    assert float(refracted_cos2(0.8, 1.5, 1 / 1.5)) == pytest.approx(0.84)  # 1 - 0.36 / 2.25
    wt, ok = refract_into(jnp.array([0.6, 0.0, 0.8]), 1.5)
    np.testing.assert_allclose(np.asarray(wt), [0.4, 0.0, 0.916515], atol=1e-6)
    assert bool(ok)


def test_sampling_maps():
    np.testing.assert_allclose([float(c) for c in uniform_to_disk(1.0, 0.5)], [1.0, 0.0], atol=1e-7)
    assert (cosine_hemisphere(0.5, 0.5) + 0.0).tolist() == [0.0, 0.0, 1.0]  # the disk's centre: the normal


# ---------------------------------------------------------------------------- matfit.fresnel
def test_clamp_cos_and_fresnel_angle():
    assert clamp_cos(jnp.array([-0.5, 1.5])).tolist() == [0.5, 1.0]
    assert float(FresnelAngle.of(-0.5).cos2) == 0.25
    assert float(FresnelAngle.of_clamped(0.5).sin2) == 0.75
    assert FresnelAngle.of(jnp.array([0.5, 0.8])).expand().c.shape == (2, 1)


# ---------------------------------------------------------------------------- matfit.fast, matfit.parallel
def test_fast_channel_helpers():
    up = np.array([[0.0, 0.0, 1.0]])
    assert soa_pairs(up, np.array([[0.6, 0.0, 0.8]])).n == 1
    m = Lambert(np.array([0.8, 0.5, 0.2]))
    assert supports_soa(m)
    assert channel_model(m, 1).reflectance.tolist() == [0.5]
    assert float(eval_channel(m, soa_pairs(up, up), 1)[0]) * np.pi == pytest.approx(0.5)


def test_parallel_mesh_and_sharding():
    one = jax.devices()[:1]
    assert device_count() == len(jax.devices()) and device_count(one) == 1
    mesh = batch_mesh(one)
    assert mesh.axis_names == ("batch",) and mesh.devices.shape == (1,)
    x = jax.device_put(jnp.zeros((4, 3)), batch_sharding(one))
    assert tuple(x.sharding.spec) == ("batch",) and x.addressable_shards[0].data.shape == (4, 3)
    (x, valid), n = shard_batch((np.arange(3.0), np.ones(3, bool)), fill=(0.0, False))
    assert n == 3 and x.shape[0] % device_count() == 0 and x[:n].tolist() == [0.0, 1.0, 2.0]
    assert bool(valid[:n].all() and not valid[n:].any())


# ---------------------------------------------------------------------------- matfit.cache
def test_cache_dir_and_switch(monkeypatch):
    monkeypatch.delenv("MATFIT_NO_CACHE", raising=False)
    monkeypatch.setenv("MATFIT_CACHE_DIR", "/tmp/matfit-doc-cache")
    assert str(cache_dir()) == "/tmp/matfit-doc-cache"
    monkeypatch.setenv("MATFIT_NO_CACHE", "1")
    assert cache_dir() is None and enable_compilation_cache() is None  # turned off: JAX untouched
    f = loop_jit(lambda x: jax.lax.fori_loop(0, 3, lambda i, a: a + x, jnp.zeros_like(x)))
    assert f(jnp.arange(3.0)).tolist() == [0.0, 3.0, 6.0]


# ---------------------------------------------------------------------------- matfit._check, matfit._dataerr
def test_check_helpers():
    real_dtype("f: x", [1, 2.5])
    with pytest.raises(ParameterError, match=r"f: x must be real numbers \(integer or floating dtype\), found dtype bool"):
        real_dtype("f: x", [True])
    check_range("Plastic", "eta", 1.5, lo=1.0, lo_open=True)
    with pytest.raises(ParameterError, match="Plastic: parameter 'eta' must be > 1.0, found"):
        check_range("Plastic", "eta", [1.5, 0.9], lo=1.0, lo_open=True)


def test_data_error_and_with_file():
    e = data_error("dims", "(90, 90, 180)", "(1, 2, 3)", file=b"...")
    assert str(e) == "<bytes>: field 'dims': expected (90, 90, 180), found (1, 2, 3)"
    assert (e.file, e.field) == ("<bytes>", "dims")
    assert str(with_file(data_error("wo", "unit vectors"), "t.csv")) == "t.csv: field 'wo': expected unit vectors"


# ---------------------------------------------------------------------------- matfit.table
def _one(**kw):
    return Table(wo=[[0.0, 0.0, 1.0]], wi=[[0.0, 0.6, 0.8]], **kw)


def test_table_replace_select_and_labels():
    t = _one(values=[0.2], channels="mono")
    assert t.replace(values=[0.4]).values.tolist() == [[0.4]] and t.values.tolist() == [[0.2]]
    t3 = Table(wo=[[0.0, 0.0, 1.0]] * 3, wi=[[0.0, 0.6, 0.8]] * 3, values=[0.1, 0.2, 0.3], channels="mono")
    s = t3.select(t3.values[:, 0] > 0.15)
    assert s.values.ravel().tolist() == [0.2, 0.3] and s.provenance["derivation"] == [{"op": "select", "n": 2}]
    assert _one(values=[[0.1, 0.2, 0.3]]).channel_labels == ["r", "g", "b"]
    assert _one(values=[[0.1, 0.2, 0.3]]).as_jax("float32").values.dtype == jnp.float32


def test_table_summary_lines():
    t = _one(values=[0.2], channels="mono", provenance={"source": "example.csv"})
    assert t.summary().splitlines() == [
        "Table: 1 samples (1 valid), channels mono",
        "  source: example.csv",
        "  value[mono]: min 0.2, median 0.2, max 0.2 1/sr",
        "  theta_i: 36.87..36.87 deg, theta_o: 0.00..0.00 deg",
        "  uncertainty: none",
    ]


def test_table_csv_text_and_bytes(tmp_path):
    _one(values=[0.2], channels="mono").save_csv(tmp_path / "t.csv")
    assert (tmp_path / "t.csv").read_text() == ('# matfit-table v1\n# channels: "mono"\n# provenance: {}\n'
                                                "wo_x,wo_y,wo_z,wi_x,wi_y,wi_z,value_mono,valid\n"
                                                "0.0,0.0,1.0,0.0,0.6,0.8,0.2,1\n")
    t = Table.load_csv(b"wo_x,wo_y,wo_z,wi_x,wi_y,wi_z,value_r,value_g,value_b\n0,0,1,0,0.6,0.8,0.1,0.2,0.3\n")
    assert t.channels == "rgb" and t.values.tolist() == [[0.1, 0.2, 0.3]]


def test_table_load_npz_bytes_error():
    with pytest.raises(DataFormatError) as ei:
        Table.load_npz(b"not a zip archive")
    assert (ei.value.file, ei.value.field, ei.value.expected) == ("<bytes>", "container", "a .npz (zip) archive")
