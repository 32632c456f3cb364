"""Helmholtz reciprocity (and its generalized form for refraction) and gradients vs finite differences.

Generalized reciprocity of the rough dielectric's transmission, verified numerically (reference and
library): with the pbrt-v4 radiance BTDF (divided by etap^2),

    f_t(wo, wi) / eta_o^2 == f_t(wi, wo) / eta_i^2,

eta_o (eta_i) being the index of the medium wo (wi) lies in: 1 outside, eta inside. The other
candidate, f_t(wo, wi) * eta_o^2 == f_t(wi, wo) * eta_i^2, is violated by a factor eta^4, and plain
symmetry f_t(wo, wi) == f_t(wi, wo) by a factor eta^2 (asserted below).
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import catalogue as C
import numpy_ref as R

N = 120


def j(x):
    return jnp.asarray(np.asarray(x, np.float64))


def rel(a, b):
    return R.rel_err(a, b, 1e-280)


# ---------------------------------------------------------------------------------------------
# Reciprocity
# ---------------------------------------------------------------------------------------------
def test_lambert_reciprocity(x64, rng):
    from matfit.models import Lambert

    wo, wi = R.random_directions(rng, N, "both", 0.01), R.random_directions(rng, N, "both", 0.01)
    model = Lambert(j([0.2, 0.5, 0.9]))
    np.testing.assert_array_equal(np.asarray(model.eval(j(wo), j(wi))), np.asarray(model.eval(j(wi), j(wo))))


RECIPROCITY_LOBES = C.lobe_params(alphas=((0.4, None), (0.4, 0.15)))


@pytest.mark.check
@pytest.mark.parametrize("lobe", RECIPROCITY_LOBES)
def test_rough_conductor_reciprocity(lobe, x64, rng):
    wo, wi = C.random_pairs(rng, N, 0.01)
    model = C.rough_conductor(lobe)
    f1, f2 = np.asarray(model.eval(j(wo), j(wi))), np.asarray(model.eval(j(wi), j(wo)))
    assert np.count_nonzero(f1) > N
    assert rel(f1, f2).max() <= 1e-10


@pytest.mark.parametrize("eta", [1.5, 0.67])
@pytest.mark.parametrize("lobe", RECIPROCITY_LOBES)
def test_rough_dielectric_reciprocity(lobe, eta, x64, rng):
    model = C.rough_dielectric(lobe, eta)
    ref = lobe.ref()
    masking = lobe.masking
    # reflection, from outside and from inside
    for hemi in ["upper", "lower"]:
        wo, wi = C.random_pairs(rng, N, 0.01, hemi)
        f1, f2 = np.asarray(model.eval(j(wo), j(wi))), np.asarray(model.eval(j(wi), j(wo)))
        assert np.count_nonzero(f1) > N // 2
        assert rel(f1, f2).max() <= 1e-10, f"reflection reciprocity ({hemi})"
    # transmission: wo outside (eta_o = 1), wi inside (eta_i = eta)
    wo, wi = R.random_directions(rng, 4 * N, "upper", 0.01), R.random_directions(rng, 4 * N, "lower", 0.01)
    f1, f2 = np.asarray(model.eval(j(wo), j(wi)))[:, 0], np.asarray(model.eval(j(wi), j(wo)))[:, 0]
    np.testing.assert_array_equal(f1 > 0, f2 > 0)
    # Skip values in the subnormal range and pairs within |sin^2 theta_t - 1| < 1e-3 of the critical
    # angle, where 1 - F evaluated from the inside (for the reversed pair) is ill-conditioned.
    s2_outside, m = C.sin2_transmitted(wo, wi, eta)  # wo outside: (1 - c^2)/eta^2 seen from the other side
    s2_inside = eta**2 * (1 - np.sum(wi * m, -1) ** 2)
    nz = (f1 > 1e-250) & (np.abs(s2_inside - 1) > 1e-3) & (np.abs(s2_outside - 1) > 1e-3)
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


def check_model_gradients(cls, lobe, params, wo, wi):
    """Gradients of ``sum(eval)`` of ``cls(**params, <lobe's options>)`` w.r.t. every parameter
    (alpha_y too when the lobe is anisotropic) and, per point, w.r.t. wo and wi, against central
    differences."""
    params = dict(params, alpha=lobe.alpha, alpha_y=lobe.alpha_y)
    options = dict(distribution=lobe.dist, masking=lobe.masking)

    def make(**over):
        p = {k: (v if isinstance(v, jax.Array) or v is None else j(v)) for k, v in {**params, **over}.items()}
        return cls(**p, **options)

    W0, W1 = j(wo), j(wi)
    for name, x in params.items():
        if x is not None:
            check_param_grad(lambda v, name=name: make(**{name: v}).eval(W0, W1).sum(), x, name)
    model = make()
    check_dir_grad(lambda v: model.eval(v, W1).sum(-1), wo, "wo")
    check_dir_grad(lambda v: model.eval(W0, v).sum(-1), wi, "wi")


def test_lambert_gradients(x64, rng):
    from matfit.models import Lambert

    wo, wi = C.random_pairs(rng, 40)
    albedo = np.array([0.2, 0.5, 0.9])
    g = check_param_grad(lambda a: Lambert(a).eval(j(wo), j(wi)).sum(), albedo, "albedo")
    np.testing.assert_allclose(g, len(wo) / np.pi, rtol=1e-12)


GRADIENT_LOBES = C.lobe_params(alphas=((0.35, None), (0.35, 0.2)))


@pytest.mark.parametrize("lobe", GRADIENT_LOBES)
def test_rough_conductor_gradients(lobe, x64, rng):
    from matfit.models import RoughConductor

    wo, wi = C.random_pairs(rng, 40)
    check_model_gradients(RoughConductor, lobe, dict(eta=np.array(C.GOLD_ETA), k=np.array(C.GOLD_K)), wo, wi)


@pytest.mark.parametrize("eta", [1.5, 0.67])
@pytest.mark.parametrize("lobe", GRADIENT_LOBES)
def test_rough_dielectric_gradients(lobe, eta, x64, rng):
    from matfit.models import RoughDielectric

    wo, wi = C.smooth_dielectric_pairs(rng, eta, lobe.ref())
    check_model_gradients(RoughDielectric, lobe, dict(eta=eta), wo, wi)


# Special configurations where the value is 0 or a formula has a removable singularity (the
# catalogue's SPECIAL_PAIRS): the gradients must still be finite (no NaN leaking through a `where`).
# (The layered models' gradients at such pairs: tests/test_layered.py, test_gradients_finite_edges;
# the delta models': tests/test_hard_cases.py, test_delta_models_eval_pdf_zero.)
@pytest.mark.parametrize("case", C.model_params())
def test_gradients_finite_at_special_points(case, x64):
    wo, wi = (j(x) for x in C.special_pairs())
    model = case.build(np.float64)
    val = model.eval(wo, wi)
    assert np.all(np.isfinite(np.asarray(val))), f"{case.id}.eval not finite: {val}"
    params, static = eqx.partition(model, eqx.is_inexact_array)
    gp = jax.grad(lambda p: eqx.combine(p, static).eval(wo, wi).sum())(params)
    for path, leaf in jax.tree_util.tree_flatten_with_path(gp)[0]:
        assert np.all(np.isfinite(np.asarray(leaf))), f"{case.id}: d/d{jax.tree_util.keystr(path)} not finite: {leaf}"
    gwo, gwi = jax.grad(lambda a, b: model.eval(a, b).sum(), argnums=(0, 1))(wo, wi)
    bad = ~np.all(np.isfinite(np.asarray(gwo)), -1) | ~np.all(np.isfinite(np.asarray(gwi)), -1)
    assert not bad.any(), (
        f"{case.id}: d/dwo or d/dwi not finite at pairs {[C.SPECIAL_PAIRS[i] for i in np.flatnonzero(bad)]}"
    )
