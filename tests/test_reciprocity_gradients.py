"""Helmholtz reciprocity (and its generalized form for refraction) and gradients vs finite differences.

Generalized reciprocity of the rough dielectric's transmission, verified numerically (reference and
library): with the pbrt-v4 radiance BTDF (divided by etap^2),

    f_t(wo, wi) / eta_o^2 == f_t(wi, wo) / eta_i^2,

eta_o (eta_i) being the index of the medium wo (wi) lies in: 1 outside, eta inside. The other
candidate, f_t(wo, wi) * eta_o^2 == f_t(wi, wo) * eta_i^2, is violated by a factor eta^4, and plain
symmetry f_t(wo, wi) == f_t(wi, wo) by a factor eta^2 (asserted below).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import reference as R

KINDS = ["ggx", "beckmann", "blinn_phong"]
MASKINGS = ["separable", "height_correlated"]
N = 120
GOLD_ETA = [0.143, 0.374, 1.442]
GOLD_K = [3.983, 2.385, 1.603]


def j(x):
    return jnp.asarray(np.asarray(x, np.float64))


def rel(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    with np.errstate(all="ignore"):
        e = np.abs(a - b) / np.maximum(np.abs(b), 1e-280)
    return np.where(a == b, 0.0, e)


# ---------------------------------------------------------------------------------------------
# Reciprocity
# ---------------------------------------------------------------------------------------------
def half_vectors(wo, wi, eta):
    co, ci = wo[:, 2], wi[:, 2]
    etap = np.where(co * ci > 0, 1.0, np.where(co > 0, eta, 1 / eta))
    m = etap[:, None] * wi + wo
    m /= np.linalg.norm(m, axis=-1, keepdims=True)
    return np.where(m[:, 2:3] < 0, -m, m)


def test_lambert_reciprocity(x64, rng):
    from matfit.models import Lambert

    wo, wi = R.random_directions(rng, N, "both", 0.01), R.random_directions(rng, N, "both", 0.01)
    model = Lambert(j([0.2, 0.5, 0.9]))
    np.testing.assert_array_equal(np.asarray(model.eval(j(wo), j(wi))), np.asarray(model.eval(j(wi), j(wo))))


@pytest.mark.parametrize("alpha_y", [None, 0.15], ids=["iso", "aniso"])
@pytest.mark.parametrize("masking", MASKINGS)
@pytest.mark.parametrize("kind", KINDS)
def test_rough_conductor_reciprocity(kind, masking, alpha_y, x64, rng):
    from matfit.models import RoughConductor

    wo, wi = R.random_directions(rng, N, "upper", 0.01), R.random_directions(rng, N, "upper", 0.01)
    model = RoughConductor(j(0.4), j(GOLD_ETA), j(GOLD_K), distribution=kind, masking=masking,
                           alpha_y=None if alpha_y is None else j(alpha_y))
    f1, f2 = np.asarray(model.eval(j(wo), j(wi))), np.asarray(model.eval(j(wi), j(wo)))
    assert np.count_nonzero(f1) > N
    assert rel(f1, f2).max() <= 1e-10


@pytest.mark.parametrize("eta", [1.5, 0.67])
@pytest.mark.parametrize("alpha_y", [None, 0.15], ids=["iso", "aniso"])
@pytest.mark.parametrize("masking", MASKINGS)
@pytest.mark.parametrize("kind", KINDS)
def test_rough_dielectric_reciprocity(kind, masking, alpha_y, eta, x64, rng):
    from matfit.models import RoughDielectric

    model = RoughDielectric(j(0.4), j(eta), distribution=kind, masking=masking,
                            alpha_y=None if alpha_y is None else j(alpha_y))
    ref = R.Dist(kind, 0.4, alpha_y)
    # reflection, from outside and from inside
    for hemi in ["upper", "lower"]:
        wo, wi = R.random_directions(rng, N, hemi, 0.01), R.random_directions(rng, N, hemi, 0.01)
        f1, f2 = np.asarray(model.eval(j(wo), j(wi))), np.asarray(model.eval(j(wi), j(wo)))
        assert np.count_nonzero(f1) > N // 2
        assert rel(f1, f2).max() <= 1e-10, f"reflection reciprocity ({hemi})"
    # transmission: wo outside (eta_o = 1), wi inside (eta_i = eta)
    wo, wi = R.random_directions(rng, 4 * N, "upper", 0.01), R.random_directions(rng, 4 * N, "lower", 0.01)
    f1, f2 = np.asarray(model.eval(j(wo), j(wi)))[:, 0], np.asarray(model.eval(j(wi), j(wo)))[:, 0]
    np.testing.assert_array_equal(f1 > 0, f2 > 0)
    # Skip values in the subnormal range and pairs within |sin^2 theta_t - 1| < 1e-3 of the critical
    # angle, where 1 - F evaluated from the inside (for the reversed pair) is ill-conditioned.
    m = half_vectors(wo, wi, eta)
    c = np.sum(wo * m, -1)  # wo outside: sin^2 theta_t = (1 - c^2)/eta^2 seen from the other side
    s2_inside = eta**2 * (1 - np.sum(wi * m, -1) ** 2)
    nz = (f1 > 1e-250) & (np.abs(s2_inside - 1) > 1e-3) & (np.abs((1 - c**2) / eta**2 - 1) > 1e-3)
    assert np.count_nonzero(nz) > 20
    eta_o, eta_i = 1.0, eta
    # the form that holds, for the library and for the reference
    assert rel(f1[nz] / eta_o**2, f2[nz] / eta_i**2).max() <= 1e-9
    r1, r2 = R.dielectric_eval(wo, wi, ref, eta, masking)[:, 0], R.dielectric_eval(wi, wo, ref, eta, masking)[:, 0]
    assert rel(r1[nz] / eta_o**2, r2[nz] / eta_i**2).max() <= 1e-9
    # ... and the ones that do not: plain symmetry is off by eta^2, the inverted form by eta^4
    np.testing.assert_allclose(f1[nz] / f2[nz], (eta_o / eta_i) ** 2, rtol=1e-9)
    assert np.all(rel(f1[nz] * eta_o**2, f2[nz] * eta_i**2) > 0.1)


# ---------------------------------------------------------------------------------------------
# Gradients vs central finite differences (float64)
# ---------------------------------------------------------------------------------------------
FD_RTOL = 1e-5


def central_fd(fn, x, h):
    """Central differences of fn (returning an array) w.r.t. each entry of x (same leading shape)."""
    x = np.asarray(x, float)
    out = []
    for idx in np.ndindex(x.shape):
        xp, xm = x.copy(), x.copy()
        xp[idx] += h
        xm[idx] -= h
        out.append((np.asarray(fn(xp), float) - np.asarray(fn(xm), float)) / (2 * h))
    return np.stack(out, axis=-1).reshape(np.shape(out[0]) + x.shape)


def check_param_grad(loss, x, name, h_rel=1e-6):
    """jax.grad of a scalar loss w.r.t. a parameter array x against central differences."""
    x = np.asarray(x, float)
    g = np.asarray(jax.grad(lambda p: loss(p))(j(x)))
    assert np.all(np.isfinite(g)), f"d/d{name}: non-finite gradient {g}"
    h = h_rel * max(1.0, float(np.abs(x).max()))
    fd = central_fd(lambda p: loss(j(p)), x, h)
    err = np.abs(g - fd).max() / max(np.abs(fd).max(), 1e-300)
    assert err <= FD_RTOL, f"d/d{name}: grad {g} vs FD {fd} (rel err {err:.2e})"
    return g


def check_dir_grad(per_point, w, name, h=1e-6):
    """Per-point gradient of per_point(w) (shape (n,)) w.r.t. raw direction vectors w (n, 3)."""
    w = np.asarray(w, float)
    g = np.asarray(jax.grad(lambda v: per_point(v).sum())(j(w)))
    assert np.all(np.isfinite(g)), f"d/d{name}: non-finite gradient"
    fd = np.zeros_like(w)
    for c in range(3):
        d = np.zeros_like(w)
        d[:, c] = h
        fd[:, c] = (np.asarray(per_point(j(w + d))) - np.asarray(per_point(j(w - d)))) / (2 * h)
    scale = np.abs(fd).max(axis=-1)  # (not the 2-norm: squares of tiny values underflow)
    err = np.abs(g - fd).max(axis=-1) / np.maximum(scale, 1e-300)
    err = np.where(np.abs(g - fd).max(axis=-1) == 0, 0, err)
    i = int(np.argmax(err))
    assert err[i] <= FD_RTOL, f"d/d{name}[{i}]: grad {g[i]} vs FD {fd[i]} (rel err {err[i]:.2e}) at {name}={w[i]}"


def smooth_conductor_points(rng, n=40):
    """Upper-hemisphere pairs away from the horizon (no discontinuity of the conductor BRDF there)."""
    return R.random_directions(rng, n, "upper", 0.15), R.random_directions(rng, n, "upper", 0.15)


def smooth_dielectric_points(rng, eta, dist, n=40):
    """Pairs whose generalized half vector is well inside the valid region and away from the
    critical angle (where F has a square-root kink and 1 - F a corner)."""
    wo = R.random_directions(rng, 25 * n, "both", 0.15)
    wi = R.random_directions(rng, 25 * n, "both", 0.15)
    co, ci = wo[:, 2], wi[:, 2]
    etap = np.where(co * ci > 0, 1.0, np.where(co > 0, eta, 1 / eta))
    m = etap[:, None] * wi + wo
    hn = np.linalg.norm(m, axis=-1)
    m /= hn[:, None]
    m = np.where(m[:, 2:3] < 0, -m, m)
    wom, wim = np.sum(wo * m, -1), np.sum(wi * m, -1)
    e = np.where(wom < 0, 1 / eta, eta)
    s2t = (1 - wom**2) / e**2
    f = R.dielectric_eval(wo, wi, dist, eta)[:, 0]
    ok = (hn > 0.2) & (wom * co > 0.1) & (wim * ci > 0.1) & (np.abs(s2t - 1) > 0.05) & (f > 1e-8)
    ok &= m[:, 2] > 0.15
    wo, wi = wo[ok], wi[ok]
    refl = wo[:, 2] * wi[:, 2] > 0
    # balance reflection and transmission
    k = min(n // 2, int(refl.sum()), int((~refl).sum()))
    assert k >= 8
    return np.concatenate([wo[refl][:k], wo[~refl][:k]]), np.concatenate([wi[refl][:k], wi[~refl][:k]])


def test_lambert_gradients(x64, rng):
    from matfit.models import Lambert

    wo, wi = smooth_conductor_points(rng)
    albedo = np.array([0.2, 0.5, 0.9])
    g = check_param_grad(lambda a: Lambert(a).eval(j(wo), j(wi)).sum(), albedo, "albedo")
    np.testing.assert_allclose(g, len(wo) / np.pi, rtol=1e-12)


@pytest.mark.parametrize("alpha_y", [None, 0.2], ids=["iso", "aniso"])
@pytest.mark.parametrize("masking", MASKINGS)
@pytest.mark.parametrize("kind", KINDS)
def test_rough_conductor_gradients(kind, masking, alpha_y, x64, rng):
    from matfit.models import RoughConductor

    wo, wi = smooth_conductor_points(rng)
    alpha, eta, k = 0.35, np.array(GOLD_ETA), np.array(GOLD_K)

    def make(alpha=alpha, eta=eta, k=k, alpha_y=alpha_y):
        conv = lambda x: x if isinstance(x, jax.Array) else j(x)
        return RoughConductor(conv(alpha), conv(eta), conv(k), distribution=kind, masking=masking,
                              alpha_y=None if alpha_y is None else conv(alpha_y))

    W0, W1 = j(wo), j(wi)
    check_param_grad(lambda a: make(alpha=a).eval(W0, W1).sum(), alpha, "alpha")
    if alpha_y is not None:
        check_param_grad(lambda a: make(alpha_y=a).eval(W0, W1).sum(), alpha_y, "alpha_y")
    check_param_grad(lambda e: make(eta=e).eval(W0, W1).sum(), eta, "eta")
    check_param_grad(lambda kk: make(k=kk).eval(W0, W1).sum(), k, "k")
    model = make()
    check_dir_grad(lambda v: model.eval(v, W1).sum(-1), wo, "wo")
    check_dir_grad(lambda v: model.eval(W0, v).sum(-1), wi, "wi")


@pytest.mark.parametrize("eta", [1.5, 0.67])
@pytest.mark.parametrize("alpha_y", [None, 0.2], ids=["iso", "aniso"])
@pytest.mark.parametrize("masking", MASKINGS)
@pytest.mark.parametrize("kind", KINDS)
def test_rough_dielectric_gradients(kind, masking, alpha_y, eta, x64, rng):
    from matfit.models import RoughDielectric

    alpha = 0.35
    wo, wi = smooth_dielectric_points(rng, eta, R.Dist(kind, alpha, alpha_y))

    def make(alpha=alpha, eta=eta, alpha_y=alpha_y):
        conv = lambda x: x if isinstance(x, jax.Array) else j(x)
        return RoughDielectric(conv(alpha), conv(eta), distribution=kind, masking=masking,
                               alpha_y=None if alpha_y is None else conv(alpha_y))

    W0, W1 = j(wo), j(wi)
    check_param_grad(lambda a: make(alpha=a).eval(W0, W1).sum(), alpha, "alpha")
    if alpha_y is not None:
        check_param_grad(lambda a: make(alpha_y=a).eval(W0, W1).sum(), alpha_y, "alpha_y")
    check_param_grad(lambda e: make(eta=e).eval(W0, W1).sum(), eta, "eta")
    model = make()
    check_dir_grad(lambda v: model.eval(v, W1)[..., 0], wo, "wo")
    check_dir_grad(lambda v: model.eval(W0, v)[..., 0], wi, "wi")


# Special configurations where the value is 0 or a formula has a removable singularity: the
# gradients must still be finite (no NaN leaking through a `where`).
SPECIAL_PAIRS = [
    ([0, 0, 1], [0, 0, 1]),  # normal incidence, h = n (Blinn-Phong's phi is undefined there)
    ([0.6, 0, 0.8], [-0.6, 0, 0.8]),  # mirror configuration, h = n
    ([0.6, 0, 0.8], [0.0, 0.6, -0.8]),  # one direction below the surface
    ([0, 0, 1], [0, 0, -1]),  # straight through
    ([0, 0, -1], [0, 0, -1]),  # inside, normal
    ([0.8, 0, -0.6], [-0.8, 0, -0.6]),  # inside mirror configuration (TIR at eta = 1.5)
    ([1.0, 0, 0.0], [0.0, 0, 1.0]),  # grazing wo
]


@pytest.mark.parametrize("kind", KINDS)
def test_gradients_finite_at_special_points(kind, x64):
    from matfit.models import Lambert, RoughConductor, RoughDielectric

    wo = j([p[0] for p in SPECIAL_PAIRS])
    wi = j([p[1] for p in SPECIAL_PAIRS])
    for masking in MASKINGS:
        builders = {
            "Lambert": (lambda p: Lambert(p[0] * jnp.ones(3)), j([0.5])),
            "RoughConductor": (lambda p: RoughConductor(p[0], p[1] * jnp.asarray(GOLD_ETA), p[2] * jnp.asarray(GOLD_K),
                                                         distribution=kind, masking=masking, alpha_y=p[3]), j([0.3, 1, 1, 0.2])),
            "RoughDielectric": (lambda p: RoughDielectric(p[0], p[1], distribution=kind, masking=masking, alpha_y=p[2]),
                                j([0.3, 1.5, 0.2])),
        }
        for name, (build, p0) in builders.items():
            val = build(p0).eval(wo, wi)
            assert np.all(np.isfinite(np.asarray(val))), f"{name}.eval not finite: {val}"
            gp = jax.grad(lambda p: build(p).eval(wo, wi).sum())(p0)
            assert np.all(np.isfinite(np.asarray(gp))), f"{name}({kind}, {masking}): d/dparams not finite: {gp}"
            gwo, gwi = jax.grad(lambda a, b: build(p0).eval(a, b).sum(), argnums=(0, 1))(wo, wi)
            bad = ~np.all(np.isfinite(np.asarray(gwo)), -1) | ~np.all(np.isfinite(np.asarray(gwi)), -1)
            assert not bad.any(), (
                f"{name}({kind}, {masking}): d/dwo or d/dwi not finite at pairs "
                f"{[SPECIAL_PAIRS[i] for i in np.flatnonzero(bad)]}"
            )
