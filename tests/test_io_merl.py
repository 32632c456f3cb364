"""MERL .binary reader/writer: layout, bit-exact round trip, cell rule, surrogate files from ../shared."""
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from matfit.io import load, read_merl, write_merl
from matfit.io.merl import RES, SCALE, MerlBRDF, cell_centres, cell_index
from matfit.io import dirs_to_half_diff, half_diff_to_dirs

SHARED = Path(__file__).parents[1].parent / "shared"
TOOL = SHARED / "tools" / "merl_surrogate.py"
WEIGHTS = SHARED / "data" / "merl_nbrdf" / "weights.npz"
MATERIAL = "pink-felt"


def synthetic_raw(seed=0):
    rng = np.random.default_rng(seed)
    raw = rng.uniform(0.0, 3000.0, size=(3,) + RES)
    raw[:, -3:, -2:, :] = -1.0  # a few invalid cells
    return raw


@pytest.mark.check
def test_round_trip_bit_exact(tmp_path):
    m = MerlBRDF(synthetic_raw())
    write_merl(tmp_path / "a.binary", m)
    data = (tmp_path / "a.binary").read_bytes()
    assert len(data) == 12 + 3 * 90 * 90 * 180 * 8
    assert np.frombuffer(data[:12], "<i4").tolist() == [90, 90, 180]
    m2 = read_merl(tmp_path / "a.binary")
    np.testing.assert_array_equal(m2.raw, m.raw)
    write_merl(tmp_path / "b.binary", m2)
    assert (tmp_path / "b.binary").read_bytes() == data
    # the layout: channel-major, flat index phi_d + 180 * (theta_d + 90 * theta_h)
    i, j, k = 17, 42, 101
    flat = k + 180 * (j + 90 * i)
    g = np.frombuffer(data, "<f8", offset=12)
    assert g[90 * 90 * 180 + flat] == m.raw[1, i, j, k]
    np.testing.assert_allclose(m2.values[:, i, j, k], m.raw[:, i, j, k] * SCALE, rtol=0)
    assert not m2.valid[-1, -1, 0] and m2.valid[0, 0, 0]


def test_cell_rule():
    th, td, pd = cell_centres()
    ih, _, _ = cell_index(th, np.zeros(90), np.zeros(90))
    np.testing.assert_array_equal(ih, np.arange(90))
    _, idd, _ = cell_index(np.zeros(90), td, np.zeros(90))
    np.testing.assert_array_equal(idd, np.arange(90))
    _, _, ip = cell_index(np.zeros(180), np.zeros(180), pd)
    np.testing.assert_array_equal(ip, np.arange(180))
    _, _, ip2 = cell_index(np.zeros(180), np.zeros(180), pd - np.pi)  # folding by reciprocity
    np.testing.assert_array_equal(ip2, np.arange(180))
    # theta_h index is sqrt-spaced: theta_h = 45 deg -> int(sqrt(0.5) * 90) = 63
    assert cell_index(np.pi / 4, 0.0, 0.0)[0] == 63
    # clamping at the ends
    assert cell_index(np.pi / 2, np.pi / 2, np.pi)[0:3] == (89, 89, 179)
    assert cell_index(0.0, 0.0, 0.0) == (0, 0, 0)


def test_half_diff_round_trip():
    rng = np.random.default_rng(1)
    th = rng.uniform(0, np.pi / 2, 1000)
    td = rng.uniform(0, np.pi / 2, 1000)
    pd = rng.uniform(-np.pi, np.pi, 1000)
    ph = rng.uniform(-np.pi, np.pi, 1000)
    wo, wi = half_diff_to_dirs(th, td, pd, ph)
    th2, ph2, td2, pd2 = dirs_to_half_diff(wo, wi)
    np.testing.assert_allclose(th2, th, atol=1e-9)
    np.testing.assert_allclose(td2, td, atol=1e-9)
    np.testing.assert_allclose(np.angle(np.exp(1j * (pd2 - pd))), 0, atol=1e-7)


