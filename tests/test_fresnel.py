"""matfit.fresnel against colour-science, the numpy reference and known values."""

import jax.numpy as jnp
import numpy as np
import pytest
from colour.phenomena import polarised_light_reflection_coefficient

import numpy_ref as R


def tol(dtype):
    return 1e-10 if dtype == np.float64 else 1e-4


def colour_dielectric(cos_i, n1, n2):
    """Unpolarised reflectance from colour-science (average of R_s and R_p); 1 under TIR."""
    cos_i = np.asarray(cos_i, float)
    n1, n2 = np.broadcast_arrays(np.asarray(n1, float), np.asarray(n2, float))
    sin_i = np.sqrt(np.maximum(0.0, 1.0 - cos_i**2))
    sin_t = n1 * sin_i / n2
    tir = sin_t >= 1
    theta_i = np.degrees(np.arccos(cos_i))
    theta_t = np.degrees(np.arcsin(np.where(tir, 0.0, sin_t)))
    rs_rp = np.real(polarised_light_reflection_coefficient(n1, n2, theta_i, theta_t))
    return np.where(tir, 1.0, rs_rp.mean(axis=-1))


COS = np.concatenate([np.linspace(0.0, 1.0, 41)[1:], [1e-3, 0.02, 0.999999]])
ETAS = [1.01, 1.33, 1.5, 2.4, 3.0, 0.67]


def test_reference_dielectric_matches_colour():
    for eta in ETAS:
        np.testing.assert_allclose(R.fresnel_dielectric(COS, eta), colour_dielectric(COS, 1.0, eta), rtol=1e-12)
        np.testing.assert_allclose(R.fresnel_dielectric(-COS, eta), colour_dielectric(COS, eta, 1.0), rtol=1e-12)


def test_reference_conductor_complex_vs_real():
    c = np.linspace(0, 1, 101)
    for eta, k in [(0.2, 3.0), (1.5, 0.5), (2.0, 0.0), (0.05, 4.0), (1.2, 7.0)]:
        np.testing.assert_allclose(R.fresnel_conductor(c, eta, k), R.fresnel_conductor_real(c, eta, k), rtol=1e-12)


@pytest.mark.parametrize("eta", ETAS)
def test_dielectric_outside_vs_colour(eta, dtype):
    from matfit.fresnel import fresnel_dielectric

    c = np.asarray(COS, dtype)
    e = dtype(eta)
    out = fresnel_dielectric(jnp.asarray(c), jnp.asarray(e))
    assert out.dtype == dtype
    ref = colour_dielectric(c.astype(float), 1.0, float(e))
    np.testing.assert_allclose(np.asarray(out, float), ref, rtol=tol(dtype), atol=0)


@pytest.mark.check
@pytest.mark.parametrize("eta", ETAS)
def test_dielectric_inside_vs_colour(eta, dtype):
    """cos < 0: light arrives from inside (medium eta) towards outside (index 1)."""
    from matfit.fresnel import fresnel_dielectric

    c = np.asarray(COS, dtype)
    e = dtype(eta)
    ref = colour_dielectric(c.astype(float), float(e), 1.0)
    # float32: exclude a narrow band around the critical angle, where dF/dcos is infinite and one
    # ulp of cos moves F by ~sqrt(ulp).
    s2t = float(e) ** 2 * (1 - c.astype(float) ** 2)
    keep = (np.abs(s2t - 1) > 1e-3) if dtype == np.float32 else np.ones(c.shape, bool)
    out = fresnel_dielectric(jnp.asarray(-c), jnp.asarray(e))
    assert out.dtype == dtype
    np.testing.assert_allclose(np.asarray(out, float)[keep], ref[keep], rtol=tol(dtype), atol=0)


def test_dielectric_tir_is_exactly_one(dtype):
    from matfit.fresnel import fresnel_dielectric

    eta = 1.5
    cos_c = np.sqrt(1 - 1 / eta**2)  # critical cosine inside
    c = np.linspace(0.0, cos_c * 0.999, 30).astype(dtype)
    out = np.asarray(fresnel_dielectric(jnp.asarray(-c), jnp.asarray(dtype(eta))))
    np.testing.assert_array_equal(out, 1.0)
    # the same from outside with eta < 1
    out = np.asarray(fresnel_dielectric(jnp.asarray(c), jnp.asarray(dtype(1 / eta))))
    np.testing.assert_array_equal(out, 1.0)


