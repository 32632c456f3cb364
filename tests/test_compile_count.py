"""No recompilation between calls that differ only in parameter values or direction values.

Compilations are counted with a JAX monitoring listener on the backend-compile event (one event
per XLA compilation, whatever triggers it: jit, an eager primitive on a new shape, a solver).
Every scenario first runs once to compile, then repeats with new values of the same shapes and
must compile nothing.
"""

import contextlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax import monitoring

import numpy_ref as R
from matfit import Table
from matfit.fast import eval_soa, soa_pairs
from matfit.fitting import fit
from matfit.models import Lambert, RoughConductor

try:  # the event name jax uses for one XLA compilation
    from jax._src.dispatch import BACKEND_COMPILE_EVENT
except ImportError:  # pragma: no cover - older/newer jax
    BACKEND_COMPILE_EVENT = "/jax/core/compile/backend_compile_duration"


@contextlib.contextmanager
def count_compilations():
    """Collect one entry per XLA compilation inside the block."""
    seen = []

    def listener(event, duration_secs, **kwargs):
        if event == BACKEND_COMPILE_EVENT:
            seen.append(kwargs.get("fun_name", "?"))

    monitoring.register_event_duration_secs_listener(listener)
    try:
        yield seen
    finally:
        monitoring.unregister_event_duration_listener(listener)


def _pairs(seed, n):
    rng = np.random.default_rng(seed)
    return R.random_directions(rng, n, "upper"), R.random_directions(rng, n, "upper")


def _conductor(alpha, eta, k):
    return RoughConductor(jnp.asarray(alpha), jnp.asarray(eta), jnp.asarray(k))


@pytest.mark.check
def test_counter_sees_a_compilation():
    # The counter itself must work, or the zero counts below would prove nothing.
    with count_compilations() as seen:
        jax.jit(lambda x: jnp.sin(x) * 3.25)(jnp.arange(7.0)).block_until_ready()
    assert len(seen) >= 1


def test_eval_soa_compiles_once_per_structure(x64):
    wo, wi = _pairs(0, 257)  # odd: padded when there are several devices
    params = [(0.2, [0.14, 0.37, 1.44], [3.98, 2.38, 1.60]), (0.45, [1.1, 0.9, 0.6], [2.1, 2.7, 3.1]),
              (0.07, [0.2, 0.2, 0.2], [3.0, 3.0, 3.0])]
    jax.block_until_ready(eval_soa(_conductor(*params[0]), soa_pairs(wo, wi)))
    jax.block_until_ready(eval_soa(Lambert(jnp.asarray(params[0][1]) / 2), soa_pairs(wo, wi)))
    outs = []
    with count_compilations() as seen:
        for seed, p in enumerate(params[1:], start=1):
            pairs = soa_pairs(*_pairs(seed, 257))  # new directions, same count
            outs.append(eval_soa(_conductor(*p), pairs))
            outs.append(eval_soa(Lambert(jnp.asarray(p[1]) / 2), pairs))
        jax.block_until_ready(outs)
    assert seen == [], f"recompiled for new parameter/direction values: {seen}"


@pytest.mark.check
def test_jitted_eval_compiles_once(x64):
    traces = []  # one entry per trace of the function: a new trace would mean a new compilation
    f = jax.jit(lambda m, a, b: (traces.append(1), m.eval(a, b))[1])
    wo, wi = _pairs(3, 64)
    f(_conductor(0.2, [0.14, 0.37, 1.44], [3.98, 2.38, 1.60]), jnp.asarray(wo), jnp.asarray(wi)).block_until_ready()
    with count_compilations() as seen:
        wo, wi = _pairs(4, 64)
        f(_conductor(0.6, [1.0, 1.2, 1.4], [2.0, 2.5, 3.0]), jnp.asarray(wo), jnp.asarray(wi)).block_until_ready()
    assert seen == [], seen
    assert len(traces) == 1, f"traced {len(traces)} times for new parameter and direction values"


def _lambert_table(seed, albedo, n=24):
    rng = np.random.default_rng(seed)
    wo = R.random_directions(rng, n, "upper", 0.1)
    wi = R.random_directions(rng, n, "upper", 0.1)
    values = R.lambert_eval(wo, wi, albedo) * (1 + 0.01 * rng.standard_normal((n, 1)))
    return Table(wo=wo, wi=wi, values=values, channels="mono")


def test_fit_does_not_recompile_for_a_new_table_of_the_same_shape(x64):
    r1 = fit(_lambert_table(0, 0.3), model="lambert", starts=2, max_steps=32)
    with count_compilations() as seen:
        r2 = fit(_lambert_table(1, 0.7), model="lambert", starts=2, max_steps=32)
    assert seen == [], f"fit recompiled for a table of the same shape: {seen}"
    # ... and it really fitted the new values (the cache did not return the old answer).
    assert abs(float(r1.params["albedo"][0]) - 0.3) < 0.02
    assert abs(float(r2.params["albedo"][0]) - 0.7) < 0.03


def _conductor_table(seed, n=40):
    rng = np.random.default_rng(seed)
    wo, wi = (R.random_directions(rng, n, "upper", 0.1) for _ in range(2))
    f = R.conductor_eval(wo, wi, R.Dist("ggx", 0.3), [0.2, 0.9, 1.4], [3.6, 2.5, 1.9])
    y = f * (1 + 0.05 * rng.standard_normal(f.shape)) + 1e-3
    return Table(wo=wo, wi=wi, values=y, sigma=0.05 * y, channels="rgb")


def test_log_prob_does_not_recompile_for_a_new_table_of_the_same_shape(x64):
    from matfit.fitting import make_log_prob

    Z = np.random.default_rng(3).normal(0, 1, size=(8, 7))
    lp1 = make_log_prob(_conductor_table(0), "conductor")
    v1 = lp1(Z)
    with count_compilations() as seen:
        lp2 = make_log_prob(_conductor_table(1), "conductor")
        v2, v2_part = lp2(Z), lp2(Z[:5])
    assert seen == [], f"make_log_prob recompiled for a table of the same shape: {seen}"
    # the new table's values are the ones evaluated (the packed arguments are not the old ones)
    assert np.all(np.abs(v2 - v1) > 1e-6 * np.abs(v1))
    np.testing.assert_array_equal(v2_part, v2[:5])
