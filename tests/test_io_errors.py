"""Malformed input: each kind raises a DataFormatError naming the file and field; readers are fuzzed."""
import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from matfit.errors import DataFormatError, MatfitError
from matfit.io import load, read_alta, read_merl, read_rgl, read_tensor_file, write_tensor_file
from matfit.io.merl import FILE_SIZE, RES
from matfit.table import Table

SHARED = Path(__file__).parents[1].parent / "shared"


# ----------------------------------------------------------------------------------------- helpers
def rgl_fields(nt=4, n=8, m=4):
    """A small, valid, isotropic RGB tensor file (constant tables)."""
    return {
        "description": np.frombuffer(b"synthetic", dtype=np.uint8),
        "phi_i": np.zeros(1, np.float32),
        "theta_i": np.linspace(0, np.pi / 2, nt).astype(np.float32),
        "sigma": np.ones((2, n), np.float32),
        "ndf": np.ones((2, n), np.float32),
        "vndf": np.ones((1, nt, n, n), np.float32),
        "luminance": np.ones((1, nt, m, m), np.float32),
        "rgb": np.full((1, nt, 3, m, m), 0.5, np.float32),
        "jacobian": np.ones(1, np.uint8),
        "valid": np.ones(m * m, np.uint8),
    }


def rgl_bytes(tmp_path, **changes):
    f = rgl_fields()
    for k, v in changes.items():
        if v is None:
            f.pop(k)
        else:
            f[k] = v
    p = tmp_path / "x.bsdf"
    write_tensor_file(p, f)
    return p


def merl_bytes(fill=1.0):
    return np.array(RES, "<i4").tobytes() + np.full(3 * 90 * 90 * 180, fill, "<f8").tobytes()


def expect(exc_info, *needles):
    msg = str(exc_info.value)
    assert isinstance(exc_info.value, MatfitError) and isinstance(exc_info.value, ValueError)
    for n in needles:
        assert n in msg, f"{n!r} not in {msg!r}"


def good_csv(tmp_path):
    p = tmp_path / "t.csv"
    p.write_text("wo_x,wo_y,wo_z,wi_x,wi_y,wi_z,value_r,value_g,value_b\n0,0,1,0,0,1,0.1,0.2,0.3\n")
    return p


# ----------------------------------------------------------------------------------------- MERL
def test_merl_empty_file(tmp_path):
    p = tmp_path / "e.binary"
    p.write_bytes(b"")
    with pytest.raises(DataFormatError) as ei:
        read_merl(p)
    expect(ei, "e.binary", "empty")


def test_merl_truncated(tmp_path):
    p = tmp_path / "t.binary"
    p.write_bytes(merl_bytes()[:-8])
    with pytest.raises(DataFormatError) as ei:
        read_merl(p)
    expect(ei, "t.binary", "file size", str(FILE_SIZE), "truncated")


def test_merl_trailing_bytes(tmp_path):
    p = tmp_path / "l.binary"
    p.write_bytes(merl_bytes() + b"\0")
    with pytest.raises(DataFormatError) as ei:
        read_merl(p)
    expect(ei, "file size", "trailing")


def test_merl_wrong_dims(tmp_path):
    p = tmp_path / "d.binary"
    p.write_bytes(np.array([90, 90, 360], "<i4").tobytes() + merl_bytes()[12:])
    with pytest.raises(DataFormatError) as ei:
        read_merl(p)
    expect(ei, "d.binary", "dims", "(90, 90, 180)", "(90, 90, 360)")


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_merl_non_finite(tmp_path, bad):
    raw = bytearray(merl_bytes())
    raw[12 + 8 * 12345: 12 + 8 * 12346] = np.array([bad], "<f8").tobytes()
    p = tmp_path / "n.binary"
    p.write_bytes(bytes(raw))
    with pytest.raises(DataFormatError) as ei:
        read_merl(p)
    expect(ei, "n.binary", "data", "finite", "NaN/Inf")


# ----------------------------------------------------------------------------------------- RGL
def test_rgl_synthetic_is_valid(tmp_path):
    b = read_rgl(rgl_bytes(tmp_path))
    t = b.to_table()
    assert len(t) == 4 * 16 and np.isfinite(t.values).all()


