"""Checks moved from the docstring examples of matfit.microfacet, matfit.render and
matfit.appearance: the values and behaviours those examples asserted, as small fast tests."""

import jax.numpy as jnp
import numpy as np
import pytest

from matfit.appearance import (LIGHTINGS, appearance_difference, ciede2000_map, disc_light, display, flip_map,
                               itp_map, lab, map_light)
from matfit.errors import ParameterError
from matfit.microfacet import (GGX, Beckmann, BlinnPhong, TabulatedNDF, back_facing_area, interpolate_ndf,
                               make_distribution, ndf_grid, projected_mass)
from matfit.microfacet.beckmann import beckmann_lambda
from matfit.render import (Environment, load_environment, save_png, sky_map, sphere_frames, srgb_decode, srgb_encode,
                           tonemap)

N = jnp.array([0.0, 0.0, 1.0])


# ------------------------------------------------------------------------------------------------
# matfit.microfacet
# ------------------------------------------------------------------------------------------------
@pytest.mark.check
def test_make_distribution_by_name():
    assert type(make_distribution("ggx", 0.2)) is GGX
    with pytest.raises(ValueError, match="distribution must be one of"):
        make_distribution("phong", 0.2)


@pytest.mark.parametrize("cls", [GGX, Beckmann, BlinnPhong])
def test_peak_is_one_over_pi_alpha_x_alpha_y_and_smith_terms_at_the_normal(cls):
    d = cls(0.3, 0.5)
    assert float(d.D(N)) == pytest.approx(1 / (np.pi * 0.3 * 0.5), rel=1e-5)
    assert float(d.Lambda(N)) == 0.0
    assert float(d.G1(N, N)) == 1.0 and float(d.G1(N, -N)) == 0.0


def test_blinn_phong_sample_dcos_and_no_visible_sampling():
    d = BlinnPhong(0.3)
    m = d.sample_dcos(jnp.array([[0.2, 0.7], [0.9, 0.1]]))
    assert m.shape == (2, 3) and bool(jnp.all(m[:, 2] > 0))
    np.testing.assert_allclose(np.linalg.norm(np.asarray(m), axis=-1), 1.0, rtol=1e-6)
    with pytest.raises(NotImplementedError, match="no visible-normal sampling"):
        d.sample_visible(N, jnp.array([0.3, 0.6]))


def test_reflection_ratio_g2_and_pdfs():
    d = GGX(0.3)
    wo, wi = jnp.array([0.0, 0.6, 0.8]), jnp.array([0.6, 0.0, 0.8])
    m = (wo + wi) / jnp.linalg.norm(wo + wi)
    num, den, vis = d.reflection_ratio(wo, wi, m)
    assert bool(vis) and float(num / den) == pytest.approx(float(d.D(m) * d.G2(wo, wi, m)), rel=1e-6)
    assert float(d.G2(wo, wo, N)) == pytest.approx(float(d.G1(wo, N)) ** 2, rel=1e-6)
    assert float(d.G2(wo, wo, N, "height_correlated")) > float(d.G2(wo, wo, N))
    assert float(d.pdf_dcos(wo)) == pytest.approx(float(d.D(wo)) * 0.8, rel=1e-6)
    assert float(d.pdf_visible(N, N)) == pytest.approx(float(d.D(N)), rel=1e-6)


def test_beckmann_lambda_values():
    assert float(beckmann_lambda(0.0)) == 0.0
    assert round(float(beckmann_lambda(1.0)), 4) == 0.0251


def test_ndf_grid_is_square_root_spaced():
    t = ndf_grid(5)
    assert t[0] == 0.0 and t[-1] == pytest.approx(np.pi / 2) and t[2] / t[-1] == pytest.approx(0.25)
    with pytest.raises(ParameterError, match="n must be an integer >= 3"):
        ndf_grid(2)


def test_table_functions_on_simple_tables():
    t = np.array([0.0, 0.5, np.pi / 2])
    d = np.exp(-np.sin(t) ** 2)  # log-linear in sin^2: interpolated exactly
    assert float(interpolate_ndf(t, d, 0.25)) == pytest.approx(np.exp(-np.sin(0.25) ** 2), rel=1e-12)
    t = np.linspace(0.0, np.pi / 2, 200)
    lambertian = np.full(200, 1 / np.pi)  # a Lambertian microsurface
    assert projected_mass(t, lambertian) == pytest.approx(1.0, abs=1e-12)
    b = back_facing_area(t, lambertian, np.array([1.0, 0.0]))
    assert b[0] == 0.0 and b[1] == pytest.approx(0.5, abs=1e-6)  # none at the normal, 1/2 at grazing


