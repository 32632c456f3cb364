"""Table: validation, subsets, npz / CSV round trips, JAX view."""
import json

import numpy as np
import pytest

from matfit.errors import DataFormatError, MatfitError
from matfit.table import Table


def _dirs(rng, n):
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2]) + 0.1
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def make_table(n=50, channels="rgb", seed=0, **kw):
    rng = np.random.default_rng(seed)
    c = {"mono": 1}.get(channels, 3) if isinstance(channels, str) else len(channels)
    args = dict(wo=_dirs(rng, n), wi=_dirs(rng, n), values=rng.uniform(0.01, 2.0, size=(n, c)),
                channels=channels, provenance={"source": "unit-test", "ground_truth": {"alpha": 0.3}})
    args.update(kw)
    return Table(**args)


def test_construct_basic():
    t = make_table()
    assert len(t) == 50 and t.n_channels == 3 and t.n_valid == 50
    assert t.values.dtype == np.float64 and t.valid.dtype == bool
    assert not t.values.flags.writeable  # immutable
    with pytest.raises(Exception):
        t.values[0, 0] = 1.0
    assert "50 samples" in t.summary() and "unit-test" in t.summary()


def test_errors_are_value_errors_and_name_the_field():
    with pytest.raises(DataFormatError) as ei:
        make_table(values=np.ones((50, 2)))
    assert isinstance(ei.value, MatfitError) and isinstance(ei.value, ValueError)
    assert "values" in str(ei.value) and "(N, 3)" in str(ei.value) and "(50, 2)" in str(ei.value)


@pytest.mark.parametrize("field,bad,needle", [
    ("wo", np.ones((50, 2)), "shape (50, 3)"),
    ("wi", np.full((50, 3), 0.6), "unit vectors"),
    ("values", np.full((50, 3), np.nan), "finite"),
    ("sigma", np.zeros((50, 3)), "> 0"),
    ("weight", -np.ones((50, 3)), ">= 0"),
    ("valid", np.full(50, 2), "booleans"),
    ("valid", np.ones(49, dtype=bool), "shape (50,)"),
    ("channels", "xyz", "'mono', 'rgb'"),
    ("channels", [550.0, -1.0, 600.0], "positive"),
    ("provenance", {"x": object()}, "JSON"),
])
def test_validation(field, bad, needle):
    with pytest.raises(DataFormatError) as ei:
        make_table(**{field: bad})
    assert field in str(ei.value) and needle in str(ei.value)


def test_sigma_and_weight_exclusive_and_broadcast():
    with pytest.raises(DataFormatError, match="sigma/weight"):
        make_table(sigma=np.ones(50), weight=np.ones(50))
    t = make_table(sigma=np.full(50, 0.5))
    assert t.sigma.shape == (50, 3)
    np.testing.assert_allclose(t.effective_weight(), 4.0)
    valid = np.ones(50, bool)
    valid[:5] = False
    t = make_table(weight=np.full((50, 1), 2.0), valid=valid)
    w = t.effective_weight()
    assert w.shape == (50, 3) and (w[:5] == 0).all() and (w[5:] == 2).all()


def test_mono_and_spectral_channels():
    t = make_table(channels="mono", values=np.ones(50))
    assert t.values.shape == (50, 1) and t.channel_labels == ["mono"]
    t = make_table(channels=[450, 550.5, 650])
    assert t.channels == (450.0, 550.5, 650.0) and t.channel_labels == ["450nm", "550.5nm", "650nm"]


def test_select_subsample_split():
    valid = np.arange(50) % 5 != 0
    t = make_table(valid=valid)
    s = t.select(t.values[:, 0] > 1.0)
    assert len(s) == int((t.values[:, 0] > 1.0).sum())
    s2 = t.select(np.array([3, 1, 2]))
    np.testing.assert_array_equal(s2.values, t.values[[3, 1, 2]])
    sub = t.subsample(20, seed=3)
    assert len(sub) == 20 and sub.valid.all()
    np.testing.assert_array_equal(sub.values, t.subsample(20, seed=3).values)  # deterministic
    assert sub.provenance["derivation"][-1] == {"op": "subsample", "n": 20, "seed": 3, "valid_only": True}
    with pytest.raises(DataFormatError, match="n"):
        t.subsample(41)  # only 40 valid rows
    fit, hold = t.split(0.8, seed=1)
    assert len(fit) == 40 and len(hold) == 10
    both = np.concatenate([fit.values, hold.values])
    assert sorted(map(tuple, both)) == sorted(map(tuple, t.values))  # a partition
    assert fit.provenance["ground_truth"] == {"alpha": 0.3}
    with pytest.raises(DataFormatError, match="frac"):
        t.split(1.0)
    with pytest.raises(DataFormatError, match="mask"):
        t.select(np.ones(3, bool))


def _assert_same(a: Table, b: Table):
    for f in ("wo", "wi", "values", "valid"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
    for f in ("sigma", "weight"):
        x, y = getattr(a, f), getattr(b, f)
        assert (x is None) == (y is None)
        if x is not None:
            np.testing.assert_array_equal(x, y)
    assert a.channels == b.channels and a.provenance == b.provenance


@pytest.mark.parametrize("kw", [dict(), dict(sigma=np.full(50, 0.1)), dict(weight=np.linspace(0, 1, 50)),
                                dict(channels="mono", values=np.linspace(0.1, 1, 50)),
                                dict(channels=[400.0, 500.0, 600.0, 700.0], values=np.ones((50, 4)))])
def test_npz_and_csv_round_trip(tmp_path, kw):
    valid = np.arange(50) % 7 != 0
    t = make_table(valid=valid, **kw)
    t.save_npz(tmp_path / "t.npz")
    _assert_same(t, Table.load_npz(tmp_path / "t.npz"))
    t.save_csv(tmp_path / "t.csv")
    _assert_same(t, Table.load_csv(tmp_path / "t.csv"))  # repr(float) round-trips exactly
    with np.load(tmp_path / "t.npz", allow_pickle=False) as z:  # no object arrays inside
        assert json.loads(str(z["provenance"]))["source"] == "unit-test"


def test_csv_header_documented_layout(tmp_path):
    t = make_table(sigma=np.full(50, 0.1))
    t.save_csv(tmp_path / "t.csv")
    header = [l for l in (tmp_path / "t.csv").read_text().splitlines() if not l.startswith("#")][0]
    assert header == ("wo_x,wo_y,wo_z,wi_x,wi_y,wi_z,value_r,value_g,value_b,"
                      "sigma_r,sigma_g,sigma_b,valid")


def test_csv_minimal_hand_written(tmp_path):
    p = tmp_path / "m.csv"
    p.write_text("wo_x,wo_y,wo_z,wi_x,wi_y,wi_z,value_mono\n0,0,1,0,0,1,0.3\n0.6,0,0.8,0,0,1,0.25\n")
    t = Table.load_csv(p)
    assert t.channels == "mono" and len(t) == 2 and t.valid.all() and t.provenance == {}


@pytest.mark.check
def test_as_jax():
    import jax.numpy as jnp

    t = make_table(valid=np.arange(50) % 2 == 0)
    a = t.as_jax()
    assert isinstance(a.values, jnp.ndarray) and a.values.shape == (50, 3)
    assert float(a.weight[1, 0]) == 0.0 and float(a.weight[0, 0]) == 1.0
