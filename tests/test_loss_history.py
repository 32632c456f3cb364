"""matfit.fitting.loss_history: the per-iteration objective of each start of fit(), and its place in reports."""
from __future__ import annotations

import json

import numpy as np
import pytest

from matfit import Table
from matfit.errors import ParameterError
from matfit.fitting import fit
from matfit.fitting import loss_history
from matfit.report import write_report


def _table(rng, n=300):
    wo = rng.normal(size=(n, 3))
    wi = rng.normal(size=(n, 3))
    wo[:, 2], wi[:, 2] = np.abs(wo[:, 2]) + 0.05, np.abs(wi[:, 2]) + 0.05
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    albedo = np.array([0.6, 0.3, 0.1])
    y = albedo / np.pi * (1.0 + 0.2 * rng.standard_normal((n, 3)))
    return Table(wo=wo, wi=wi, values=np.abs(y), channels="rgb")


@pytest.fixture(scope="module")
def fitted():
    """One fit (3 starts, start 0 from a given init) and its loss history; shared by the tests."""
    import jax

    jax.config.update("jax_enable_x64", True)
    rng = np.random.default_rng(7)
    t = _table(rng)
    kw = dict(method="lm", loss="e2", starts=3, seed=1, max_steps=50, init={"albedo": np.array([0.9, 0.9, 0.9])})
    return t, fit(t, "lambert", **kw), loss_history(t, "lambert", **kw)


def test_history_ends_where_fit_ends_and_never_increases(fitted):
    t, res, hist = fitted
    assert len(hist) == 3
    for h, final in zip(hist, res.start_objectives):
        assert h.ndim == 1 and len(h) >= 2
        assert np.all(np.diff(h) <= 1e-12 * h[0])  # objective at the last accepted iterate
        assert h[-1] == pytest.approx(float(final), rel=1e-8)
    assert min(h[0] for h in hist) > 1.5 * res.objective  # every start begins away from the optimum


def test_history_starts_at_init(fitted):
    t, _, hist = fitted
    c = t.wi[:, 2:3]
    r = np.log1p(0.9 / np.pi * c) - np.log1p(t.values * c)
    assert hist[0][0] == pytest.approx(0.5 * np.sum(r * r), rel=1e-8)  # entry 0: objective at the init


def test_report_carries_history(fitted, tmp_path):
    t, res, hist = fitted
    s = write_report(res, t, tmp_path, history=hist)
    assert (tmp_path / "loss.png").stat().st_size > 0
    data = json.loads((tmp_path / "report.json").read_text())
    assert [len(h) for h in data["loss_history"]] == [len(h) for h in hist]
    assert s["loss_history"][0][-1] == pytest.approx(hist[0][-1])
    assert "Loss history: objective after each solver iteration" in (tmp_path / "report.md").read_text()


@pytest.mark.check
def test_bad_method():
    t = Table(wo=[[0, 0, 1.0]] * 3, wi=[[0, 0, 1.0]] * 3, values=[[0.1]] * 3, channels="mono")
    with pytest.raises(ParameterError, match="method"):
        loss_history(t, "lambert", method="bfgs")
