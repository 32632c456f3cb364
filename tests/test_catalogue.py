"""The test catalogue (tests/catalogue.py) against the library's registry of models.

1. Every entry of ``matfit.models.MODELS`` has a model structure in ``catalogue.STRUCTURES`` (the
   hard-case matrix and the property checks of tests/test_hard_cases.py run through every
   structure), and every structure builds a model of the class its entry names (a factory: the
   class it returns): a new model without a catalogue entry fails here.
2. Sampling of the models with no chi-square test of their own elsewhere (GltfPBR: its three
   lobes; SpecularLobe on its own, with a thin film): chi-square of ``sample`` against ``pdf``
   (tests/chi2.py, through tests/test_sampling.py's ``run_case``: a sphere grid, a grid of
   stretched half vectors), weight == f cos / pdf, int pdf == the valid fraction, the mean weight
   (Monte Carlo albedo) <= 1.
3. Library bugs the catalogue found, fixed, with their minimal reproductions: a narrow bright sheen
   (eval < 0), a measured table's empty batch (every model now takes one).
"""

from __future__ import annotations

import math
import os
import sys
import typing
from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import catalogue as C  # noqa: E402
import test_sampling as S  # noqa: E402

from matfit.models import MODELS, GltfPBR, Lambert, Sheen  # noqa: E402


def _registered_class(entry):
    """The class of the models an entry of MODELS builds: the class, or a factory's return type."""
    if isinstance(entry, type):
        return entry
    return typing.get_type_hints(entry)["return"]


# ------------------------------------------------------------------------------------------------
# 1. every model of the registry is in the catalogue
# ------------------------------------------------------------------------------------------------
@pytest.mark.check
def test_every_registered_model_has_a_catalogue_structure(x64):
    by_model = {}
    for s in C.STRUCTURES.values():
        by_model.setdefault(s.model, []).append(s)
    missing = sorted(set(MODELS) - set(by_model))
    assert not missing, (f"models of matfit.models.MODELS without a structure in tests/catalogue.py STRUCTURES: "
                         f"{missing} (add one, with its hard parameter values)")
    unknown = sorted(set(by_model) - set(MODELS))
    assert not unknown, f"catalogue structures naming no entry of MODELS: {unknown}"
    for name, structures in by_model.items():
        cls = _registered_class(MODELS[name])
        for s in structures:
            assert s.cases, s.name
            model = s.build(np.float64, s.cases[0])
            assert type(model) is cls, (f"structure {s.name} builds a {type(model).__name__}, not a {cls.__name__} "
                                        f"({name})")
            # the tags say what the model is
            assert (C.TRANSMISSION in s.tags) == bool(model.transmits), s.name
            assert (C.REFLECTION in s.tags) != (C.TRANSMISSION in s.tags), s.name
            assert (C.DELTA in s.tags) == bool(model.is_delta), s.name
            assert (C.DELTA_LOBE in s.tags) == bool(model.has_delta_lobe and not model.is_delta), s.name


def test_structures_are_well_formed():
    names = [s.name for s in C.STRUCTURES.values()]
    assert len(names) == len(set(names))
    for s in C.STRUCTURES.values():
        assert s.zs in (C.Z_REFL, C.Z_DIEL), s.name
        if C.STOCHASTIC not in s.tags and s.name != "measured_rgl":
            # the pdf's integral needs a parameter set whose lobes the quadrature resolves (the
            # RGL density is not integrable by a fixed rule: tests/catalogue.py)
            assert any(s.resolved(c) for c in s.cases), s.name
        assert any(s.energy_bound(c) is not None for c in s.cases) or s.name == "measured_rgl", s.name


# ------------------------------------------------------------------------------------------------
# 2. chi-square of the sampler of GltfPBR (diffuse, specular and clear-coat lobes)
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class GltfCase(S.Case):
    clearcoat_alpha: float = 0.1

    @property
    def id(self):
        return f"gltf-{self.space}-{self.deg:g}deg"

    def make(self):
        f32 = S.f32
        return C._cast(GltfPBR(f32(C.RGB), metallic=f32(0.5), alpha=f32(0.3), clearcoat=f32(0.5),
                               clearcoat_alpha=f32(self.clearcoat_alpha)), np.float32)


@dataclass(frozen=True)
class FilmLobeCase(S.Case):
    @property
    def id(self):
        return f"specular-lobe-film-{self.space}-{self.deg:g}deg"

    def make(self):
        from matfit.models import SpecularLobe

        f32 = S.f32
        return SpecularLobe(f32(self.alpha), "thin_film", f32(1.0), alpha_y=f32(self.alpha_y), thickness=f32(350.0),
                            film_eta=f32(1.8), eta=f32(1.4))


SAMPLE_CASES = [GltfCase("gltf", "sphere", deg=50.0), GltfCase("gltf", "sphere", deg=80.0, clearcoat_alpha=0.3),
                FilmLobeCase("conductor", "slope", alpha=0.2, alpha_y=0.2, deg=60.0)]


@pytest.mark.parametrize("case", SAMPLE_CASES, ids=[c.id for c in SAMPLE_CASES])
def test_sampling_matches_pdf(case):
    r = S.run_case(case)
    S.check_sampled(r, len(SAMPLE_CASES))
    assert np.all(r.mean_energy <= 1 + 5 * r.se_energy), r.mean_energy


# ------------------------------------------------------------------------------------------------
# 3. library bugs the catalogue found, fixed (minimal reproductions)
# ------------------------------------------------------------------------------------------------
def test_narrow_bright_sheen_creates_no_energy(x64):
    """Below alpha ~ 0.06 the white Charlie lobe's albedo E passes 1 towards grazing (2.1 at alpha =
    0.01); Sheen divides the lobe by max(1, E) there: eval >= 0 (once -0.29 here) and the
    directional albedo of a white sheen over a white base <= 1 (quadrature)."""
    m = Sheen(Lambert(1.0), 1.0, 0.01)
    wo = jnp.array([math.sqrt(1 - 0.01**2), 0.0, 0.01])
    assert float(m.eval(wo, jnp.array([0.0, 0.0, 1.0]))[0]) >= 0
    for mu in (0.01, 0.05, 0.2, 1.0):
        w = jnp.array([math.sqrt(1 - mu**2), 0.0, mu])
        assert float(m.albedo(w[None], n=256)[0, 0]) <= 1 + 1e-3, mu


@pytest.mark.parametrize("name", sorted(C.STRUCTURES))
def test_empty_batch(name, x64):
    """Every model takes a batch of 0 directions: eval (0, C), pdf (0,), sample (0, 3) (MeasuredRGL
    raised ZeroDivisionError there once)."""
    s = C.STRUCTURES[name]
    m = s.build(np.float64, s.cases[0])
    empty = jnp.zeros((0, 3))
    f = m.eval(empty, empty)
    assert f.shape[0] == 0 and f.ndim == 2, f.shape
    if C.STOCHASTIC not in s.tags:
        assert m.pdf(empty, empty).shape == (0,)
        wi, w, pdf = m.sample(empty, jnp.zeros((0, 3)))
        assert wi.shape == (0, 3) and w.shape[0] == 0 and pdf.shape == (0,)
