"""RGL material database files (``.bsdf``): Mitsuba/powitacq tensor files, Dupuy & Jakob 2018.

Container ("tensor file", little-endian)::

    char[12]  "tensor_file\\0"
    uint8[2]  version (1, 0)
    uint32    number of fields
    per field: uint16 name length, name bytes, uint16 ndim, uint8 dtype code, uint64 offset,
               uint64[ndim] shape
    field data at the given offsets, C order

dtype codes (powitacq's ``Tensor::Type``): 1 uint8, 2 int8, 3 uint16, 4 int16, 5 uint32, 6 int32,
7 uint64, 8 int64, 9 float16, 10 float32, 11 float64.

BRDF fields: ``theta_i``, ``phi_i`` (measured incidence angles), ``ndf`` and ``sigma`` (2-D, indexed by
``(phi, theta)`` in unit coordinates), ``vndf`` and ``luminance`` (4-D: phi_i, theta_i, rows, cols),
``rgb`` (5-D: phi_i, theta_i, 3, rows, cols) or ``spectra`` + ``wavelengths``, ``jacobian`` (uint8 flag),
``description`` (uint8 text), optional ``valid`` (uint8 per sample-space node).

Evaluation follows the published scheme of the RGL loader (powitacq_rgb): the half vector is mapped to
unit coordinates ``u_m = (sqrt(theta_m / (pi/2)), (phi_m - phi_i + pi) / 2pi mod 1)``; the inverse of the
VNDF warp (a marginal-conditional warp of the bilinearly interpolated ``vndf`` table, itself linearly
interpolated over ``phi_i, theta_i``) takes it to the sample space where the ``rgb``/``spectra`` table is
bilinearly interpolated (and linearly over incidence angles); the result, clipped at 0, is multiplied by
``ndf(u_m) / (4 sigma(u_i))`` (when ``jacobian`` is set) to give ``f_r * cos(theta_o)``. ``wi`` (light) is
the file's incidence direction. :meth:`RglBRDF.eval` divides by ``cos(theta_o)`` to return the BRDF in 1/sr.

Errors (:class:`~matfit.errors.DataFormatError`, naming the file or ``<bytes>`` and the field).
:func:`read_tensor_file`: an empty or truncated file, a wrong magic or version, a field count too
large for the file, a field name that is not non-empty printable ASCII, an unknown type code, more
than 16 dimensions, data outside the file, a repeated name. :class:`RglBRDF`: a missing field, a
wrong type code or shape, NaN / Inf, fewer than 2 ``theta_i`` or 2 x 2 grid nodes, angles not
strictly increasing or out of range, negative densities or non-positive ``sigma``, wavelengths not
increasing and positive, an anisotropic file without the full 2 pi azimuth range, an all-zero
``vndf`` slice, a ``valid`` field that is not uint8 of one entry per node.
:func:`tensor_file_bytes`: a dtype outside :data:`DTYPES`.
"""
from __future__ import annotations

import math
import struct
from dataclasses import dataclass

import numpy as np

from .._dataerr import data_error
from ..table import Table
from ._source import read_source

__all__ = ["TensorFile", "read_tensor_file", "write_tensor_file", "tensor_file_bytes", "uniform_fields", "RglBRDF",
           "read_rgl", "DTYPES"]

MAGIC = b"tensor_file\x00"
DTYPES = {1: np.dtype("<u1"), 2: np.dtype("<i1"), 3: np.dtype("<u2"), 4: np.dtype("<i2"), 5: np.dtype("<u4"),
          6: np.dtype("<i4"), 7: np.dtype("<u8"), 8: np.dtype("<i8"), 9: np.dtype("<f2"), 10: np.dtype("<f4"),
          11: np.dtype("<f8")}
_CODES = {v: k for k, v in DTYPES.items()}
_ONE_MINUS_EPS = 0.999999940395355225
_MAX_NDIM = 16


@dataclass(frozen=True)
class TensorFile:
    """A parsed tensor file; ``tf[name]`` is ``tf.fields[name]``, ``name in tf`` tells whether it has the field.

    Attributes
    ----------
    fields : dict
        Field name -> read-only array of the file's shape and dtype (:data:`DTYPES`), C order.
    dtype_codes, offsets : dict
        Field name -> the file's type code (1..11), and the byte offset of its data.
    source : str or None
        The file read (None for bytes).

    Examples
    --------
    >>> import numpy as np
    >>> from matfit.io.rgl import read_tensor_file, tensor_file_bytes
    >>> tf = read_tensor_file(tensor_file_bytes({"theta_i": np.array([0.0, 0.5], np.float32)}))
    >>> "theta_i" in tf, tf["theta_i"].tolist(), tf.dtype_codes["theta_i"], tf.offsets["theta_i"] % 8
    (True, [0.0, 0.5], 10, 0)
    """

    fields: dict
    dtype_codes: dict
    offsets: dict
    source: str | None = None

    def __getitem__(self, name):
        return self.fields[name]

    def __contains__(self, name):
        return name in self.fields


