"""matfit (JAX) against the independent numpy reference in tests/reference.py.

Max relative error <= 1e-10 in float64 and <= 1e-4 in float32, with an absolute floor only for
values that are (numerically) zero: |lib - ref| / max(|ref|, FLOOR), FLOOR = 1e-280 (float64, just above the subnormal range) and
1e-30 (float32, whose smallest normal number is ~1e-38; values that small are meaningless for
rendering). In float32 the reference is evaluated on the float32-rounded inputs and parameters
(converted exactly to float64), so only the library's float32 arithmetic is measured.

Model eval/pdf checks skip ill-conditioned points only: points where the reference itself changes
by more than rtol/2 when its inputs (wo, wi) are perturbed by relative noise of the dtype's unit
roundoff (`reference.input_sensitivity`). There no implementation in that precision can meet rtol
(deep exponential tails of Beckmann/Blinn-Phong far from the peak, nearly cancelling half vectors
for eta ~ 1, 1 - F next to the critical angle). At most max_skipped() of the points may be skipped
and the number skipped is asserted, so the check stays meaningful.
"""

import jax.numpy as jnp
import numpy as np
import pytest

import reference as R

KINDS = ["ggx", "beckmann", "blinn_phong"]
ALPHAS = [(0.05, None), (0.3, None), (1.0, None), (0.05, 0.3), (1.0, 0.3)]
ALPHA_IDS = ["a0.05", "a0.3", "a1", "aniso0.05x0.3", "aniso1x0.3"]
MASKINGS = ["separable", "height_correlated"]
ETAS = [1.01, 1.5, 3.0, 0.67]
N = 240  # directions per check (a few hundred, modest for a 2-core machine)
# Largest fraction of ill-conditioned points a check may skip. float32 needs a larger allowance
# only for eta = 1.01: near-forward transmission through an almost index-matched interface forms m
# from etap*wi + wo with |etap*wi + wo| ~ 0.01-0.02, losing ~2 digits to cancellation right where a
# narrow (alpha = 0.05) lobe peaks (up to ~30% of those points).
def max_skipped(dtype, eta=None):
    if dtype == np.float64:
        return 0.03
    return 0.35 if eta == 1.01 else 0.10


UNIT_ROUNDOFF = {np.float32: 2.0**-24, np.float64: 2.0**-53}


def tol(dtype):
    return (1e-10, 1e-280) if dtype == np.float64 else (1e-4, 1e-30)


def rounded(x, dtype):
    """x rounded to dtype, returned as float64 numpy (what the reference sees)."""
    return np.asarray(np.asarray(x, dtype=dtype), dtype=np.float64)


def lib(x, dtype):
    return jnp.asarray(np.asarray(x, dtype=dtype))


def rparam(a, dtype):
    return None if a is None else float(np.asarray(a, dtype=dtype))


def well_conditioned(fns, arrays, dtype, rng, eta=None):
    """Mask of points where every reference function in fns is well conditioned (see docstring)."""
    rtol, floor = tol(dtype)
    keep = np.ones(len(arrays[0]), bool)
    for fn in fns:
        keep &= R.input_sensitivity(fn, arrays, UNIT_ROUNDOFF[dtype], rng, floor=floor) <= rtol / 2
    skipped = 1 - keep.mean()
    assert skipped <= max_skipped(dtype, eta), f"{skipped:.1%} of the points are ill-conditioned"
    return keep


def check_dtype(out, dtype, what):
    assert out.dtype == dtype, f"{what}: output dtype {out.dtype}, expected {np.dtype(dtype)}"


def lib_dist(kind, ax, ay, dtype):
    from matfit.microfacet import GGX, Beckmann, BlinnPhong

    cls = {"ggx": GGX, "beckmann": Beckmann, "blinn_phong": BlinnPhong}[kind]
    return cls(lib(ax, dtype), None if ay is None else lib(ay, dtype))