def test_rgl_wrong_magic(tmp_path):
    p = rgl_bytes(tmp_path)
    raw = bytearray(p.read_bytes())
    raw[:12] = b"tensor_fil3\0"
    p.write_bytes(bytes(raw))
    with pytest.raises(DataFormatError) as ei:
        read_rgl(p)
    expect(ei, "x.bsdf", "magic", "tensor_fil3")


def test_rgl_wrong_version(tmp_path):
    p = rgl_bytes(tmp_path)
    raw = bytearray(p.read_bytes())
    raw[12] = 2
    p.write_bytes(bytes(raw))
    with pytest.raises(DataFormatError) as ei:
        read_rgl(p)
    expect(ei, "version", "1.0", "2.0")


def test_rgl_truncated_header(tmp_path):
    p = tmp_path / "h.bsdf"
    p.write_bytes(b"tensor_file\0\1\0")
    with pytest.raises(DataFormatError) as ei:
        read_rgl(p)
    expect(ei, "h.bsdf", "header", "truncated")


def test_rgl_truncated_data(tmp_path):
    p = rgl_bytes(tmp_path)
    p.write_bytes(p.read_bytes()[:-100])
    with pytest.raises(DataFormatError) as ei:
        read_rgl(p)
    expect(ei, "offset/shape", "inside the")


def test_rgl_absurd_field_count(tmp_path):
    p = rgl_bytes(tmp_path)
    raw = bytearray(p.read_bytes())
    raw[14:18] = struct.pack("<I", 2 ** 31)
    p.write_bytes(bytes(raw))
    with pytest.raises(DataFormatError) as ei:
        read_rgl(p)
    expect(ei, "field count", str(2 ** 31))


def test_rgl_bad_dtype_code(tmp_path):
    p = rgl_bytes(tmp_path)
    raw = bytearray(p.read_bytes())
    # first field: uint16 name length, name, uint16 ndim, uint8 dtype
    nlen = struct.unpack_from("<H", raw, 18)[0]
    raw[18 + 2 + nlen + 2] = 12
    p.write_bytes(bytes(raw))
    with pytest.raises(DataFormatError) as ei:
        read_rgl(p)
    expect(ei, "description.dtype", "1..11", "12")


def test_rgl_absurd_offset(tmp_path):
    p = rgl_bytes(tmp_path)
    raw = bytearray(p.read_bytes())
    nlen = struct.unpack_from("<H", raw, 18)[0]
    struct.pack_into("<Q", raw, 18 + 2 + nlen + 3, 2 ** 62)
    p.write_bytes(bytes(raw))
    with pytest.raises(DataFormatError) as ei:
        read_rgl(p)
    expect(ei, "description.offset/shape", str(2 ** 62))


def test_rgl_absurd_shape(tmp_path):
    p = rgl_bytes(tmp_path)
    raw = bytearray(p.read_bytes())
    nlen = struct.unpack_from("<H", raw, 18)[0]
    struct.pack_into("<Q", raw, 18 + 2 + nlen + 11, 2 ** 60)  # description's length
    p.write_bytes(bytes(raw))
    with pytest.raises(DataFormatError) as ei:
        read_rgl(p)
    expect(ei, "description.offset/shape", str(2 ** 60))


def test_rgl_wrong_field_dtype(tmp_path):
    p = rgl_bytes(tmp_path, theta_i=np.linspace(0, 1.5, 4))  # float64 instead of float32
    with pytest.raises(DataFormatError) as ei:
        read_rgl(p)
    expect(ei, "theta_i.dtype", "code 10", "code 11")


def test_rgl_missing_field(tmp_path):
    p = rgl_bytes(tmp_path, vndf=None)
    with pytest.raises(DataFormatError) as ei:
        read_rgl(p)
    expect(ei, "x.bsdf", "'vndf'", "none")


def test_rgl_wrong_shape(tmp_path):
    p = rgl_bytes(tmp_path, vndf=np.ones((1, 5, 8, 8), np.float32))
    with pytest.raises(DataFormatError) as ei:
        read_rgl(p)
    expect(ei, "vndf.shape", "(1, 4, *, *)", "(1, 5, 8, 8)")