def read_tensor_file(path) -> TensorFile:
    """Parse a tensor file with strict bounds checks (errors: the module docstring).

    Parameters
    ----------
    path : str, PathLike or bytes
        The file, or its contents.

    Returns
    -------
    TensorFile
        Every field, as a read-only view of the bytes read.
    """
    buf, src, file = read_source(path, expected="a tensor file")
    size = len(buf)
    if size < 18:
        raise data_error("header", "at least 18 bytes (magic, version, field count)", f"{size} bytes (truncated)", file=file)
    if buf[:12] != MAGIC:
        raise data_error("magic", repr(MAGIC), repr(buf[:12]), file=file)
    if (buf[12], buf[13]) != (1, 0):
        raise data_error("version", "1.0", f"{buf[12]}.{buf[13]}", file=file)
    (n_fields,) = struct.unpack_from("<I", buf, 14)
    if n_fields > (size - 18) // 13:
        raise data_error("field count", f"at most {(size - 18) // 13} fields for a {size}-byte file", str(n_fields), file=file)
    pos = 18
    fields, codes, offsets = {}, {}, {}

    def need(nbytes, what):
        if pos + nbytes > size:
            raise data_error(what, f"{nbytes} more bytes at offset {pos}", f"end of file at {size} (truncated)", file=file)

    for k in range(n_fields):
        need(2, f"field #{k} name length")
        (nlen,) = struct.unpack_from("<H", buf, pos)
        pos += 2
        need(nlen, f"field #{k} name")
        try:
            name = buf[pos:pos + nlen].decode("ascii")
        except UnicodeDecodeError:
            raise data_error(f"field #{k} name", "ASCII text", repr(buf[pos:pos + nlen][:40]), file=file) from None
        if not name.isprintable() or not name:
            raise data_error(f"field #{k} name", "a non-empty printable name", repr(name[:40]), file=file)
        pos += nlen
        need(2 + 1 + 8, f"field '{name}' header")
        ndim, code, offset = struct.unpack_from("<HBQ", buf, pos)
        pos += 11
        if code not in DTYPES:
            raise data_error(f"{name}.dtype", "a type code in 1..11", str(code), file=file)
        if ndim > _MAX_NDIM:
            raise data_error(f"{name}.ndim", f"at most {_MAX_NDIM} dimensions", str(ndim), file=file)
        need(8 * ndim, f"field '{name}' shape")
        shape = struct.unpack_from(f"<{ndim}Q", buf, pos)
        pos += 8 * ndim
        nbytes = DTYPES[code].itemsize * math.prod(shape)
        if offset > size or nbytes > size - offset:
            raise data_error(f"{name}.offset/shape", f"data inside the {size}-byte file",
                             f"offset {offset} + {nbytes} bytes (shape {tuple(shape)})", file=file)
        if name in fields:
            raise data_error(f"{name}", "unique field names", "a duplicate", file=file)
        count = math.prod(shape)
        if count == 0:
            arr = np.empty(shape, dtype=DTYPES[code])
        else:
            arr = np.frombuffer(buf, dtype=DTYPES[code], count=count, offset=offset).reshape(shape)
        fields[name] = arr
        codes[name] = code
        offsets[name] = offset
    return TensorFile(fields, codes, offsets, src)


def write_tensor_file(path, fields: dict) -> None:
    """Write numpy arrays as a tensor file (:func:`tensor_file_bytes`).

    Parameters
    ----------
    path : str or PathLike
        Replaced if present.
    fields : dict
        Field name (ASCII) -> array of a dtype in :data:`DTYPES`.
    """
    data = tensor_file_bytes(fields, file=path)
    with open(path, "wb") as fh:
        fh.write(data)