@pytest.mark.check
def test_lookup_reciprocal_and_horizon():
    m = MerlBRDF(synthetic_raw(2))
    rng = np.random.default_rng(3)
    v = rng.normal(size=(2000, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    w = rng.normal(size=(2000, 3))
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    a, oka = m.lookup(v, w)
    b, okb = m.lookup(w, v)
    np.testing.assert_array_equal(oka, okb)
    # swapping wi/wo flips the difference vector: same theta_d, phi_d + pi -> same folded cell
    np.testing.assert_array_equal(a, b)
    below = (v[:, 2] <= 0) | (w[:, 2] <= 0)
    assert not oka[below].any() and (a[below] == 0).all()


# ------------------------------------------------------------------------------- surrogate files
def _network(name, theta_h, theta_d, phi_d):
    """The Sztrajman et al. network, as data/README.md describes it (computed here independently)."""
    with np.load(WEIGHTS, allow_pickle=False) as z:
        W = [z[f"{name}/W{i}"].astype(np.float64) for i in (1, 2, 3)]
        b = [z[f"{name}/b{i}"].astype(np.float64) for i in (1, 2, 3)]
    half = np.stack([np.sin(theta_h), 0 * theta_h, np.cos(theta_h)], -1)  # phi_h = 0
    diff = np.stack([np.sin(theta_d) * np.cos(phi_d), np.sin(theta_d) * np.sin(phi_d), np.cos(theta_d)], -1)
    x = np.concatenate([half, diff], -1)
    for i in range(2):
        x = np.maximum(x @ W[i] + b[i], 0.0)
    return np.maximum(np.expm1(x @ W[2] + b[2]), 0.0)  # exp(x) - 1, BRDF >= 0


@pytest.fixture(scope="module")
def surrogate_file(tmp_path_factory):
    if not (TOOL.is_file() and WEIGHTS.is_file()):
        pytest.skip(f"shared data not found at {SHARED} (needs tools/merl_surrogate.py and data/merl_nbrdf/weights.npz)")
    out = tmp_path_factory.mktemp("merl")
    subprocess.run([sys.executable, str(TOOL), MATERIAL, "--out", str(out)], check=True, capture_output=True)
    return out / f"{MATERIAL}.binary"


def test_surrogate_values_at_cell_centres(surrogate_file):
    m = read_merl(surrogate_file)
    th, td, pd = cell_centres()
    TH, TD, PD = np.meshgrid(th, td, pd, indexing="ij")
    net = _network(MATERIAL, TH, TD, PD)  # (90, 90, 180, 3)
    valid = m.valid
    # below-horizon cells are the invalid ones, nothing else
    wo, wi = half_diff_to_dirs(TH, TD, PD)
    np.testing.assert_array_equal(valid, (wo[..., 2] > 0) & (wi[..., 2] > 0))
    got = np.moveaxis(m.values, 0, -1)[valid]
    np.testing.assert_allclose(got, net[valid], rtol=1e-12, atol=1e-15)
    assert 0.6 < valid.mean() < 0.9


def test_surrogate_table_and_lookup(surrogate_file, tmp_path):
    table, m = load(surrogate_file, return_native=True)
    assert len(table) == 90 * 90 * 180 and table.channels == "rgb"
    assert table.n_valid == int(m.valid.sum())
    sub = table.subsample(5000, seed=0)
    th, _, td, pd = dirs_to_half_diff(sub.wo, sub.wi)
    net = _network(MATERIAL, th, td, pd)
    np.testing.assert_allclose(sub.values, net, rtol=1e-9, atol=1e-12)
    vals, ok = m.lookup(sub.wo, sub.wi)
    assert ok.all()
    np.testing.assert_array_equal(vals, sub.values)
    # bit-exact rewrite of the surrogate's own file
    write_merl(tmp_path / "copy.binary", m)
    assert (tmp_path / "copy.binary").read_bytes() == Path(surrogate_file).read_bytes()
    # pink-felt: a rough, reddish diffuse material (red > green > blue, modest peak)
    med = np.median(table.values[table.valid], axis=0)
    assert med[0] > med[1] > med[2] > 0.03
