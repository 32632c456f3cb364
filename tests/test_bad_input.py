"""Bad input at the public entry points: each case raises a clear matfit error naming the argument.

Cases already held by other test files (readers, Table, scenes, CLI, sample_posterior) are listed
in docs/robustness.md; this file holds the rest. Every error here is raised before any JAX
compilation, except the two jit checks, which compile one tiny Lambert evaluation.
"""

import re

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

from matfit.errors import MatfitError, ParameterError
from matfit.fitting import FAMILIES, Parametrization, fit, fit_batch, residuals, robust_fit
from matfit.models import (Blend, Lambert, Layered, Plastic, RoughConductor, RoughDielectric, SmoothConductor,
                           SmoothDielectric)
from matfit.table import Table

Z = np.array([0.0, 0.0, 1.0])
W45 = np.array([np.sqrt(0.5), 0.0, np.sqrt(0.5)])


def raises(exc, *needles):
    """pytest.raises checking the type is a MatfitError and every needle is in the message."""
    return pytest.raises(exc, match=".*".join(re.escape(n) for n in needles))


@pytest.fixture(scope="module")
def mono():
    rng = np.random.default_rng(0)
    wi = rng.normal(size=(12, 3))
    wi[:, 2] = np.abs(wi[:, 2])
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    return Table(wo=np.tile(Z, (12, 1)), wi=wi, values=np.full((12, 1), 0.1), channels="mono")


# ----------------------------------------------------------------------------------------- model parameters
@pytest.mark.parametrize("value, dtype", [
    ("red", "<U3"), (0.5 + 1j, "complex128"), (True, "bool"), (np.array([0.5, None], dtype=object), "object"),
])
def test_model_parameter_dtype(value, dtype):
    with raises(ParameterError, "Lambert: parameter 'albedo' must be real numbers", f"found dtype {dtype}"):
        Lambert(value)


@pytest.mark.parametrize("make, needle", [
    (lambda: RoughConductor(0.1, 1.5 + 0.1j, 2.0), "RoughConductor: parameter 'eta' must be real numbers"),
    (lambda: RoughDielectric("0.1", 1.5), "RoughDielectric: parameter 'alpha' must be real numbers"),
    (lambda: SmoothConductor(1.5, np.array(["2"])), "SmoothConductor: parameter 'k' must be real numbers"),
    (lambda: SmoothDielectric(1.5j), "SmoothDielectric: parameter 'eta' must be real numbers"),
    (lambda: Plastic(0.5, 0.1, True), "Plastic: parameter 'eta' must be real numbers"),
    (lambda: Blend(Lambert(0.2), Lambert(0.3), 0.5j), "Blend: parameter 'weight' must be real numbers"),
    (lambda: Layered(SmoothDielectric(1.5), Lambert(0.3), thickness="1"),
     "Layered: parameter 'thickness' must be real numbers"),
])
def test_model_parameter_dtype_every_model(make, needle):
    with raises(ParameterError, needle):
        make()


# ----------------------------------------------------------------------------------------- directions and u
@pytest.mark.parametrize("wo, needle", [
    (np.array([0.0, 0.0, 2.0]), "Lambert.eval: wo must be unit vectors (|norm - 1| <= 0.0001), found norm 2"),
    (np.zeros(3), "Lambert.eval: wo must be unit vectors (|norm - 1| <= 0.0001), found norm 0"),
    (np.array([[0.0, 0.0, 1.0], [0.0, 0.0, np.nan]]), "Lambert.eval: wo must be finite, found nan at index (1, 2)"),
    (np.array([0.0, 0.0, 1.0 + 0j]), "Lambert.eval: wo must be real numbers (integer or floating dtype), "
                                     "found dtype complex128"),
    (np.array(["0", "0", "1"]), "Lambert.eval: wo must be real numbers"),
    ([0.0, 0.0, 1.0], "Lambert.eval: wo must be an array (numpy or JAX) of shape (..., 3), found list"),
    (np.zeros(2), "Lambert.eval: wo must have shape (..., 3), found (2,)"),
    (np.tile(Z, (3, 1)), "Lambert.eval: direction batch shapes do not broadcast: wo (3, 3), wi (4, 3)"),
])
def test_eval_directions(wo, needle):
    wi = np.tile(Z, (4, 1)) if np.shape(wo) == (3, 3) else Z
    with raises(ParameterError, needle):
        Lambert(0.5).eval(wo, wi)