def tensor_file_bytes(fields: dict, file=None) -> bytes:
    """The bytes of a tensor file holding ``fields``: header, then each field little-endian in C order at an 8-byte aligned offset.

    Parameters
    ----------
    fields : dict
        Field name (ASCII) -> array of a dtype in :data:`DTYPES`.
    file : str or PathLike, optional
        Named in error messages.

    Returns
    -------
    bytes
    """
    path = file
    items = []
    for name, a in fields.items():
        a = np.ascontiguousarray(a)
        dt = a.dtype.newbyteorder("<") if a.dtype.byteorder == ">" else a.dtype
        key = np.dtype(dt.str.replace("=", "<").replace("|", "<"))
        if key not in _CODES:
            raise data_error(name, "a dtype among " + ", ".join(str(d) for d in DTYPES.values()), str(a.dtype), file=path)
        items.append((name.encode("ascii"), a.astype(key, copy=False), _CODES[key]))
    header = 18 + sum(2 + len(n) + 11 + 8 * a.ndim for n, a, _ in items)
    off = (header + 7) // 8 * 8
    parts, blobs = [MAGIC, bytes([1, 0]), struct.pack("<I", len(items))], []
    for n, a, code in items:
        parts.append(struct.pack("<H", len(n)) + n + struct.pack("<HBQ", a.ndim, code, off)
                     + struct.pack(f"<{a.ndim}Q", *a.shape))
        pad = (-a.nbytes) % 8
        blobs.append(a.tobytes() + b"\0" * pad)
        off += a.nbytes + pad
    head = b"".join(parts)
    head += b"\0" * ((header + 7) // 8 * 8 - len(head))
    return head + b"".join(blobs)


def uniform_fields(value=0.5, n_theta: int = 4, nodes: int = 4, description: str = "uniform") -> dict:
    """The fields of a small isotropic RGB measurement whose tables are constant, for tests and examples.

    Every density (``ndf``, ``sigma``, ``vndf``, ``luminance``) is 1 and every ``rgb`` node is
    ``value``, so ``f_r cos(theta_o) = value / 4`` wherever both directions are above the horizon.

    Parameters
    ----------
    value : float, default 0.5
    n_theta : int, default 4
        Incidence angles, evenly spaced over [0, pi/2] (one azimuth).
    nodes : int, default 4
        The ``rgb`` and ``luminance`` grids are ``nodes x nodes``; ``vndf`` is twice as fine.
    description : str, default "uniform"

    Returns
    -------
    dict
        Field name -> array, for :func:`tensor_file_bytes` or :func:`write_tensor_file`.
    """
    n2 = 2 * nodes
    return {"description": np.frombuffer(description.encode("utf-8"), np.uint8),
            "phi_i": np.zeros(1, np.float32),
            "theta_i": np.linspace(0, np.pi / 2, n_theta, dtype=np.float32),
            "ndf": np.ones((2, n2), np.float32), "sigma": np.ones((2, n2), np.float32),
            "vndf": np.ones((1, n_theta, n2, n2), np.float32),
            "luminance": np.ones((1, n_theta, nodes, nodes), np.float32),
            "rgb": np.full((1, n_theta, 3, nodes, nodes), value, np.float32),
            "jacobian": np.ones(1, np.uint8)}


# ----------------------------------------------------------------------------------------------------
# Marginal-conditional 2-D warp with linear interpolation over parameters (numpy, float64)
# ----------------------------------------------------------------------------------------------------
class _Warp2D:
    def __init__(self, data, param_values=(), build_cdf=True):
        data = np.asarray(data, dtype=np.float64)
        self.param_values = [np.asarray(v, dtype=np.float64) for v in param_values]
        self.param_res = tuple(len(v) for v in self.param_values)
        self.ny, self.nx = data.shape[-2:]
        s = int(np.prod(self.param_res)) if self.param_res else 1
        d = data.reshape(s, self.ny, self.nx)
        self.strides = [int(np.prod(self.param_res[i + 1:])) for i in range(len(self.param_res))]
        self.build_cdf = build_cdf
        if build_cdf:
            cond = np.zeros_like(d)
            cond[:, :, 1:] = np.cumsum(0.5 * (d[:, :, :-1] + d[:, :, 1:]), axis=2)
            marg = np.zeros((s, self.ny))
            marg[:, 1:] = np.cumsum(0.5 * (cond[:, :-1, -1] + cond[:, 1:, -1]), axis=1)
            total = marg[:, -1].copy()
            self.totals = total
            norm = 1.0 / np.where(total > 0, total, 1.0)
            self.cond = (cond * norm[:, None, None]).reshape(s, -1)
            self.marg = marg * norm[:, None]
            d = d * norm[:, None, None]
        self.data = d.reshape(s, -1)
        self.inv_patch = np.array([self.nx - 1, self.ny - 1], dtype=np.float64)

    def _weights(self, params):
        slices = np.zeros((1, 1), dtype=np.int64)
        w = np.ones((1, 1))
        for dim, vals in enumerate(self.param_values):
            p = np.asarray(params[dim], dtype=np.float64)
            if len(vals) == 1:
                continue
            i = np.clip(np.searchsorted(vals, p, side="right") - 1, 0, len(vals) - 2)
            w1 = np.clip((p - vals[i]) / (vals[i + 1] - vals[i]), 0.0, 1.0)
            st = self.strides[dim]
            idx = np.stack([i, i + 1], 1) * st  # (N, 2)
            ww = np.stack([1.0 - w1, w1], 1)
            slices = (slices[:, :, None] + idx[:, None, :]).reshape(idx.shape[0], -1)
            w = (w[:, :, None] * ww[:, None, :]).reshape(ww.shape[0], -1)
        return slices, w

    @staticmethod
    def _lookup(table, slices, w, idx):
        # table (S, M); slices, w (N or 1, K); idx (N,) -> (N,)
        return np.sum(w * table[slices, idx[:, None]], axis=1)

    def eval(self, pos, params=()):
        pos = np.asarray(pos, dtype=np.float64)
        slices, w = self._weights(params)
        p = pos * self.inv_patch
        off = np.clip(np.floor(p), 0, self.inv_patch - 1).astype(np.int64)
        w1 = p - off
        w0 = 1.0 - w1
        idx = off[:, 0] + off[:, 1] * self.nx
        L = lambda i: self._lookup(self.data, slices, w, i)  # noqa: E731
        v00, v10, v01, v11 = L(idx), L(idx + 1), L(idx + self.nx), L(idx + self.nx + 1)
        r = w0[:, 1] * (w0[:, 0] * v00 + w1[:, 0] * v10) + w1[:, 1] * (w0[:, 0] * v01 + w1[:, 0] * v11)
        return r * (self.inv_patch.prod() if self.build_cdf else 1.0)

    def invert(self, sample, params=()):
        """Inverse of :meth:`sample`: a point of the warped domain -> its uniform sample and pdf."""
        nx = self.nx
        slices, w = self._weights(params)
        s = np.asarray(sample, dtype=np.float64) * self.inv_patch
        pos = np.clip(np.floor(s), 0, self.inv_patch - 1).astype(np.int64)
        s = s - pos
        off = pos[:, 0] + pos[:, 1] * nx
        L = lambda t, i: self._lookup(t, slices, w, i)  # noqa: E731
        v00, v10, v01, v11 = L(self.data, off), L(self.data, off + 1), L(self.data, off + nx), L(self.data, off + nx + 1)
        sx, sy = s[:, 0], s[:, 1]
        c0 = (1 - sy) * v00 + sy * v01
        c1 = (1 - sy) * v10 + sy * v11
        pdf = (1 - sx) * c0 + sx * c1
        sx = sx * (c0 + 0.5 * sx * (c1 - c0))
        sx = sx + (1 - sy) * L(self.cond, off) + sy * L(self.cond, off + nx)
        roff = pos[:, 1] * nx
        r0 = L(self.cond, roff + nx - 1)
        r1 = L(self.cond, roff + 2 * nx - 1)
        den = (1 - sy) * r0 + sy * r1
        with np.errstate(divide="ignore", invalid="ignore"):
            sx = np.where(den > 0, sx / np.where(den > 0, den, 1.0), 0.0)
        sy = sy * (r0 + 0.5 * sy * (r1 - r0))
        sy = sy + L(self.marg, pos[:, 1])
        return np.stack([sx, sy], 1), pdf * self.inv_patch.prod()

    def sample(self, u, params=()):
        """Warp uniform samples (N, 2) in [0, 1]^2 to the density; returns (positions, pdf)."""
        nx, ny = self.nx, self.ny
        u = np.clip(np.asarray(u, dtype=np.float64), 1.0 - _ONE_MINUS_EPS, _ONE_MINUS_EPS)
        n = u.shape[0]
        slices, w = self._weights(params)
        slices = np.broadcast_to(slices, (n, slices.shape[1]))
        w = np.broadcast_to(w, (n, w.shape[1]))
        ux, uy = u[:, 0].copy(), u[:, 1].copy()
        M = np.einsum("nk,nky->ny", w, self.marg[slices])
        row = np.clip(np.sum(M < uy[:, None], axis=1) - 1, 0, ny - 2)
        ar = np.arange(n)
        uy = uy - M[ar, row]
        cidx = row[:, None] * nx + np.arange(2 * nx)[None, :]
        C = np.einsum("nk,nkm->nm", w, self.cond[slices[:, :, None], cidx[:, None, :]])
        r0, r1 = C[:, nx - 1], C[:, 2 * nx - 1]
        uy = _solve_linear_cdf(uy, r0, r1)
        ux = ux * ((1 - uy) * r0 + uy * r1)
        F = (1 - uy)[:, None] * C[:, :nx] + uy[:, None] * C[:, nx:]
        col = np.clip(np.sum(F < ux[:, None], axis=1) - 1, 0, nx - 2)
        ux = ux - F[ar, col]
        off = row * nx + col
        L = lambda i: self._lookup(self.data, slices, w, i)  # noqa: E731
        v00, v10, v01, v11 = L(off), L(off + 1), L(off + nx), L(off + nx + 1)
        c0 = (1 - uy) * v00 + uy * v01
        c1 = (1 - uy) * v10 + uy * v11
        ux = _solve_linear_cdf(ux, c0, c1)
        pos = np.stack([(col + ux) / (nx - 1), (row + uy) / (ny - 1)], 1)
        return pos, ((1 - ux) * c0 + ux * c1) * self.inv_patch.prod()


def _solve_linear_cdf(s, a, b):
    """Solve a t + (b - a) t^2 / 2 = s for t (the inverse CDF of a linear density on [0, 1])."""
    with np.errstate(divide="ignore", invalid="ignore"):
        is_const = np.abs(a - b) < 1e-4 * (a + b)
        t_const = 2.0 * s / np.where(a + b != 0, a + b, 1.0)
        t_lin = (a - np.sqrt(np.maximum(a * a - 2.0 * s * (a - b), 0.0))) / np.where(a != b, a - b, 1.0)
    return np.where(is_const, t_const, t_lin)


def _theta2u(t):
    return np.sqrt(np.maximum(t, 0.0) * (2.0 / np.pi))


def _phi2u(p):
    return (p + np.pi) / (2.0 * np.pi)


def _u2theta(u):
    return u * u * (np.pi / 2.0)


def _u2phi(u):
    return (2.0 * u - 1.0) * np.pi


def _elevation(d):
    # numerically stable acos(d.z) for unit d
    dist = np.sqrt(d[:, 0] ** 2 + d[:, 1] ** 2 + (d[:, 2] - 1.0) ** 2)
    return 2.0 * np.arcsin(np.clip(0.5 * dist, 0.0, 1.0))


def _sph(theta, phi):
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], -1)