def ref_dist(kind, ax, ay, dtype):
    return R.Dist(kind, rparam(ax, dtype), rparam(ay, dtype))


def normals(rng, ax, ay, n=N):
    """Microfacet normals: half concentrated where D has its mass, the rest uniform + a few below."""
    k = n // 2
    m = np.concatenate(
        [
            R.random_normals_near_z(rng, k, ax, ay if ay is not None else ax),
            R.random_directions(rng, n - k - 10, "upper"),
            R.random_directions(rng, 10, "lower"),
        ]
    )
    m[0] = [0.0, 0.0, 1.0]
    return m


def directions(rng, n=N, hemisphere="both", min_abs_cos=0.02):
    v = R.random_directions(rng, n - 20, hemisphere, min_abs_cos)
    # directions close to the normal (small Lambda) and the normal itself
    w = R.random_normals_near_z(rng, 20, 0.02, 0.02)
    w[0] = [0, 0, 1]
    if hemisphere == "lower":
        w[:, 2] *= -1
    elif hemisphere == "both":
        w[10:, 2] *= -1
    return np.concatenate([v, w])


def half_vectors(wo, wi, eta=1.5):
    """Generalized half vectors (reflection or refraction with index eta), flipped up."""
    co, ci = wo[:, 2], wi[:, 2]
    etap = np.where(co * ci > 0, 1.0, np.where(co > 0, eta, 1 / eta))
    m = etap[:, None] * wi + wo
    m /= np.linalg.norm(m, axis=-1, keepdims=True)
    return np.where(m[:, 2:3] < 0, -m, m)


# ---------------------------------------------------------------------------------------------
# Distributions
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("alphas", ALPHAS, ids=ALPHA_IDS)
@pytest.mark.parametrize("kind", KINDS)
def test_D(kind, alphas, dtype, rng):
    ax, ay = alphas
    rtol, floor = tol(dtype)
    m = rounded(normals(rng, ax, ay), dtype)
    out = lib_dist(kind, ax, ay, dtype).D(lib(m, dtype))
    check_dtype(out, dtype, "D")
    R.assert_rel(out, ref_dist(kind, ax, ay, dtype).D(m), rtol, floor, f"{kind}.D", m=m)


@pytest.mark.parametrize("alphas", ALPHAS, ids=ALPHA_IDS)
@pytest.mark.parametrize("kind", KINDS)
def test_Lambda(kind, alphas, dtype, rng):
    ax, ay = alphas
    rtol, floor = tol(dtype)
    v = rounded(directions(rng), dtype)
    out = lib_dist(kind, ax, ay, dtype).Lambda(lib(v, dtype))
    check_dtype(out, dtype, "Lambda")
    R.assert_rel(out, ref_dist(kind, ax, ay, dtype).Lambda(v), rtol, floor, f"{kind}.Lambda", v=v)


@pytest.mark.parametrize("alphas", ALPHAS, ids=ALPHA_IDS)
@pytest.mark.parametrize("kind", KINDS)
def test_G1(kind, alphas, dtype, rng):
    ax, ay = alphas
    rtol, floor = tol(dtype)
    v = rounded(directions(rng), dtype)
    m = rounded(normals(rng, ax, ay), dtype)
    out = lib_dist(kind, ax, ay, dtype).G1(lib(v, dtype), lib(m, dtype))
    check_dtype(out, dtype, "G1")
    R.assert_rel(out, ref_dist(kind, ax, ay, dtype).G1(v, m), rtol, floor, f"{kind}.G1", v=v, m=m)


