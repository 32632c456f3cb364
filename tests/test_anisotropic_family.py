"""The anisotropic conductor family (``conductor_aniso``, brushed metal): the start read from the
peak's shape, recovery by the default fit, the choice's cue and the automatic choice."""

import jax.numpy as jnp
import numpy as np
import pytest

from test_choose import GOLD, _table
from matfit import Table
from matfit.fitting import appearance_cues, candidates_for, choose_family, fit
from matfit.fitting._aniso_guess import anisotropy_guess
from matfit.models import Rotated, RoughConductor

pytestmark = pytest.mark.filterwarnings("ignore::RuntimeWarning")


def _brushed(ax=0.08, ay=0.35, phi=0.6):
    return Rotated(RoughConductor(ax, alpha_y=ay, **GOLD), phi)


def _canonical(alpha, alpha_y, angle):
    """The same lobe with the narrow width first and the angle in (-pi/2, pi/2]."""
    if alpha > alpha_y:
        alpha, alpha_y, angle = alpha_y, alpha, angle + np.pi / 2
    return alpha, alpha_y, float(angle - np.pi * np.round(angle / np.pi))


@pytest.mark.check
def test_guess_reads_the_widths_and_the_angle_of_the_peak():
    rng = np.random.default_rng(2)
    for ax, ay, phi in [(0.1, 0.4, 0.6), (0.3, 0.08, -1.2), (0.05, 0.25, 1.4)]:
        t = _table(_brushed(ax, ay, phi), n=400, seed=int(rng.integers(100)))
        g = anisotropy_guess(t.wo, t.wi, t.values)
        a, b, p = _canonical(ax, ay, phi)
        assert g is not None
        assert abs(g[0] / a - 1) < 0.15 and b / 1.5 < g[1] < 2.5 * b, (g, (a, b, p))
        assert abs(np.angle(np.exp(2j * (g[2] - p)))) / 2 < 0.05, (g, (a, b, p))
    # an isotropic lobe reads as one; an in-plane sweep (slopes on a line) gives no guess
    g = anisotropy_guess(*_iso_arrays())
    assert g is not None and abs(g[1] / g[0] - 1) < 0.1
    th = np.radians(np.linspace(-60, 60, 40))
    wo = np.stack([np.sin(th), 0 * th, np.cos(th)], 1)
    wi = np.tile([[-0.3, 0.0, np.sqrt(1 - 0.09)]], (40, 1))
    assert anisotropy_guess(wo, wi, np.asarray(RoughConductor(0.2, **GOLD).eval(jnp.asarray(wo), jnp.asarray(wi)))) is None


def _iso_arrays():
    t = _table(RoughConductor(0.2, **GOLD), n=400)
    return t.wo, t.wi, t.values


def test_default_fit_recovers_a_brushed_metal():
    rng = np.random.default_rng(1)
    wo = rng.normal(size=(160, 3))
    wo[:, 2] = np.abs(wo[:, 2]) + 0.3
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    wi = wo * [-1, -1, 1] + rng.normal(scale=0.15, size=wo.shape)  # around the mirror: the lobe's shape
    wi[:, 2] = np.abs(wi[:, 2]) + 0.1
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    truth = _brushed(0.3, 0.08, -1.2)
    f = np.asarray(truth.eval(jnp.asarray(wo), jnp.asarray(wi)))
    r = fit(Table(wo=wo, wi=wi, values=f, channels="rgb"), model="conductor_aniso")
    assert r.converged and r.family == "conductor_aniso"
    got = _canonical(float(r.params["alpha"]), float(r.params["alpha_y"]), float(r.params["angle"]))
    np.testing.assert_allclose(got, _canonical(0.3, 0.08, -1.2), rtol=2e-3, atol=1e-3)
    np.testing.assert_allclose(r.params["eta"], GOLD["eta"], rtol=2e-3)
    np.testing.assert_allclose(r.params["k"], GOLD["k"], rtol=2e-3)


def test_cue_calls_for_the_anisotropic_family_only_where_the_table_can_show_it():
    brushed = appearance_cues(_table(_brushed(), n=400))
    assert brushed["azimuthal"] and brushed["incidence_planes"] >= 2 and "conductor_aniso" in candidates_for(brushed)
    iso = appearance_cues(_table(RoughConductor(0.2, **GOLD), n=400))
    assert "conductor_aniso" not in candidates_for(iso)
    # the brushed metal measured in one plane of incidence (as an isotropic RGL file): no candidate
    t = _table(_brushed(), n=400)
    phi = np.arctan2(t.wi[:, 1], t.wi[:, 0])
    c, s = np.cos(-phi)[:, None], np.sin(-phi)[:, None]

    def turn(w):
        return np.concatenate([c * w[:, :1] - s * w[:, 1:2], s * w[:, :1] + c * w[:, 1:2], w[:, 2:]], 1)

    wo1, wi1 = turn(t.wo), turn(t.wi)
    one = Table(wo=wo1, wi=wi1, values=np.asarray(_brushed().eval(jnp.asarray(wo1), jnp.asarray(wi1))))
    cues = appearance_cues(one)
    assert cues["incidence_planes"] == 1 and "conductor_aniso" not in candidates_for(cues)


def test_choice_by_appearance_returns_the_anisotropic_family():
    truth = _brushed()
    result, choice = choose_family(_table(truth, n=400), reference=truth, candidates=["conductor", "conductor_aniso"],
                                   starts=1)
    assert choice.chosen == "conductor_aniso" and result.appearance.looks_alike, choice.summary()
    rows = {r["family"]: r for r in choice.rows}
    assert rows["conductor"]["score"] > 1 >= rows["conductor_aniso"]["score"]


def test_one_plane_azimuthal_dependence_is_not_called_anisotropy():
    from matfit.fitting._choose import _missing

    one = _missing({"azimuthal": True, "dark_floor": True, "incidence_planes": 1})
    assert len(one) == 1 and "cannot tell them apart" in one[0]
    assert _missing({"azimuthal": True, "dark_floor": False, "incidence_planes": 3}) == [
        "an azimuthal dependence (anisotropy)"]
    assert _missing({"azimuthal": True, "dark_floor": True, "incidence_planes": 3}) == []  # conductor_aniso's
