"""emcee posterior sampling (matfit.fitting.mcmc): accuracy, the log-probability, intervals, I/O, errors."""
import math

import numpy as np
import pytest

from matfit import ParameterError, Table
from matfit.fitting import PosteriorResult, fit, make_log_prob, sample_posterior

TRUTH = np.array([0.2, 0.5, 0.8])


def _lambert_table(rel=0.02, seed=0, n=60, sigma=True):
    rng = np.random.default_rng(seed)
    wi = rng.normal(size=(n, 3))
    wi[:, 2] = np.abs(wi[:, 2]) + 0.1
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo = rng.normal(size=(n, 3))
    wo[:, 2] = np.abs(wo[:, 2]) + 0.1
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    f = np.broadcast_to(TRUTH / np.pi, (n, 3))
    y = f * (1 + rel * rng.standard_normal(f.shape))
    return Table(wo=wo, wi=wi, values=y, sigma=rel * f if sigma else None, channels="rgb")


@pytest.fixture(scope="module")
def lambert_posteriors(tmp_path_factory):
    import jax

    jax.config.update("jax_enable_x64", True)
    out = {}
    for rel in (0.01, 0.04):
        t = _lambert_table(rel)
        out[rel] = (t, sample_posterior(t, model="lambert", progress=False, seed=1, max_steps=4000))
    return out


def test_median_close_to_truth(lambert_posteriors):
    for rel, (t, post) in lambert_posteriors.items():
        # Standard error of an albedo: truth * rel / sqrt(60 residuals per channel).
        se = TRUTH * rel / math.sqrt(60)
        assert post.labels == ["albedo[0]", "albedo[1]", "albedo[2]"]
        assert post.chain.shape[1:] == (post.n_walkers, 3) and post.n_walkers == 12
        assert np.all(np.abs(post.median - TRUTH) < 4 * se), (post.median, se)
        assert np.all((post.ci90[:, 0] < post.median) & (post.median < post.ci90[:, 1]))
        assert np.all((post.ci90[:, 0] < post.ci68[:, 0]) & (post.ci68[:, 1] < post.ci90[:, 1]))
        # The posterior sd matches the Gauss-Newton standard error of the same table.
        fr = fit(t, model="lambert", starts=1)
        np.testing.assert_allclose(post.std, fr.stderr, rtol=0.25)
        assert 0.2 < np.mean(post.acceptance_fraction) < 0.9
        assert post.converged and post.n_steps > post.tau_factor * post.autocorr_time.max()
        np.testing.assert_allclose(post.n_effective, post.n_walkers * post.n_steps / post.autocorr_time)
        assert post.burn_in >= 100 and post.thin >= 1
        assert "albedo[1]" in post.summary()


def test_intervals_widen_with_noise(lambert_posteriors):
    w_lo = np.diff(lambert_posteriors[0.01][1].ci90, axis=1)[:, 0]
    w_hi = np.diff(lambert_posteriors[0.04][1].ci90, axis=1)[:, 0]
    # 4x the noise: 4x the width, up to Monte Carlo error.
    assert np.all(w_hi > 2.5 * w_lo), (w_lo, w_hi)
    assert np.all(w_hi < 6 * w_lo), (w_lo, w_hi)


def test_saved_chains_reload(lambert_posteriors, tmp_path):
    post = lambert_posteriors[0.01][1]
    path = tmp_path / "post.npz"
    post.save(path, note="test")
    with np.load(path, allow_pickle=False) as f:  # no pickle needed
        assert f["chain"].shape == post.chain.shape
    back = PosteriorResult.load(path)
    assert back.labels == post.labels and back.converged == post.converged and back.thin == post.thin
    for k in ("chain", "log_prob", "median", "ci90", "ci68", "acceptance_fraction", "autocorr_time"):
        np.testing.assert_array_equal(getattr(back, k), getattr(post, k))
    assert back.summary() == post.summary()