def test_rgl_nan_in_table(tmp_path):
    v = np.ones((1, 4, 8, 8), np.float32)
    v[0, 2, 3, 3] = np.nan
    with pytest.raises(DataFormatError) as ei:
        read_rgl(rgl_bytes(tmp_path, vndf=v))
    expect(ei, "'vndf'", "finite")


def test_rgl_negative_density(tmp_path):
    with pytest.raises(DataFormatError) as ei:
        read_rgl(rgl_bytes(tmp_path, ndf=-np.ones((2, 8), np.float32)))
    expect(ei, "'ndf'", "non-negative")


def test_rgl_unsorted_angles(tmp_path):
    with pytest.raises(DataFormatError) as ei:
        read_rgl(rgl_bytes(tmp_path, theta_i=np.array([0, 1, 0.5, 1.5], np.float32)))
    expect(ei, "theta_i", "increasing")


# ----------------------------------------------------------------------------------------- CSV / npz
def test_csv_empty(tmp_path):
    p = tmp_path / "e.csv"
    p.write_text("")
    with pytest.raises(DataFormatError) as ei:
        Table.load_csv(p)
    expect(ei, "e.csv", "empty")


def test_csv_wrong_header(tmp_path):
    p = tmp_path / "h.csv"
    p.write_text("wi_x,wi_y,wi_z,wo_x,wo_y,wo_z,value_r,value_g,value_b\n0,0,1,0,0,1,1,1,1\n")
    with pytest.raises(DataFormatError) as ei:
        Table.load_csv(p)
    expect(ei, "h.csv", "header", "wo_x,wo_y,wo_z,wi_x,wi_y,wi_z")


def test_csv_wrong_row_length(tmp_path):
    p = good_csv(tmp_path)
    p.write_text(p.read_text() + "0,0,1,0,0,1,0.1,0.2\n")
    with pytest.raises(DataFormatError) as ei:
        Table.load_csv(p)
    expect(ei, "t.csv", "row", "9 columns", "8 columns", "line 3")


def test_csv_not_a_number(tmp_path):
    p = good_csv(tmp_path)
    p.write_text(p.read_text() + "0,0,1,0,0,1,0.1,abc,0.3\n")
    with pytest.raises(DataFormatError) as ei:
        Table.load_csv(p)
    expect(ei, "value_g", "a number", "'abc'", "line 3")


def test_csv_non_unit_direction(tmp_path):
    p = good_csv(tmp_path)
    p.write_text(p.read_text() + "0,0,2,0,0,1,0.1,0.2,0.3\n")
    with pytest.raises(DataFormatError) as ei:
        Table.load_csv(p)
    expect(ei, "t.csv", "'wo'", "unit vectors", "norm 2")


def test_csv_channel_mismatch(tmp_path):
    p = tmp_path / "c.csv"
    p.write_text("wo_x,wo_y,wo_z,wi_x,wi_y,wi_z,value_r,value_g\n0,0,1,0,0,1,1,1\n")
    with pytest.raises(DataFormatError) as ei:
        Table.load_csv(p)
    expect(ei, "c.csv", "header", "mono | r,g,b")


def test_csv_sigma_columns_mismatch(tmp_path):
    p = tmp_path / "s.csv"
    p.write_text("wo_x,wo_y,wo_z,wi_x,wi_y,wi_z,value_r,value_g,value_b,sigma_r\n0,0,1,0,0,1,1,1,1,1\n")
    with pytest.raises(DataFormatError) as ei:
        Table.load_csv(p)
    expect(ei, "sigma_ columns matching")


def test_npz_not_an_archive(tmp_path):
    p = tmp_path / "r.npz"
    p.write_bytes(b"\x80\x04garbage that is not a zip")
    with pytest.raises(DataFormatError) as ei:
        Table.load_npz(p)
    expect(ei, "r.npz", "container")


def test_npz_missing_key(tmp_path):
    p = tmp_path / "m.npz"
    np.savez(p, wo=np.zeros((1, 3)))
    with pytest.raises(DataFormatError) as ei:
        Table.load_npz(p)
    expect(ei, "m.npz", "keys", "missing")


