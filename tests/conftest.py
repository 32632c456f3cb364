import os
import shutil
import sys
import tempfile
import zlib
from pathlib import Path

import jax
import numpy as np
import pytest

# The repository root holds numpy_ref (the numpy references shared with the benchmarks, not part of
# the library): importable however pytest was started, in xdist workers too.
ROOT = str(Path(__file__).resolve().parents[1])
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)



def pytest_configure(config):
    # float64 is on for the whole session, switched once here (float32 tests pass float32
    # arrays and parameters explicitly); no test module switches it at import
    jax.config.update("jax_enable_x64", True)
    # the CLI switches JAX's persistent compilation cache on; in-process CLI tests must neither
    # write into the user's cache nor change how the rest of the session compiles
    # (tests/test_cache.py tests the cache in subprocesses of its own)
    os.environ["MATFIT_NO_CACHE"] = "1"
    # one JAX persistent compilation cache for the session, in a fresh folder shared by the xdist
    # workers: a program that both workers (or two tests building the same program afresh)
    # compile is compiled once and loaded after; removed when the session ends
    folder = os.environ.get("MATFIT_TEST_JAX_CACHE")
    if folder is None:
        folder = tempfile.mkdtemp(prefix="matfit-test-jax-")
        os.environ["MATFIT_TEST_JAX_CACHE"] = folder  # inherited by the workers, started after this
        config._matfit_cache_owner = folder
    jax.config.update("jax_compilation_cache_dir", folder)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.2)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    config.addinivalue_line("markers", "check: the quick `make check` tier: one or a few quick tests per test file "
                            "(and the library's doctests), so that the tier touches every module in a few minutes")


def pytest_unconfigure(config):
    folder = getattr(config, "_matfit_cache_owner", None)
    if folder:
        shutil.rmtree(folder, ignore_errors=True)


#: Memory mappings of a worker above which its compiled programs are dropped (the kernel's limit,
#: ``vm.max_map_count``, is 65,530 here).
MAPPINGS_CLEAR = 25_000


def _mappings():
    try:
        with open("/proc/self/maps", "rb") as f:
            return sum(1 for _ in f)
    except OSError:
        return MAPPINGS_CLEAR + 1  # unknown: always release


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    """Drop JAX's in-memory compiled programs after every test module. Each XLA CPU executable
    holds memory mappings, and a worker that kept every program of its share of the suite came
    within a few thousand of the kernel's limit (``vm.max_map_count``, 65,530: 52,490 mappings
    late in a run); past it XLA's compiler cannot map code and the worker dies of a segfault.
    A program needed again is loaded from the session's persistent cache (above)."""
    yield
    if os.environ.get("MATFIT_CLEAR_ALWAYS") or _mappings() > MAPPINGS_CLEAR:
        jax.clear_caches()


@pytest.fixture(autouse=True, scope="module")
def _x64_stays_on(request):
    """The session runs in float64 (``pytest_configure``); a module that switches it off would run
    every later module of its worker in float32 unnoticed (test_conductor_guess.py once did)."""
    yield
    if not jax.config.read("jax_enable_x64"):
        jax.config.update("jax_enable_x64", True)
        pytest.fail(f"{request.module.__name__} left jax_enable_x64 off for the modules after it")


def pytest_collection_modifyitems(config, items):
    from _pytest.doctest import DoctestItem

    for item in items:
        # the library's doctests belong to the quick tier as well (one pytest run for make check)
        if isinstance(item, DoctestItem):
            item.add_marker(pytest.mark.check)


# --- dtype / rng fixtures (reference-agreement helper) -------------------------------------------
# x64 is switched on by the `dtype` fixture and stays on for the rest of the session; float32 tests
# therefore pass explicit float32 arrays (inputs and parameters) to the library.
@pytest.fixture(params=[np.float32, np.float64], ids=["f32", "f64"])
def dtype(request):
    jax.config.update("jax_enable_x64", True)
    return request.param


@pytest.fixture
def rng(request):
    """A numpy Generator seeded from the test id (reproducible, different per test)."""
    seed = zlib.crc32(request.node.nodeid.encode())
    return np.random.default_rng(seed)


@pytest.fixture
def x64():
    """Enable float64 in JAX (for float64-only tests that do not use `dtype`)."""
    jax.config.update("jax_enable_x64", True)
    return np.float64
