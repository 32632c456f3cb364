"""Malformed input: each kind raises a DataFormatError naming the file and field; readers are fuzzed."""
import functools
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


def check_malformed(tmp_path, reader, name, content, needles):
    """``reader`` of a file ``name`` holding ``content`` (bytes or text, or a function returning
    them) raises a DataFormatError whose message holds every one of ``needles``."""
    p = tmp_path / name
    content = content() if callable(content) else content
    if isinstance(content, str):
        p.write_text(content)
    else:
        p.write_bytes(content)
    with pytest.raises(DataFormatError) as ei:
        reader(p)
    expect(ei, *needles)


def cases(table):
    """``pytest.param`` s of a ``{id: (argument, ...)}`` table."""
    return [pytest.param(*args, id=case) for case, args in table.items()]


# ----------------------------------------------------------------------------------------- MERL
MERL_CASES = {  # id: (file name, content, needles)
    "empty_file": ("e.binary", b"", ("e.binary", "empty")),
    "truncated": ("t.binary", lambda: merl_bytes()[:-8], ("t.binary", "file size", str(FILE_SIZE), "truncated")),
    "trailing_bytes": ("l.binary", lambda: merl_bytes() + b"\0", ("file size", "trailing")),
    "wrong_dims": ("d.binary", lambda: np.array([90, 90, 360], "<i4").tobytes() + merl_bytes()[12:],
                   ("d.binary", "dims", "(90, 90, 180)", "(90, 90, 360)")),
}


@pytest.mark.parametrize("name,content,needles", cases(MERL_CASES))
def test_merl_malformed(tmp_path, name, content, needles):
    check_malformed(tmp_path, read_merl, name, content, needles)


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_merl_non_finite(tmp_path, bad):
    raw = bytearray(merl_bytes())
    raw[12 + 8 * 12345: 12 + 8 * 12346] = np.array([bad], "<f8").tobytes()
    check_malformed(tmp_path, read_merl, "n.binary", bytes(raw), ("n.binary", "data", "finite", "NaN/Inf"))


# ----------------------------------------------------------------------------------------- RGL
def test_rgl_synthetic_is_valid(tmp_path):
    b = read_rgl(rgl_bytes(tmp_path))
    t = b.to_table()
    assert len(t) == 4 * 16 and np.isfinite(t.values).all()


def _first_field(raw):
    """Offset of the first field's record after its name: uint16 ndim, uint8 dtype, uint64 offset,
    uint64 shape[0], ... (the header: 12-byte magic, 2-byte version, uint32 field count, then per
    field a uint16 name length and the name)."""
    return 18 + 2 + struct.unpack_from("<H", raw, 18)[0]


def _pack(fmt, at, value):
    """A mutation of the file's bytes: ``value`` packed as ``fmt`` at ``at`` (an offset, or a
    function of the bytes giving one)."""
    def mutate(raw):
        struct.pack_into(fmt, raw, at(raw) if callable(at) else at, value)
        return raw
    return mutate


RGL_BYTES_CASES = {  # id: (mutation of the valid file's bytes, needles)
    "wrong_magic": (_pack("12s", 0, b"tensor_fil3\0"), ("x.bsdf", "magic", "tensor_fil3")),
    "wrong_version": (_pack("B", 12, 2), ("version", "1.0", "2.0")),
    "truncated_data": (lambda raw: raw[:-100], ("offset/shape", "inside the")),
    "absurd_field_count": (_pack("<I", 14, 2 ** 31), ("field count", str(2 ** 31))),
    "bad_dtype_code": (_pack("B", lambda raw: _first_field(raw) + 2, 12), ("description.dtype", "1..11", "12")),
    "absurd_offset": (_pack("<Q", lambda raw: _first_field(raw) + 3, 2 ** 62),
                      ("description.offset/shape", str(2 ** 62))),
    "absurd_shape": (_pack("<Q", lambda raw: _first_field(raw) + 11, 2 ** 60),  # description's length
                     ("description.offset/shape", str(2 ** 60))),
}


@pytest.mark.check
@pytest.mark.parametrize("mutate,needles", cases(RGL_BYTES_CASES))
def test_rgl_malformed_bytes(tmp_path, mutate, needles):
    p = rgl_bytes(tmp_path)
    check_malformed(tmp_path, read_rgl, p.name, bytes(mutate(bytearray(p.read_bytes()))), needles)


def test_rgl_truncated_header(tmp_path):
    check_malformed(tmp_path, read_rgl, "h.bsdf", b"tensor_file\0\1\0", ("h.bsdf", "header", "truncated"))


def _vndf_with_nan():
    v = np.ones((1, 4, 8, 8), np.float32)
    v[0, 2, 3, 3] = np.nan
    return v