def test_npz_object_array_is_not_unpickled(tmp_path):
    from tests.test_table import make_table

    p = tmp_path / "o.npz"
    make_table().save_npz(p)
    with np.load(p, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["provenance"] = np.array([{"evil": 1}], dtype=object)  # would need pickle to load
    np.savez(p, **arrays)
    with pytest.raises(DataFormatError) as ei:
        Table.load_npz(p)
    expect(ei, "o.npz", "provenance", "no pickles")


def test_npz_wrong_format_version(tmp_path):
    from tests.test_table import make_table

    p = tmp_path / "v.npz"
    make_table().save_npz(p)
    with np.load(p, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["format"] = np.array("matfit.table/99")
    np.savez(p, **arrays)
    with pytest.raises(DataFormatError) as ei:
        Table.load_npz(p)
    expect(ei, "format", "matfit.table/1", "matfit.table/99")


# ----------------------------------------------------------------------------------------- ALTA / dispatch
def test_alta_missing_dim(tmp_path):
    p = tmp_path / "a.alta"
    p.write_text("#PARAM_IN COS_TH\n#PARAM_OUT RGB_COLOR\n1 0.1 0.1 0.1\n")
    with pytest.raises(DataFormatError) as ei:
        read_alta(p)
    expect(ei, "a.alta", "#DIM", "none")


def test_alta_unknown_param(tmp_path):
    p = tmp_path / "a.alta"
    p.write_text("#DIM 1 3\n#PARAM_IN COS_BANANA\n#PARAM_OUT RGB_COLOR\n1 0.1 0.1 0.1\n")
    with pytest.raises(DataFormatError) as ei:
        read_alta(p)
    expect(ei, "#PARAM_IN", "COS_BANANA")


def test_alta_dim_mismatch(tmp_path):
    p = tmp_path / "a.alta"
    p.write_text("#DIM 1 2\n#PARAM_IN COS_TH\n#PARAM_OUT RGB_COLOR\n1 0.1 0.1\n")
    with pytest.raises(DataFormatError) as ei:
        read_alta(p)
    expect(ei, "#DIM", "n_out = 3", "found 2")


def test_alta_wrong_column_count(tmp_path):
    p = tmp_path / "a.alta"
    p.write_text("#DIM 1 3\n#PARAM_IN COS_TH\n#PARAM_OUT RGB_COLOR\n1 0.1 0.1 0.1\n0.9 0.1 0.1\n")
    with pytest.raises(DataFormatError) as ei:
        read_alta(p)
    expect(ei, "a.alta", "row", "4 numbers", "line 5")


def test_alta_nan(tmp_path):
    p = tmp_path / "a.alta"
    p.write_text("#DIM 1 3\n#PARAM_IN COS_TH\n#PARAM_OUT RGB_COLOR\n1 nan 0.1 0.1\n")
    with pytest.raises(DataFormatError) as ei:
        read_alta(p)
    expect(ei, "finite", "line 4")


def test_alta_cosine_out_of_range(tmp_path):
    p = tmp_path / "a.alta"
    p.write_text("#DIM 1 3\n#PARAM_IN COS_TH\n#PARAM_OUT RGB_COLOR\n1.5 0.1 0.1 0.1\n")
    with pytest.raises(DataFormatError) as ei:
        read_alta(p)
    expect(ei, "COS_TH", "[0, 1]", "1.5")


def test_alta_binary_rejected(tmp_path):
    p = tmp_path / "a.alta"
    p.write_text("#DIM 1 3\n#PARAM_IN COS_TH\n#PARAM_OUT RGB_COLOR\n#FORMAT binary\n")
    with pytest.raises(DataFormatError) as ei:
        read_alta(p)
    expect(ei, "#FORMAT", "binary")


def test_load_unknown_extension(tmp_path):
    p = tmp_path / "x.exr"
    p.write_bytes(b"\0")
    with pytest.raises(DataFormatError) as ei:
        load(p)
    expect(ei, "x.exr", "extension", ".bsdf")


# ----------------------------------------------------------------------------------------- fuzzing
FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                       HealthCheck.too_slow])


def _ok_or_format_error(fn, *a):
    try:
        return fn(*a)
    except DataFormatError:
        return None


def _rgl_full(data):
    b = read_rgl(data)
    t = b.to_table()
    assert np.isfinite(t.values).all()
    return b


