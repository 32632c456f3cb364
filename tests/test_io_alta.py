"""ALTA text slices: header parsing, geometry of 1-D theta_h slices, the real pink-felt slice."""
from pathlib import Path

import numpy as np
import pytest

from matfit.io import load, read_alta
from matfit.io import dirs_to_half_diff

SHARED = Path(__file__).parents[1].parent / "shared"
PINK = SHARED / "data" / "merl_slices" / "pink-felt-1d.alta"


@pytest.mark.check
def test_minimal_cos_th(tmp_path):
    p = tmp_path / "s.alta"
    p.write_text("# a comment\n#DIM 1 3\n#PARAM_IN COS_TH\n#PARAM_OUT RGB_COLOR\n"
                 "1.0 0.5 0.4 0.3\n0.8 0.2 0.1 0.05\n\n0.5\t0.1\t0.1\t0.1\n")
    a = read_alta(p)
    assert a.x.shape == (3, 1) and a.y.shape == (3, 3) and a.param_in == "COS_TH"
    t = a.to_table()
    # theta_d = 0: light and view both along the half vector (retro-reflection slice)
    np.testing.assert_allclose(t.wo, t.wi, atol=1e-12)
    np.testing.assert_allclose(t.wo[:, 2], [1.0, 0.8, 0.5], atol=1e-12)
    np.testing.assert_allclose(t.wo[:, 1], 0.0, atol=1e-12)
    assert t.channels == "rgb" and t.valid.all()
    # overriding theta_d gives a proper half/difference geometry
    t2 = a.to_table(theta_d=0.3, phi_d=np.pi / 2)
    th, _, td, _ = dirs_to_half_diff(t2.wo, t2.wi)
    np.testing.assert_allclose(th, np.arccos([1.0, 0.8, 0.5]), atol=1e-7)
    np.testing.assert_allclose(td, 0.3, atol=1e-9)


def test_other_parametrizations(tmp_path):
    p = tmp_path / "r.alta"
    p.write_text("#DIM 3 1\n#PARAM_IN RUSIN_TH_TD_PD\n#PARAM_OUT INV_STERADIAN\n#VS 1\n"
                 "0.2 0.4 1.0 0.7 0.05\n0.3 0.1 2.0 0.6 0.02\n")
    t = load(p)
    assert t.channels == "mono" and t.sigma is not None
    np.testing.assert_allclose(t.sigma[:, 0], [0.05, 0.02])
    th, _, td, pd = dirs_to_half_diff(t.wo, t.wi)
    np.testing.assert_allclose(th, [0.2, 0.3], atol=1e-9)
    np.testing.assert_allclose(td, [0.4, 0.1], atol=1e-9)
    np.testing.assert_allclose(pd, [1.0, 2.0], atol=1e-9)
    p2 = tmp_path / "c.alta"
    p2.write_text("#DIM 6 3\n#PARAM_IN CARTESIAN\n#PARAM_OUT RGB_COLOR\n0 0 1 0.6 0 0.8 0.1 0.2 0.3\n")
    t2 = load(p2)
    np.testing.assert_allclose(t2.wi[0], [0, 0, 1])
    np.testing.assert_allclose(t2.wo[0], [0.6, 0, 0.8])


@pytest.mark.check
def test_pink_felt_slice():
    if not PINK.is_file():
        pytest.skip(f"shared ALTA slice not found: {PINK}")
    a, t = read_alta(PINK), load(PINK)
    assert a.header["DIM"] == "1 3" and a.param_in == "COS_TH" and a.param_out == "RGB_COLOR"
    assert len(t) == 90 and t.valid.all() and t.channels == "rgb"
    assert any("pink-felt" in c for c in a.comments)
    # theta_h increases along the file, up to about 84 deg; felt: red > green, all ~0.06-0.15 1/sr
    th = np.degrees(np.arccos(t.wo[:, 2]))
    assert np.all(np.diff(th) > 0) and 0.2 < th[0] < 0.4 and 83 < th[-1] < 85
    assert (t.values[:, 0] > t.values[:, 1]).all()
    assert 0.05 < t.values.min() and t.values.max() < 0.2
    # the file's COS_TH column: sin(theta_h) = (i + 1/2) / 90 (documented in matfit.io.alta)
    np.testing.assert_allclose(np.sin(np.radians(th)) * 90, np.arange(90) + 0.5, rtol=1e-4)
