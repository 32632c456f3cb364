"""Checks moved from the docstring examples of matfit.models (values, invariants, errors), and of the
model registry (matfit.models.MODELS) against its users."""

import re

import jax.numpy as jnp
import numpy as np
import pytest

from matfit.errors import ParameterError
from matfit.models import Lambert, SmoothConductor, SmoothDielectric, SoAPairs

UP = jnp.array([0.0, 0.0, 1.0])


@pytest.mark.check
def test_lambert_contract_values():
    m = Lambert(0.5)
    assert round(float(m.eval(UP, UP)[0] * jnp.pi), 6) == 0.5
    assert round(float(m.pdf(UP, UP) * jnp.pi), 6) == 1.0  # cosine-weighted: cos / pi
    wi, weight, _ = m.sample(UP, jnp.array([0.0, 0.3, 0.7]))
    assert bool(wi[2] > 0) and round(float(weight[0]), 6) == 0.5
    assert round(float(m.albedo(UP)[0]), 6) == 0.5
    up = UP[None]
    assert bool(jnp.array_equal(m.eval_pairs(SoAPairs.of(up, up)), m.eval(up, up)))


def test_energy_factor_and_delta_albedo():
    assert float(Lambert(0.5).energy_factor(UP, UP)) == 1.0
    assert float(SmoothDielectric(1.5).energy_factor(UP, -UP)) == 2.25
    assert float(Lambert(0.5).delta_albedo(UP)[0]) == 0.0
    assert float(SmoothDielectric(1.5).delta_albedo(UP)[0]) == 1.0


def test_dielectric_energy_factor():
    from matfit.models._base import dielectric_energy_factor

    assert float(dielectric_energy_factor(UP, -UP, 2.0)) == 4.0
    assert float(dielectric_energy_factor(-UP, UP, 2.0)) == 0.25


def test_delta_model_has_no_value_or_density():
    m = SmoothConductor(0.2, 3.9)
    assert m.is_delta and float(m.eval(UP, UP)[0]) == 0.0 and float(m.pdf(UP, UP)) == 0.0


def test_valid_reflection_and_half_vector():
    from matfit.models import half_vector, valid_reflection

    assert bool(valid_reflection(UP, UP)) and not bool(valid_reflection(UP, -UP))
    h, cos_d = half_vector(jnp.array([0.6, 0.0, 0.8]), jnp.array([-0.6, 0.0, 0.8]))
    assert h.tolist() == [0.0, 0.0, 1.0] and round(float(cos_d), 6) == 0.8


def test_soa_pairs_constructors_and_isotropic():
    from matfit._math import Vec3

    up = Vec3(jnp.zeros(2), jnp.zeros(2), jnp.ones(2))
    assert SoAPairs.from_directions(up, up, n=1).n == 1
    assert SoAPairs.of(jnp.array([[0.0, 0.0, 1.0]]), jnp.array([[0.6, 0.0, 0.8]])).shape == (1, 3)
    wo, wi, h, ok = SoAPairs.of(jnp.array([[0.0, 0.6, 0.8]]), jnp.array([[0.0, 0.0, -1.0]])).isotropic()
    assert not bool(ok[0]) and float(wo.z[0]) == 1.0 and float(h.z[0]) == 1.0  # invalid: mapped to the normal


def test_coat_helpers():
    from matfit.models import RoughDielectric
    from matfit.models._coat import (coat_internal_reflectance, coat_reflection, coat_reflection_pairs,
                                     coat_transmittance, coat_transmittance_table, is_smooth, make_coat)

    assert type(make_coat(0.0, 1.5)) is SmoothDielectric and type(make_coat(0.1, 1.5)) is RoughDielectric
    assert is_smooth(SmoothDielectric(1.5))
    coat = RoughDielectric(0.2, 1.5)
    assert bool(coat_reflection(coat, UP, UP) > 0)
    wo, wi = jnp.array([[0.0, 0.6, 0.8]]), jnp.array([[0.0, -0.6, 0.8]])
    assert bool(jnp.allclose(coat_reflection_pairs(coat, SoAPairs.of(wo, wi)), coat_reflection(coat, wo, wi)))
    mu, T = coat_transmittance_table(coat, order=4, nodes=5)
    assert mu.shape == (5,) and 0.9 < float(T[-1]) < 1.0
    assert round(float(coat_transmittance(SmoothDielectric(1.5), 1.0)), 6) == 0.96  # 1 - ((1.5 - 1) / 2.5)^2
    assert round(float(coat_internal_reflectance(SmoothDielectric(1.5))), 3) == 0.596  # internal Fresnel average


