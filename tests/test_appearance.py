"""matfit.appearance against independent computations: each metric from its published formula
(FLIP on uniform images from the paper's colour pipeline, CIEDE2000 on Sharma et al.'s test
pairs, ΔE_ITP from BT.2100's matrices and PQ curve), the noise-free render against a white
furnace and against the Monte Carlo renderer, and where a poor fit is said to fail."""

import numpy as np
import pytest

from matfit.appearance import (LIGHTINGS, appearance_difference, ciede2000_map, disc_light, flip_map, itp_map,
                               lighting, map_light, render_lit, render_references)
from matfit.errors import ParameterError
from matfit.models import Lambert, Plastic, RoughConductor

pytestmark = pytest.mark.filterwarnings("ignore::RuntimeWarning")

_M_XYZ = np.array([[0.4124564, 0.3575761, 0.1804375], [0.2126729, 0.7151522, 0.0721750],
                   [0.0193339, 0.1191920, 0.9503041]])


def _lab(rgb):
    """CIE L*a*b* of linear sRGB, white = sRGB white (written from CIE 15)."""
    t = (np.asarray(rgb, float) @ _M_XYZ.T) / _M_XYZ.sum(1)
    d = 6 / 29
    f = np.where(t > d**3, np.cbrt(t), t / (3 * d * d) + 4 / 29)
    return np.stack([116 * f[..., 1] - 16, 500 * (f[..., 0] - f[..., 1]), 200 * (f[..., 1] - f[..., 2])], -1)


def _flip_uniform(c1, c2):
    """FLIP of two uniform images (Andersson et al. 2020): the spatial filters keep a constant and
    the feature pipeline sees no edge, so FLIP is the remapped HyAB distance of Hunt-adjusted Lab."""
    hunt = lambda L: np.stack([L[..., 0], 0.01 * L[..., 0] * L[..., 1], 0.01 * L[..., 0] * L[..., 2]], -1)  # noqa: E731
    hyab = lambda a, b: np.abs(a[..., 0] - b[..., 0]) + np.hypot(a[..., 1] - b[..., 1], a[..., 2] - b[..., 2])  # noqa: E731
    qc, pc, pt = 0.7, 0.4, 0.95
    cmax = hyab(hunt(_lab([0.0, 1.0, 0.0])), hunt(_lab([0.0, 0.0, 1.0]))) ** qc
    e = hyab(hunt(_lab(c1)), hunt(_lab(c2))) ** qc
    return np.where(e < pc * cmax, pt / (pc * cmax) * e, pt + (e - pc * cmax) / (cmax - pc * cmax) * (1 - pt))


@pytest.mark.parametrize("c1, c2", [((0.2, 0.3, 0.4), (0.2, 0.3, 0.45)), ((0.5, 0.5, 0.5), (0.6, 0.5, 0.5)),
                                    ((0.1, 0.1, 0.1), (0.9, 0.2, 0.1)), ((0.0, 0.5, 0.0), (0.0, 0.0, 0.5))])
@pytest.mark.check
def test_flip_of_uniform_images_is_the_papers_colour_difference(c1, c2):
    f = flip_map(np.broadcast_to(c1, (48, 48, 3)), np.broadcast_to(c2, (48, 48, 3)))
    np.testing.assert_allclose(f, _flip_uniform(np.array(c1), np.array(c2)), atol=2e-4)
    assert flip_map(np.broadcast_to(c1, (8, 8, 3)), np.broadcast_to(c1, (8, 8, 3))).max() == 0


# G. Sharma, W. Wu, E. N. Dalal (2005), Table 1: (L1, a1, b1), (L2, a2, b2), ΔE00
SHARMA = [((50.0, 2.6772, -79.7751), (50.0, 0.0, -82.7485), 2.0425),
          ((50.0, 3.1571, -77.2803), (50.0, 0.0, -82.7485), 2.8615),
          ((50.0, 2.8361, -74.0200), (50.0, 0.0, -82.7485), 3.4412),
          ((50.0, -1.3802, -84.2814), (50.0, 0.0, -82.7485), 1.0000),
          ((50.0, 2.5, 0.0), (73.0, 25.0, -18.0), 27.1492),
          ((60.2574, -34.0099, 36.2677), (60.4626, -34.1751, 39.4387), 1.2644)]


@pytest.mark.check
def test_ciede2000_on_sharmas_test_pairs():
    import colour

    def rgb(lab):  # back through the same white as matfit.appearance.lab (exact round trip)
        white = colour.XYZ_to_xy(_M_XYZ.sum(1))
        return np.linalg.solve(_M_XYZ, colour.Lab_to_XYZ(np.array(lab), white))

    for l1, l2, de in SHARMA:
        assert float(ciede2000_map(rgb(l1), rgb(l2))) == pytest.approx(de, abs=2e-3)