def _np_log_sigmoid(z):
    return -np.logaddexp(0.0, -z)


@pytest.mark.check
@pytest.mark.parametrize("noise", ["table", "fit"])
@pytest.mark.parametrize("prior", ["uniform", "gauss"])
def test_log_prob_matches_numpy(x64, noise, prior):
    t = _lambert_table(0.03, seed=3, n=25)
    pri = "uniform" if prior == "uniform" else {"albedo": ([0.3, 0.4, 0.5], 0.2), "albedo[2]": (0.7, 0.05)}
    lp = make_log_prob(t, "lambert", noise=noise, prior=pri)
    rng = np.random.default_rng(7)
    Z = rng.normal(0, 1.5, size=(9, lp.ndim))
    if noise == "fit":
        Z[:, 3] = rng.uniform(-8, -1, size=9)  # log s
    got = lp(Z)
    y = np.asarray(t.values)
    for z, g in zip(Z, got):
        a = 1 / (1 + np.exp(-z[:3]))  # albedo in (0, 1)
        f = np.broadcast_to(a / np.pi, y.shape)
        if noise == "table":
            sig = np.asarray(t.sigma)
            lpri_noise = 0.0
        else:
            sig = np.exp(z[3]) * np.abs(y) + 1e-5 * np.median(np.abs(y))
            lpri_noise = -np.log(np.log(10.0) - np.log(1e-6))
        ll = np.sum(-0.5 * ((f - y) / sig) ** 2 - np.log(sig) - 0.5 * np.log(2 * np.pi))
        if prior == "uniform":
            lpri = 0.0  # -log(1 - 0) per albedo
        else:
            m, s = np.array([0.3, 0.4, 0.7]), np.array([0.2, 0.2, 0.05])
            lpri = np.sum(-0.5 * ((a - m) / s) ** 2 - np.log(s) - 0.5 * np.log(2 * np.pi))
        ljac = np.sum(_np_log_sigmoid(z[:3]) + _np_log_sigmoid(-z[:3]))
        np.testing.assert_allclose(g, ll + lpri + ljac + lpri_noise, rtol=1e-9, atol=1e-8)
    # single point in, scalar out; the noise scale outside its prior range has zero probability
    assert np.isclose(lp(Z[0]), got[0])
    if noise == "fit":
        Zb = Z.copy()
        Zb[:, 3] = np.log(100.0)
        assert np.all(lp(Zb) == -np.inf)


def test_noise_fit_recovers_scale(x64):
    t = _lambert_table(0.03, seed=5, n=60, sigma=False)
    post = sample_posterior(t, model="lambert", noise="fit", progress=False, max_steps=3000, tau_factor=30)
    assert post.labels[-1] == "noise_scale"
    lo, hi = post.ci90[-1]
    assert lo < 0.03 < hi and hi - lo < 0.02, post.ci90[-1]


def test_demo_posterior_meets_its_criterion():
    """`make demo`'s posterior (the gold conductor of the demo scene, 34 rows, the demo's cap):
    the default DE moves meet ``n_steps > tau_factor * max(tau)``; emcee's stretch move needed
    over 20000 steps here (the red channel's eta and k trade off along a ridge)."""
    import inspect

    from data_synth import load_scene, synthesize

    from matfit.demo import run_fit_demo
    from matfit.pipeline import run_pipeline

    table = synthesize(load_scene("demo"))
    cap = inspect.signature(run_fit_demo).parameters["mcmc_steps"].default
    res = run_pipeline(table, "conductor", posterior_steps=cap, log=None)
    post = res.posterior
    assert post.moves == "de" and post.burn_in + post.n_steps <= cap
    assert post.converged and post.n_steps > post.tau_factor * post.autocorr_time.max(), post.summary()
    # what the chain is good for: every parameter has hundreds of independent samples
    assert post.n_effective.min() > 500, post.summary()


