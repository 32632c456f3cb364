"""MERL BRDF database files (Matusik, Pfister, Brand, McMillan 2003), ``.binary``.

Layout (little-endian): ``int32[3]`` dims ``(90, 90, 180)`` for ``(theta_h, theta_d, phi_d)``, then
``3 * 90 * 90 * 180`` float64 values, channel-major (R block, G block, B block), flat index
``phi_d + 180 * (theta_d + 90 * theta_h)``: ``FILE_SIZE`` = 12 + 3*90*90*180*8 bytes. A stored value
times ``SCALE = (1/1500, 1.15/1500, 1.66/1500)`` is the BRDF in 1/sr. Negative cells (the database
writes -1 below the horizon) are invalid.

Cell rule (BRDFRead.cpp): ``theta_h`` index ``int(sqrt(theta_h / (pi/2) * 90 * 90))``, ``theta_d`` index
``int(theta_d / (pi/2) * 90)``, ``phi_d`` folded to ``[0, pi)`` by reciprocity then ``int(phi_d / pi * 180)``,
each clamped to the grid (NaN angles give 0). Cell centres: ``theta_h = ((i + 1/2) / 90)^2 pi/2``,
``theta_d = (j + 1/2) / 90 pi/2``, ``phi_d = (k + 1/2) / 180 pi``.

Errors: :func:`read_merl` raises :class:`~matfit.errors.DataFormatError` naming the file (or
``<bytes>``) for an empty file, a header under 12 bytes, dims other than (90, 90, 180), a size other
than ``FILE_SIZE`` (truncated, or trailing data), or NaN / Inf values (counted, the first cell named);
:meth:`MerlBRDF.from_values` and :func:`write_merl` for a wrong shape (and non-finite values).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._dataerr import data_error
from ..table import Table
from ._halfdiff import dirs_to_half_diff, half_diff_to_dirs
from ._source import read_source

__all__ = ["MerlBRDF", "read_merl", "write_merl", "RES", "SCALE", "cell_centres", "cell_index"]

RES = (90, 90, 180)
SCALE = np.array([1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0])
_N = RES[0] * RES[1] * RES[2]
FILE_SIZE = 12 + 3 * _N * 8


def cell_centres():
    """``(theta_h, theta_d, phi_d)``: the cell centres in radians, (90,), (90,), (180,).

    Returns
    -------
    theta_h, theta_d, phi_d : numpy.ndarray
        ``theta_h`` on MERL's square-root grid.
    """
    th = ((np.arange(RES[0]) + 0.5) / RES[0]) ** 2 * (np.pi / 2)
    td = (np.arange(RES[1]) + 0.5) / RES[1] * (np.pi / 2)
    pd = (np.arange(RES[2]) + 0.5) / RES[2] * np.pi
    return th, td, pd


def cell_index(theta_h, theta_d, phi_d):
    """MERL's cell indices of half/difference angles (the module's cell rule).

    Parameters
    ----------
    theta_h, theta_d, phi_d : array_like
        Radians; ``phi_d`` in (-pi, pi] is folded to [0, pi).

    Returns
    -------
    i_h, i_d, i_p : numpy.ndarray of int64
        Clamped to the grid.
    """
    theta_h = np.asarray(theta_h, dtype=np.float64)
    deg = theta_h / (np.pi / 2) * RES[0]
    ih = np.where(theta_h <= 0.0, 0, np.floor(np.sqrt(np.maximum(deg * RES[0], 0.0))))
    ih = np.clip(np.nan_to_num(ih, nan=0.0), 0, RES[0] - 1).astype(np.int64)
    idd = np.floor(np.asarray(theta_d, dtype=np.float64) / (np.pi / 2) * RES[1])
    idd = np.clip(np.nan_to_num(idd, nan=0.0), 0, RES[1] - 1).astype(np.int64)
    pd = np.asarray(phi_d, dtype=np.float64)
    pd = np.where(pd < 0.0, pd + np.pi, pd)
    ip = np.floor(pd / np.pi * (2 * RES[2]) / 2)
    ip = np.clip(np.nan_to_num(ip, nan=0.0), 0, RES[2] - 1).astype(np.int64)
    return ih, idd, ip


@dataclass(frozen=True, eq=False)
class MerlBRDF:
    """A MERL table: the stored numbers exactly as in the file.

    Attributes
    ----------
    raw : numpy.ndarray, (3, 90, 90, 180) float64
        Indexed ``(channel, theta_h, theta_d, phi_d)``; the BRDF is ``raw * SCALE``
        (:attr:`values`), negative cells are invalid.
    source : str or None
        The file read (None for bytes or a table built in memory).

    References
    ----------
    W. Matusik, H. Pfister, M. Brand, L. McMillan, "A Data-Driven Reflectance Model",
    ACM Transactions on Graphics 22(3), 2003.

    Examples
    --------
    >>> import numpy as np
    >>> from matfit.io import MerlBRDF
    >>> m = MerlBRDF.from_values(np.full((3, 90, 90, 180), 0.3))
    >>> m.raw.shape, round(float(m.values[1, 0, 0, 0]), 12), bool(m.valid.all())
    ((3, 90, 90, 180), 0.3, True)
    """

    raw: np.ndarray
    source: str | None = None

    @property
    def values(self) -> np.ndarray:
        """BRDF in 1/sr, shape (3, 90, 90, 180); invalid cells are negative."""
        return self.raw * SCALE[:, None, None, None]

    @property
    def valid(self) -> np.ndarray:
        """(90, 90, 180) bool: all three channels >= 0."""
        return (self.raw >= 0).all(axis=0)

    @classmethod
    def from_values(cls, values, valid=None, source=None) -> "MerlBRDF":
        """Build from finite BRDF values (3, 90, 90, 180) in 1/sr; cells where ``valid`` (90, 90, 180) is false are stored as -1."""
        v = np.asarray(values, dtype=np.float64)
        if v.shape != (3,) + RES:
            raise data_error("values", f"shape {(3,) + RES}", f"shape {v.shape}")
        if not np.isfinite(v).all():
            raise data_error("values", "finite values", f"{int((~np.isfinite(v)).sum())} non-finite")
        raw = v / SCALE[:, None, None, None]
        if valid is not None:
            raw = np.where(np.asarray(valid, dtype=bool)[None], raw, -1.0)
        return cls(np.ascontiguousarray(raw), source)

    def lookup(self, wo, wi):
        """``(values (N, 3), valid (N,))``: the BRDF in 1/sr of the cells direction pairs fall in (MERL's
        cell rule; ``wi`` is MERL's incoming direction); pairs below either horizon or in an invalid cell
        are invalid, with value 0.
        """
        wo = np.atleast_2d(np.asarray(wo, dtype=np.float64))
        wi = np.atleast_2d(np.asarray(wi, dtype=np.float64))
        th, _ph, td, pd = dirs_to_half_diff(wo, wi)
        ih, idd, ip = cell_index(th, td, pd)
        raw = self.raw[:, ih, idd, ip].T  # (N, 3)
        ok = (raw >= 0).all(axis=1) & (wo[:, 2] > 0) & (wi[:, 2] > 0)
        vals = np.where(ok[:, None], raw * SCALE, 0.0)
        return vals, ok

    def to_table(self, drop_invalid: bool = False) -> Table:
        """An ``"rgb"`` Table at the 90*90*180 cell centres with phi_h = 0, rows in file order.

        ``wi`` is the difference vector rotated by theta_h about y, ``wo`` its mirror about the half
        vector. Invalid cells keep their row (value 0, valid=False) unless ``drop_invalid``.
        """
        th, td, pd = cell_centres()
        TH, TD, PD = np.meshgrid(th, td, pd, indexing="ij")
        wo, wi = half_diff_to_dirs(TH.ravel(), TD.ravel(), PD.ravel())
        raw = self.raw.reshape(3, -1).T
        valid = (raw >= 0).all(axis=1) & (wo[:, 2] > 0) & (wi[:, 2] > 0)
        vals = np.where(valid[:, None], raw * SCALE, 0.0)
        prov = {"format": "merl", "source": self.source, "instrument": "MERL gonioreflectometer (Matusik et al. 2003)",
                "geometry": "cell centres, phi_h = 0"}
        if drop_invalid:
            return Table(wo=wo[valid], wi=wi[valid], values=vals[valid], channels="rgb", provenance=prov)
        return Table(wo=wo, wi=wi, values=vals, valid=valid, channels="rgb", provenance=prov)


def read_merl(path) -> MerlBRDF:
    """Read a MERL ``.binary`` file with strict checks (errors: the module docstring).

    Parameters
    ----------
    path : str, PathLike or bytes
        The file, or its contents.

    Returns
    -------
    MerlBRDF
        ``raw`` read-only, exactly the file's numbers.
    """
    buf, src, file = read_source(path, FILE_SIZE + 1, expected=f"{FILE_SIZE} bytes")
    if len(buf) < 12:
        raise data_error("dims", "a 12-byte int32[3] header", f"{len(buf)} bytes (truncated)", file=file)
    dims = np.frombuffer(buf, dtype="<i4", count=3)
    if tuple(int(d) for d in dims) != RES:
        raise data_error("dims", f"{RES}", f"{tuple(int(d) for d in dims)}", file=file)
    if len(buf) != FILE_SIZE:
        raise data_error("file size", f"{FILE_SIZE} bytes (12 + 3*90*90*180*8)",
                         f"{len(buf)}{'+' if len(buf) > FILE_SIZE else ''} bytes "
                         f"({'truncated' if len(buf) < FILE_SIZE else 'trailing data'})", file=file)
    raw = np.frombuffer(buf, dtype="<f8", count=3 * _N, offset=12).astype(np.float64).reshape((3,) + RES)
    bad = ~np.isfinite(raw)
    if bad.any():
        c, i, j, k = (int(x) for x in np.argwhere(bad)[0])
        raise data_error("data", "finite float64 values", f"{int(bad.sum())} NaN/Inf "
                         f"(first: channel {c}, theta_h {i}, theta_d {j}, phi_d {k})", file=file)
    raw.setflags(write=False)
    return MerlBRDF(raw, src)


def write_merl(path, brdf: MerlBRDF) -> None:
    """Write ``brdf.raw`` in the MERL layout (bit-exact round trip with :func:`read_merl`).

    Parameters
    ----------
    path : str or PathLike
        Replaced if present.
    brdf : MerlBRDF
    """
    raw = np.asarray(brdf.raw, dtype=np.float64)
    if raw.shape != (3,) + RES:
        raise data_error("raw", f"shape {(3,) + RES}", f"shape {raw.shape}", file=path)
    with open(path, "wb") as fh:
        fh.write(np.array(RES, dtype="<i4").tobytes())
        fh.write(np.ascontiguousarray(raw, dtype="<f8").tobytes())