def test_direction_tolerance_follows_dtype():
    """float32 directions normalized in float32 pass; a 1e-3 error does not (any dtype)."""
    w = (W45 + 1e-7).astype(np.float32)
    w /= np.linalg.norm(w)
    Lambert(0.5).eval(w, Z.astype(np.float32))
    with raises(ParameterError, "RoughConductor.pdf: wi must be unit vectors"):
        RoughConductor(0.3, 1.5, 2.0).pdf(Z, W45 * 1.001)


@pytest.mark.parametrize("model", [Lambert(0.5), SmoothConductor(1.5, 2.0), Plastic(0.5, 0.2, 1.5)],
                         ids=lambda m: type(m).__name__)
@pytest.mark.parametrize("u, needle", [
    (np.array([1.5, 0.5, 0.5]), "u must be uniform numbers in [0, 1), found 1.5 at index (0,)"),
    (np.array([0.5, np.nan, 0.5]), "u must be uniform numbers in [0, 1), found nan at index (1,)"),
    (np.array([0.5, 0.5]), "u must have shape (..., 3)"),
])
def test_sample_u(model, u, needle):
    with raises(ParameterError, f"{type(model).__name__}.sample: {needle}"):
        model.sample(W45, u)


def test_sample_wo_checked():
    with raises(ParameterError, "RoughDielectric.sample: wo must be unit vectors"):
        RoughDielectric(0.3, 1.5).sample(2 * W45, np.full(3, 0.5))


def test_values_unchecked_under_jit_shapes_checked():
    """Traced directions cannot raise on their values: jit evaluates, and shape errors still raise."""
    m = Lambert(0.5)
    f = eqx.filter_jit(lambda m, wo, wi: m.eval(wo, wi))
    wo = jnp.asarray(np.tile(W45, (2, 1)))
    np.testing.assert_allclose(f(m, wo, wo), 0.5 / np.pi, rtol=1e-6)
    np.testing.assert_allclose(f(m, 2 * wo, wo), 0.5 / np.pi, rtol=1e-6)  # no value check inside jit
    with raises(ParameterError, "Lambert.eval: wo must have shape (..., 3), found (2, 2)"):
        f(m, wo[:, :2], wo)