def _ictcp(rgb, nits=100.0):
    """ICtCp (ITU-R BT.2100) of linear sRGB shown with white at ``nits``: BT.709 -> BT.2020 (BT.2087),
    the LMS matrix, the PQ curve and the ICtCp matrix, written from the standards."""
    to2020 = np.array([[0.6274, 0.3293, 0.0433], [0.0691, 0.9195, 0.0114], [0.0164, 0.0880, 0.8956]])
    lms = (np.asarray(rgb, float) @ to2020.T) @ (np.array([[1688, 2146, 262], [683, 2951, 462],
                                                          [99, 309, 3688]]) / 4096).T
    y = np.clip(lms * nits / 10000, 0, None)
    m1, m2, c1, c2, c3 = 2610 / 16384, 2523 / 4096 * 128, 3424 / 4096, 2413 / 4096 * 32, 2392 / 4096 * 32
    pq = ((c1 + c2 * y**m1) / (1 + c3 * y**m1)) ** m2
    return pq @ (np.array([[2048, 2048, 0], [6610, -13613, 7003], [17933, -17390, -543]]) / 4096).T


def test_delta_e_itp_is_bt2124_of_bt2100_ictcp():
    rng = np.random.default_rng(3)
    a, b = rng.uniform(0.02, 1, (40, 3)), rng.uniform(0.02, 1, (40, 3))
    b[:10] = a[:10] * 1.02
    d = _ictcp(a) - _ictcp(b)
    ref = 720 * np.sqrt(d[:, 0] ** 2 + (0.5 * d[:, 1]) ** 2 + d[:, 2] ** 2)
    np.testing.assert_allclose(itp_map(a, b), ref, rtol=3e-3)


@pytest.mark.check
def test_white_lambertian_sphere_in_the_furnace_renders_one():
    for refine, tol in ((1, 5e-3), (2, 2e-3)):
        img, inside = render_lit(Lambert(1.0), "furnace", size=24, refine=refine)
        np.testing.assert_allclose(img[inside], 1.0, atol=tol)
        assert np.all(img[~inside] == 0)


def test_disc_light_irradiance_is_exact_for_a_lambertian_facing_it():
    # a small disc light straight along a pixel's normal: radiance albedo E cos / pi, cos ~ 1
    light = disc_light([0.0, 0.0, 1.0], 0.05, [1.0, 2.0, 3.0])
    img, inside = render_lit(Lambert(0.5), light, size=33)
    np.testing.assert_allclose(img[16, 16], 0.5 * np.array([1.0, 2.0, 3.0]) / np.pi, rtol=2e-3)


@pytest.mark.parametrize("model", [Lambert([0.7, 0.5, 0.3]), RoughConductor(0.3, eta=0.2, k=3.0)])
def test_noise_free_render_agrees_with_the_monte_carlo_renderer(model):
    """The same smooth sky map (no sun), summed by quadrature and sampled by matfit.render at
    4096 samples per pixel: the sphere means within 1.5 %, pixels within 6 % RMS."""
    from matfit.render import render_sphere, sky_map

    env = sky_map((32, 64), sun=False)
    q, inside = render_lit(model, map_light(env, refine=2), size=20)
    mc = render_sphere(model, env, size=20, spp=4096, seed=1)
    a, b = q[inside], mc[inside]
    assert a.mean() == pytest.approx(b.mean(), rel=0.015)
    assert np.sqrt(np.mean((a - b) ** 2)) / b.mean() < 0.06


def test_identical_materials_look_alike_and_differences_are_located():
    same = appearance_difference(Lambert(0.5), Lambert(0.5), size=32)
    assert same.looks_alike and same.worst("flip") == 0 and same.warning() is None and same.where() == []
    darker = appearance_difference(Lambert(0.25), Lambert(0.5), size=32)
    assert not darker.looks_alike and "poor fit in appearance" in darker.warning()
    hue = appearance_difference(Lambert([0.6, 0.4, 0.4]), Lambert([0.4, 0.4, 0.6]), size=32)
    assert "in colour" in hue.where()
    gloss = appearance_difference(Plastic(0.5, 0.05, 1.5), Plastic(0.5, 0.15, 1.5), size=48)
    assert "near the mirror" in gloss.where() and "in colour" not in gloss.where()
    # judging many fits against one measurement renders the measurement once
    refs = render_references(Lambert(0.5), size=32)
    assert appearance_difference(Lambert(0.25), refs).to_dict() == darker.to_dict()


def test_lightings_and_bad_input():
    for name, light in LIGHTINGS.items():
        assert light.name == name and light.description and np.all(light.weights >= 0)
        np.testing.assert_allclose(np.linalg.norm(light.directions, axis=1), 1.0, atol=1e-12)
        assert lighting(name) is light
    # the sky's sun carries the irradiance of matfit.render's sun disc
    from matfit.render import SUN_RADIANCE, SUN_RADIUS

    sun = LIGHTINGS["sky"].weights[-disc_light([0, 0, 1], 0.1, 1.0, rings=6).directions.shape[0]:].sum(0)
    np.testing.assert_allclose(sun, SUN_RADIANCE * 2 * np.pi * (1 - np.cos(SUN_RADIUS)), rtol=1e-9)
    with pytest.raises(ParameterError, match="expected one of"):
        lighting("moon")
    with pytest.raises(ParameterError, match="radius"):
        disc_light([0, 0, 1], 2.0, 1.0)
    with pytest.raises(ParameterError, match="matfit model"):
        render_lit("gold", "sky")
    with pytest.raises(ParameterError, match="size"):
        render_lit(Lambert(0.5), "sky", size=2)
