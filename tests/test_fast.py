"""The fast evaluation path (matfit.fast, matfit.parallel, matfit._math.Vec3) agrees with model.eval."""

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import numpy_ref as R
from matfit._math import IsoDir, Vec3, dot, normalize, reflect
from matfit.errors import MatfitError, ParameterError
from matfit.fast import channel_model, eval_soa, soa_pairs, supports_soa
from matfit.microfacet import make_distribution
from matfit.models import (Blend, CoatedConductor, Lambert, Plastic, RoughConductor, RoughDielectric)
from matfit.parallel import for_small_calls, shard_batch, use_cores, use_host_devices

ETA = [0.143, 0.375, 1.442]
K = [3.983, 2.386, 1.603]


def _models(dt):
    a = lambda x: jnp.asarray(x, dt)  # noqa: E731
    return {
        "lambert": Lambert(a([0.8, 0.5, 0.2])),
        "ggx": RoughConductor(a(0.2), a(ETA), a(K)),
        "beckmann_hc_aniso": RoughConductor(a(0.3), a(ETA), a(K), "beckmann", "height_correlated", alpha_y=a(0.1)),
        "beckmann_hc": RoughConductor(a(0.3), a(ETA), a(K), "beckmann", "height_correlated"),
        "blinn_phong": RoughConductor(a(0.3), a(ETA), a(K), "blinn_phong"),
        "plastic_smooth": Plastic(a([0.7, 0.1, 0.1]), 0.0, a(1.5)),
        "plastic_rough": Plastic(a([0.7, 0.1, 0.1]), a(0.2), a(1.5)),
        "blend": Blend(Lambert(a([0.8, 0.5, 0.2])), RoughConductor(a(0.2), a(ETA), a(K)), a(0.3)),
        "dielectric (fallback)": RoughDielectric(a(0.2), a(1.5)),
        "coated (fallback)": CoatedConductor(a(0.2), a(ETA), a(K), 0.0, a(1.5)),
    }


