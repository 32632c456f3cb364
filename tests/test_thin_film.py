"""The thin-film Fresnel (Airy summation, integrated to linear sRGB) and its lobe and family.

1. The spectrum against an independent numpy transcription (numpy_ref: the layer's
   characteristic matrix, Born & Wolf 1.6.2, complex arithmetic): 1e-5 relative, the hard
   cases included (grazing, normal, no film, index-matched film, film index 1, base index 1).
2. The RGB sum against numpy_ref's own (colour's tables, the sRGB matrix written out).
3. Limits: no film is the dielectric Fresnel of the base; a quarter-wave film is an
   anti-reflection coat; grazing light reflects totally; R in [0, 1].
4. Gradients in every argument against central finite differences (float64); float32 finite at
   the hard cases, values and gradients, and close to float64.
5. The lobe: white-furnace albedo <= 1 and equal to a numpy quadrature of the reference.
6. The family: the data-driven start reads the film from how the hue turns; a fit recovers a
   synthetic film table.
7. Bad input raises ParameterError naming the problem.

The lobe's eval, pdf, reciprocity and sampling (chi-square) are in tests/test_multi_lobe.py
(its "film" case).
"""

from __future__ import annotations

import os
import sys

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import numpy_ref as R  # noqa: E402
from catalogue import unit  # noqa: E402

from matfit import Table  # noqa: E402
from matfit.errors import ParameterError  # noqa: E402
from matfit.fitting import Lobe, Parametrization, compose_family, fit, initial_guess  # noqa: E402
from matfit.fresnel import fresnel_dielectric, fresnel_thin_film, thin_film_spectrum  # noqa: E402
from matfit.models import MultiLobe, SpecularLobe  # noqa: E402

LAM = np.arange(380.0, 781.0, 5.0)
#: the hard cases: (cos, thickness, film index, base index)
HARD = [(c, d, nf, nb) for c in (0.0, 1e-7, 1e-4, 0.5, 1.0) for d in (0.0, 1e-3, 400.0, 1000.0)
        for nf, nb in ((1.0, 1.5), (1.5, 1.5), (2.6, 1.0), (1.33, 3.0), (1.0, 1.0))]


def _random(rng, n=3000):
    return (rng.random(n), rng.random(n) * 1000, 1 + rng.random(n) * 1.6, 1 + rng.random(n) * 2.0)


def _hard():
    return tuple(np.array(x) for x in zip(*HARD))


@pytest.fixture
def film_args(rng):
    return tuple(np.concatenate([a, b]) for a, b in zip(_random(rng), _hard()))


@pytest.mark.check
def test_spectrum_matches_the_characteristic_matrix(x64, film_args):
    a = np.asarray(thin_film_spectrum(*film_args, LAM))
    b = R.thin_film_spectrum(*film_args, LAM)
    # 1e-5 relative, plus 1e-7 absolute: at grazing light (cos clamped at 1e-7) on an index-matched
    # stack or at a free film's resonances, both forms cancel to R ~ 1e-8 in different ways
    err = np.abs(a - b) - 1e-5 * np.abs(b)
    assert err.max() <= 1e-7, (err.max(), np.unravel_index(err.argmax(), err.shape))
    assert b.min() >= 0 and b.max() <= 1 + 1e-12
    assert np.ptp(b, axis=-1).max() > 0.3  # the spectra do vary (a film, not a flat Fresnel)


def test_rgb_matches_reference(x64, film_args):
    a = np.asarray(fresnel_thin_film(*film_args))
    b = R.thin_film_rgb(*film_args)
    assert a.shape == b.shape == (len(film_args[0]), 3)
    err = np.abs(a - b) - 1e-5 * np.abs(b)
    assert err.max() <= 1e-7, (err.max(), np.unravel_index(err.argmax(), err.shape))


