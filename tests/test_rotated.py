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


@dataclass(frozen=True)
class AnisotropicGltfCase(RotatedCase):
    @property
    def id(self):
        return f"gltf-anisotropic-{self.space}-{self.deg:g}deg-phi{self.angle:g}"

    def make(self):
        from matfit.models import GltfPBR

        f32 = S.f32
        return GltfPBR(f32(C.RGB), metallic=f32(0.5), alpha=f32(self.alpha), anisotropy=f32(0.7),
                       anisotropy_rotation=f32(self.angle))


SAMPLE_CASES = [RotatedCase("conductor", "sphere", alpha=0.15, alpha_y=0.5, deg=50.0, angle=0.7),
                RotatedCase("conductor", "sphere", alpha=0.5, alpha_y=0.2, deg=75.0, angle=-2.0),
                AnisotropicGltfCase("conductor", "sphere", alpha=0.1, alpha_y=0.1, deg=60.0, angle=0.9)]


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


def _khr_anisotropic_metal(wo, wi, c, alpha, strength, rotation):
    """numpy: the KHR_materials_anisotropy specification's metal BRDF, F_schlick(c) V D, with its
    anisotropic GGX D and height-correlated V written in the tangent T and bitangent B."""
    at = alpha + (1 - alpha) * strength ** 2
    ab = alpha
    T = np.array([np.cos(rotation), np.sin(rotation), 0.0])
    B = np.array([-np.sin(rotation), np.cos(rotation), 0.0])
    h = wo + wi
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    nh, nv, nl = h[:, 2], wo[:, 2], wi[:, 2]
    D = 1 / (np.pi * at * ab * ((h @ T / at) ** 2 + (h @ B / ab) ** 2 + nh ** 2) ** 2)
    lv = nl * np.sqrt((at * (wo @ T)) ** 2 + (ab * (wo @ B)) ** 2 + nv ** 2)
    ll = nv * np.sqrt((at * (wi @ T)) ** 2 + (ab * (wi @ B)) ** 2 + nl ** 2)
    V = 0.5 / (lv + ll)
    vh = np.sum(wo * h, 1)[:, None]
    F = np.asarray(c)[None] + (1 - np.asarray(c)[None]) * (1 - vh) ** 5
    return F * (V * D)[:, None]


@pytest.mark.parametrize("strength, rotation", [(0.6, 0.7), (1.0, -2.0), (0.3, 0.0)])
def test_gltf_anisotropy_matches_the_khr_formula(strength, rotation):
    from matfit.models import GltfPBR

    wo, wi = _pairs(300, seed=11)
    c = [0.9, 0.6, 0.3]
    m = GltfPBR(c, metallic=1.0, alpha=0.12, anisotropy=strength, anisotropy_rotation=rotation)
    np.testing.assert_allclose(np.asarray(m.eval(jnp.asarray(wo), jnp.asarray(wi))),
                               _khr_anisotropic_metal(wo, wi, c, 0.12, strength, rotation), rtol=1e-9, atol=1e-12)
    iso = GltfPBR(c, metallic=1.0, alpha=0.12)
    np.testing.assert_allclose(GltfPBR(c, metallic=1.0, alpha=0.12, anisotropy=jnp.zeros(()), anisotropy_rotation=1.0)
                               .eval(jnp.asarray(wo), jnp.asarray(wi)), iso.eval(jnp.asarray(wo), jnp.asarray(wi)),
                               rtol=1e-12)


def test_brushed_metal_exports_with_its_anisotropy():
    """glTF (KHR_materials_anisotropy, read back by pygltflib), standard_surface and OpenPBR
    (validated by materialx inside the exporter); an anisotropic glTF material maps exactly and its
    document's values rebuild a GltfPBR that evaluates equal."""
    pygltflib = pytest.importorskip("pygltflib")
    pytest.importorskip("MaterialX")
    from matfit.export import to_gltf, to_materialx, to_openpbr
    from matfit.export._materialx import anisotropic_roughness
    from matfit.models import GltfPBR

    brushed = Rotated(RoughConductor(0.08, C.GOLD_ETA, C.GOLD_K, alpha_y=0.35), 0.6)
    r = to_gltf(brushed)
    ext = r.content["materials"][0]["extensions"]["KHR_materials_anisotropy"]
    assert "KHR_materials_anisotropy" in r.content["extensionsUsed"] and not r.exact
    assert pygltflib.GLTF2().from_dict(r.content).materials[0].extensions["KHR_materials_anisotropy"] == ext
    # the wide axis is the lobe's y axis: a quarter turn from its x axis (modulo a half turn)
    assert abs(np.angle(np.exp(2j * (ext["anisotropyRotation"] - (0.6 + np.pi / 2))))) / 2 < 0.05, ext
    assert r.fidelity.relative_rmse < 0.06, r.fidelity
    # the isotropic glTF metal fitted to the same lobe comes out far worse
    from matfit.export._fidelity import fit_target, measure
    from matfit.export._gltf import families

    iso = fit_target(brushed, families()["metal"], init={"base_color": np.full(3, 0.8), "alpha": 0.17}, channels=3)
    assert measure(brushed, iso).relative_rmse > 3 * r.fidelity.relative_rmse

    g = GltfPBR([0.9, 0.6, 0.3], 1.0, 0.12, anisotropy=0.6, anisotropy_rotation=0.4)
    rg = to_gltf(g)
    mat = rg.content["materials"][0]
    e = mat["extensions"]["KHR_materials_anisotropy"]
    back = GltfPBR(mat["pbrMetallicRoughness"]["baseColorFactor"][:3], mat["pbrMetallicRoughness"]["metallicFactor"],
                   mat["pbrMetallicRoughness"]["roughnessFactor"] ** 2, anisotropy=e["anisotropyStrength"],
                   anisotropy_rotation=e["anisotropyRotation"])
    wo, wi = (jnp.asarray(x) for x in _pairs(100, seed=4))
    assert rg.exact
    np.testing.assert_allclose(back.eval(wo, wi), g.eval(wo, wi), rtol=1e-9)

    for export, surface in ((to_materialx, "standard_surface"), (to_openpbr, "open_pbr_surface")):
        m = {p.target: p.value for p in export(brushed).mapping}
        a_b = float(np.asarray(r.model.alpha))
        a_t = a_b + (1 - a_b) * float(np.asarray(r.model.anisotropy)) ** 2
        rough, aniso = anisotropic_roughness(surface, a_t, a_b)
        if surface == "standard_surface":  # MaterialX's mx_roughness_anisotropy
            aspect = np.sqrt(1 - m["specular_anisotropy"])
            np.testing.assert_allclose([m["specular_roughness"] ** 2 / aspect, m["specular_roughness"] ** 2 * aspect],
                                       [a_t, a_b], rtol=1e-9)
            np.testing.assert_allclose(m["specular_rotation"] * 2 * np.pi, np.mod(float(r.model.anisotropy_rotation),
                                                                                 2 * np.pi), rtol=1e-9)
        else:  # OpenPBR's specification
            a = m["specular_roughness_anisotropy"]
            at = m["specular_roughness"] ** 2 * np.sqrt(2 / (1 + (1 - a) ** 2))
            np.testing.assert_allclose([at, (1 - a) * at], [a_t, a_b], rtol=1e-9)
