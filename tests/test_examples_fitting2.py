"""Checks moved from docstring examples of matfit.fitting (mcmc, select, diagnostics, fit, the
conductor guess): small values and behaviours that the examples asserted, without fits."""

import json

import numpy as np
import pytest

from matfit import ParameterError, Table
from matfit.fitting import (ModelComparison, PosteriorResult, channel_correlation, make_log_prob, noise_level,
                            refit_line)
from matfit.fitting.diagnostics import diagnose
from matfit.fitting.select import information_criteria

WO = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, 0.6, 0.8]])


def _table(**kw):
    return Table(wo=WO, wi=WO[[1, 2, 0]], values=np.full((3, 3), 0.1), **kw)


def _posterior(moves="de"):
    """A PosteriorResult of a made-up chain (no sampling)."""
    chain = 0.3 + 0.01 * np.random.default_rng(0).standard_normal((50, 12, 3))
    flat = chain.reshape(-1, 3)
    q = np.percentile(flat, [5, 16, 50, 84, 95], axis=0)
    return PosteriorResult(
        family="lambert", loss="l2", noise="table", prior="uniform", labels=["albedo[0]", "albedo[1]", "albedo[2]"],
        chain=chain, log_prob=np.zeros((50, 12)), median=q[2], mean=flat.mean(0), std=flat.std(0, ddof=1),
        ci90=np.stack([q[0], q[4]], 1), ci68=np.stack([q[1], q[3]], 1), acceptance_fraction=np.full(12, 0.5),
        autocorr_time=np.full(3, 2.0), n_effective=np.full(3, 300.0), burn_in=100, n_steps=50, thin=1, n_walkers=12,
        tau_factor=10.0, converged=True, wall_time=1.0, moves=moves)


# ---------------------------------------------------------------------------------------- mcmc
def test_log_prob_to_natural_with_a_sampled_noise_scale():
    lp = make_log_prob(_table(sigma=np.full((3, 3), 0.01)), model="lambert", noise="fit")
    assert lp.labels == ["albedo[0]", "albedo[1]", "albedo[2]", "noise_scale"]
    # z = 0: albedos mid-range; the last coordinate is log s
    np.testing.assert_allclose(lp.to_natural(np.array([0.0, 0.0, 0.0, np.log(0.1)])), [0.5, 0.5, 0.5, 0.1])


def test_gaussian_prior_description_and_pull():
    lp = make_log_prob(_table(sigma=np.full((3, 3), 0.01)), model="lambert", prior={"albedo": (0.3, 0.05)})
    assert lp.prior == 'gaussian {"albedo": [[0.3, 0.3, 0.3], [0.05, 0.05, 0.05]]}'
    assert lp(np.full(3, -0.78)) > lp(np.full(3, 1.0))  # albedos 0.31 against 0.73


def test_posterior_interval_summary_and_files(tmp_path):
    post = _posterior()
    assert post.samples.shape == (600, 3)
    lo, hi = post.interval(0.5)[0]
    assert post.ci90[0, 0] < lo < post.median[0] < hi < post.ci90[0, 1]
    for level in (0.0, 1.0):
        with pytest.raises(ParameterError):
            post.interval(level)
    lines = post.summary().splitlines()
    assert len(lines) == 5 and lines[1].split()[:2] == ["parameter", "median"] and lines[2].split()[0] == "albedo[0]"
    assert lines[0].startswith("lambert posterior (l2, noise=table, prior=uniform, moves=de): 12 walkers")
    path = tmp_path / "post.npz"
    post.save(path, note="example")
    with np.load(path) as f:
        meta = json.loads(str(f["meta"]))
    assert meta["format"] == "matfit.posterior/1" and meta["extra"] == {"note": "example"}
    back = PosteriorResult.load(path)
    assert back.labels == post.labels and back.n_steps == post.n_steps and np.array_equal(back.chain, post.chain)


# ---------------------------------------------------------------------------------------- select
@pytest.mark.check
def test_information_criteria_values():
    np.testing.assert_allclose(information_criteria(1.0, 100, 2), [-456.517, -451.307], atol=1e-3)


def test_model_comparison_summary_and_dict():
    row = {"model": "lambert", "p": 3, "n": 9, "rss": 1e-12, "aic": -300.0, "bic": -299.0, "holdout_rmse": 1e-7,
           "holdout_rmse_raw": 1e-8, "objective": 5e-13, "converged": True, "seconds": 0.1}
    cmp = ModelComparison(rows=[row], recommended="lambert", best="lambert", tol=0.02, n_fit=3, n_holdout=1)
    lines = cmp.summary().splitlines()
    assert lines[0] == "model comparison: 3 fit rows, 1 hold-out rows, tolerance 2%"
    assert lines[2].split()[:2] == ["lambert", "3"] and lines[2].endswith("<- recommended")
    assert lines[-1] == "  recommended: lambert (best hold-out: lambert)"
    d = json.loads(json.dumps(cmp.to_dict()))
    assert sorted(d) == ["best", "n_fit", "n_holdout", "recommended", "rows", "tol"] and d["rows"][0]["p"] == 3


# ---------------------------------------------------------------------------------------- diagnostics
def test_diagnose_flags_a_parameter_at_its_bound():
    warnings, unident = diagnose(labels=["alpha"], values=np.array([1e-6]), stderr=np.array([0.01]),
                                 lower=np.zeros(1), upper=np.ones(1), residuals=np.full(10, 0.1), converged=True,
                                 steps=5, max_steps=256, known_sigma=False, dof=9, Jt=np.ones((10, 1)))
    assert [w.split(":")[0] for w in warnings] == ["at a bound"] and unident == []


# ---------------------------------------------------------------------------------------- fit
def test_refit_line_and_noise_level():
    np.testing.assert_allclose(refit_line([8, 72]), [3.0, 1 + 4 * np.sqrt(2 / 72)])
    assert round(float(refit_line([72])[0]), 2) == 1.67
    assert noise_level(np.r_[np.full(15, 1e-4), 1.0], False) == 1e-4  # the median of 16 tables
    assert np.isnan(noise_level(np.ones(3), False))  # fewer than REFIT_MIN_BATCH tables: no level


def test_independent_channel_noise_is_uncorrelated():
    assert abs(channel_correlation(np.random.default_rng(0).standard_normal((2000, 3)))) < 0.05


# ---------------------------------------------------------------------------------------- conductor guess
def test_curve_readable_needs_enough_rows():
    from data_synth import geometry
    from matfit.fitting._conductor_guess import curve_readable

    wo, wi, ok, _ = geometry.merl_grid(8, 8, 16)
    wo, wi = np.asarray(wo)[ok][None], np.asarray(wi)[ok][None]
    v = np.ones(wo.shape[:2] + (3,))
    assert curve_readable(wo, wi, v, np.ones(wo.shape[:2], bool)).tolist() == [True]
    assert curve_readable(wo[:, :20], wi[:, :20], v[:, :20], np.ones((1, 20), bool)).tolist() == [False]