def _dirs(rng, n):
    wo = R.random_directions(rng, n, "both")
    wi = R.random_directions(rng, n, "both")
    wo[: n // 2, 2] = np.abs(wo[: n // 2, 2])  # half the pairs on the upper side, where f > 0
    wi[: n // 2, 2] = np.abs(wi[: n // 2, 2])
    return wo, wi


# float32 only where the SoA kernels differ from the general path (the fallbacks call model.eval).
CASES = [(n, np.float64) for n in _models(jnp.float32)] + [
    (n, np.float32) for n in ("lambert", "ggx", "beckmann_hc", "beckmann_hc_aniso", "blinn_phong", "plastic_smooth", "plastic_rough",
                            "blend")]


@pytest.mark.parametrize("name,dtype", CASES, ids=[f"{n}-{np.dtype(d).name}" for n, d in CASES])
def test_eval_soa_matches_eval(name, dtype, rng, x64):
    model = _models(dtype)[name]
    wo, wi = _dirs(rng, 301)
    ref = np.asarray(model.eval(jnp.asarray(wo, dtype), jnp.asarray(wi, dtype)))
    out = eval_soa(model, soa_pairs(wo, wi, dtype=dtype), stack=True)
    assert out.dtype == dtype and out.shape == ref.shape
    assert np.all(np.isfinite(np.asarray(out)))
    assert np.count_nonzero(ref) > 100  # the comparison covers non-zero values
    # Same formulas, possibly another order of float operations inside XLA's fused loops.
    rtol = 1e-12 if dtype == np.float64 else 3e-5
    scale = np.max(np.abs(ref))
    np.testing.assert_allclose(np.asarray(out), ref, rtol=rtol, atol=rtol * 1e-3 * scale)
    tup = eval_soa(model, soa_pairs(wo, wi, dtype=dtype))
    assert len(tup) == model.channels and all(t.shape == (301,) for t in tup)


def test_supports_soa_lists_the_structure_of_arrays_models():
    m = _models(jnp.float32)
    assert supports_soa(m["ggx"]) and supports_soa(m["blend"]) and supports_soa(m["plastic_smooth"])
    assert not supports_soa(m["dielectric (fallback)"]) and not supports_soa(m["coated (fallback)"])
    assert supports_soa(m["plastic_rough"])  # a rough coat's lobe and table read the pairs too


@pytest.mark.parametrize("kind", ["ggx", "beckmann", "blinn_phong"])
def test_distributions_accept_vec3(kind, x64, rng):
    # D, Lambda and G2 read vectors only through components: a Vec3 gives the same numbers.
    d = make_distribution(kind, 0.25, 0.4)
    wo, wi = _dirs(rng, 200)
    h = np.asarray(normalize(jnp.asarray(wo + wi)))
    V = Vec3.from_array
    for form in ("separable", "height_correlated"):
        np.testing.assert_array_equal(d.G2(V(wo), V(wi), V(h), form), d.G2(jnp.asarray(wo), jnp.asarray(wi), jnp.asarray(h), form))
    np.testing.assert_array_equal(d.D(V(h)), d.D(jnp.asarray(h)))
    np.testing.assert_array_equal(d.Lambda(V(wo)), d.Lambda(jnp.asarray(wo)))



def _iso(v):
    return IsoDir(jnp.asarray(v[:, 2]), jnp.asarray(v[:, 0] ** 2 + v[:, 1] ** 2))


@pytest.mark.check
@pytest.mark.parametrize("kind", ["ggx", "beckmann", "blinn_phong"])
def test_isotropic_distributions_read_only_cosines(kind, x64, rng):
    # An isotropic lobe of a reflection pair depends on the cosines and h's squared sine only:
    # D, Lambda and G2 on IsoDir equal those on the vectors (another order of operations).
    d = make_distribution(kind, 0.25)
    wo, wi = (R.random_directions(rng, 300, "upper", 1e-4) for _ in range(2))
    h = np.asarray(normalize(jnp.asarray(wo + wi)))
    for form in ("separable", "height_correlated"):
        np.testing.assert_allclose(d.G2(_iso(wo), _iso(wi), _iso(h), form), d.G2(wo, wi, h, form), rtol=1e-12)
    # Blinn-Phong's D is exp(e log cos): far out (D ~ 1e-294) the exponent amplifies rounding.
    np.testing.assert_allclose(d.D(_iso(h)), d.D(jnp.asarray(h)), rtol=1e-9)
    # Lambda enters as 1 + Lambda: tiny values (Beckmann's ~exp(-1/tan^2)) compared absolutely.
    np.testing.assert_allclose(d.Lambda(IsoDir.from_cos(jnp.asarray(wo[:, 2]))), d.Lambda(jnp.asarray(wo)),
                               rtol=1e-12, atol=1e-15)
    assert np.all(np.asarray(d.G2(_iso(wo), _iso(wi), _iso(h))) > 0)
    with pytest.raises(TypeError, match="cosine"):
        _iso(wo)[..., 0]


def test_float32_kernel_keeps_sharp_peaks(rng, x64):
    # The cosine-only kernel takes h's squared sine from its components (SoAPairs.iso): near the
    # peak of a sharp lobe 1 - h_z^2 would keep ~2 digits of it in float32 (D off by percents).
    # Against the float64 reference on the same (float32-rounded) directions: float32 rounding.
    alpha = 2e-3
    wo = R.random_directions(rng, 400, "upper", 0.2)
    m = R.random_normals_near_z(rng, 400, alpha, spread=2.0)
    wi = np.asarray(reflect(jnp.asarray(wo), jnp.asarray(m)))
    keep = wi[:, 2] > 0.05
    wo, wi = (v[keep].astype(np.float32) for v in (wo, wi))
    model = RoughConductor(jnp.float32(alpha), jnp.asarray(ETA, jnp.float32), jnp.asarray(K, jnp.float32))
    out = eval_soa(model, soa_pairs(wo, wi, dtype=np.float32), stack=True)
    ref = R.conductor_eval(wo, wi, R.Dist("ggx", alpha), ETA, K)
    assert np.min(ref) > 1.0  # on the peak
    R.assert_rel(out, ref, 1e-3, 1e-30, "float32 eval_soa near a sharp peak", wo=wo, wi=wi)


def test_vec3_behaves_like_a_direction_array(x64):
    v = jnp.array([[3.0, 0.0, 4.0], [0.0, 0.0, 0.0]])
    V = Vec3.from_array(v)
    assert V.shape == (2, 3)
    np.testing.assert_array_equal(normalize(V).to_array(), normalize(v))  # zero vector -> +z in both
    np.testing.assert_array_equal(dot(V, V), dot(v, v))
    np.testing.assert_array_equal((V - V + V).to_array(), v)
    with pytest.raises(TypeError, match="component access"):
        V[0]


@pytest.mark.check
def test_channel_model_slices_per_channel_parameters_only(x64):
    m = RoughConductor(0.3, jnp.asarray(ETA), jnp.asarray(K))
    m1 = channel_model(m, 2)
    assert m1.channels == 1 and float(m1.eta[0]) == ETA[2] and float(m1.alpha) == 0.3
    with pytest.raises(ParameterError, match="out of range"):
        channel_model(m, 3)


def test_soa_pairs_rejects_bad_shapes():
    with pytest.raises(ParameterError, match=r"shape \(N, 3\)"):
        soa_pairs(np.zeros((4, 2)), np.zeros((4, 3)))
    with pytest.raises(ParameterError, match="soa_pairs"):
        eval_soa(Lambert(0.5), (np.zeros((4, 3)), np.zeros((4, 3))))


def test_shard_batch_pads_with_valid_rows():
    x, n = shard_batch(np.arange(5.0))
    assert n == 5 and x.shape[0] % jax.device_count() == 0
    np.testing.assert_array_equal(np.asarray(x)[:5], np.arange(5.0))
    assert np.all(np.asarray(x)[5:] == 4.0)
    with pytest.raises(MatfitError, match="same first-axis length"):
        shard_batch((np.zeros(3), np.zeros(4)))


def test_use_host_devices_refuses_after_backend_start():
    jax.devices()
    have = len(jax.devices("cpu"))
    assert use_host_devices(have) == have
    with pytest.raises(MatfitError, match="already started"):
        use_host_devices(have + 1)


def test_use_cores_refuses_after_backend_start():
    jax.devices()
    with pytest.raises(MatfitError, match="already started"):
        use_cores(1)
    with pytest.raises(MatfitError, match="n must be >= 1"):
        use_cores(0)


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="CPU affinity is Linux-only")
def test_use_cores_limits_the_process_before_jax_starts():
    code = textwrap.dedent(
        """
        import os, jax, jax.numpy as jnp
        from matfit.parallel import use_cores
        assert use_cores(1) == 1
        assert len(os.sched_getaffinity(0)) == 1
        assert float(jnp.arange(4.0).sum()) == 6.0
        print("ok")
        """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0 and r.stdout.strip().endswith("ok"), r.stderr


def test_for_small_calls_refuses_after_backend_start():
    jax.devices()
    with pytest.raises(MatfitError, match="already started"):
        for_small_calls()
    with pytest.raises(MatfitError, match="already started"):
        for_small_calls(None)


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="CPU affinity is Linux-only")
def test_for_small_calls_runs_synchronously_on_one_core():
    code = textwrap.dedent(
        """
        import os, jax, jax.numpy as jnp
        from matfit.parallel import for_small_calls
        assert for_small_calls() == 1
        assert len(os.sched_getaffinity(0)) == 1
        assert jax.config.values["jax_cpu_enable_async_dispatch"] is False
        assert float(jnp.arange(4.0).sum()) == 6.0
        print("ok")
        """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0 and r.stdout.strip().endswith("ok"), r.stderr


def test_two_host_devices_split_the_batch_and_agree():
    # A fresh process: the device count must be set before JAX starts.
    code = textwrap.dedent(
        """
        import jax, numpy as np, jax.numpy as jnp
        from matfit.parallel import use_host_devices
        use_host_devices(2)
        jax.config.update("jax_enable_x64", True)
        from matfit.models import RoughConductor
        from matfit.fast import soa_pairs, eval_soa
        rng = np.random.default_rng(0)
        wo = rng.normal(size=(101, 3)); wo[:, 2] = abs(wo[:, 2]); wo /= np.linalg.norm(wo, axis=1, keepdims=True)
        wi = rng.normal(size=(101, 3)); wi[:, 2] = abs(wi[:, 2]); wi /= np.linalg.norm(wi, axis=1, keepdims=True)
        m = RoughConductor(0.3, jnp.array([0.2, 0.9, 1.1]), jnp.array([3.9, 2.4, 2.2]))
        p = soa_pairs(wo, wi)
        assert len(p.wo.x.sharding.device_set) == 2 and p.n_padded == 102
        out = np.asarray(eval_soa(m, p, stack=True))
        ref = np.asarray(m.eval(jnp.asarray(wo), jnp.asarray(wi)))
        assert np.allclose(out, ref, rtol=1e-12, atol=0), np.max(abs(out - ref))
        print("OK", len(jax.devices()))
        """
    )
    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ, PYTHONPATH=str(root), JAX_PLATFORMS="cpu")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "OK 2" in r.stdout
