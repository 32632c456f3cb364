"""Preview renders: white-furnace invariants, agreement of the three sampling strategies, and
the work a scene calls for (counted)."""

import jax.numpy as jnp
import numpy as np
import pytest

from matfit.errors import DataFormatError, ParameterError
from matfit.models import (Blend, CoatedConductor, GltfPBR, Lambert, Plastic, RoughConductor, RoughDielectric,
                           SmoothDielectric)
from matfit.render import image_ciede2000, render_sphere, sky_map
from matfit.render import sphere_frames as _frames

LOSSLESS_METAL = RoughConductor(0.4, 1e-3, 1e3)  # F = 1 to 1e-5: only masking loses energy


def _albedo_per_pixel(model, size, idx):
    inside, fr = _frames(size)
    mu = fr[inside][idx, 2, 2]  # cos(theta_o) = n . camera
    wo = np.stack([np.sqrt(1 - mu**2), 0 * mu, mu], -1)
    return np.asarray(model.albedo(jnp.asarray(wo), n=128))[:, 0], inside


@pytest.mark.check
def test_lambert_white_renders_one_everywhere_in_the_furnace():
    img = render_sphere(Lambert(1.0), "furnace", size=48, spp=8)
    inside, _ = _frames(48)
    np.testing.assert_allclose(img[inside], 1.0, rtol=0.01)


@pytest.mark.parametrize("model", [LOSSLESS_METAL, RoughDielectric(0.3, 1.5)], ids=["conductor", "dielectric"])
def test_lossless_models_render_their_albedo_never_above_one(model):
    size = 24
    inside, _ = _frames(size)
    idx = np.arange(0, int(inside.sum()), 7)
    albedo, _ = _albedo_per_pixel(model, size, idx)
    img = render_sphere(model, "furnace", size=size, spp=256)
    px = img[inside][idx, 0]
    # per-sample weights of these models are <= 1, so no pixel mean may exceed 1
    assert img[inside].max() <= 1.0 + 1e-6
    # away from the rim the quadrature albedo is accurate: pixels agree within Monte Carlo noise
    keep = albedo > 0.5
    assert np.median(np.abs(px[keep] - albedo[keep])) < 0.025
    assert abs(np.mean(px[keep] - albedo[keep])) < 0.005  # no bias beyond the noise of the mean


def test_furnace_error_falls_as_one_over_sqrt_spp():
    size = 24
    inside, _ = _frames(size)
    idx = np.arange(int(inside.sum()))
    albedo, _ = _albedo_per_pixel(LOSSLESS_METAL, size, idx)
    keep = albedo > 0.6
    err = {}
    for spp in (16, 256):
        imgs = [render_sphere(LOSSLESS_METAL, "furnace", size=size, spp=spp, seed=s)[inside][:, 0] for s in range(3)]
        err[spp] = np.sqrt(np.mean([(im[keep] - albedo[keep]) ** 2 for im in imgs]))
    ratio = err[16] / err[256]  # sqrt(256 / 16) = 4 for an unbiased estimator
    assert 2.8 < ratio < 5.5, err


@pytest.mark.parametrize("model", [Lambert([0.7, 0.5, 0.3]), RoughConductor(0.3, [0.2, 0.9, 1.1], [3.9, 2.4, 2.2]),
                                   Plastic([0.7, 0.2, 0.1], 0.15, 1.5), RoughDielectric(0.4, 1.5),
                                   Blend(Lambert([0.7, 0.5, 0.3]), RoughConductor(0.2, 0.2, 3.0), 0.5),
                                   CoatedConductor(0.3, [0.2, 0.9, 1.1], [3.9, 2.4, 2.2], alpha_coat=0.1),
                                   GltfPBR([0.8, 0.5, 0.2], 0.5, 0.2, clearcoat=0.5, clearcoat_alpha=0.05)],
                         ids=["lambert", "conductor", "plastic", "dielectric", "blend", "car_paint", "gltf"])
def test_bsdf_env_and_mis_sampling_agree_within_noise(model):
    size, spp = 24, 128
    inside, _ = _frames(size)
    means = {}
    for strategy in ("bsdf", "env", "mis"):
        runs = [render_sphere(model, "sky", size=size, spp=spp, seed=s, strategy=strategy)[inside].mean(0) for s in range(4)]
        means[strategy] = (np.mean(runs, 0), np.std(runs, 0, ddof=1) / 2)
    ref, ref_se = means["mis"]
    for strategy in ("bsdf", "env"):
        m, se = means[strategy]
        z = np.abs(m - ref) / np.sqrt(se**2 + ref_se**2 + (1e-3 * ref) ** 2)
        assert np.all(z < 5), (strategy, m, ref, se, ref_se)


def test_only_what_the_scene_calls_for_is_computed():
    _, s = render_sphere(Lambert(0.5), "furnace", size=16, spp=4, return_stats=True)
    assert s.env_samples == 0 and s.env_lookups == 0 and s.evaluations == 0 and s.bsdf_samples > 0
    _, s = render_sphere(RoughConductor(0.3, 0.2, 3.0), "sky", size=16, spp=4, return_stats=True)
    assert s.env_samples > 0 and s.transmission_evaluations == 0
    _, s = render_sphere(RoughDielectric(0.3, 1.5), "sky", size=16, spp=4, return_stats=True)
    assert s.transmission_evaluations > 0
    _, s = render_sphere(SmoothDielectric(1.5), "sky", size=16, spp=4, return_stats=True)
    assert s.evaluations == 0 and s.env_samples == 0  # delta lobes only: never evaluated


def test_render_shows_the_environment_outside_the_sphere_and_checks_its_input():
    env = np.zeros((8, 16, 3), np.float32)
    env[..., 1] = 0.25
    img = render_sphere(Lambert(0.5), env, size=16, spp=2)
    np.testing.assert_allclose(img[0, 0], [0.0, 0.25, 0.0])
    with pytest.raises(DataFormatError, match=r"\(H, W, 3\)"):
        render_sphere(Lambert(0.5), np.zeros((8, 16)))
    with pytest.raises(DataFormatError, match="finite"):
        render_sphere(Lambert(0.5), np.full((8, 16, 3), np.nan))
    with pytest.raises(ParameterError, match="size must be a positive integer"):
        render_sphere(Lambert(0.5), "furnace", size=0)
    with pytest.raises(ParameterError, match="strategy"):
        render_sphere(Lambert(0.5), "furnace", strategy="path")
    with pytest.raises(ParameterError, match="no such file"):
        render_sphere(Lambert(0.5), "/nonexistent/sky.hdr")


def test_sky_and_ciede2000():
    sky = sky_map()
    assert sky.shape[-1] == 3 and sky.max() > 10  # the sun
    a = render_sphere(Lambert([0.5, 0.4, 0.3]), "sky", size=16, spp=16)
    b = render_sphere(Lambert([0.3, 0.4, 0.5]), "sky", size=16, spp=16)
    assert image_ciede2000(a, a) == 0.0 and image_ciede2000(a, b) > 2.0
