"""Every registered fitting method on two families: each recovers a noise-free material.

The default (``lm_fd``) is tested in depth elsewhere (test_fit_lm_fd.py, test_stable_fits.py);
here every entry of :data:`matfit.fitting.METHODS` runs the same ``fit`` call on a rough
conductor (7 parameters, per-channel index) and a diffuse-plus-specular material (7 parameters:
a Lambertian albedo beside a GGX lobe with a per-channel Schlick F0), from the default
data-driven starts, and must end at the truth; the default method and the undamped one (from a
near start) also on a plastic (5 parameters, a coat over a diffuse base). (Every method on the
plastic compiled its solver for 10-40 s each, 185 s in all, against 29 s on diffuse_specular.)"""

import jax.numpy as jnp
import numpy as np
import pytest

from testdata import random_pairs
from matfit import Table
from matfit.fitting import METHODS, fit
from matfit.models import DiffuseSpecular, Plastic, RoughConductor

TRUTHS = {
    "conductor": ({"alpha": 0.3, "eta": [0.2, 0.9, 1.4], "k": [3.6, 2.5, 1.9]},
                  lambda p: RoughConductor(p["alpha"], jnp.asarray(p["eta"]), jnp.asarray(p["k"]))),
    "plastic": ({"albedo": [0.6, 0.3, 0.1], "alpha": 0.2, "eta": 1.6},
                lambda p: Plastic(jnp.asarray(p["albedo"]), p["alpha"], p["eta"])),
    "diffuse_specular": ({"albedo": [0.6, 0.3, 0.1], "f0": [0.04, 0.05, 0.06], "alpha": 0.2},
                         lambda p: DiffuseSpecular(jnp.asarray(p["albedo"]), jnp.asarray(p["f0"]), p["alpha"])),
}
#: Each method on these two; the default also on the plastic.
METHOD_FAMILIES = ("conductor", "diffuse_specular")


def _table(family, n=96, seed=0):
    wo, wi = random_pairs(np.random.default_rng(seed), n)
    wi[: n // 3] = wo[: n // 3] * [-1, -1, 1]  # a third at the mirror: the peak pins the width
    params, build = TRUTHS[family]
    f = np.asarray(build(params).eval(jnp.asarray(wo), jnp.asarray(wi)))
    return Table(wo=wo, wi=wi, values=f, channels="rgb"), params


#: Methods without damping: from a far start they may stop short, and must say so.
UNDAMPED = {"gn"}
#: A start near the truth (each value 10-20 % off).
NEAR = {"conductor": {"alpha": 0.25, "eta": [0.3, 1.0, 1.2], "k": [3.0, 2.0, 2.0]},
        "plastic": {"albedo": [0.5, 0.35, 0.12], "alpha": 0.25, "eta": 1.4}}


def _assert_recovered(r, truth, what):
    for name, want in truth.items():
        got = np.broadcast_to(np.asarray(r.params[name], float), np.shape(want))
        np.testing.assert_allclose(got, want, rtol=2e-3, err_msg=f"{what}: {name}")


@pytest.mark.parametrize("method, family", [(m, f) for m in sorted(METHODS) for f in METHOD_FAMILIES]
                         + [("lm_fd", "plastic")])
def test_every_method_recovers_a_noise_free_material(method, family, x64):
    table, truth = _table(family)
    r = fit(table, model=family, method=method, starts=2, max_steps=500)
    if r.converged or method not in UNDAMPED:
        assert r.converged, f"{method} on {family}: not converged ({r.steps} steps)"
        _assert_recovered(r, truth, f"{method} on {family}")
    else:  # an undamped method that stopped short says so
        assert any(w.startswith("not converged") for w in r.warnings) and not r.ok


@pytest.mark.parametrize("family", [pytest.param("conductor", marks=pytest.mark.check), "plastic"])
@pytest.mark.parametrize("method", sorted(UNDAMPED))
def test_an_undamped_method_converges_from_a_near_start(method, family, x64):
    table, truth = _table(family)
    r = fit(table, model=family, method=method, starts=1, init=NEAR[family], max_steps=500)
    assert r.converged, f"{method} on {family} from a near start: not converged ({r.steps} steps)"
    _assert_recovered(r, truth, f"{method} on {family} from a near start")