@pytest.mark.parametrize("form", MASKINGS)
@pytest.mark.parametrize("alphas", ALPHAS, ids=ALPHA_IDS)
@pytest.mark.parametrize("kind", KINDS)
def test_G2(kind, alphas, form, dtype, rng):
    ax, ay = alphas
    rtol, floor = tol(dtype)
    wo = directions(rng)
    wi = directions(rng)
    m = half_vectors(wo, wi)
    # plus some arbitrary normals (visibility indicators)
    m[-40:] = normals(rng, ax, ay, 40)
    wo, wi, m = (rounded(x, dtype) for x in (wo, wi, m))
    out = lib_dist(kind, ax, ay, dtype).G2(lib(wo, dtype), lib(wi, dtype), lib(m, dtype), form=form)
    check_dtype(out, dtype, "G2")
    ref = ref_dist(kind, ax, ay, dtype).G2(wo, wi, m, form)
    assert np.count_nonzero(ref) > N // 4  # the test exercises visible configurations
    R.assert_rel(out, ref, rtol, floor, f"{kind}.G2[{form}]", wo=wo, wi=wi, m=m)


@pytest.mark.parametrize("alphas", ALPHAS, ids=ALPHA_IDS)
@pytest.mark.parametrize("kind", KINDS)
def test_pdf_visible_and_dcos(kind, alphas, dtype, rng):
    ax, ay = alphas
    rtol, floor = tol(dtype)
    wo = rounded(directions(rng), dtype)
    m = rounded(normals(rng, ax, ay), dtype)
    d, rd = lib_dist(kind, ax, ay, dtype), ref_dist(kind, ax, ay, dtype)
    out = d.pdf_dcos(lib(m, dtype))
    check_dtype(out, dtype, "pdf_dcos")
    R.assert_rel(out, rd.pdf_dcos(m), rtol, floor, f"{kind}.pdf_dcos", m=m)
    out = d.pdf_visible(lib(wo, dtype), lib(m, dtype))
    check_dtype(out, dtype, "pdf_visible")
    R.assert_rel(out, rd.pdf_visible(wo, m), rtol, floor, f"{kind}.pdf_visible", wo=wo, m=m)


# ---------------------------------------------------------------------------------------------
# Models
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("albedo", [0.7, [0.2, 0.5, 0.9]], ids=["scalar", "rgb"])
def test_lambert(albedo, dtype, rng):
    from matfit.models import Lambert

    rtol, floor = tol(dtype)
    wo = rounded(directions(rng), dtype)
    wi = rounded(directions(rng), dtype)
    model = Lambert(lib(albedo, dtype))
    out = model.eval(lib(wo, dtype), lib(wi, dtype))
    check_dtype(out, dtype, "Lambert.eval")
    R.assert_rel(out, R.lambert_eval(wo, wi, rounded(albedo, dtype)), rtol, floor, "Lambert.eval", wo=wo, wi=wi)
    up = (wo[:, 2] > 0) & (wi[:, 2] > 0)
    out = model.pdf(lib(wo[up], dtype), lib(wi[up], dtype))
    check_dtype(out, dtype, "Lambert.pdf")
    R.assert_rel(out, R.lambert_pdf(wo[up], wi[up]), rtol, floor, "Lambert.pdf", wo=wo[up], wi=wi[up])


def conductor_dirs(rng, ax, ay):
    wo = directions(rng, N, "upper")
    wi = directions(rng, N, "upper")
    # a few below-horizon configurations (must be 0)
    wi[-12:-6, 2] *= -1
    wo[-6:, 2] *= -1
    # specular-ish configurations: wi close to the mirror direction of wo
    k = N // 3
    jitter = R.random_normals_near_z(rng, k, ax, ax if ay is None else ay, spread=1.5)
    mirror = wo[:k] * np.array([-1, -1, 1])
    wi[:k] = mirror + 2 * (jitter - [0, 0, 1])
    wi[:k, 2] = np.abs(wi[:k, 2]) + 0.02
    wi[:k] /= np.linalg.norm(wi[:k], axis=-1, keepdims=True)
    return wo, wi


