"""Rotated: an anisotropic lobe turned about the normal.

The hard-case matrix (tests/test_hard_cases.py, structure ``rotated_anisotropic_conductor``)
checks finite values and gradients, reciprocity, energy, the pdf's integral and sampling validity;
here: agreement with an independent numpy transcription (the directions turned by hand, the
anisotropic GGX conductor of numpy_ref), the symmetries of the angle, chi-square of its sampler,
its albedo and a finite-difference gradient in the angle.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import catalogue as C  # noqa: E402
import test_sampling as S  # noqa: E402

import numpy_ref as R  # noqa: E402
from matfit.errors import ParameterError  # noqa: E402
from matfit.models import Lambert, Rotated, RoughConductor  # noqa: E402

AX, AY = 0.08, 0.45


def _pairs(n=400, seed=3):
    rng = np.random.default_rng(seed)
    wo, wi = C.random_pairs(rng, n)
    return wo, wi


def _turn(w, phi):
    c, s = np.cos(phi), np.sin(phi)
    return np.stack([c * w[:, 0] + s * w[:, 1], -s * w[:, 0] + c * w[:, 1], w[:, 2]], -1)


@pytest.mark.check
@pytest.mark.parametrize("phi", [0.0, 0.6, -2.3, 7.0])
def test_eval_and_pdf_match_numpy_reference(phi):
    wo, wi = _pairs()
    m = Rotated(RoughConductor(AX, C.GOLD_ETA, C.GOLD_K, alpha_y=AY), phi)
    dist = R.Dist("ggx", AX, AY)
    want = R.conductor_eval(_turn(wo, phi), _turn(wi, phi), dist, C.GOLD_ETA, C.GOLD_K)
    got = np.asarray(m.eval(jnp.asarray(wo), jnp.asarray(wi)))
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12)
    want_p = R.conductor_pdf(_turn(wo, phi), _turn(wi, phi), dist)
    np.testing.assert_allclose(np.asarray(m.pdf(jnp.asarray(wo), jnp.asarray(wi))), want_p, rtol=1e-9, atol=1e-12)


def test_angle_symmetries():
    wo, wi = (jnp.asarray(x) for x in _pairs(200, seed=5))
    base = RoughConductor(AX, 0.2, 3.0, alpha_y=AY)
    f = Rotated(base, 0.4).eval(wo, wi)
    np.testing.assert_allclose(Rotated(base, 0.4 + np.pi).eval(wo, wi), f, rtol=1e-9)  # a half turn: the same lobe
    swapped = RoughConductor(AY, 0.2, 3.0, alpha_y=AX)
    np.testing.assert_allclose(Rotated(swapped, 0.4 - np.pi / 2).eval(wo, wi), f, rtol=1e-9)  # the widths swapped
    iso = RoughConductor(0.3, 0.2, 3.0)
    np.testing.assert_allclose(Rotated(iso, 1.1).eval(wo, wi), iso.eval(wo, wi), rtol=1e-9)  # isotropic: unchanged
    lam = Lambert([0.2, 0.5, 0.7])
    np.testing.assert_allclose(Rotated(lam, 2.0).albedo(wo[:3]), lam.albedo(wo[:3]), rtol=1e-12)


def test_sample_is_the_base_sample_turned():
    rng = np.random.default_rng(0)
    wo = jnp.asarray(C.from_degrees(50.0, 0.9)[None].repeat(64, 0))
    wo = wo / jnp.linalg.norm(wo, axis=-1, keepdims=True)
    u = jnp.asarray(rng.random((64, 3)))
    base = RoughConductor(AX, 0.2, 3.0, alpha_y=AY)
    phi = 0.8
    wi, w, p = Rotated(base, phi).sample(wo, u)
    wib, wb, pb = base.sample(jnp.asarray(_turn(np.asarray(wo), phi)), u)
    np.testing.assert_allclose(_turn(np.asarray(wi), phi), wib, atol=1e-12)
    np.testing.assert_allclose(w, wb, rtol=1e-12)
    np.testing.assert_allclose(p, pb, rtol=1e-12)


def test_angle_gradient_matches_finite_differences():
    wo, wi = (jnp.asarray(x) for x in _pairs(50, seed=9))

    def total(phi):
        return jnp.sum(Rotated(RoughConductor(AX, 0.2, 3.0, alpha_y=AY), phi).eval(wo, wi))

    g = float(jax.grad(total)(0.5))
    h = 1e-6
    fd = (float(total(0.5 + h)) - float(total(0.5 - h))) / (2 * h)
    assert np.isfinite(g) and abs(g - fd) <= 1e-6 * max(1.0, abs(fd)), (g, fd)
    assert abs(g) > 1e-3  # the angle matters for an anisotropic lobe


def test_albedo_is_the_base_albedo_in_its_frame():
    wo = jnp.asarray(C.from_degrees(60.0, 0.3))
    wo = wo / jnp.linalg.norm(wo)
    base = RoughConductor(AX, 0.2, 3.0, alpha_y=AY)
    got = Rotated(base, 0.9).albedo(wo, n=64)
    want = base.albedo(jnp.asarray(_turn(np.asarray(wo)[None], 0.9)[0]), n=64)
    np.testing.assert_allclose(got, want, rtol=1e-12)
    assert 0 < float(got[0]) <= 1


@dataclass(frozen=True)
class RotatedCase(S.Case):
    angle: float = 0.7

    @property
    def id(self):
        return f"rotated-{self.space}-{self.alpha:g}x{self.alpha_y:g}-{self.deg:g}deg-phi{self.angle:g}"

    def make(self):
        f32 = S.f32
        return Rotated(RoughConductor(f32(self.alpha), f32(S.COND_ETA), f32(S.COND_K), alpha_y=f32(self.alpha_y)),
                       f32(self.angle))


SAMPLE_CASES = [RotatedCase("conductor", "sphere", alpha=0.15, alpha_y=0.5, deg=50.0, angle=0.7),
                RotatedCase("conductor", "sphere", alpha=0.5, alpha_y=0.2, deg=75.0, angle=-2.0)]


@pytest.mark.parametrize("case", SAMPLE_CASES, ids=[c.id for c in SAMPLE_CASES])
def test_sampling_matches_pdf(case):
    r = S.run_case(case)
    S.check_sampled(r, len(SAMPLE_CASES))
    assert np.all(r.mean_energy <= 1 + 5 * r.se_energy), r.mean_energy


def test_bad_input_named():
    with pytest.raises(ParameterError, match="Rotated: base"):
        Rotated("ggx", 0.3)
    with pytest.raises(ParameterError, match="Rotated: parameter 'angle' must be finite"):
        Rotated(Lambert(0.5), np.nan)
    with pytest.raises(ParameterError, match="Rotated.eval"):
        Rotated(Lambert(0.5), 0.1).eval(jnp.array([0.0, 0.0, 2.0]), jnp.array([0.0, 0.0, 1.0]))