def test_microfacet_reflection_sample_pdf_and_lobe():
    from matfit.models import RoughConductor

    assert type(RoughConductor(0.3, 1.5, 3.0, distribution="beckmann").dist()).__name__ == "Beckmann"
    wi = RoughConductor(0.05, 1.5, 3.0).reflection_sample(jnp.array([0.6, 0.0, 0.8]), jnp.array([0.5, 0.5]))
    assert bool(wi[0] < -0.5)  # near the mirror direction of a narrow lobe
    m = RoughConductor(0.3, 1.5, 3.0)
    wo, wi = jnp.array([0.0, 0.6, 0.8]), jnp.array([0.0, -0.6, 0.8])
    assert bool(jnp.isclose(m.reflection_pdf(wo, wi), m.pdf(wo, wi))) and float(m.reflection_pdf(wo, -wi)) == 0.0
    up = UP[None]
    lobe = RoughConductor(0.5, 1.0, 0.0).reflection_lobe(SoAPairs.of(up, up))
    assert round(float(lobe[0] * 4 * jnp.pi * 0.25), 6) == 1.0  # D(0) = 1 / (pi alpha^2), G2 = 1


def test_param_helpers_accept_valid_input():
    from matfit.models._params import (as_channels, channel_count, check_channels, check_choice, check_complex_index,
                                       check_directions, check_u)

    assert as_channels(0.5).shape == (1,)
    assert channel_count(jnp.ones(1), jnp.ones((4, 3))) == 3
    check_channels("M", a=[0.1, 0.2, 0.3], b=2.0)
    check_complex_index("M", [0.2, 0.9, 1.1], [3.9, 2.4, 2.2])
    check_choice("M", "masking", "separable", ("separable", "height_correlated"))
    check_directions("M.eval", wo=np.array([0.0, 0.0, 1.0]), wi=np.array([[0.6, 0.0, 0.8]]))
    check_u("M.sample", np.array([0.5, 0.25, 0.75]), 3)


def test_stochastic_layered_index_matched_eval_and_no_sampler():
    # eval_with_error and the albedo of a black base (an absorbing thick coat) are checked in
    # test_stochastic_layered.py
    from matfit.models import StochasticLayered

    ref = StochasticLayered(SmoothDielectric(1.0 + 1e-6), Lambert(0.5), n_samples=64, max_depth=2)
    assert round(float(ref.eval(UP, UP)[0] * jnp.pi), 3) == 0.5  # an index-matched coat: the base alone
    with pytest.raises(NotImplementedError, match="evaluation reference; sample with Layered or Plastic"):
        ref.sample(UP, jnp.zeros(3))


def test_specular_lobe_fresnel_and_multilobe_probabilities():
    from matfit.models import MultiLobe, SpecularLobe

    up = UP[None]  # normal incidence: w F0 = 0.5 * 0.04
    assert round(float(SpecularLobe(0.2, weight=0.5, f0=0.04).fresnel_term(SoAPairs.of(up, up))[0, 0]), 6) == 0.02
    assert round(float(SpecularLobe(0.2, "dielectric", eta=1.5).normal_reflectance()[0]), 6) == 0.04  # (0.5/2.5)^2
    assert round(float(SpecularLobe(0.2, weight=0.7, f0=1.0).reflectance_estimate()[0]), 6) == 0.7
    p = MultiLobe(0.0, [SpecularLobe(0.1, f0=1.0), SpecularLobe(0.3, f0=1.0)]).probabilities()
    assert [round(float(x), 6) for x in p] == [0.0, 0.5, 0.5]


