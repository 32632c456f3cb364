"""StochasticLayered (the random-walk reference) against closed forms and the analytic layerings.

The closed forms use the independent numpy reference (numpy_ref: Fresnel and its average).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import catalogue as C
import numpy_ref as R
from matfit.models import Lambert, Layered, Plastic, RoughConductor, RoughDielectric, SmoothDielectric, StochasticLayered

WO = C.from_degrees([0.0, 40.0, 75.0])
MU = WO[:, 2]


@pytest.fixture(autouse=True)
def _x64():
    jax.config.update("jax_enable_x64", True)


def _dirs(n=len(WO)):
    """The first n of the directions WO, as a jax array."""
    return jnp.asarray(WO[:n])


def test_albedo_matches_closed_form_smooth_coat():
    rho, eta = 0.5, 1.5
    ref = StochasticLayered(SmoothDielectric(eta), Lambert(rho), n_samples=8192, max_depth=32)
    e = np.asarray(ref.albedo(_dirs(), key=jax.random.PRNGKey(3)))[:, 0]
    F = R.fresnel_dielectric(MU, eta)
    fi = R.fresnel_dielectric_average(1 / eta)
    closed = F + (1 - F) * rho * (1 - fi) / (1 - rho * fi)
    # Each walk's exiting energy is in [0, 1]: standard error <= 0.5 / sqrt(n).
    assert np.all(np.abs(e - closed) < 4 * 0.5 / np.sqrt(8192)), (e, closed)


def test_white_base_lossless_coat_keeps_energy():
    ref = StochasticLayered(SmoothDielectric(1.5), Lambert(1.0), n_samples=2048, max_depth=64)
    e = np.asarray(ref.albedo(_dirs()))[:, 0]
    # Truncation after 64 bounces leaves R_int^64 ~ 1e-14 inside: every path leaves.
    np.testing.assert_allclose(e, 1.0, atol=1e-9)


def test_eval_matches_exact_analytic_smooth_coat():
    """For a smooth coat over a Lambertian base, Plastic (internal reflection) is exact."""
    wo = _dirs()
    wi = jnp.asarray(np.array([[0.3, 0.2, np.sqrt(1 - 0.13)]] * 3))
    ref = StochasticLayered(SmoothDielectric(1.5), Lambert(0.7), n_samples=8192, max_depth=32)
    f, se = ref.eval_with_error(wo, wi, jax.random.PRNGKey(1))
    exact = np.asarray(Plastic(0.7, 0.0, 1.5).eval(wo, wi))
    assert np.all(np.abs(np.asarray(f) - exact) < 4 * np.asarray(se) + 1e-6), (f, se, exact)


def test_rough_coat_tends_to_smooth_and_error_falls_with_samples():
    """Each estimate lies within its error of the smooth coat's exact value, and that error is
    honest: the spread of 16 independent estimates (other keys) matches the reported standard
    error, and falls as 1/sqrt(n) between 1024 and 8192 walks."""
    wo = _dirs(2)
    wi = jnp.asarray(np.array([[0.3, 0.2, np.sqrt(1 - 0.13)]] * 2))
    exact = np.asarray(Plastic(0.5, 0.0, 1.5).eval(wo, wi))
    spread = []
    for n in (1024, 8192):
        ref = StochasticLayered(RoughDielectric(0.01, 1.5), Lambert(0.5), n_samples=n, max_depth=24)
        keys = jax.random.split(jax.random.PRNGKey(n), 16)
        f, se = (np.asarray(x) for x in jax.jit(jax.vmap(lambda k: ref.eval_with_error(wo, wi, k)))(keys))
        assert np.all(np.abs(f - exact) < 4 * se + 0.02 * exact)
        # 15 degrees of freedom: the sample sd over the true sd lies in [0.48, 1.63] at 99.9 %
        ratio = f.std(axis=0, ddof=1) / se.mean(axis=0)
        assert np.all((0.45 < ratio) & (ratio < 1.7)), (n, ratio)
        spread.append(f.std(axis=0, ddof=1))
    # 8x the walks: sqrt(8) = 2.8x less spread (the ratio of two 15-dof sample sds: 1.6-5.0 at 99 %)
    fall = spread[0] / spread[1]
    assert np.all((1.6 < fall) & (fall < 5.0)), fall


def test_limits_thick_coat_and_index_matched_coat():
    wo = _dirs()
    thick = StochasticLayered(SmoothDielectric(1.5), Lambert(0.9), thickness=50.0, sigma_a=1.0, n_samples=4096)
    F = R.fresnel_dielectric(MU, 1.5)
    # The coat's mirror reflection is chosen with probability F (weight 1): a binomial estimate.
    e = np.asarray(thick.albedo(wo, key=jax.random.PRNGKey(5)))[:, 0]
    assert np.all(np.abs(e - F) <= 4 * np.sqrt(F * (1 - F) / 4096) + 1e-12), (e, F)
    base = RoughConductor(0.3, 0.8, 2.0)
    matched = StochasticLayered(SmoothDielectric(1.0), base, n_samples=4096, max_depth=4)
    e_ref = np.asarray(base.albedo(wo, method="mc", n=2**16))
    e = np.asarray(matched.albedo(wo, key=jax.random.PRNGKey(7)))
    assert np.all(np.abs(e - e_ref) < 0.02), (e, e_ref)


def test_analytic_layered_error_is_measurable():
    """Layered (Weidlich-Wilkie, no interreflection) under-estimates a smooth-coated white base."""
    wo = _dirs(1)
    ref = StochasticLayered(SmoothDielectric(1.5), Lambert(0.8), n_samples=4096, max_depth=32)
    e_ref = float(ref.albedo(wo)[0, 0])
    e_ww = float(Layered(SmoothDielectric(1.5), Lambert(0.8)).albedo(wo)[0, 0])
    assert e_ww < e_ref - 0.1, (e_ww, e_ref)


@pytest.mark.check
def test_no_pdf_or_sample():
    ref = StochasticLayered(SmoothDielectric(1.5), Lambert(0.5))
    with pytest.raises(NotImplementedError, match="closed-form pdf"):
        ref.pdf(jnp.array([0.0, 0.0, 1.0]), jnp.array([0.0, 0.0, 1.0]))
