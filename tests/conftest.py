import zlib

import jax
import numpy as np
import pytest


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