def test_limits(x64, rng):
    c = rng.random(500)
    nb = 1 + 2 * rng.random(500)
    ref = np.asarray(fresnel_dielectric(c, nb))[:, None]
    for d, nf in ((0.0, 1.9), (350.0, 1.0), (350.0, None)):  # no film, film index 1, index-matched film
        got = np.asarray(fresnel_thin_film(c, d, nb if nf is None else nf, nb))
        np.testing.assert_allclose(got, np.broadcast_to(ref, got.shape), rtol=1e-9, atol=1e-12)
    # a quarter-wave layer of index sqrt(1.5) on glass reflects nothing at 550 nm, normal incidence
    n = np.sqrt(1.5)
    assert float(thin_film_spectrum(1.0, 550.0 / (4 * n), n, 1.5, np.array([550.0]))[0]) < 1e-12
    # grazing light reflects totally, whatever the film
    np.testing.assert_allclose(np.asarray(fresnel_thin_film(0.0, rng.random(20) * 1000, 1.5, 1.5)), 1.0, atol=1e-5)
    # the hue turns with the angle: the chromaticity at normal incidence differs from that at 60 degrees
    rgb = np.asarray(fresnel_thin_film(np.array([1.0, 0.5]), 400.0, 1.8, 1.5))
    chroma = rgb / rgb.sum(-1, keepdims=True)
    assert np.abs(chroma[0] - chroma[1]).max() > 0.05


def test_gradients_match_finite_differences(x64, rng):
    args = [np.array(x) for x in zip(*[(0.3 + 0.6 * rng.random(), 50 + 900 * rng.random(), 1.1 + rng.random(),
                                        1.1 + rng.random()) for _ in range(12)])]
    wts = jnp.asarray(rng.random((12, 3)))

    @jax.jit
    def loss(*a):
        return jnp.sum(fresnel_thin_film(*a) * wts)

    g = jax.jit(jax.grad(loss, argnums=(0, 1, 2, 3)))(*(jnp.asarray(x) for x in args))
    for i in range(4):
        for k in range(12):
            h = 1e-6 * max(1.0, abs(args[i][k]))
            up, dn = [x.copy() for x in args], [x.copy() for x in args]
            up[i][k] += h
            dn[i][k] -= h
            fd = (float(loss(*up)) - float(loss(*dn))) / (2 * h)
            assert abs(float(g[i][k]) - fd) <= 1e-5 * max(1.0, abs(fd)), (i, k, float(g[i][k]), fd)


def test_float32_finite_at_the_hard_cases():
    args32 = tuple(jnp.asarray(x, jnp.float32) for x in _hard())
    v = fresnel_thin_film(*args32)
    assert v.dtype == jnp.float32 and np.all(np.isfinite(np.asarray(v)))
    grads = jax.grad(lambda *a: jnp.sum(fresnel_thin_film(*a)), argnums=(0, 1, 2, 3))(*args32)
    for gr in grads:
        assert np.all(np.isfinite(np.asarray(gr)))
    # close to float64 where float32 resolves the angle (cos >= 1e-4: 1 - cos^2 rounds to 1 below
    # ~3e-4); at grazing light the film's resonances move with the rounding (a free-standing film
    # jumps between R = 0 and 1)
    keep = _hard()[0] >= 1e-4
    np.testing.assert_allclose(np.asarray(v)[keep], R.thin_film_rgb(*_hard())[keep], rtol=2e-3, atol=2e-5)


def _film_lobe(alpha=0.2, dt=np.float64):
    return SpecularLobe(jnp.asarray(alpha, dt), "thin_film", jnp.asarray(1.0, dt), thickness=jnp.asarray(420.0, dt),
                        film_eta=jnp.asarray(2.0, dt), eta=jnp.asarray(1.5, dt))


@eqx.filter_jit
def _albedo(model, wo):
    return model.albedo(wo, method="quadrature", n=128)


