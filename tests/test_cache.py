"""The persistent compilation cache (matfit.cache): a second process loads what the first compiled."""

import json
import os
import subprocess
import sys
import textwrap

import pytest

SCRIPT = textwrap.dedent("""
    import json
    import numpy as np
    from jax import monitoring
    import matfit.cache
    where = matfit.cache.enable_compilation_cache()
    counts = {"compiles": 0, "hits": 0}
    def on_duration(event, duration_secs, **kw):
        if event.endswith("backend_compile_duration"):
            counts["compiles"] += 1
    def on_event(event, **kw):
        if event == "/jax/compilation_cache/cache_hits":
            counts["hits"] += 1
    monitoring.register_event_duration_secs_listener(on_duration)
    monitoring.register_event_listener(on_event)
    from matfit import Table
    from matfit.fitting import fit
    rng = np.random.default_rng(0)
    wi = rng.normal(size=(64, 3)); wi[:, 2] = abs(wi[:, 2]); wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo = np.tile([0.0, 0.0, 1.0], (64, 1))
    r = fit(Table(wo=wo, wi=wi, values=np.full((64, 3), 0.2), channels="rgb"), model="lambert", starts=1)
    exported = sorted((p.name, p.stat().st_mtime_ns) for p in (where / "exported").glob("*")) if where else []
    print("RESULT " + json.dumps({**counts, "dir": None if where is None else str(where),
                                  "albedo": float(r.params["albedo"][0]), "exported": exported}))
""")


def _run(env):
    p = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, env=env, timeout=600)
    assert p.returncode == 0, p.stderr[-2000:]
    line = [ln for ln in p.stdout.splitlines() if ln.startswith("RESULT ")][-1]
    return json.loads(line[len("RESULT "):])


def test_second_process_loads_compiled_programs(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "MATFIT_NO_CACHE"}
    env["MATFIT_CACHE_DIR"] = str(tmp_path / "cache")
    first = _run(env)
    assert first["dir"] == env["MATFIT_CACHE_DIR"] and first["compiles"] > 0
    assert any((tmp_path / "cache").iterdir())  # entries were written
    second = _run(env)
    assert first["hits"] == 0 and second["hits"] > 0  # programs loaded from the cache
    assert second["albedo"] == first["albedo"]  # the loaded programs compute the same fit
    # the solver's traced program was written once and read back, not traced and written again
    assert first["exported"] and second["exported"] == first["exported"]
    off = _run({**env, "MATFIT_NO_CACHE": "1"})
    assert off["dir"] is None and off["hits"] == 0 and off["compiles"] > 0


def test_persistent_jit_reads_the_exported_program(tmp_path, monkeypatch):
    import jax
    import jax.numpy as jnp

    import matfit.cache as cache

    monkeypatch.setattr(cache, "_exported_dir", tmp_path / "exported")
    x = jnp.arange(4.0)
    first = cache.persistent_jit(jax.jit(lambda v: 2 * v), ("test", 1))
    assert first(x).tolist() == [0.0, 2.0, 4.0, 6.0]
    (written,) = list((tmp_path / "exported").iterdir())
    # a new wrapper of the same key (a later process) runs the program on disk: the function it
    # was given is not traced
    again = cache.persistent_jit(jax.jit(lambda v: 3 * v), ("test", 1))
    assert again(x).tolist() == [0.0, 2.0, 4.0, 6.0]
    # another argument shape or another key is another program
    assert again(jnp.arange(2.0)).tolist() == [0.0, 3.0]
    assert cache.persistent_jit(jax.jit(lambda v: 3 * v), ("test", 2))(x).tolist() == [0.0, 3.0, 6.0, 9.0]
    # a damaged file is traced and written again, never trusted
    written.write_bytes(b"not a program")
    assert cache.persistent_jit(jax.jit(lambda v: 5 * v), ("test", 1))(x).tolist() == [0.0, 5.0, 10.0, 15.0]
    assert written.read_bytes() != b"not a program"
    # under a transformation, and with the cache off, it is the function it was given
    assert jax.grad(lambda v: cache.persistent_jit(jax.jit(lambda u: 7 * u), ("test", 1))(v).sum())(x).tolist() == [7.0] * 4
    monkeypatch.setattr(cache, "_exported_dir", None)
    assert cache.persistent_jit(jax.jit(lambda v: 11 * v), ("test", 1))(x).tolist() == [0.0, 11.0, 22.0, 33.0]


def _while_body_text(hlo):
    """The text of the first while loop's body and every computation it calls, in compiled HLO."""
    import re

    comps = {c.split(" ", 1)[0].lstrip("%"): c for c in re.split(r"\n(?=\S)", hlo) if c.strip()}

    def reach(name, seen):
        if name in seen or name not in comps:
            return ""
        seen.add(name)
        called = re.findall(r"(?:calls|to_apply|body|condition|branch_computations)=\{?%?([\w.\-]+)", comps[name])
        return comps[name] + "".join(reach(c, seen) for c in called)

    body = re.search(r"body=%?([\w.\-]+)", hlo).group(1)
    return reach(body, set())


@pytest.mark.check
def test_loop_jit_keeps_table_only_work_inside_the_loop():
    """XLA hoists a loop body's loop-invariant work (here sqrt of the table) out of a while loop;
    the solvers' programs (matfit.cache.loop_jit) are compiled without that pass, so the body
    recomputes it in its own fused kernels instead of reading a hoisted array."""
    import jax
    import jax.numpy as jnp

    from matfit.cache import loop_jit

    def f(x):
        return jax.lax.fori_loop(0, 5, lambda i, a: a + jnp.sum(jnp.sqrt(x) * i.astype(x.dtype)), jnp.zeros((), x.dtype))

    x = jnp.arange(1.0, 1001.0)
    assert "sqrt" not in _while_body_text(jax.jit(f).lower(x).compile().as_text())  # hoisted by default
    assert "sqrt" in _while_body_text(loop_jit(f).lower(x).compile().as_text())
    assert abs(float(loop_jit(f)(x)) - float(jax.jit(f)(x))) <= 1e-5 * float(jax.jit(f)(x))
