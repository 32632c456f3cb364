"""Checks moved from the docstring examples of matfit.fitting's lm, params, methods, losses,
_result and _compose modules (small and fast: no fits, tiny arrays)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from matfit.fitting.lm import LevenbergMarquardtFD, half_sq, jacobian, normal_equations, widen


# -- lm ----------------------------------------------------------------------------------------------

@pytest.mark.check
def test_widen_is_float64_only_with_x64():
    want = jnp.float64 if jax.config.read("jax_enable_x64") else jnp.float32
    assert widen(jnp.ones(2, jnp.float32)).dtype == want


def test_normal_equations_of_a_linear_model():
    x = jnp.linspace(0.0, 1.0, 5)
    F, A, g, r = normal_equations(lambda z, x: (z[0] * x)[:, None], jnp.array([1.0]), x, np.eye(1), np.ones((1, 1)))
    assert abs(A[0, 0] - 1.875) < 1e-3 and abs(g[0] - 1.875) < 1e-3  # both sum(x^2), to rounding


def test_half_sq_of_channel_split_residuals():
    assert float(half_sq((jnp.array([1.0, 2.0]), jnp.array([2.0])))) == 4.5


def test_jacobian_materialized():
    r, J = jacobian(lambda z, a: (z[0] * a)[:, None], jnp.array([2.0]), jnp.array([1.0, 3.0]), np.eye(1), np.ones((1, 1)))
    assert J.shape == (2, 1, 1)
    np.testing.assert_allclose(np.asarray(J[:, 0, 0]), [1.0, 3.0], atol=1e-4)


def test_grouped_differences_central_and_evaluations():
    assert LevenbergMarquardtFD(1e-8, 1e-10, central=True).is_central(jnp.float64)
    assert LevenbergMarquardtFD(1e-8, 1e-10).evaluations(3, jnp.float32) == 6  # central in float32: two per group


def test_nielsen_damping_accepted_and_rejected_updates():
    solver = LevenbergMarquardtFD(1e-8, 1e-10)
    mu, nu = solver._damping(jnp.asarray(1.0), jnp.asarray(2.0), jnp.asarray(True), jnp.asarray(1.0))
    assert float(mu) == pytest.approx(1 / 3) and float(nu) == 2.0
    mu, nu = solver._damping(jnp.asarray(1.0), jnp.asarray(2.0), jnp.asarray(False), jnp.asarray(0.0))
    assert float(mu) == 2.0 and float(nu) == 4.0  # rejected: mu <- mu nu, nu <- 2 nu


def test_boxed_step_caps_each_coordinate():
    d = LevenbergMarquardtFD(1e-8, 1e-10, max_step=1.0)._step(jnp.eye(2), jnp.asarray(0.0), jnp.ones(2),
                                                              jnp.array([-5.0, 0.5]))
    np.testing.assert_allclose(np.asarray(d), [1.0, -0.5], atol=1e-12)


def test_a_start_at_the_minimum_stops_without_a_step():
    res = LevenbergMarquardtFD(1e-8, 1e-10).minimise(lambda z, a: (z - a)[None, :], jnp.ones(2), jnp.ones(2),
                                                     np.eye(2), np.ones((2, 2)))
    assert bool(res.converged) and int(res.steps) == 0 and int(res.evals) == 3  # the start and its Jacobian


def test_minimise_shifted_identity():
    solver = LevenbergMarquardtFD(1e-8, 1e-10)
    res = solver.minimise(lambda z, a: (z - a)[None, :], jnp.zeros(2), jnp.array([1.0, -1.0]), np.eye(2), np.ones((2, 2)))
    np.testing.assert_allclose(np.asarray(res.z), [1.0, -1.0], atol=1e-6)


# -- params ------------------------------------------------------------------------------------------

def test_param_maps_at_the_middle_of_a_unit_range():
    from matfit.fitting import Param

    p = Param("albedo", 0.0, 1.0)
    assert float(p.to_unconstrained(0.5)) == 0.0 and float(p.from_unconstrained(0.0)) == 0.5
    assert float(np.exp(p.log_jacobian(0.0))) == pytest.approx(0.25)  # sigmoid'(0)


def test_family_generic_start_truth_and_lookup():
    from matfit.fitting import TruthMap, family_describing, get_family

    assert TruthMap("Lambert").matches({"model": "Lambert", "albedo": 0.5})
    assert get_family("conductor").generic_start({"alpha": 0.05, "eta": 0.2, "k": 4.0}) == {"alpha": 0.2, "eta": 1.0, "k": 3.0}
    assert get_family("conductor_beckmann").describes({"model": "RoughConductor", "distribution": "beckmann"})
    assert family_describing({"model": "Blend"}) is None
    assert [p.name for p in get_family("plastic").params] == ["albedo", "alpha", "eta"]


def test_check_solver_options_names_the_option():
    from matfit.errors import ParameterError
    from matfit.fitting.params import check_solver_options

    check_solver_options("fit", starts=2, max_steps=10)
    with pytest.raises(ParameterError, match=r"^fit: starts must be an integer >= 1, got 0$"):
        check_solver_options("fit", starts=0)


def test_parametrization_layout_and_maps():
    from matfit.fitting import Parametrization

    par = Parametrization("plastic", 3, fixed={"eta": 1.5})
    assert par.check_value("init", "alpha", 0.3) == 0.3 and par.check_theta("init", {"alpha": 0.2}) is None
    assert [a.tolist() for a in par.lower_upper()] == [[0.0, 0.0, 0.0, 0.001], [1.0, 1.0, 1.0, 1.5]]
    assert Parametrization("conductor", 1).physical_bounds().tolist() == [[False, False], [False, False], [True, False]]
    assert {k: v.tolist() for k, v in par.split(np.array([0.1, 0.2, 0.3, 0.4])).items()} == {
        "albedo": [0.1, 0.2, 0.3], "alpha": 0.4}
    z = par.z_from_theta({"albedo": 0.5, "alpha": 0.3})
    assert z.shape == (4,) and float(par.theta(z)["alpha"]) == pytest.approx(0.3)
    np.testing.assert_allclose(np.asarray(par.theta_vector(z)), [0.5, 0.5, 0.5, 0.3], atol=1e-6)
    np.testing.assert_allclose(np.asarray(par.theta_vector(par.z_vector([0.5, 0.2, 0.9, 0.3]))), [0.5, 0.2, 0.9, 0.3],
                               atol=1e-6)
    assert float(par.log_jacobian(np.zeros(4))) == pytest.approx(3 * np.log(0.25) + np.log(1.499 / 4), abs=1e-4)
    assert round(float(par.log_jacobian(np.zeros(4))), 4) == -5.1404
    full = par.full({"albedo": 0.5, "alpha": 0.3})
    assert float(full["eta"]) == 1.5 and full["albedo"].shape == (3,)
    assert type(par.model(z)).__name__ == "Plastic"


# -- methods -----------------------------------------------------------------------------------------

def test_method_registry_builds():
    from matfit.fitting.methods import get_method

    assert type(get_method("dogleg").build(1e-6, 1e-9)).__name__ == "OptimistixLeastSquares"
    assert get_method("lm_fd").residuals == "channels"


def test_solver_solve_and_trace():
    from matfit.fitting.methods import METHODS

    sol = METHODS["lm"].build(1e-8, 1e-10, 50).solve(lambda z, a: z - a, jnp.zeros(2), jnp.ones(2))
    np.testing.assert_allclose(np.asarray(sol.z), [1.0, 1.0], atol=1e-6)
    seen = []
    F = METHODS["gn"].build(1e-8, 1e-10, 20).trace(lambda z, a: z - a, jnp.zeros(1), jnp.ones(1),
                                               lambda n, v: seen.append(v))
    assert float(F) < 1e-12 and len(seen) > 0


# -- losses ------------------------------------------------------------------------------------------

def test_check_loss_names_the_choices():
    from matfit.errors import ParameterError
    from matfit.fitting.losses import check_loss

    check_loss("e2", "huber")
    with pytest.raises(ParameterError) as e:
        check_loss("l1", None)
    assert str(e.value) == "loss must be one of ['l2', 'e2', 'cbrt', 'cosine', 'relative'], got 'l1'"


def test_prepared_targets_and_robust_residuals():
    from matfit.fitting.losses import prepare_targets, residuals, residuals_from_targets

    assert float(residuals(jnp.array([[2.0]]), jnp.array([[1.0]]), jnp.array([[0.0]]), jnp.array([1.0]))[0, 0]) == 0.0
    t, f = prepare_targets(jnp.array([[1.0]]), jnp.array([[4.0]]), jnp.array([0.5]), "cosine")
    assert (float(t[0, 0]), float(f[0, 0])) == (1.0, 1.0)  # sqrt(4) x cos 0.5
    t, f = prepare_targets(jnp.array([[1.0]]), jnp.array([[4.0]]), jnp.array([1.0]))
    assert float(residuals_from_targets(jnp.array([[2.0]]), t, f, jnp.array([1.0]))[0, 0]) == 2.0
    huber = residuals_from_targets(jnp.array([[2.0]]), t, f, jnp.array([1.0]), robust="huber")
    assert round(float(huber[0, 0]), 4) == 1.8897  # sqrt(2 x 1.345 (2 - 1.345 / 2))


# -- _result -----------------------------------------------------------------------------------------

def test_fit_result_summary_first_line():
    from matfit.fitting import FitResult

    e = np.zeros((1, 1))
    r = FitResult("lambert", "lm_fd", "l2", {}, ["albedo"], np.array([0.3]), np.array([0.01]), e, e, 0.5, 1.0, 9, 8, 3,
                  True, 0.1, np.array([0.5]), None)
    lines = r.summary().splitlines()
    assert lines[0] == "lambert fit (lm_fd, l2): objective 0.5, 3 steps, converged=True, 0.10 s"
    assert lines[1].startswith("  albedo         = 0.3 +- 0.01")


# -- _compose ----------------------------------------------------------------------------------------

def test_lobe_layouts():
    from matfit.fitting._compose import Lobe, lobe_layout

    assert [s.name for s in lobe_layout("lambert", (Lobe(), Lobe()), "channels", True, ("f0",), ())] == [
        "albedo", "alpha_1", "ks_1", "f0", "ratio_2", "ks_2"]
    assert [s.name for s in lobe_layout(None, (Lobe(fresnel="conductor"),) * 2, "mixture", True, ("eta", "k"), ())] == [
        "alpha_1", "eta", "k", "ratio_2", "mix_2"]


def test_lobe_spec_names_widths_weights_and_build():
    from matfit.fitting import get_family

    spec = get_family("lobes2").build
    assert type(spec).__name__ == "LobeSpec" and type(get_family("lobes2").refine).__name__ == "LobeRefine"
    assert spec.lobe_names(1) == {"width": "ratio_2", "ks": "ks_2", "f0": "f0"}
    widths = get_family("lobes3").build.widths({"alpha_1": 0.05, "ratio_2": 4.0, "ratio_3": 2.0})
    np.testing.assert_allclose([float(a) for a in widths], [0.05, 0.2, 0.4], rtol=1e-6)
    np.testing.assert_allclose([float(w) for w in get_family("metal2").build.lobe_weights({"mix_2": 0.25})], [0.75, 0.25])
    m = get_family("lobes1").build({"albedo": 0.5, "alpha_1": 0.1, "ks_1": 0.9, "f0": 0.04}, 1)
    assert type(m).__name__ == "MultiLobe" and len(m.lobes) == 1


def test_lobe_refine_reads_a_lambertian_level():
    from matfit import Table
    from matfit.fitting import Parametrization, initial_guess

    wo = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, 0.6, 0.8], [0.0, -0.6, 0.8]])
    t = Table(wo=wo, wi=wo[[0, 3, 1, 2]], values=np.full((4, 3), 0.3 / np.pi))
    g = initial_guess(t, Parametrization("lobes1", 3))
    assert [round(float(a), 2) for a in g["albedo"]] == [0.3, 0.3, 0.3]