RGL_FIELD_CASES = {  # id: (changes to the valid file's fields (None: left out), needles)
    "wrong_field_dtype": (dict(theta_i=np.linspace(0, 1.5, 4)),  # float64 instead of float32
                          ("theta_i.dtype", "code 10", "code 11")),
    "missing_field": (dict(vndf=None), ("x.bsdf", "'vndf'", "none")),
    "wrong_shape": (dict(vndf=np.ones((1, 5, 8, 8), np.float32)), ("vndf.shape", "(1, 4, *, *)", "(1, 5, 8, 8)")),
    "nan_in_table": (dict(vndf=_vndf_with_nan()), ("'vndf'", "finite")),
    "negative_density": (dict(ndf=-np.ones((2, 8), np.float32)), ("'ndf'", "non-negative")),
    "unsorted_angles": (dict(theta_i=np.array([0, 1, 0.5, 1.5], np.float32)), ("theta_i", "increasing")),
}


@pytest.mark.parametrize("changes,needles", cases(RGL_FIELD_CASES))
def test_rgl_malformed_fields(tmp_path, changes, needles):
    with pytest.raises(DataFormatError) as ei:
        read_rgl(rgl_bytes(tmp_path, **changes))
    expect(ei, *needles)


# ----------------------------------------------------------------------------------------- CSV / npz
CSV_HEADER = "wo_x,wo_y,wo_z,wi_x,wi_y,wi_z,value_r,value_g,value_b\n"
GOOD_CSV = CSV_HEADER + "0,0,1,0,0,1,0.1,0.2,0.3\n"
CSV_CASES = {  # id: (file name, content, needles)
    "empty": ("e.csv", "", ("e.csv", "empty")),
    "wrong_header": ("h.csv", "wi_x,wi_y,wi_z,wo_x,wo_y,wo_z,value_r,value_g,value_b\n0,0,1,0,0,1,1,1,1\n",
                     ("h.csv", "header", "wo_x,wo_y,wo_z,wi_x,wi_y,wi_z")),
    "wrong_row_length": ("t.csv", GOOD_CSV + "0,0,1,0,0,1,0.1,0.2\n",
                         ("t.csv", "row", "9 columns", "8 columns", "line 3")),
    "not_a_number": ("t.csv", GOOD_CSV + "0,0,1,0,0,1,0.1,abc,0.3\n", ("value_g", "a number", "'abc'", "line 3")),
    "non_unit_direction": ("t.csv", GOOD_CSV + "0,0,2,0,0,1,0.1,0.2,0.3\n",
                           ("t.csv", "'wo'", "unit vectors", "norm 2")),
    "channel_mismatch": ("c.csv", "wo_x,wo_y,wo_z,wi_x,wi_y,wi_z,value_r,value_g\n0,0,1,0,0,1,1,1\n",
                         ("c.csv", "header", "mono | r,g,b")),
    "sigma_columns_mismatch": ("s.csv", CSV_HEADER[:-1] + ",sigma_r\n0,0,1,0,0,1,1,1,1,1\n",
                               ("sigma_ columns matching",)),
}


@pytest.mark.parametrize("name,content,needles", cases(CSV_CASES))
def test_csv_malformed(tmp_path, name, content, needles):
    check_malformed(tmp_path, Table.load_csv, name, content, needles)


def test_npz_not_an_archive(tmp_path):
    check_malformed(tmp_path, Table.load_npz, "r.npz", b"\x80\x04garbage that is not a zip", ("r.npz", "container"))


def test_npz_missing_key(tmp_path):
    p = tmp_path / "m.npz"
    np.savez(p, wo=np.zeros((1, 3)))
    with pytest.raises(DataFormatError) as ei:
        Table.load_npz(p)
    expect(ei, "m.npz", "keys", "missing")


NPZ_EDITS = {  # id: (array replaced in a valid archive, its new value, needles)
    "object_array_is_not_unpickled": ("provenance", np.array([{"evil": 1}], dtype=object),  # would need pickle
                                      ("o.npz", "provenance", "no pickles")),
    "wrong_format_version": ("format", np.array("matfit.table/99"), ("o.npz", "format", "matfit.table/1",
                                                                      "matfit.table/99")),
}