@FUZZ
@given(st.binary(max_size=3000))
def test_fuzz_random_bytes_all_readers(data):
    for fn in (read_merl, read_rgl, read_alta, Table.load_csv, Table.load_npz):
        with pytest.raises(DataFormatError):
            fn(data)


_SYN = {}


def _synthetic_rgl_bytes():
    if "b" not in _SYN:
        import tempfile

        with tempfile.TemporaryDirectory() as d:
            p = Path(d) / "s.bsdf"
            write_tensor_file(p, rgl_fields())
            _SYN["b"] = p.read_bytes()
    return _SYN["b"]


def _header_len(b):
    tf = read_tensor_file(b)
    return min(tf.offsets.values())


@FUZZ
@given(st.lists(st.tuples(st.integers(0, 10 ** 6), st.integers(0, 255)), min_size=1, max_size=6))
def test_fuzz_mutated_rgl_header(muts):
    real = SHARED / "data" / "rgl" / "paper_white_rgb.bsdf"
    for base in [_synthetic_rgl_bytes()] + ([_SYN.setdefault("real", real.read_bytes())] if real.is_file() else []):
        raw = bytearray(base)
        hl = _header_len(base)
        for pos, val in muts:
            raw[pos % hl] = val
        _ok_or_format_error(_rgl_full, bytes(raw))


@FUZZ
@given(st.lists(st.tuples(st.integers(0, 10 ** 9), st.integers(0, 255)), min_size=1, max_size=8))
def test_fuzz_mutated_rgl_data(muts):
    raw = bytearray(_synthetic_rgl_bytes())
    for pos, val in muts:
        raw[pos % len(raw)] = val
    _ok_or_format_error(_rgl_full, bytes(raw))


_MERL = {}


@settings(max_examples=25, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 11), st.integers(0, 255)), min_size=1, max_size=4),
       st.integers(-2, 2), st.booleans())
def test_fuzz_mutated_merl(muts, size_delta, nan_cell):
    if "b" not in _MERL:
        _MERL["b"] = merl_bytes(0.5)
    raw = bytearray(_MERL["b"])
    for pos, val in muts:
        raw[pos] = val
    if nan_cell:
        raw[-8:] = b"\xff" * 8  # a NaN bit pattern
    if size_delta < 0:
        raw = raw[:size_delta]
    elif size_delta > 0:
        raw += b"\0" * size_delta
    m = _ok_or_format_error(read_merl, bytes(raw))
    if m is not None:
        assert np.isfinite(m.raw).all()


ALTA_OK = "#DIM 1 3\n#PARAM_IN COS_TH\n#PARAM_OUT RGB_COLOR\n1 0.1 0.2 0.3\n0.5 0.1 0.2 0.3\n"
CSV_OK = "# channels: \"rgb\"\nwo_x,wo_y,wo_z,wi_x,wi_y,wi_z,value_r,value_g,value_b,valid\n0,0,1,0,0,1,0.1,0.2,0.3,1\n"


@FUZZ
@given(st.sampled_from([ALTA_OK, CSV_OK]),
       st.lists(st.tuples(st.integers(0, 500), st.sampled_from(list("0123456789.,-#e \nxnaIf_DIMPRG\t\"[]{}:"))),
                min_size=1, max_size=6))
def test_fuzz_mutated_text(base, muts):
    s = list(base)
    for pos, ch in muts:
        s[pos % len(s)] = ch
    data = "".join(s).encode()
    fn = (lambda b: read_alta(b).to_table()) if base is ALTA_OK else Table.load_csv
    _ok_or_format_error(fn, data)


_NPZ = {}


@FUZZ
@given(st.lists(st.tuples(st.integers(0, 10 ** 6), st.integers(0, 255)), min_size=1, max_size=4))
def test_fuzz_mutated_npz(muts):
    if "b" not in _NPZ:
        from tests.test_table import make_table

        t = make_table(n=5)
        import tempfile

        with tempfile.TemporaryDirectory() as d:
            t.save_npz(Path(d) / "t.npz")
            _NPZ["b"] = (Path(d) / "t.npz").read_bytes()
    raw = bytearray(_NPZ["b"])
    for pos, val in muts:
        raw[pos % len(raw)] = val
    _ok_or_format_error(Table.load_npz, bytes(raw))