@pytest.mark.parametrize("masking", MASKINGS)
@pytest.mark.parametrize("alphas", ALPHAS, ids=ALPHA_IDS)
@pytest.mark.parametrize("kind", KINDS)
def test_rough_conductor(kind, alphas, masking, dtype, rng):
    from matfit.models import RoughConductor

    ax, ay = alphas
    rtol, floor = tol(dtype)
    wo, wi = (rounded(x, dtype) for x in conductor_dirs(rng, ax, ay))
    eta = rounded([0.143, 0.374, 1.442], dtype)  # gold-ish, per channel
    k = rounded([3.983, 2.385, 1.603], dtype)
    rd = ref_dist(kind, ax, ay, dtype)
    keep = well_conditioned(
        [
            lambda a, b: R.conductor_eval(a, b, rd, eta, k, masking),
            lambda a, b: R.conductor_pdf(a, b, rd, "visible"),
            lambda a, b: R.conductor_pdf(a, b, rd, "dcos"),
        ],
        [wo, wi],
        dtype,
        rng,
    )
    wo, wi = wo[keep], wi[keep]
    ref_f = R.conductor_eval(wo, wi, rd, eta, k, masking)
    assert np.count_nonzero(ref_f[:, 0] > 1e-3) > N // 10
    for sampling in ["visible", "dcos"]:
        model = RoughConductor(
            lib(ax, dtype),
            lib(eta, dtype),
            lib(k, dtype),
            distribution=kind,
            masking=masking,
            alpha_y=None if ay is None else lib(ay, dtype),
            sampling=sampling,
        )
        what = f"RoughConductor({kind}, {alphas}, {masking}, {sampling})"
        out = model.eval(lib(wo, dtype), lib(wi, dtype))
        check_dtype(out, dtype, what + ".eval")
        R.assert_rel(out, ref_f, rtol, floor, what + ".eval", wo=wo, wi=wi)
        out = model.pdf(lib(wo, dtype), lib(wi, dtype))
        check_dtype(out, dtype, what + ".pdf")
        R.assert_rel(out, R.conductor_pdf(wo, wi, rd, sampling), rtol, floor, what + ".pdf", wo=wo, wi=wi)


def dielectric_dirs(rng, eta, ax=0.3, ay=None):
    """wo from both sides; wi: reflections and refractions around the specular directions + random."""
    wo = directions(rng, N, "both")
    n1 = N // 3
    wi_rand = R.random_directions(rng, N - 2 * n1, "both", 0.02)
    # perturbed microfacet normal, then reflect / refract wo about it
    m = R.random_normals_near_z(rng, 2 * n1, ax, ax if ay is None else ay, spread=2.0)
    w = wo[: 2 * n1]
    c = np.sum(w * m, axis=-1)
    refl = 2 * c[:, None] * m - w
    inside = c < 0
    e = np.where(inside, 1 / eta, eta)  # index ratio (other side / wo side), pbrt-v4 convention
    mm = np.where(inside[:, None], -m, m)
    ca = np.abs(c)
    s2 = np.maximum(0, 1 - ca**2) / e**2
    ok = s2 < 1
    ct = np.sqrt(np.maximum(0, 1 - s2))
    refr = -w / e[:, None] + (ca / e - ct)[:, None] * mm
    refr = np.where(ok[:, None], refr, refl)
    wi = np.concatenate([refl[:n1], refr[n1:], wi_rand])
    wi /= np.linalg.norm(wi, axis=-1, keepdims=True)
    # keep away from the horizon
    bad = np.abs(wi[:, 2]) < 0.02
    wi[bad] = R.random_directions(rng, int(bad.sum()), "both", 0.02)
    return wo, wi


