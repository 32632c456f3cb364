"""Test data shared by several test files: random direction pairs, and the RGL measurements of
the ``shared`` folder beside the checkout (a test that needs a missing file is skipped)."""

from pathlib import Path

import numpy as np
import pytest

#: The measured RGL ``.bsdf`` files (``../shared/data/rgl`` beside the checkout).
RGL_DIR = Path(__file__).parents[1].parent / "shared" / "data" / "rgl"


def random_pairs(rng, n):
    """``(wo, wi)``, ``n`` random direction pairs each of cosine uniform in (0.15, 1) and of
    uniform azimuth (drawn from ``rng``: ``wo``'s cosines and azimuths, then ``wi``'s)."""

    def dirs():
        th = np.arccos(rng.uniform(0.15, 1.0, n))
        ph = rng.uniform(0, 2 * np.pi, n)
        return np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1)

    wo = dirs()
    return wo, dirs()


def rgl_path(name):
    """The path of the RGL measurement ``name`` (``{name}_rgb.bsdf``); skips the test when absent."""
    p = RGL_DIR / f"{name}_rgb.bsdf"
    if not p.is_file():
        pytest.skip(f"shared RGL data not found: {p} (../shared beside the checkout)")
    return p
