"""numpy_ref/published.py at single points: each model's value at normal incidence or on a mirror
pair against its closed form (the class docstrings' formulas worked out by hand), and each reader
on a one-line file. (These were the module's docstring examples, which no test ran.)
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import numpy_ref.published as P

SHARED = Path(__file__).resolve().parent.parent.parent / "shared"
PI = math.pi
F15 = 0.04  # Cook-Torrance / Snell Fresnel of eta = 1.5 at normal incidence, ((eta - 1) / (eta + 1))^2
NORMAL = np.array([[0.0, 0.0, 1.0]])
WO, WI = np.array([[0.6, 0.0, 0.8]]), np.array([[-0.6, 0.0, 0.8]])  # a mirror pair: h = +z, c = 0.8

# (model, wo, wi, expected f[0, 0]): at normal incidence D and S take their peak, G = 1, c = 1
POINTS = [
    # Löw's Cook-Torrance: D = 1 / m^2 (no 1/pi), F = 0.04, over pi ci co
    pytest.param(P.LowCookTorrance(kd=0.0, ks=1.0, m=0.2, eta=1.5), NORMAL, NORMAL, F15 / (PI * 0.04),
                 id="LowCookTorrance"),
    pytest.param(P.LowAshikhminShirley(kd=0.0, ks=1.0, n=100.0, eta=1.5), NORMAL, NORMAL, 101 / (8 * PI) * F15,
                 id="LowAshikhminShirley"),
    # a mirror pair: |Ip + Op| = 0, c' = sqrt(1 - 1.2^2 / 4) = 0.8
    pytest.param(P.LowSmooth(kd=0.0, A=2.0, B=100.0, C=1.0, eta=1.5), WO, WI, 2.0 * float(P.fresnel_cook(1.5, 0.8)),
                 id="LowSmooth"),
    pytest.param(P.LowMicrofacet(kd=0.0, A=1.0, B=10.0, C=2.0, eta=1.5), NORMAL, NORMAL, F15 / PI, id="LowMicrofacet"),
    # u = alpha, D(0) = K exp(-alpha) / (alpha^p pi), G1 = 1 (theta = 0 <= theta0), F(1) = f0 - f1
    pytest.param(P.BagherSGD(kd=0.0, rho_s=1.0, alpha=0.1, p=0.5, f0=0.5, f1=0.0, K=1.0, Lambda=0.0, c_g=0.0,
                             k=1.0, theta0=1.0), NORMAL, NORMAL, math.exp(-0.1) / 0.1 ** 0.5 / PI * 0.5 / PI,
                 id="BagherSGD"),
    # normalized Beckmann D = 1 / (pi m^2), Schlick F(1) = f0
    pytest.param(P.NganCookTorrance(kd=0.0, ks=1.0, f0=0.05, m=0.2), NORMAL, NORMAL, 0.05 / (PI ** 2 * 0.04),
                 id="NganCookTorrance"),
    pytest.param(P.NganAshikhminShirley(kd=0.0, ks=1.0, f0=0.1, n=100.0), NORMAL, NORMAL, 101 / (8 * PI) * 0.1,
                 id="NganAshikhminShirley"),
    pytest.param(P.NganBlinnPhong(kd=0.0, ks=1.0, n=10.0), NORMAL, NORMAL, 12 / (2 * PI), id="NganBlinnPhong"),
    pytest.param(P.NganWard(kd=0.0, ks=1.0, alpha=0.1), NORMAL, NORMAL, 1 / (4 * PI * 0.01), id="NganWard"),
    # a mirror pair: Cxy (wi_x wo_x) + Cz wi_z wo_z = 0.18 + 0.32 = 0.5 = max(|Cz|, |Cxy|)
    pytest.param(P.NganLafortune(kd=0.0, ks=1.0, cxy=-0.5, cz=0.5, n=50.0), WO, WI, 52 / (2 * PI), id="NganLafortune"),
]


@pytest.mark.check
@pytest.mark.parametrize("model, wo, wi, expected", POINTS)
def test_model_at_a_point(model, wo, wi, expected):
    assert float(model(wo, wi)[0, 0]) == pytest.approx(expected, rel=1e-12)


def test_diffuse_part_is_kd_over_pi():
    m = P.NganWard(kd=[0.1, 0.2, 0.3], ks=0.0, alpha=0.1)
    np.testing.assert_allclose(m(NORMAL, NORMAL)[0] * PI, [0.1, 0.2, 0.3], rtol=1e-12)


def test_ward_duer_differs_from_ward_by_sqrt_ci_co():
    a = P.NganWard(0.0, 1.0, 0.1)(WO, WI)[0, 0]
    b = P.NganWardDuer(0.0, 1.0, 0.1)(WO, WI)[0, 0]
    assert a / b == pytest.approx(0.8, rel=1e-12)  # sqrt(ci co) = 0.8


def test_fresnel_forms_at_the_ends():
    assert float(P.fresnel_cook(1.5, 1.0)) == pytest.approx(F15, rel=1e-12)
    assert float(P.fresnel_schlick_f0(0.04, 0.0)) == pytest.approx(1.0, rel=1e-12)


def test_half_diff_angles_of_a_mirror_pair():
    th, _, td, _ = P.half_diff_angles(WO, WI)
    assert float(th[0]) == pytest.approx(0.0, abs=1e-12)
    assert float(np.cos(td[0])) == pytest.approx(0.8, rel=1e-12)


def test_phong_mirror_lobe_peaks_on_the_mirror_pair():
    f = P.phong_mirror_lobe(WO, WI, 0.1, 10.0)
    assert float(f[0, 0]) == pytest.approx(0.1 * 12 / (2 * PI), rel=1e-12)


def test_undefined_model_keeps_its_values():
    m = P.UndefinedModel(0.1, "NganHe", {"roughness": [0.5]}, "ambiguous")
    assert m.values["roughness"][0] == 0.5
    with pytest.raises(NotImplementedError, match="ambiguous"):
        m(NORMAL, NORMAL)


# --- the readers on one-line files ----------------------------------------------------------------

def test_read_bbm_long(tmp_path):
    rows = [("Lambertian", "albedo", i, 0.1) for i in range(3)] + \
           [("NganWard", "albedo", i, 0.05) for i in range(3)] + [("NganWard", "roughness", 0, 0.1)]
    p = tmp_path / "f.csv"
    p.write_text("source,material,component,param,index,value\n"
                 + "".join(f"ngan_ward,x,{c},{q},{i},{v}\n" for c, q, i, v in rows))
    assert P.read_bbm_long(p)[("ngan_ward", "x")].alpha == 0.1


def test_read_fit_file(tmp_path):
    p = tmp_path / "ngan_ward.fit"
    p.write_text("# c\nx = Aggregate(Lambertian(albedo = [0.1, 0.1, 0.1]), "
                 "NganWard(albedo = [0.05, 0.05, 0.05], roughness = 0.1))\n")
    m = P.read_fit_file(p)["x"]
    assert (m.alpha, m.source) == (0.1, "ngan_ward")


def test_read_sgd_csv(tmp_path):
    p = tmp_path / "s.csv"
    p.write_text(",".join(P._SGD_COLS) + "\n" + ",".join(["x"] + ["0.5"] * (len(P._SGD_COLS) - 1)) + "\n")
    assert float(P.read_sgd_csv(p)["x"].published_error[0]) == 0.5


def test_read_abc_csv(tmp_path):
    p = tmp_path / "a.csv"
    p.write_text(",".join(P._ABC_COLS) + "\nx,0.1,0.1,0.1,5,5,5,100,1.2,1.5\n")
    assert P.read_abc_csv(p)["x"].B == 100.0


@pytest.mark.skipif(not (SHARED / "data" / "published_fits").is_dir(), reason=f"shared data not found: {SHARED}")
def test_published_fits_hold_red_plastic():
    assert "red-plastic" in P.published_fits(SHARED)