def critical_band_mask(wo, wi, eta, width):
    """True where wo.m is within `width` (in sin^2 theta_t) of the critical angle (to be excluded)."""
    co, ci = wo[:, 2], wi[:, 2]
    etap = np.where(co * ci > 0, 1.0, np.where(co > 0, eta, 1 / eta))
    m = etap[:, None] * wi + wo
    m /= np.linalg.norm(m, axis=-1, keepdims=True)
    m = np.where(m[:, 2:3] < 0, -m, m)
    c = np.sum(wo * m, axis=-1)
    e = np.where(c < 0, 1 / eta, eta)
    s2t = (1 - c**2) / e**2
    return np.abs(s2t - 1) < width


@pytest.mark.parametrize("masking", MASKINGS)
@pytest.mark.parametrize("alphas", ALPHAS, ids=ALPHA_IDS)
@pytest.mark.parametrize("kind", KINDS)
def test_rough_dielectric(kind, alphas, masking, dtype, rng):
    from matfit.models import RoughDielectric

    ax, ay = alphas
    rtol, floor = tol(dtype)
    rd = ref_dist(kind, ax, ay, dtype)
    for eta in ETAS:
        eta_r = rparam(eta, dtype)
        wo, wi = (rounded(x, dtype) for x in dielectric_dirs(rng, eta_r, ax, ay))
        # float32 only: the Fresnel factor has a square-root singularity at the critical angle
        # (dF/dcos -> inf as sin^2 theta_t -> 1), so one ulp of wo.m moves F by ~sqrt(ulp). Exclude
        # the narrow band |sin^2 theta_t - 1| < 1e-3 around it in float32; float64 is tested
        # everywhere.
        keep = ~critical_band_mask(wo, wi, eta_r, 1e-3) if dtype == np.float32 else np.ones(len(wo), bool)
        wo, wi = wo[keep], wi[keep]
        keep = well_conditioned(
            [
                lambda a, b: R.dielectric_eval(a, b, rd, eta_r, masking),
                lambda a, b: R.dielectric_pdf(a, b, rd, eta_r, "visible"),
                lambda a, b: R.dielectric_pdf(a, b, rd, eta_r, "dcos"),
            ],
            [wo, wi],
            dtype,
            rng,
            eta,
        )
        wo, wi = wo[keep], wi[keep]
        ref_f = R.dielectric_eval(wo, wi, rd, eta_r, masking)
        refl = wo[:, 2] * wi[:, 2] > 0
        # Coverage guard: both lobes must be exercised (float32 at eta = 1.01 keeps ~10 refracted
        # pairs after the conditioning filter, so the bar is 5).
        assert np.count_nonzero(ref_f[refl]) >= 5 and np.count_nonzero(ref_f[~refl]) >= 5
        for sampling in ["visible", "dcos"]:
            model = RoughDielectric(
                lib(ax, dtype),
                lib(eta, dtype),
                distribution=kind,
                masking=masking,
                alpha_y=None if ay is None else lib(ay, dtype),
                sampling=sampling,
            )
            what = f"RoughDielectric({kind}, {alphas}, eta={eta}, {masking}, {sampling})"
            out = model.eval(lib(wo, dtype), lib(wi, dtype))
            check_dtype(out, dtype, what + ".eval")
            R.assert_rel(out, ref_f, rtol, floor, what + ".eval", wo=wo, wi=wi)
            out = model.pdf(lib(wo, dtype), lib(wi, dtype))
            check_dtype(out, dtype, what + ".pdf")
            ref_p = R.dielectric_pdf(wo, wi, rd, eta_r, sampling)
            R.assert_rel(out, ref_p, rtol, floor, what + ".pdf", wo=wo, wi=wi)


def test_reference_dielectric_covers_tir(rng):
    """Sanity of the test data: internal reflection configurations with F == 1 do occur."""
    wo, wi = dielectric_dirs(rng, 1.5)
    inside = (wo[:, 2] < 0) & (wi[:, 2] < 0)
    m = half_vectors(wo, wi)
    F = R.fresnel_dielectric(np.sum(wo * m, axis=-1), 1.5)
    assert np.count_nonzero(inside & (F == 1.0)) > 3