def test_white_furnace_albedo_matches_quadrature(x64):
    lobe = _film_lobe()
    wi, wts = R.upper_hemisphere_rule(160)
    wi = wi.reshape(-1, 3)
    for mu in (1.0, 0.5, 0.1):
        wo = unit(mu, 0.3)
        e = np.asarray(_albedo(MultiLobe(0.0, [lobe]), jnp.asarray(wo)))
        ok, h, val = R.reflection_lobe(np.broadcast_to(wo, wi.shape), wi, R.Dist("ggx", 0.2, None), "separable")
        F = R.thin_film_rgb(np.clip(np.sum(wo * h, -1), 0, 1), 420.0, 2.0, 1.5)
        ref = np.sum(np.where(ok[:, None], val[:, None] * F, 0) * (wi[:, 2] * wts.ravel())[:, None], axis=0)
        np.testing.assert_allclose(e, ref, rtol=2e-3)
        assert np.all(ref <= 1.0) and np.all(e <= 1.0 + 1e-6)


FILM = compose_family("film_test", [Lobe("ggx", "thin_film")], tied=("ks_1",))


def _film_table(rng, n=600, noise=0.0):
    truth = {"albedo": np.array([0.05, 0.1, 0.2]), "alpha_1": 0.15, "ks_1": 0.9, "thickness_1": 480.0,
             "film_eta_1": 1.7, "eta_1": 1.5}
    model = FILM.build(truth, 3)
    wo = R.random_directions(rng, n, "upper", 0.1)
    # half the rows near the mirror, where the film colours the highlight
    m = R.random_normals_near_z(rng, n, 0.15, 0.15, spread=2.0)
    wo2 = R.random_directions(rng, n, "upper", 0.15)
    wi2 = 2 * np.sum(wo2 * m, -1, keepdims=True) * m - wo2
    keep = wi2[:, 2] > 0.1
    WO = np.concatenate([wo, wo2[keep]])
    WI = np.concatenate([R.random_directions(rng, n, "upper", 0.1), wi2[keep]])
    v = np.asarray(model.eval(jnp.asarray(WO), jnp.asarray(WI)))
    v = v * (1 + noise * rng.standard_normal(v.shape))
    return Table(wo=WO, wi=WI, values=v), truth


def test_start_reads_the_film_from_the_hue(x64, rng):
    table, truth = _film_table(rng)
    g = initial_guess(table, Parametrization(FILM, 3))
    # the optical thickness (what the colour fixes) within 5 %
    assert abs(float(g["thickness_1"]) * float(g["film_eta_1"]) / (480.0 * 1.7) - 1) < 0.05, g


def test_fit_recovers_a_film(x64, rng):
    table, truth = _film_table(rng, noise=0.01)
    r = fit(table, model=FILM)
    for name in ("alpha_1", "thickness_1", "film_eta_1"):
        assert abs(float(np.ravel(r.params[name])[0]) / truth[name] - 1) < 0.02, (name, r.params[name])
    np.testing.assert_allclose(np.ravel(r.params["albedo"]), truth["albedo"], atol=0.01)
    assert r.converged and not r.warnings, r.warnings


@pytest.mark.parametrize("kwargs, match", [
    ({"thickness": -1.0, "film_eta": 1.5}, "thickness"),
    ({"thickness": 300.0, "film_eta": 0.9}, "film_eta"),
    ({"thickness": 300.0}, "needs thickness"),
    ({"thickness": [300.0, 310.0, 320.0], "film_eta": 1.5}, "one value for every channel"),
    ({"thickness": 300.0, "film_eta": 1.5, "k": 1.0}, "does not apply"),
])
@pytest.mark.check
def test_bad_parameters_raise(kwargs, match):
    with pytest.raises(ParameterError, match=match):
        SpecularLobe(0.2, "thin_film", **kwargs)
    with pytest.raises(ParameterError, match="eta_film"):
        fresnel_thin_film(0.5, 300.0, 0.5)