def test_stretch_moves_still_sample(lambert_posteriors):
    t, ref = lambert_posteriors[0.01]
    post = sample_posterior(t, model="lambert", progress=False, seed=1, max_steps=4000, moves="stretch")
    assert post.moves == "stretch" and post.converged
    np.testing.assert_allclose(post.median, ref.median, atol=3 * ref.std.max())


def test_bad_arguments_raise():
    t = _lambert_table(0.02, n=20)
    nos = _lambert_table(0.02, n=20, sigma=False)
    bad = [
        dict(table="not a table"),
        dict(model="no_such_family"),
        dict(noise="guess"),
        dict(table=nos, noise="table"),  # no sigma to take the noise from
        dict(loss="l3"),
        dict(prior="jeffreys"),
        dict(prior={"beta": (0.1, 0.1)}),
        dict(prior={"albedo": (0.5, -1.0)}),
        dict(prior={"albedo": "wide"}),
        dict(n_walkers=7),  # odd
        dict(n_walkers=4),  # < 2 p
        dict(max_steps=10),
        dict(tau_factor=0),
        dict(thin=0),
        dict(start="a fit"),
        dict(fixed={"eta": 1.5}),
        dict(noise_floor=1e-3),  # only with noise="fit"
        dict(moves="walk"),
        dict(moves=None),
    ]
    for kw in bad:
        kw = {"table": t, "model": "lambert", "progress": False, **kw}
        with pytest.raises(ParameterError):
            sample_posterior(**kw)


@pytest.mark.parametrize("noise", ["table", "fit"])
@pytest.mark.parametrize("family", ["conductor", "dielectric"])
def test_microfacet_log_prob_matches_numpy(x64, family, noise):
    # The conductor takes the structure-of-arrays path (channel-split residuals, cosines only),
    # the rough dielectric the general one: both against the numpy reference models.
    import numpy_ref as R

    rng = np.random.default_rng(11)
    n = 40
    wo = R.random_directions(rng, n, "upper", 0.1)
    wi = R.random_directions(rng, n, "upper" if family == "conductor" else "both", 0.1)
    if family == "conductor":
        f = R.conductor_eval(wo, wi, R.Dist("ggx", 0.3), [0.2, 0.9, 1.4], [3.6, 2.5, 1.9])
    else:
        f = R.dielectric_eval(wo, wi, R.Dist("ggx", 0.3), 1.5)
    y = f * (1 + 0.05 * rng.standard_normal(f.shape)) + 1e-3
    t = Table(wo=wo, wi=wi, values=y, sigma=0.05 * y, channels="rgb" if family == "conductor" else "mono")
    lp = make_log_prob(t, family, noise=noise)
    p = lp.par.size
    Z = rng.normal(0, 1.0, size=(5, lp.ndim))
    if noise == "fit":
        Z[:, p] = rng.uniform(-6, -1, size=5)
    got = lp(Z)
    th = lp.to_natural(Z)
    for z, g, q in zip(Z, got, th):
        if family == "conductor":
            pred = R.conductor_eval(wo, wi, R.Dist("ggx", q[0]), q[1:4], q[4:7])
        else:
            pred = R.dielectric_eval(wo, wi, R.Dist("ggx", q[0]), q[1])
        if noise == "table":
            sig, lpri_noise = 0.05 * y, 0.0
        else:
            sig = np.exp(z[p]) * np.abs(y) + 1e-5 * np.median(np.abs(y))
            lpri_noise = -np.log(np.log(10.0) - np.log(1e-6))
        ll = np.sum(-0.5 * ((pred - y) / sig) ** 2 - np.log(sig) - 0.5 * np.log(2 * np.pi))
        # uniform priors -log(hi - lo) cancel the Jacobian's log(hi - lo)
        ljac = np.sum(_np_log_sigmoid(z[:p]) + _np_log_sigmoid(-z[:p]))
        np.testing.assert_allclose(g, ll + ljac + lpri_noise, rtol=1e-9, atol=1e-8)