def test_measured_from_bytes_errors_and_measured_model():
    from matfit import Table
    from matfit.errors import DataFormatError
    from matfit.io.rgl import read_rgl, tensor_file_bytes, uniform_fields
    from matfit.models import MeasuredMERL, MeasuredRGL, measured_model

    with pytest.raises(DataFormatError, match=r"<bytes>: field 'header': expected at least 18 bytes"):
        MeasuredRGL.from_file(b"tensor_file")
    with pytest.raises(DataFormatError, match="<bytes>: field 'file': expected 34992012 bytes, found an empty file"):
        MeasuredMERL.from_file(b"")
    m = MeasuredRGL(read_rgl(tensor_file_bytes(uniform_fields(0.5))))
    assert round(float(m.eval_cos(jnp.array([0.0, 0.6, 0.8]), jnp.array([0.0, -0.6, 0.8]))[0]), 6) == 0.125
    wo = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]])
    assert measured_model(Table(wo=wo, wi=wo[::-1], values=np.ones((2, 3)))) is None  # no provenance


def test_small_helpers_of_the_model_files():
    from matfit.models import Blend, Plastic, RoughDielectric
    from matfit.models.lambert import cosine_pdf

    assert round(float(cosine_pdf(UP, UP) * jnp.pi), 6) == 1.0 and float(cosine_pdf(UP, -UP)) == 0.0
    assert float(Blend(Lambert(0.5), Lambert(0.1), 0.25).mix(1.0, 3.0)[0]) == 1.5
    assert bool(RoughDielectric(0.2, 1.0).index_matched()) and not bool(RoughDielectric(0.2, 1.5).index_matched())
    assert Plastic(0.5).has_delta_lobe and not Plastic(0.5, alpha=0.1).has_delta_lobe  # a smooth coat's mirror lobe


def test_registry_holds_every_public_model():
    import inspect

    from matfit import models

    public = {n: getattr(models, n) for n in models.__all__}
    classes = {n for n, obj in public.items() if inspect.isclass(obj) and issubclass(obj, models.AbstractBSDF)
               and not inspect.isabstract(obj) and not n.startswith("Abstract")}
    assert classes and classes <= set(models.MODELS)
    assert "CoatedConductor" in models.MODELS  # a factory, named like the model it builds
    for name, obj in models.MODELS.items():
        assert public[name] is obj and models.MODEL_USES[name] <= {"document", "scene"}
    assert models.models_for("scene") == {n: m for n, m in models.MODELS.items() if "scene" in models.MODEL_USES[n]}
    with pytest.raises(ParameterError, match="use must be one of"):
        models.models_for("renderer")


def test_model_file_and_scenes_accept_the_registry_entries_they_declare():
    from data_synth import SceneError, UnknownModelError, parse_scene
    from matfit.errors import DataFormatError
    from matfit.export import model_from_description
    from matfit.models import MODELS, models_for

    documents, scenes = models_for("document"), models_for("scene")
    assert documents and scenes and set(documents) != set(scenes)
    for name in MODELS:
        with pytest.raises(DataFormatError) as e:
            model_from_description({"type": name})  # no fields: refused, naming the problem
        assert ("expected one of" not in str(e.value)) == (name in documents)
        scene = {"geometry": {"kind": "inplane"}, "material": {"model": name}}
        try:
            parse_scene(scene, file="s.toml")
            refused = None
        except SceneError as err:
            refused = err
        assert isinstance(refused, UnknownModelError) == (name not in scenes), name
    with pytest.raises(DataFormatError, match=re.escape(f"expected one of {sorted(documents)}, found 'Phong'")):
        model_from_description({"type": "Phong"})
    with pytest.raises(UnknownModelError, match=re.escape(f"one of {sorted(scenes)}")):
        parse_scene({"geometry": {"kind": "inplane"}, "material": {"model": "Phong"}})