@pytest.mark.parametrize("key,value,needles", cases(NPZ_EDITS))
def test_npz_edited(tmp_path, key, value, needles):
    from tests.test_table import make_table

    p = tmp_path / "o.npz"
    make_table().save_npz(p)
    with np.load(p, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    arrays[key] = value
    np.savez(p, **arrays)
    with pytest.raises(DataFormatError) as ei:
        Table.load_npz(p)
    expect(ei, *needles)


# ----------------------------------------------------------------------------------------- ALTA / dispatch
ALTA_HEAD = "#PARAM_IN COS_TH\n#PARAM_OUT RGB_COLOR\n"
ALTA_CASES = {  # id: (content, needles); every file is a.alta
    "missing_dim": (ALTA_HEAD + "1 0.1 0.1 0.1\n", ("a.alta", "#DIM", "none")),
    "unknown_param": ("#DIM 1 3\n#PARAM_IN COS_BANANA\n#PARAM_OUT RGB_COLOR\n1 0.1 0.1 0.1\n",
                      ("#PARAM_IN", "COS_BANANA")),
    "dim_mismatch": ("#DIM 1 2\n" + ALTA_HEAD + "1 0.1 0.1\n", ("#DIM", "n_out = 3", "found 2")),
    "wrong_column_count": ("#DIM 1 3\n" + ALTA_HEAD + "1 0.1 0.1 0.1\n0.9 0.1 0.1\n",
                           ("a.alta", "row", "4 numbers", "line 5")),
    "nan": ("#DIM 1 3\n" + ALTA_HEAD + "1 nan 0.1 0.1\n", ("finite", "line 4")),
    "cosine_out_of_range": ("#DIM 1 3\n" + ALTA_HEAD + "1.5 0.1 0.1 0.1\n", ("COS_TH", "[0, 1]", "1.5")),
    "binary_rejected": ("#DIM 1 3\n" + ALTA_HEAD + "#FORMAT binary\n", ("#FORMAT", "binary")),
}


@pytest.mark.parametrize("content,needles", cases(ALTA_CASES))
def test_alta_malformed(tmp_path, content, needles):
    check_malformed(tmp_path, read_alta, "a.alta", content, needles)


def test_load_unknown_extension(tmp_path):
    check_malformed(tmp_path, load, "x.exr", b"\0", ("x.exr", "extension", ".bsdf"))


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


@pytest.mark.check
@FUZZ
@given(st.binary(max_size=3000))
def test_fuzz_random_bytes_all_readers(data):
    for fn in (read_merl, read_rgl, read_alta, Table.load_csv, Table.load_npz):
        with pytest.raises(DataFormatError):
            fn(data)


@functools.lru_cache(maxsize=None)
def _synthetic_rgl_bytes():
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "s.bsdf"
        write_tensor_file(p, rgl_fields())
        return p.read_bytes()


@functools.lru_cache(maxsize=None)
def _real_rgl_bytes():
    real = SHARED / "data" / "rgl" / "paper_white_rgb.bsdf"
    return real.read_bytes() if real.is_file() else None


@functools.lru_cache(maxsize=None)
def _npz_bytes():
    import tempfile

    from tests.test_table import make_table

    with tempfile.TemporaryDirectory() as d:
        make_table(n=5).save_npz(Path(d) / "t.npz")
        return (Path(d) / "t.npz").read_bytes()


def _header_len(b):
    tf = read_tensor_file(b)
    return min(tf.offsets.values())


def _mutated(base, muts, span=None):
    """``base`` with byte ``pos % span`` (default: its length) set to ``val`` for every (pos, val)."""
    raw = bytearray(base)
    for pos, val in muts:
        raw[pos % (span or len(raw))] = val
    return bytes(raw)


@FUZZ
@given(st.lists(st.tuples(st.integers(0, 10 ** 6), st.integers(0, 255)), min_size=1, max_size=6))
def test_fuzz_mutated_rgl_header(muts):
    for base in (_synthetic_rgl_bytes(), _real_rgl_bytes()):
        if base is not None:
            _ok_or_format_error(_rgl_full, _mutated(base, muts, _header_len(base)))


@FUZZ
@given(st.lists(st.tuples(st.integers(0, 10 ** 9), st.integers(0, 255)), min_size=1, max_size=8))
def test_fuzz_mutated_rgl_data(muts):
    _ok_or_format_error(_rgl_full, _mutated(_synthetic_rgl_bytes(), muts))


@settings(max_examples=25, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 11), st.integers(0, 255)), min_size=1, max_size=4),
       st.integers(-2, 2), st.booleans())
def test_fuzz_mutated_merl(muts, size_delta, nan_cell):
    raw = bytearray(_mutated(_merl_bytes_half(), muts))
    if nan_cell:
        raw[-8:] = b"\xff" * 8  # a NaN bit pattern
    if size_delta < 0:
        raw = raw[:size_delta]
    elif size_delta > 0:
        raw += b"\0" * size_delta
    m = _ok_or_format_error(read_merl, bytes(raw))
    if m is not None:
        assert np.isfinite(m.raw).all()


@functools.lru_cache(maxsize=None)
def _merl_bytes_half():
    return merl_bytes(0.5)


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


@FUZZ
@given(st.lists(st.tuples(st.integers(0, 10 ** 6), st.integers(0, 255)), min_size=1, max_size=4))
def test_fuzz_mutated_npz(muts):
    _ok_or_format_error(Table.load_npz, _mutated(_npz_bytes(), muts))