def test_dielectric_broadcasting(x64):
    from matfit.fresnel import fresnel_dielectric

    c = np.linspace(-1, 1, 7)[:, None]
    eta = np.array([1.2, 1.5, 2.0])
    out = fresnel_dielectric(jnp.asarray(c), jnp.asarray(eta))
    assert out.shape == (7, 3)
    np.testing.assert_allclose(np.asarray(out), R.fresnel_dielectric(c, eta), rtol=1e-10)


CONDUCTORS = [
    ([0.143, 0.374, 1.442], [3.983, 2.385, 1.603]),  # gold
    ([0.200, 0.924, 1.102], [3.912, 2.452, 2.142]),  # copper
    ([2.757, 2.513, 2.231], [3.867, 3.404, 3.009]),  # iron-like
    ([0.05], [7.0]),
    ([1.5], [0.3]),
]


@pytest.mark.parametrize("eta,k", CONDUCTORS)
def test_conductor_vs_reference(eta, k, dtype):
    from matfit.fresnel import fresnel_conductor

    c = np.concatenate([COS, -COS]).astype(dtype)[:, None]  # |cos| is used
    eta = np.asarray(eta, dtype)
    k = np.asarray(k, dtype)
    out = fresnel_conductor(jnp.asarray(c), jnp.asarray(eta), jnp.asarray(k))
    assert out.shape == (len(c), len(eta)) and out.dtype == dtype
    ref = R.fresnel_conductor(c.astype(float), eta.astype(float), k.astype(float))
    np.testing.assert_allclose(np.asarray(out, float), ref, rtol=tol(dtype), atol=0)


def test_conductor_k0_is_dielectric(x64):
    from matfit.fresnel import fresnel_conductor

    for eta in [1.33, 1.5, 2.4]:
        out = fresnel_conductor(jnp.asarray(COS), jnp.asarray(eta), jnp.asarray(0.0))
        np.testing.assert_allclose(np.asarray(out), colour_dielectric(COS, 1.0, eta), rtol=1e-10)


@pytest.mark.parametrize("f0", [0.0, 0.04, 0.5, [0.9, 0.6, 0.3]])
def test_schlick(f0, dtype):
    from matfit.fresnel import fresnel_schlick

    c = COS.astype(dtype)[:, None]
    f0 = np.asarray(f0, dtype)
    out = fresnel_schlick(jnp.asarray(c), jnp.asarray(f0))
    assert out.dtype == dtype
    ref = R.fresnel_schlick(c.astype(float), f0.astype(float))
    np.testing.assert_allclose(np.asarray(out, float), ref, rtol=tol(dtype), atol=1e-300)
    np.testing.assert_allclose(np.asarray(fresnel_schlick(jnp.asarray(dtype(1.0)), jnp.asarray(f0))), f0, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(fresnel_schlick(jnp.asarray(dtype(0.0)), jnp.asarray(f0))), 1.0, rtol=1e-6)


# ---------------------------------------------------------------------------------------------
# Hemispherical averages: 2 int_0^1 F(mu) mu dmu
# ---------------------------------------------------------------------------------------------
def test_reference_average_known_values():
    ext = R.fresnel_dielectric_average(1.5)
    internal = R.fresnel_dielectric_average(1 / 1.5)
    assert abs(ext - 0.0918) < 5e-5
    assert abs(internal - 0.596) < 5e-4
    # Reciprocity / energy: 1 - F_int = (1 - F_ext) / eta^2
    assert abs((1 - internal) - (1 - ext) / 1.5**2) < 1e-10


def test_average_known_values(x64):
    from matfit.fresnel import fresnel_dielectric_average

    assert abs(float(fresnel_dielectric_average(1.5)) - 0.0918) < 5e-5
    assert abs(float(fresnel_dielectric_average(1 / 1.5)) - 0.596) < 5e-4


@pytest.mark.check
@pytest.mark.parametrize("eta", [1.01, 1.33, 1.5, 2.4, 3.0, 0.67, 1 / 1.5, 1 / 3.0])
def test_average_vs_quadrature(eta, x64):
    from matfit.fresnel import fresnel_dielectric_average

    jax_val = float(fresnel_dielectric_average(jnp.asarray(eta, jnp.float64)))
    assert abs(jax_val - R.fresnel_dielectric_average(eta)) < 1e-9


def test_average_broadcasts_and_float32(x64):
    from matfit.fresnel import fresnel_dielectric_average

    eta = np.array([1.5, 1 / 1.5, 2.0], np.float32)
    out = fresnel_dielectric_average(jnp.asarray(eta))
    assert out.shape == (3,) and out.dtype == np.float32
    ref = np.array([R.fresnel_dielectric_average(float(e)) for e in eta])
    np.testing.assert_allclose(np.asarray(out, float), ref, rtol=1e-5)
