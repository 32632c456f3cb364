"""The automatic choice of a family: the cues of the data, the candidates they call for, and the
choice by rendered images on synthetic tables of known families (it must return the true one)."""

import jax.numpy as jnp
import numpy as np
import pytest

from matfit import Table
from matfit.fitting import appearance_cues, candidates_for, choose_family, fit
from matfit.models import Lambert, MultiLobe, Plastic, RoughConductor, SpecularLobe

pytestmark = pytest.mark.filterwarnings("ignore::RuntimeWarning")

GOLD = dict(eta=np.array([0.143, 0.374, 1.442]), k=np.array([3.983, 2.385, 1.603]))


def _dirs(n, rng):
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2]) + 0.05
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _table(model, n=1500, seed=0):
    """Random pairs plus pairs near the mirror (a gonioreflectometer's dense specular rows)."""
    rng = np.random.default_rng(seed)
    wo = _dirs(2 * n, rng)
    wi = _dirs(2 * n, rng)
    mir = wo[n:] * np.array([-1, -1, 1])
    wi[n:] = mir + rng.normal(scale=0.06, size=mir.shape)
    wi[n:, 2] = np.abs(wi[n:, 2]) + 0.02
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    y = np.asarray(model.eval(jnp.asarray(wo), jnp.asarray(wi)), float)
    return Table(wo=wo, wi=wi, values=np.broadcast_to(y, (2 * n, 3)).copy())


@pytest.mark.check
def test_grazing_excess_names_sheen_only_where_the_backward_rows_show_it():
    """paper_white and colodur's grazing excess lies in forward rows only (the RGL tables hold no
    backward grazing rows there): the missing effect must not be called a sheen lobe."""
    from matfit.fitting._choose import _missing

    line = 1.5  # CUE_LINES["grazing_excess"]
    both = _missing({"grazing_excess": True, "grazing_ratio": 3.0, "grazing_back_ratio": 2 * line})
    forward = _missing({"grazing_excess": True, "grazing_ratio": 3.0, "grazing_back_ratio": 0.5})
    unknown = _missing({"grazing_excess": True, "grazing_ratio": 3.0, "grazing_back_ratio": float("nan")})
    # backward as well as forward: a sheen, which the sheen family carries (a candidate, not missing)
    assert both == [] and "sheen" in candidates_for({"grazing_excess": True, "grazing_back_ratio": 2 * line})
    assert "sheen" not in candidates_for({"grazing_excess": True, "grazing_back_ratio": 0.5})
    assert "not a sheen lobe" in forward[0] and "forward grazing angles only" in forward[0]
    assert "no backward grazing rows" in unknown[0]
    assert _missing({"grazing_excess": False}) == []


def test_cues_see_what_the_material_shows():
    grey = appearance_cues(_table(Plastic(0.5, 0.1, 1.5)))
    assert not grey["coloured_highlight"] and not grey["colour_shift"] and not grey["second_lobe"]
    gold = appearance_cues(_table(RoughConductor(0.2, **GOLD)))
    assert gold["coloured_highlight"] and gold["dark_floor"] and not gold["colour_shift"]
    two = MultiLobe(jnp.array([0.3, 0.3, 0.3]), [SpecularLobe(0.05, weight=0.2, f0=0.04),
                                                 SpecularLobe(0.3, weight=1.0, f0=0.04)])
    c = appearance_cues(_table(two))
    assert c["second_lobe"] and c["lobe_misfit"] > 3 * grey["lobe_misfit"]
    assert "lobes3" in candidates_for(c) and "conductor" in candidates_for(gold) and "car_paint" in candidates_for(gold)
    # a thin film: the highlight's hue turns with the angle, and the film family is a candidate
    film = MultiLobe(jnp.array([0.05, 0.05, 0.05]), [SpecularLobe(0.08, "thin_film", 1.0, thickness=420.0,
                                                                   film_eta=1.8, eta=1.5)])
    f = appearance_cues(_table(film))
    assert f["colour_shift"] and "film" in candidates_for(f) and "film" not in candidates_for(grey)
    # an excess at grazing angles (a sheen): grazing off-mirror rows three times the Lambertian value
    t = _table(Lambert(0.5))
    th = np.degrees(np.arccos(np.stack([t.wi[:, 2], t.wo[:, 2]])))
    v = t.values.copy()
    v[(th > 70).all(0)] *= 3
    assert appearance_cues(Table(wo=t.wo, wi=t.wi, values=v))["grazing_excess"]
    assert not appearance_cues(t)["grazing_excess"]


@pytest.mark.parametrize("family, truth", [("lambert", Lambert([0.6, 0.4, 0.3])),
                                           ("plastic", Plastic([0.5, 0.3, 0.2], 0.12, 1.5)),
                                           ("conductor", RoughConductor(0.25, **GOLD))])
def test_choice_by_appearance_returns_the_true_family(family, truth):
    # the cues' candidates are tested above; here four families, two of them more flexible than the truth
    cands = ["lambert", "plastic", "conductor", "lobes1"]
    result, choice = choose_family(_table(truth, n=400), reference=truth, candidates=cands, starts=1)
    assert choice.chosen == family and result.family == family and choice.judged_by == "appearance"
    assert result.appearance.looks_alike and result.choice is choice
    assert family in choice.reason or "the best image score" in choice.reason
    rows = {r["family"]: r for r in choice.rows}
    assert set(rows) == set(cands) and choice.runner_up in rows
    # the chosen family is the one of fewest parameters within the tolerance of the best score
    best = min(r["score"] for r in rows.values() if "score" in r)
    assert all(r["p"] >= rows[family]["p"] or r["score"] > best * 1.1 for r in rows.values() if "score" in r)


def test_fit_with_no_family_named_and_no_reference_compares_held_out_error():
    t = _table(Lambert([0.6, 0.4, 0.3]), n=300)
    r = fit(t, starts=1, candidates=["lambert", "plastic"])
    assert r.family == "lambert" and r.choice.judged_by == "held-out error" and r.appearance is None
    assert r.loss == "e2" and "held-out" in r.choice.summary()
    with pytest.raises(Exception, match="name the family"):
        fit(t, fixed={"albedo": 0.5})
