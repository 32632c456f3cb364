"""Residuals of every loss against a numpy reference written from the formulas of
matfit/fitting/losses.py, and the prepared form the solvers use (data transformed once)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from matfit.fitting.losses import LOSSES, prepare_targets, residuals, residuals_from_targets


def _reference(pred, y, w, c, loss):
    sw = np.sqrt(w)
    c = c[:, None]
    r = {"l2": pred - y,
         "e2": np.log1p(np.maximum(pred * c, -0.999)) - np.log1p(np.maximum(y * c, -0.999)),
         "cbrt": np.cbrt(np.maximum(pred * c, 0) + 1e-6) - np.cbrt(np.maximum(y * c, 0) + 1e-6),
         "cosine": (pred - y) * c,
         "relative": (pred - y) / (np.abs(y) + 1e-3)}[loss]
    return np.where(w > 0, sw * np.where(w > 0, r, 0), 0)


@pytest.fixture
def data():
    rng = np.random.default_rng(0)
    n = 40
    pred, y = rng.uniform(0, 3, (n, 3)), rng.uniform(0, 3, (n, 3))
    w = rng.uniform(0.5, 4, (n, 3))
    w[:5] = 0
    y[:3] = np.nan  # masked rows may hold NaN
    c = rng.uniform(-1, 1, n)  # transmission rows have cos_i < 0
    return pred, y, w, c


@pytest.mark.check
@pytest.mark.parametrize("loss", LOSSES)
def test_residuals_match_reference(data, loss, x64):
    pred, y, w, c = data
    ref = _reference(pred, y, w, c, loss)
    got = np.asarray(residuals(jnp.asarray(pred), jnp.asarray(y), jnp.asarray(w), jnp.asarray(c), loss))
    np.testing.assert_allclose(got, ref, rtol=1e-11, atol=1e-14)
    t, f = prepare_targets(jnp.asarray(y), jnp.asarray(w), jnp.asarray(c), loss)
    assert np.all(np.isfinite(np.asarray(t))) and np.all(np.asarray(f)[:5] == 0)
    got2 = np.asarray(residuals_from_targets(jnp.asarray(pred), t, f, jnp.asarray(c), loss))
    np.testing.assert_allclose(got2, ref, rtol=1e-11, atol=1e-14)


@pytest.mark.parametrize("loss", LOSSES)
def test_prepared_residual_gradients_finite_on_masked_nan_rows(data, loss, x64):
    pred, y, w, c = data
    t, f = prepare_targets(jnp.asarray(y), jnp.asarray(w), jnp.asarray(c), loss)
    g = jax.grad(lambda p: jnp.sum(residuals_from_targets(p, t, f, jnp.asarray(c), loss) ** 2))(jnp.asarray(pred))
    assert np.all(np.isfinite(np.asarray(g))) and np.all(np.asarray(g)[:5] == 0)
    # against central differences on one entry of a valid row
    h = 1e-4
    e = np.zeros_like(pred)
    e[10, 1] = h
    F = lambda p: float(jnp.sum(residuals_from_targets(jnp.asarray(p), t, f, jnp.asarray(c), loss) ** 2))  # noqa: E731
    np.testing.assert_allclose(float(g[10, 1]), (F(pred + e) - F(pred - e)) / (2 * h), rtol=1e-6)
