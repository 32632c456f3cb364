"""ALTA text data files (Belcour et al., ALTA library), e.g. MERL slices such as pink-felt-1d.alta.

Header lines start with ``#``: ``#DIM <n_in> <n_out>`` (required), ``#PARAM_IN <name>``,
``#PARAM_OUT <name>``, optional ``#VS 0|1|2`` (confidence intervals: 1 = one symmetric half-width, 2 = a
lower and an upper bound, given after the outputs and - as in ALTA - for the first output only).
Other ``#`` lines are comments. Each data line has ``n_in + n_out (+ VS)`` numbers. Binary ALTA files
(``#FORMAT binary``) are rejected.

Geometry used for the Table (``wi`` = light, ``wo`` = viewer, phi_h = 0):

* ``COS_TH`` / ``RUSIN_TH`` (1-D theta_h slices): theta_d = 0 by default (``wi = wo = h``, the
  retro-reflection slice). For pink-felt-1d.alta this is what fits the MERL data: the pre-trained network
  of pink-felt agrees with the slice to a median 3.3 % at theta_d = 0 and to 19-26 % at theta_d = 45 deg.
  (Its COS_TH column has sin(theta_h) = (i + 1/2)/90, not MERL's cell-centre rule; we use the column as
  written.) ``theta_d`` / ``phi_d`` can be overridden.
* ``RUSIN_TH_TD``: phi_d = pi/2 by default (overridable).
* ``RUSIN_TH_TD_PD``, ``RUSIN_TH_PH_TD_PD``: the half/difference angles as given.
* ``SPHERICAL_TL_PL_TV_PV``: (theta, phi) of light then view; ``CARTESIAN``: light xyz then view xyz.

Outputs: ``RGB_COLOR`` (3 channels) or ``INV_STERADIAN`` / ``ENERGY`` (1 channel, mono), BRDF in 1/sr.
In the Table, confidence columns of a one-output file become ``sigma`` (the half-width, or half the
bounds' distance) unless some valid row has a zero width; rows below either horizon are kept invalid.

Errors: :func:`read_alta` raises :class:`~matfit.errors.DataFormatError` naming the file, the field
and the line for an empty, binary or non-UTF-8 file, a repeated header line, a missing or inconsistent
``#DIM`` (1 <= n_in <= 6, 1 <= n_out <= 64) / ``#PARAM_IN`` / ``#PARAM_OUT`` / ``#VS``, no data, a data
line of the wrong length or with non-numbers or non-finite numbers, cosines outside [0, 1], or
CARTESIAN vectors with ``|norm - 1| > 1e-4``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .._dataerr import data_error, with_file
from ..errors import DataFormatError
from ..table import Table
from ._halfdiff import half_diff_to_dirs
from ._source import read_source

__all__ = ["AltaData", "read_alta", "PARAM_IN_DIMS", "PARAM_OUT_CHANNELS"]

PARAM_IN_DIMS = {"COS_TH": 1, "RUSIN_TH": 1, "RUSIN_TH_TD": 2, "RUSIN_TH_TD_PD": 3, "RUSIN_TH_PH_TD_PD": 4,
                 "SPHERICAL_TL_PL_TV_PV": 4, "CARTESIAN": 6}
PARAM_OUT_CHANNELS = {"RGB_COLOR": 3, "INV_STERADIAN": 1, "ENERGY": 1}
_HEADER_KEYS = {"DIM", "PARAM_IN", "PARAM_OUT", "VS", "FORMAT", "VERSION", "PRECISION", "SAMPLE_COUNT", "ENDIAN"}


@dataclass(frozen=True, eq=False)
class AltaData:
    """A parsed ALTA file (:func:`read_alta`); :meth:`to_table` turns it into a :class:`~matfit.table.Table`.

    Attributes
    ----------
    header : dict
        Header key (``"DIM"``, ``"PARAM_IN"``, ...) -> the rest of its line.
    param_in, param_out : str
        Keys of :data:`PARAM_IN_DIMS` and :data:`PARAM_OUT_CHANNELS`.
    x, y : numpy.ndarray, (N, n_in) and (N, n_out) float64
        The data lines' inputs and outputs (the BRDF in 1/sr).
    ci : numpy.ndarray or None
        ``(N, 1)`` half-widths (``#VS 1``) or ``(N, 2)`` lower and upper bounds (``#VS 2``) of
        the first output; None without ``#VS``.
    source : str or None
        The file read (None for bytes).
    comments : list of str
        The ``#`` lines that are not header lines.

    Examples
    --------
    >>> from matfit.io import read_alta
    >>> d = read_alta(b"#DIM 1 1\\n#PARAM_IN COS_TH\\n#PARAM_OUT INV_STERADIAN\\n# felt\\n1.0 0.5\\n0.8 0.4\\n")
    >>> d.param_in, d.x[:, 0].tolist(), d.y[:, 0].tolist(), d.comments
    ('COS_TH', [1.0, 0.8], [0.5, 0.4], ['# felt'])
    """

    header: dict
    param_in: str
    param_out: str
    x: np.ndarray
    y: np.ndarray
    ci: np.ndarray | None = None  # (N, 1) half-width (VS 1) or (N, 2) bounds (VS 2)
    source: str | None = None
    comments: list = field(default_factory=list)

    def directions(self, theta_d: float | None = None, phi_d: float | None = None):
        """``(wo, wi)`` (N, 3) of the rows (geometry: the module docstring); ``theta_d``, ``phi_d`` override the slices' defaults."""
        x, p = self.x, self.param_in
        if p in ("COS_TH", "RUSIN_TH"):
            th = np.arccos(np.clip(x[:, 0], -1.0, 1.0)) if p == "COS_TH" else x[:, 0]
            return half_diff_to_dirs(th, 0.0 if theta_d is None else theta_d, 0.0 if phi_d is None else phi_d)
        if p == "RUSIN_TH_TD":
            return half_diff_to_dirs(x[:, 0], x[:, 1], np.pi / 2 if phi_d is None else phi_d)
        if p == "RUSIN_TH_TD_PD":
            return half_diff_to_dirs(x[:, 0], x[:, 1], x[:, 2])
        if p == "RUSIN_TH_PH_TD_PD":
            return half_diff_to_dirs(x[:, 0], x[:, 2], x[:, 3], x[:, 1])
        if p == "SPHERICAL_TL_PL_TV_PV":
            def sph(t, f):
                return np.stack([np.sin(t) * np.cos(f), np.sin(t) * np.sin(f), np.cos(t)], -1)
            return sph(x[:, 2], x[:, 3]), sph(x[:, 0], x[:, 1])
        if p == "CARTESIAN":
            wi, wo = x[:, 0:3], x[:, 3:6]
            return wo, wi
        raise data_error("PARAM_IN", "one of " + ", ".join(PARAM_IN_DIMS), p, file=self.source)  # pragma: no cover

    def to_table(self, theta_d: float | None = None, phi_d: float | None = None) -> Table:
        """The rows as a Table (``"mono"`` or ``"rgb"``; ``sigma`` as in the module docstring); provenance names the geometry used."""
        wo, wi = self.directions(theta_d, phi_d)
        channels = "rgb" if self.y.shape[1] == 3 else "mono"
        sigma = None
        if self.ci is not None and self.y.shape[1] == 1:
            sigma = self.ci[:, 0] if self.ci.shape[1] == 1 else 0.5 * (self.ci[:, 1] - self.ci[:, 0])
            sigma = np.abs(sigma)
        valid = (wo[:, 2] > 0) & (wi[:, 2] > 0)
        geometry = {"COS_TH": "theta_h = acos(COS_TH), theta_d = {td}, phi_d = {pd}, phi_h = 0",
                    "RUSIN_TH": "theta_h given, theta_d = {td}, phi_d = {pd}, phi_h = 0",
                    "RUSIN_TH_TD": "phi_d = {pd}, phi_h = 0"}.get(self.param_in, self.param_in)
        geometry = geometry.format(td=0.0 if theta_d is None else theta_d,
                                   pd=(np.pi / 2 if self.param_in == "RUSIN_TH_TD" else 0.0) if phi_d is None else phi_d)
        prov = {"format": "alta", "source": self.source, "param_in": self.param_in, "param_out": self.param_out,
                "geometry": geometry}
        try:
            return Table(wo=wo, wi=wi, values=self.y, sigma=sigma if sigma is None or (sigma[valid] > 0).all() else None,
                         valid=valid, channels=channels, provenance=prov)
        except DataFormatError as e:
            raise with_file(e, self.source) from None


def read_alta(path) -> AltaData:
    """Read an ALTA text data file (errors: the module docstring).

    Parameters
    ----------
    path : str, PathLike or bytes
        The ``.alta`` file, or its contents.

    Returns
    -------
    AltaData

    References
    ----------
    L. Belcour, P. Barla, R. Pacanowski, "ALTA: A BRDF Analysis Library", 2014,
    https://alta.gforge.inria.fr.
    """
    raw, src, file = read_source(path)
    if not raw.strip():
        raise data_error("content", "an ALTA header and data", "an empty file", file=file)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise data_error("encoding", "UTF-8 text", f"undecodable bytes at {e.start}", file=file) from None
    if "\x00" in text:
        raise data_error("encoding", "text", "NUL bytes (a binary file?)", file=file)
    header, comments, rows = {}, [], []
    for ln, line in enumerate(text.splitlines(), 1):
        s = line.strip()
        if not s:
            continue
        if s.startswith("#"):
            key, _, rest = s[1:].strip().partition(" ")
            if key in _HEADER_KEYS:
                if key in header:
                    raise data_error(f"#{key}", "one header line", "a repeated header line", file=file, detail=f"line {ln}")
                header[key] = (rest.strip(), ln)
            else:
                comments.append(s)
            continue
        rows.append((ln, s))
    if header.get("FORMAT", ("text",))[0].lower() == "binary":
        raise data_error("#FORMAT", "text", "binary (unsupported)", file=file)
    if "DIM" not in header:
        raise data_error("#DIM", "a '#DIM <n_in> <n_out>' header line", "none", file=file)
    dim_s, dim_ln = header["DIM"]
    parts = dim_s.split()
    try:
        if len(parts) != 2:
            raise ValueError
        n_in, n_out = int(parts[0]), int(parts[1])
    except ValueError:
        raise data_error("#DIM", "two integers", repr(dim_s), file=file, detail=f"line {dim_ln}") from None
    if not (1 <= n_in <= 6 and 1 <= n_out <= 64):
        raise data_error("#DIM", "1 <= n_in <= 6 and 1 <= n_out <= 64", f"{n_in} {n_out}", file=file, detail=f"line {dim_ln}")
    p_in = header.get("PARAM_IN", (None, None))[0]
    if p_in not in PARAM_IN_DIMS:
        raise data_error("#PARAM_IN", "one of " + ", ".join(PARAM_IN_DIMS), repr(p_in), file=file)
    if PARAM_IN_DIMS[p_in] != n_in:
        raise data_error("#DIM", f"n_in = {PARAM_IN_DIMS[p_in]} for PARAM_IN {p_in}", str(n_in), file=file)
    p_out = header.get("PARAM_OUT", (None, None))[0]
    if p_out not in PARAM_OUT_CHANNELS:
        raise data_error("#PARAM_OUT", "one of " + ", ".join(PARAM_OUT_CHANNELS), repr(p_out), file=file)
    if PARAM_OUT_CHANNELS[p_out] != n_out:
        raise data_error("#DIM", f"n_out = {PARAM_OUT_CHANNELS[p_out]} for PARAM_OUT {p_out}", str(n_out), file=file)
    vs = 0
    if "VS" in header:
        vs_s, vs_ln = header["VS"]
        if vs_s not in ("0", "1", "2"):
            raise data_error("#VS", "0, 1 or 2", repr(vs_s), file=file, detail=f"line {vs_ln}")
        vs = int(vs_s)
    if not rows:
        raise data_error("data", "at least one data row", "none", file=file)
    ncol = n_in + n_out + vs
    arr = np.empty((len(rows), ncol))
    for k, (ln, s) in enumerate(rows):
        toks = s.replace(",", " ").split()
        if len(toks) != ncol:
            raise data_error("row", f"{ncol} numbers (DIM {n_in} {n_out}, VS {vs})", f"{len(toks)}", file=file,
                             detail=f"line {ln}")
        try:
            vals = [float(t) for t in toks]
        except ValueError:
            raise data_error("row", "numbers", repr(s[:40]), file=file, detail=f"line {ln}") from None
        if not all(math.isfinite(v) for v in vals):
            raise data_error("row", "finite numbers", repr(s[:60]), file=file, detail=f"line {ln}")
        arr[k] = vals
    x, y = arr[:, :n_in], arr[:, n_in:n_in + n_out]
    ci = arr[:, n_in + n_out:] if vs else None
    # parameter range checks
    if p_in == "COS_TH" and ((x[:, 0] < -1e-9) | (x[:, 0] > 1 + 1e-9)).any():
        k = int(np.flatnonzero((x[:, 0] < -1e-9) | (x[:, 0] > 1 + 1e-9))[0])
        raise data_error("COS_TH", "cosines in [0, 1]", repr(x[k, 0]), file=file, detail=f"line {rows[k][0]}")
    if p_in == "CARTESIAN":
        for j, nm in ((0, "light"), (3, "view")):
            nrm = np.linalg.norm(x[:, j:j + 3], axis=1)
            bad = np.abs(nrm - 1) > 1e-4
            if bad.any():
                k = int(np.flatnonzero(bad)[0])
                raise data_error(f"CARTESIAN {nm} vector", "unit vectors (|norm - 1| <= 1e-4)", f"norm {nrm[k]:.6g}",
                                 file=file, detail=f"line {rows[k][0]}")
    hdr = {k: v for k, (v, _) in header.items()}
    return AltaData(hdr, p_in, p_out, x, y, ci, src, comments)