# ----------------------------------------------------------------------------------------------------
# The RGL BRDF
# ----------------------------------------------------------------------------------------------------
_GRAZING_COS = 1e-3  # table rows with cos(theta) below this (about 89.94 deg) are marked invalid


class RglBRDF:
    """An RGL measured isotropic (or anisotropic, reduction 1) BRDF; evaluation as in the module docstring.

    Every field is checked on construction (errors: the module docstring).

    Parameters
    ----------
    tf : TensorFile
        The parsed ``.bsdf`` file (:func:`read_rgl` reads one).

    Attributes
    ----------
    source : str or None
    description : str
        The material (the ``description`` field).
    channels : str or tuple of float
        ``"rgb"``, or the wavelengths in nm of a ``spectra`` file.
    theta_i, phi_i : numpy.ndarray
        The measured incidence angles (radians).
    isotropic : bool
        At most two azimuths of incidence.
    jacobian : bool
        Whether values are multiplied by ``ndf / (4 sigma)``.
    spectral_data : numpy.ndarray, (n_phi, n_theta, C, rows, cols) float64
        The ``rgb`` or ``spectra`` table.
    ndf, sigma : numpy.ndarray, 2-D float64
        Indexed ``(phi, theta)`` in unit coordinates.
    vndf, luminance : numpy.ndarray, (n_phi, n_theta, rows, cols) float64
        As stored (not normalized); the warps and :class:`matfit.models.MeasuredRGL` are built from them.
    grid_shape : tuple
        ``(rows, cols)`` of the sample-space grid.
    node_valid : numpy.ndarray of bool or None
        The file's ``valid`` field as a ``(rows, cols)`` grid, when present.

    References
    ----------
    J. Dupuy, W. Jakob, "An Adaptive Parameterization for Efficient Material Acquisition and
    Rendering", ACM Transactions on Graphics 37(6), 2018.

    Examples
    --------
    A constant measurement (:func:`uniform_fields`) has ``f_r cos(theta_o) = value / 4``:

    >>> from matfit.io.rgl import read_rgl, tensor_file_bytes, uniform_fields
    >>> grey = read_rgl(tensor_file_bytes(uniform_fields(0.5, description="grey")))
    >>> grey.description, grey.channels, grey.isotropic, grey.grid_shape
    ('grey', 'rgb', True, (4, 4))
    >>> grey.eval_cos([0.0, 0.0, 1.0], [0.0, 0.0, 1.0]).tolist()
    [[0.125, 0.125, 0.125]]
    """

    def __init__(self, tf: TensorFile):
        file = tf.source or "<bytes>"
        self.source = tf.source
        f = tf.fields

        def get(name, ndim, code, shape=None):
            if name not in f:
                raise data_error(name, "a field of this name", "none (fields: " + ", ".join(sorted(f)) + ")", file=file)
            a = f[name]
            if tf.dtype_codes[name] != code:
                raise data_error(f"{name}.dtype", f"code {code} ({DTYPES[code]})",
                                 f"code {tf.dtype_codes[name]} ({DTYPES[tf.dtype_codes[name]]})", file=file)
            if a.ndim != ndim or (shape is not None and any(s is not None and s != t for s, t in zip(shape, a.shape))):
                want = "(" + ", ".join("*" if s is None else str(s) for s in (shape or (None,) * ndim)) + ")"
                raise data_error(f"{name}.shape", f"{ndim}-D shape {want}", f"shape {a.shape}", file=file)
            if a.dtype.kind == "f":
                a = a.astype(np.float64)
                if not np.isfinite(a).all():
                    raise data_error(name, "finite values", f"{int((~np.isfinite(a)).sum())} NaN/Inf", file=file)
            return a

        self.description = bytes(get("description", 1, 1)).decode("utf-8", errors="replace")
        theta_i = get("theta_i", 1, 10)
        phi_i = get("phi_i", 1, 10)
        nt, nphi = theta_i.shape[0], phi_i.shape[0]
        if nt < 2:
            raise data_error("theta_i", "at least 2 incidence angles", f"{nt}", file=file)
        if nphi < 1:
            raise data_error("phi_i", "at least 1 azimuth", "none", file=file)
        for name, a, lo, hi in (("theta_i", theta_i, 0.0, np.pi / 2 + 1e-5), ("phi_i", phi_i, -np.pi - 1e-5, 2 * np.pi + 1e-5)):
            if (np.diff(a) <= 0).any():
                raise data_error(name, "strictly increasing angles", np.array2string(a, precision=4), file=file)
            if a.min() < lo or a.max() > hi:
                raise data_error(name, f"angles in [{lo:.4f}, {hi:.4f}] rad", f"range [{a.min():.4g}, {a.max():.4g}]", file=file)
        ndf = get("ndf", 2, 10)
        sigma = get("sigma", 2, 10)
        vndf = get("vndf", 4, 10, (nphi, nt, None, None))
        lum = get("luminance", 4, 10, (nphi, nt, None, None))
        if lum.shape[2] != lum.shape[3]:
            raise data_error("luminance.shape", "square sample grid (.., n, n)", f"shape {lum.shape}", file=file)
        if "rgb" in f:
            spec_name, data = "rgb", get("rgb", 5, 10, (nphi, nt, 3, lum.shape[2], lum.shape[3]))
            chan_params = np.array([0.0, 1.0, 2.0])
            self.channels = "rgb"
        elif "spectra" in f:
            wl = get("wavelengths", 1, 10)
            data = get("spectra", 5, 10, (nphi, nt, wl.shape[0], lum.shape[2], lum.shape[3]))
            spec_name = "spectra"
            if wl.shape[0] < 1 or (np.diff(wl) <= 0).any() or wl.min() <= 0:
                raise data_error("wavelengths", "strictly increasing positive wavelengths (nm)", str(wl[:8]), file=file)
            chan_params = wl
            self.channels = tuple(float(x) for x in wl)
        else:
            raise data_error("rgb/spectra", "an 'rgb' or 'spectra' field", "neither", file=file)
        jac = get("jacobian", 1, 1, (1,))
        self.jacobian = bool(jac[0])
        for name, a, small in (("ndf", ndf, 2), ("sigma", sigma, 2), ("vndf", vndf, 2), ("luminance", lum, 2),
                               (spec_name, data, 2)):
            if min(a.shape[-2:]) < small:
                raise data_error(f"{name}.shape", "at least 2 x 2 grid nodes", f"shape {a.shape}", file=file)
        for name, a in (("ndf", ndf), ("vndf", vndf), ("luminance", lum)):
            if (a < 0).any():
                raise data_error(name, "non-negative densities", f"min {a.min():.4g}", file=file)
        if (sigma <= 0).any():
            raise data_error("sigma", "positive projected areas", f"min {sigma.min():.4g}", file=file)
        self.isotropic = nphi <= 2
        if not self.isotropic:
            red = int(round(2 * np.pi / (phi_i[-1] - phi_i[0])))
            if red != 1:
                raise data_error("phi_i", "a full 2*pi azimuth range (reduction 1)", f"reduction {red}", file=file)
        self.theta_i, self.phi_i = theta_i, phi_i
        self.ndf, self.sigma, self.vndf, self.luminance = ndf, sigma, vndf, lum
        self._ndf = _Warp2D(ndf, build_cdf=False)
        self._sigma = _Warp2D(sigma, build_cdf=False)
        self._vndf = _Warp2D(vndf, (phi_i, theta_i))
        if (self._vndf.totals <= 0).any():
            raise data_error("vndf", "every (phi_i, theta_i) slice with positive total density", "an all-zero slice", file=file)
        self._spec = _Warp2D(data, (phi_i, theta_i, chan_params), build_cdf=False)
        self._chan_params = chan_params
        self.spectral_data = data  # (nphi, nt, C, ny, nx) float64
        self.grid_shape = data.shape[-2:]
        valid = f.get("valid")
        if valid is not None:
            if tf.dtype_codes["valid"] != 1 or valid.shape != (data.shape[-2] * data.shape[-1],):
                raise data_error("valid", f"uint8 (code 1) shape ({data.shape[-2] * data.shape[-1]},)",
                                 f"code {tf.dtype_codes['valid']} shape {valid.shape}", file=file)
            valid = valid.reshape(data.shape[-2:]).astype(bool)
        self.node_valid = valid

    # -------------------------------------------------------------------------------------- evaluation
    @property
    def n_channels(self) -> int:
        """C: the number of channels (3 for ``rgb``, else the wavelengths)."""
        return len(self._chan_params)

    def eval_cos(self, wo, wi) -> np.ndarray:
        """``f_r(wi, wo) * cos(theta_o)`` (N, C), clipped at 0, as powitacq's ``eval(wi, wo)``; 0 below either horizon."""
        wo = np.atleast_2d(np.asarray(wo, dtype=np.float64))
        wi = np.atleast_2d(np.asarray(wi, dtype=np.float64))
        active = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        wm = wi + wo
        nrm = np.linalg.norm(wm, axis=1, keepdims=True)
        wm = wm / np.where(nrm > 0, nrm, 1.0)
        theta_i, phi_i = _elevation(wi), np.arctan2(wi[:, 1], wi[:, 0])
        theta_m, phi_m = _elevation(wm), np.arctan2(wm[:, 1], wm[:, 0])
        u_wi = np.stack([_theta2u(theta_i), _phi2u(phi_i)], 1)
        u_wm = np.stack([_theta2u(theta_m), _phi2u(phi_m - phi_i if self.isotropic else phi_m)], 1)
        u_wm[:, 1] -= np.floor(u_wm[:, 1])
        params = (phi_i, theta_i)
        sample, _ = self._vndf.invert(u_wm, params)
        out = np.empty((wo.shape[0], self.n_channels))
        for c, cp in enumerate(self._chan_params):
            out[:, c] = np.maximum(0.0, self._spec.eval(sample, (phi_i, theta_i, np.full_like(phi_i, cp))))
        if self.jacobian:
            out *= (self._ndf.eval(u_wm) / (4.0 * self._sigma.eval(u_wi)))[:, None]
        out[~active] = 0.0
        return out

    def eval(self, wo, wi) -> np.ndarray:
        """The BRDF in 1/sr (N, C): ``eval_cos / cos(theta_o)``; 0 below either horizon."""
        wo = np.atleast_2d(np.asarray(wo, dtype=np.float64))
        fc = self.eval_cos(wo, wi)
        cos_o = wo[:, 2]
        return np.where((cos_o > 0)[:, None], fc / np.where(cos_o > 0, cos_o, 1.0)[:, None], 0.0)

    def _measured(self, u, phi, theta):
        """Directions (wo) and VNDF pdf for sample-space points u (N, 2) at one incidence (phi, theta)."""
        n = u.shape[0]
        ph, th = np.full(n, phi), np.full(n, theta)
        u_wm, pdf = self._vndf.sample(u, (ph, th))
        theta_m, phi_m = _u2theta(u_wm[:, 0]), _u2phi(u_wm[:, 1])
        if self.isotropic:
            phi_m = phi_m + phi
        wm = _sph(theta_m, phi_m)
        wi = np.broadcast_to(_sph(np.array([theta]), np.array([phi])), (n, 3))
        wo = 2.0 * np.sum(wm * wi, 1, keepdims=True) * wm - wi
        wo /= np.linalg.norm(wo, axis=1, keepdims=True)
        return wo, wi, wm, u_wm, pdf

    def albedo(self, theta_i: float, phi_i: float = 0.0, n: int = 64) -> np.ndarray:
        """Directional-hemispherical reflectance (C,) at incidence ``(theta_i, phi_i)`` (radians).

        The integral of ``f cos(theta_o)`` over the outgoing hemisphere by a midpoint rule on an
        ``n x n`` grid of the VNDF sample space (importance sampling with stratified points).
        """
        g = (np.arange(n) + 0.5) / n
        u = np.stack(np.meshgrid(g, g, indexing="xy"), -1).reshape(-1, 2)
        wo, wi, wm, u_wm, pdf = self._measured(u, phi_i, theta_i)
        sin_m = np.sin(_u2theta(u_wm[:, 0]))
        jac = np.maximum(2.0 * np.pi ** 2 * u_wm[:, 0] * sin_m, 1e-6) * 4.0 * np.sum(wi * wm, 1)
        pdf_w = pdf / jac
        fc = self.eval_cos(wo, wi)
        ok = (wo[:, 2] > 0) & (pdf_w > 0)
        contrib = np.where(ok[:, None], fc / np.where(ok, pdf_w, 1.0)[:, None], 0.0)
        return contrib.mean(axis=0)

    # -------------------------------------------------------------------------------------- table
    def stored_samples(self, use_file_valid: bool = True):
        """The file's own samples at the measured incidences: ``(wo, wi, f (N, C) in 1/sr, valid)``.

        For every measured (phi_i, theta_i) (incidence-major) and every node of the ``rgb``/``spectra``
        grid, the node's sample-space position is warped by the VNDF to a half vector and reflected to
        ``wo``; the value is the stored node value (clipped at 0) times ``ndf / (4 sigma)`` divided by
        ``cos(theta_o)``. Rows are invalid (value 0) when either direction is within 0.06 deg of the
        horizon (this drops the theta_i = 90 deg incidence) and, with ``use_file_valid``, where the file's
        ``valid`` field is 0. (The RGL loaders ignore that field and render all nodes; its pattern - e.g.
        every other node for the diffuse paper - suggests it marks the nodes actually measured.)
        """
        ny, nx = self.grid_shape
        gy, gx = np.meshgrid(np.arange(ny) / (ny - 1), np.arange(nx) / (nx - 1), indexing="ij")
        u = np.stack([gx.ravel(), gy.ravel()], 1)  # row-major over (row, col); x = col
        WO, WI, F, V = [], [], [], []
        for a, phi in enumerate(self.phi_i):
            for t, theta in enumerate(self.theta_i):
                wo, wi, wm, u_wm, _ = self._measured(u, phi, theta)
                vals = np.maximum(self.spectral_data[a, t].reshape(self.n_channels, -1).T, 0.0)
                if self.jacobian:
                    u_wi = np.broadcast_to(np.array([[_theta2u(theta), _phi2u(phi)]]), (u.shape[0], 2))
                    vals = vals * (self._ndf.eval(u_wm) / (4.0 * self._sigma.eval(u_wi)))[:, None]
                ok = (wo[:, 2] >= _GRAZING_COS) & (wi[:, 2] >= _GRAZING_COS)
                if use_file_valid and self.node_valid is not None:
                    ok &= self.node_valid.ravel()
                f = np.where(ok[:, None], vals / np.where(ok, wo[:, 2], 1.0)[:, None], 0.0)
                WO.append(wo), WI.append(np.array(wi)), F.append(f), V.append(ok)
        return np.concatenate(WO), np.concatenate(WI), np.concatenate(F), np.concatenate(V)

    def to_table(self, use_file_valid: bool = True) -> Table:
        """A Table of :meth:`stored_samples` (invalid rows kept with ``valid=False``); provenance names the file and material."""
        wo, wi, f, ok = self.stored_samples(use_file_valid)
        prov = {"format": "rgl-tensor", "source": self.source, "material": self.description,
                "instrument": "RGL gonio-photometer (Dupuy & Jakob 2018)",
                "geometry": "measured incidences x VNDF-warped sample-space nodes",
                "use_file_valid": bool(use_file_valid)}
        return Table(wo=wo, wi=wi, values=f, valid=ok, channels=self.channels, provenance=prov)


def read_rgl(path) -> RglBRDF:
    """Read and validate an RGL ``.bsdf`` file (errors: the module docstring).

    Parameters
    ----------
    path : str, PathLike or bytes
        The file (e.g. ``paper_white_rgb.bsdf`` of the RGL material database), or its contents.

    Returns
    -------
    RglBRDF
    """
    return RglBRDF(read_tensor_file(path))