def test_tabulated_constructors():
    tab = TabulatedNDF.from_function(lambda t: np.cos(t) ** 2)  # normalized Blinn-Phong, e = 2
    assert float(tab.d_nodes[0]) == pytest.approx(2 / np.pi, rel=1e-4)  # D(0) = (e + 2) / (2 pi)
    assert float(TabulatedNDF.from_distribution(Beckmann(0.2)).alpha_x) == pytest.approx(0.2, abs=5e-5)


# ------------------------------------------------------------------------------------------------
# matfit.render
# ------------------------------------------------------------------------------------------------
def test_sky_and_load_environment():
    sky = sky_map((16, 32))
    assert sky.shape == (16, 32, 3) and sky.dtype == np.float32 and sky[0].mean() > sky[-1].mean()
    assert load_environment("furnace") is None and load_environment("sky").shape == (128, 256, 3)
    assert load_environment(np.ones((2, 4, 4))).shape == (2, 4, 3)  # RGBA: alpha dropped


def test_environment_tables_lookup_and_pdf():
    env = Environment.of(np.ones((4, 8, 3), np.float32))
    assert float(env.row_cdf[-1]) == 1.0 and float(env.pixel_p.sum()) == pytest.approx(1.0, abs=1e-6)
    assert float(env.pdf(jnp.array([1.0, 0.0, 0.0]))) * 4 * np.pi == pytest.approx(1.0, abs=1e-5)  # uniform
    env = Environment.of(sky_map((16, 32)))
    assert float(env.pixel_p.max() / env.pixel_p.min()) > 100  # the sun is drawn most often
    zenith, nadir = env.lookup(jnp.array([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0]]))
    assert float(zenith[2]) > float(nadir[2])  # blue sky above, brown ground below


def test_sphere_frames():
    inside, frames = sphere_frames(8)
    assert int(inside.sum()) == 52 and frames.shape == (8, 8, 3, 3)
    np.testing.assert_allclose(frames[4, 4, 2], [0.125, -0.125, np.sqrt(1 - 2 * 0.125 ** 2)], atol=1e-12)


def test_srgb_tonemap_and_png(tmp_path):
    assert round(float(srgb_encode(0.25)), 4) == 0.5371
    assert float(srgb_decode(srgb_encode(0.25))) == pytest.approx(0.25, abs=1e-12)
    assert float(srgb_decode(1.0)) == 1.0
    assert tonemap(np.ones((1, 1, 3)))[0, 0].tolist() == [255, 255, 255]
    assert tonemap(np.full((1, 1, 3), 0.5), exposure=0.5)[0, 0].tolist() == [137, 137, 137]  # linear 0.25
    p = save_png(tmp_path / "previews" / "grey.png", np.full((4, 6, 3), 0.18))
    assert p.name == "grey.png" and p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# ------------------------------------------------------------------------------------------------
# matfit.appearance
# ------------------------------------------------------------------------------------------------
def test_display_and_colour_maps():
    assert display([[2.0, 0.5, -1.0]], 0.5).tolist() == [[1.0, 0.25, 0.0]]
    np.testing.assert_allclose(lab([1.0, 1.0, 1.0]), [100.0, 0.0, 0.0], atol=5e-4)  # display white neutral
    assert float(ciede2000_map([0.2, 0.3, 0.4], [0.2, 0.3, 0.4])) == 0.0
    assert float(itp_map([0.5, 0.5, 0.5], [0.5, 0.5, 0.5])) == 0.0
    assert float(flip_map(np.full((8, 8, 3), 0.3), np.full((8, 8, 3), 0.3)).max()) == 0.0


def test_lightings_quadratures():
    assert LIGHTINGS["sky"].renamed("my sky", "a copy").name == "my sky"
    studio = LIGHTINGS["studio"]
    assert studio.refined(2).directions.shape[0] > studio.directions.shape[0]
    light = map_light(np.ones((8, 16, 3)))
    assert float(light.weights[:, 0].sum()) == pytest.approx(4 * np.pi, rel=1e-12)  # the whole sphere
    disc = disc_light([0, 1, 0], 0.1, 2.0, rings=3)
    assert disc.directions.shape == (19, 3) and float(disc.weights[:, 1].sum()) == pytest.approx(2.0)


def test_a_small_albedo_change_is_judged_under_both_lightings():
    from matfit.models import Lambert

    d = appearance_difference(Lambert(0.5), Lambert(0.55), size=16)
    assert sorted(d.lights) == ["sky", "studio"] and d.worst("ciede2000") > 1.0
    assert sorted(d.to_dict()) == ["looks_alike", "sky", "studio", "where"]