def test_composite_models_pass_masked_directions_to_components():
    """Layered/Blend evaluate components on masked, non-unit refracted directions; only the
    outermost call is checked, so eager evaluation of a stack works on any valid input."""
    rng = np.random.default_rng(3)
    v = rng.normal(size=(8, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    wo = np.abs(v)
    wi = np.roll(v, 1, axis=0)  # both hemispheres
    lay = Layered(RoughDielectric(0.2, 1.5), Lambert(0.5))
    m = Blend(lay, RoughConductor(0.3, 1.5, 2.0), 0.4)
    assert np.isfinite(np.asarray(m.eval(wo, wi))).all()
    assert np.isfinite(np.asarray(m.pdf(wo, wi))).all()
    wi_s, _, _ = m.sample(wo, rng.uniform(size=(8, 3)))
    assert np.isfinite(np.asarray(wi_s)).all()
    with raises(ParameterError, "Blend.eval: wi must be unit vectors"):
        m.eval(wo, 1.5 * wi)


# ----------------------------------------------------------------------------------------- Parametrization
@pytest.mark.parametrize("kw, needle", [
    (dict(fixed={"eta": np.nan}), "fixed eta=nan: expected finite values"),
    (dict(fixed={"eta": "abc"}), "fixed eta='abc': expected real numbers, found dtype <U3"),
    (dict(fixed={"eta": 1.5 + 1j}), "fixed eta=(1.5+1j): expected real numbers, found dtype complex128"),
    (dict(fixed={"albedo": [0.1, 0.2]}), "fixed albedo=[0.1, 0.2]: expected a scalar or 3 values (one per "
                                         "channel), found shape (2,)"),
    (dict(fixed={"eta": [1.5, 1.6, 1.7]}), "fixed eta=[1.5, 1.6, 1.7]: expected a scalar, found shape (3,)"),
    (dict(fixed={"eta": 5.0}), "fixed eta=5.0 is outside its range [1.05, 3.0]"),
    (dict(fixed=[("eta", 1.5)]), "fixed must be a dict of parameter values, got list"),
    (dict(tied="albedo"), "tied must be a sequence of parameter names, got the string 'albedo'"),
    (dict(channels=0), "channels must be a positive integer, got 0"),
    (dict(channels=2.5), "channels must be a positive integer, got 2.5"),
    (dict(family=3), "model must be a family name (str) or a Family, got int"),
    (dict(family="phong"), f"model must be one of {sorted(FAMILIES)}, got 'phong'"),
])
def test_parametrization(kw, needle):
    args = {"family": "plastic", "channels": 3, **kw}
    with raises(ParameterError, needle):
        Parametrization(args.pop("family"), args.pop("channels"), **args)


# ----------------------------------------------------------------------------------------- fit / fit_batch / robust_fit
@pytest.mark.parametrize("kw, needle", [
    (dict(starts=0), "fit: starts must be an integer >= 1, got 0"),
    (dict(starts=1.5), "fit: starts must be an integer >= 1, got 1.5"),
    (dict(max_steps=0), "fit: max_steps must be an integer >= 1, got 0"),
    (dict(rtol=-1.0), "fit: rtol must be a finite number >= 0, got -1.0"),
    (dict(atol=np.nan), "fit: atol must be a finite number >= 0, got nan"),
    (dict(robust="huber", robust_scale=0.0), "fit: robust_scale must be a finite number > 0, got 0.0"),
    (dict(dtype="int32"), "fit: dtype must be None, float32 or float64, got 'int32'"),
    (dict(dtype="banana"), "fit: dtype must be None, float32 or float64, got 'banana'"),
    (dict(init={"beta": 0.3}), "fit: init: 'beta' is not a parameter of family 'lambert'; the free parameters "
                               "are ['albedo']"),
    (dict(init={"albedo": np.nan}), "fit: init albedo=nan: expected finite values"),
    (dict(init={"albedo": 2.0}), "fit: init albedo=2.0 is outside its range [0.0, 1.0]"),
    (dict(init=[0.3]), "fit: init must be a dict of parameter values, got list"),
    (dict(fixed={"albedo": "x"}), "fixed albedo='x': expected real numbers"),
    (dict(model="plastic", fixed={"eta": 1.5}, init={"eta": 1.5}), "fit: init: 'eta' is fixed"),
    (dict(method="newton"), "fit: method must be one of"),
    (dict(loss="l3"), "loss must be one of ['l2', 'e2', 'cbrt', 'cosine', 'relative'], got 'l3'"),
])
def test_fit_arguments(mono, kw, needle):
    kw = {"model": "lambert", **kw}
    with raises(ParameterError, needle):
        fit(mono, **kw)


def test_fit_table_type():
    with raises(ParameterError, "fit: table must be a matfit.Table, got str"):
        fit("table.npz", model="lambert")


@pytest.mark.parametrize("tables, kw, needle", [
    ("T", {}, "fit_batch: tables must be a sequence of matfit.Table, got Table"),
    (["a", "b"], {}, "fit_batch: table 0 must be a matfit.Table, got str"),
    ("TT", dict(method="newton"), "fit_batch: method must be one of"),
    ("TT", dict(loss="l3"), "loss must be one of"),
    ("TT", dict(starts=0), "fit_batch: starts must be an integer >= 1, got 0"),
    ("TT", dict(fixed={"albedo": np.inf}), "fixed albedo=inf: expected finite values"),
    ([], {}, "fit_batch: no tables given"),
])
def test_fit_batch_arguments(mono, tables, kw, needle):
    tables = {"T": mono, "TT": [mono, mono]}.get(tables, tables) if isinstance(tables, str) else tables
    with raises(ParameterError, needle):
        fit_batch(tables, model="lambert", **kw)


def test_robust_fit_arguments(mono):
    with raises(ParameterError, "robust_fit: table must be a matfit.Table, got str"):
        robust_fit("t", "lambert")
    with raises(ParameterError, "robust_fit: init: 'beta' is not a parameter of family 'lambert'"):
        robust_fit(mono, "lambert", init={"beta": 1.0})


def test_residuals_arguments():
    one = jnp.ones((2, 1))
    with raises(ParameterError, "residuals: shapes do not broadcast: pred (2, 1), values (3, 1), weight (2, 1), "
                                "cos_i (2,)"):
        residuals(one, jnp.ones((3, 1)), one, jnp.ones(2))
    for scale in (0.0, -1.0, np.nan):
        with raises(ParameterError, "residuals: scale must be finite and > 0 for robust='huber'"):
            residuals(one, 0 * one, one, jnp.ones(2), robust="huber", scale=scale)
    with raises(ParameterError, "robust must be one of [None, 'huber', 'cauchy'], got 'tukey'"):
        residuals(one, one, one, jnp.ones(2), robust="tukey")


# ----------------------------------------------------------------------------------------- io / scenes / CLI
def test_save_rejects_non_table(tmp_path):
    from matfit.io import save

    with raises(ParameterError, "save: table must be a matfit.Table, got str (call save(path, table))"):
        save(tmp_path / "x.npz", "table")


def test_unknown_scene_names_shipped_scenes():
    from data_synth import load_scene

    with pytest.raises(FileNotFoundError, match=r"nope_scene: no such scene file, nor a shipped scene of that name "
                                                r"\(.*demo.*\)"):
        load_scene("nope_scene")


@pytest.mark.parametrize("argv", [["synth", "demo", "-o", "x.npz", "--seed", "-1"],
                                  ["fit", "x.npz", "--model", "lambert", "--seed", "abc"]])
def test_cli_seed(argv, capsys):
    from matfit.cli import main

    with pytest.raises(SystemExit) as ei:
        main(argv)
    assert ei.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "argument --seed: expected a non-negative integer seed" in err, err


def test_errors_are_matfit_value_errors():
    with pytest.raises(MatfitError) as ei:
        Lambert(0.5).eval(np.zeros(3), Z)
    assert isinstance(ei.value, ValueError)


def test_compare_models_arguments(mono):
    from matfit.fitting import compare_models

    for kw, needle in [(dict(table="t"), "compare_models: table must be a matfit.Table, got str"),
                       (dict(models=()), "compare_models: no models given"),
                       (dict(holdout=1.5), "compare_models: holdout must be a fraction in (0, 1), got 1.5"),
                       (dict(tol=-1), "compare_models: tol must be >= 0, got -1")]:
        kw = {"table": mono, "models": ("lambert",), **kw}
        with raises(ParameterError, needle):
            compare_models(**kw)


@pytest.mark.parametrize("field, bad, dtype", [("values", np.ones((4, 3)) + 1j, "complex128"),
                                               ("values", np.full((4, 3), "a"), "<U1"),
                                               ("wo", np.tile([False, False, True], (4, 1)), "bool")])
def test_table_dtypes(field, bad, dtype):
    from matfit.errors import DataFormatError

    args = dict(wo=np.tile(Z, (4, 1)), wi=np.tile(Z, (4, 1)), values=np.ones((4, 3)))
    args[field] = bad
    with raises(DataFormatError, f"field '{field}': expected a real numeric array, found dtype {dtype}"):
        Table(**args)


@pytest.mark.check
def test_albedo_method():
    with pytest.raises(ValueError, match=re.escape("albedo: method must be 'quadrature' or 'mc', got 'foo'")):
        Lambert(0.5).albedo(Z, method="foo")


# --------------------------------------------------------------------------------------------
# Gaps closed after the audit: channel counts, albedo, fresnel, Table.as_jax, synthesize, reports
# --------------------------------------------------------------------------------------------
@pytest.mark.check
def test_channel_counts_must_match():
    from matfit.models import Blend, Lambert, RoughConductor, SmoothConductor

    with pytest.raises(ParameterError, match=r"RoughConductor: the colour channels .* eta has 3, k has 2"):
        RoughConductor(0.1, [1.5, 1.5, 1.5], [1.0, 1.0])
    with pytest.raises(ParameterError, match=r"SmoothConductor: the colour channels"):
        SmoothConductor([1.5, 1.5], [1.0, 1.0, 1.0])
    with pytest.raises(ParameterError, match=r"Blend: the colour channels .* a has 3, b has 2"):
        Blend(Lambert([0.1, 0.2, 0.3]), Lambert([0.1, 0.2]), 0.5)
    RoughConductor(0.1, 1.5, [1.0, 2.0, 3.0])  # a scalar broadcasts
    Blend(Lambert(0.5), Lambert([0.1, 0.2, 0.3]), 0.5)


def test_albedo_checks_wo_method_and_n():
    from matfit.models import Lambert

    m = Lambert(0.5)
    with pytest.raises(ParameterError, match=r"Lambert.albedo.*wo"):
        m.albedo(np.array([0.0, 0.0, 2.0]))
    with pytest.raises(ParameterError, match=r"Lambert.albedo: method must be"):
        m.albedo(np.array([0.0, 0.0, 1.0]), method="exact")
    with pytest.raises(ParameterError, match=r"Lambert.albedo: n must be a positive integer, got 0"):
        m.albedo(np.array([0.0, 0.0, 1.0]), n=0)


def test_fresnel_parameters():
    from matfit.fresnel import fresnel_conductor, fresnel_dielectric, fresnel_dielectric_average

    with pytest.raises(ParameterError, match=r"fresnel_dielectric: parameter 'eta' must be > 0.0, found \[ *-1\.\]"):
        fresnel_dielectric(0.5, -1.0)
    with pytest.raises(ParameterError, match=r"fresnel_dielectric_average: parameter 'eta' must be > 0.0, found \[ *0\.\]"):
        fresnel_dielectric_average(0.0)
    with pytest.raises(ParameterError, match=r"fresnel_conductor: parameter 'k' must be >= 0.0, found \[ *-0\.1\]"):
        fresnel_conductor(0.5, 1.5, -0.1)
    with pytest.raises(ParameterError, match=r"fresnel_conductor: parameter 'eta' must be finite, found \[ *nan\]"):
        fresnel_conductor(0.5, np.nan, 1.0)


def test_table_as_jax_dtype():
    from matfit import Table
    from matfit.errors import DataFormatError

    t = Table(wo=np.array([[0.0, 0.0, 1.0]]), wi=np.array([[0.0, 0.0, 1.0]]), values=np.ones((1, 3)))
    with pytest.raises(DataFormatError, match=r"field 'dtype': expected a floating dtype"):
        t.as_jax("int32")


def test_synthesize_rejects_a_dict():
    from data_synth.synth import synthesize

    with pytest.raises(TypeError, match=r"synthesize: scene must be a data_synth Scene or a path.*got dict"):
        synthesize({"material": {}})


def test_write_report_rejects_non_results(tmp_path):
    from matfit import Table
    from matfit.report import write_report

    t = Table(wo=np.array([[0.0, 0.0, 1.0]]), wi=np.array([[0.0, 0.0, 1.0]]), values=np.ones((1, 3)))
    with pytest.raises(ParameterError, match=r"write_report: result must be a matfit FitResult.*got dict"):
        write_report({}, t, tmp_path)


def test_fit_refuses_a_table_too_large_for_the_memory_before_allocating(monkeypatch):
    """A fit whose estimated working memory exceeds what the system has raises one clear error
    naming the row count, the estimate and the available memory."""
    import importlib

    from matfit.fitting import FitError, fit

    fm = importlib.import_module("matfit.fitting._memory")
    monkeypatch.setattr(fm, "available_memory", lambda: 2**20)  # 1 MiB available
    wo = np.tile([0.0, 0.0, 1.0], (5000, 1))
    t = Table(wo=wo, wi=wo, values=np.full((5000, 3), 0.1), channels="rgb")
    with pytest.raises(FitError, match=r"5000 rows x 3 channels needs about 1\.\d MiB .* 1\.0 MiB are available"):
        fit(t, model="lambert")
