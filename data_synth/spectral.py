"""Spectral rendering: metal n, k tables and the spectrum -> linear sRGB map (via colour-science).

* :func:`metal_nk` interpolates the shipped table ``data/metals_nk.csv`` (gold and copper from Johnson &
  Christy 1972, aluminium from Rakic 1995, transcribed from the refractiveindex.info database; see the
  file header) linearly in wavelength.
* :func:`rgb_matrix` returns the (W, 3) matrix taking a spectral BRDF sampled at ``W`` wavelengths to
  linear sRGB under an illuminant: ``XYZ = sum_l f(l) S(l) xbar(l) dl / sum_l S(l) ybar(l) dl`` is
  computed by ``colour.msds_to_XYZ`` (method "Integration", CMFS ``colour.MSDS_CMFS[observer]``,
  illuminant ``colour.SDS_ILLUMINANTS[name]``), then ``colour.XYZ_to_sRGB`` without the transfer
  function (values stay linear, in 1/sr), with chromatic adaptation from the illuminant's white point.
  A constant spectrum f = 1 therefore renders to RGB (1, 1, 1) (to 1e-3).
"""
from __future__ import annotations

import csv
import functools
from pathlib import Path

import numpy as np

DATA_FILE = Path(__file__).with_name("data") / "metals_nk.csv"
DEFAULT_OBSERVER = "CIE 1931 2 Degree Standard Observer"
#: Wavelengths (nm) used for eta/k when a metal is named in an RGB (non-spectral) scene.
RGB_WAVELENGTHS = (630.0, 532.0, 465.0)


@functools.lru_cache(maxsize=None)
def _table():
    rows = {}
    with open(DATA_FILE, newline="") as fh:
        lines = [ln for ln in fh if not ln.startswith("#")]
    for r in csv.DictReader(lines):
        rows.setdefault(r["metal"], []).append((float(r["wavelength_nm"]), float(r["n"]), float(r["k"])))
    return {m: np.array(sorted(v)) for m, v in rows.items()}


def metals():
    """Names of the tabulated metals."""
    return sorted(_table())


def metal_range(name):
    """(min, max) wavelength in nm covered by the metal's table."""
    t = _table()[name]
    return float(t[0, 0]), float(t[-1, 0])


def metal_nk(name, wavelengths):
    """``(n, k)`` arrays at ``wavelengths`` (nm), linearly interpolated. Raises KeyError/ValueError."""
    t = _table()[name]
    wl = np.asarray(wavelengths, dtype=np.float64)
    if wl.min() < t[0, 0] or wl.max() > t[-1, 0]:
        raise ValueError(f"{name}: wavelengths must lie in [{t[0, 0]:g}, {t[-1, 0]:g}] nm")
    return np.interp(wl, t[:, 0], t[:, 1]), np.interp(wl, t[:, 0], t[:, 2])


def illuminants():
    import colour

    return sorted(colour.SDS_ILLUMINANTS)


def observers():
    import colour

    return sorted(colour.MSDS_CMFS)


@functools.lru_cache(maxsize=32)
def rgb_matrix(start, stop, step, illuminant="D65", observer=DEFAULT_OBSERVER):
    """(W, 3) matrix M with ``rgb = spectrum @ M`` (linear sRGB) for the grid start..stop (nm) by step."""
    import colour

    shape = colour.SpectralShape(float(start), float(stop), float(step))
    cmfs = colour.MSDS_CMFS[observer].copy().align(shape)
    ill = colour.SDS_ILLUMINANTS[illuminant].copy().align(shape)
    w = len(shape.wavelengths)
    xyz = colour.msds_to_XYZ(np.eye(w), cmfs, ill, method="Integration", shape=shape) / 100.0  # (W, 3)
    white = colour.XYZ_to_xy(colour.sd_to_XYZ(ill, cmfs) / 100.0)
    rgb = colour.XYZ_to_sRGB(xyz, illuminant=white, apply_cctf_encoding=False)
    return np.asarray(rgb, dtype=np.float64)


def wavelength_grid(start, stop, step):
    import colour

    return np.asarray(colour.SpectralShape(float(start), float(stop), float(step)).wavelengths, dtype=np.float64)
