"""Measurement tables: BRDF samples with their directions, channels, uncertainty and provenance.

A :class:`Table` holds ``N`` samples (its fields and conventions are in its docstring), validated,
copied and made read-only on construction; :class:`TableArrays` is its view as JAX arrays. See
docs/data.md for the ``.npz`` and CSV layouts.
"""
from __future__ import annotations

import copy
import csv
import io as _io
import json
import math
from dataclasses import dataclass, field
from typing import NamedTuple, Sequence

import numpy as np

from ._dataerr import data_error, with_file
from .errors import DataFormatError

__all__ = ["Table", "TableArrays", "UNIT_TOL", "NPZ_FORMAT", "CSV_MAGIC"]

UNIT_TOL = 1e-4
NPZ_FORMAT = "matfit.table/1"
CSV_MAGIC = "# matfit-table v1"
_RGB_LABELS = ("r", "g", "b")


class TableArrays(NamedTuple):
    """The table as JAX arrays (see :meth:`Table.as_jax`).

    Attributes
    ----------
    wo, wi : jax.Array, (N, 3)
        Directions to the viewer and to the light.
    values : jax.Array, (N, C)
        The BRDF in 1/sr.
    weight : jax.Array, (N, C)
        The effective fitting weight (:meth:`Table.effective_weight`), 0 on invalid rows.
    valid : jax.Array, (N,) bool

    Examples
    --------
    >>> from matfit.table import Table
    >>> arrays = Table(wo=[[0.0, 0.0, 1.0]], wi=[[0.0, 0.6, 0.8]], values=[[0.2]], channels="mono").as_jax()
    >>> arrays._fields, arrays.values.shape
    (('wo', 'wi', 'values', 'weight', 'valid'), (1, 1))
    """

    wo: "object"
    wi: "object"
    values: "object"
    weight: "object"  # (N, C): effective weight, 0 on invalid rows
    valid: "object"


def _norm_channels(channels):
    if isinstance(channels, str):
        if channels not in ("mono", "rgb"):
            raise data_error("channels", "'mono', 'rgb' or a list of wavelengths in nm", repr(channels))
        return channels
    if isinstance(channels, np.ndarray):
        channels = channels.tolist()
    if not isinstance(channels, (list, tuple)):
        raise data_error("channels", "'mono', 'rgb' or a list of wavelengths in nm", type(channels).__name__)
    if len(channels) == 0:
        raise data_error("channels", "at least one wavelength", "an empty list")
    out = []
    for c in channels:
        if isinstance(c, bool) or not isinstance(c, (int, float, np.integer, np.floating)):
            raise data_error("channels", "wavelengths as numbers (nm)", repr(c))
        c = float(c)
        if not (math.isfinite(c) and c > 0):
            raise data_error("channels", "finite positive wavelengths in nm", repr(c))
        out.append(c)
    if len(set(out)) != len(out):
        raise data_error("channels", "distinct wavelengths", str(out))
    return tuple(out)


def _n_channels(channels) -> int:
    return {"mono": 1, "rgb": 3}[channels] if isinstance(channels, str) else len(channels)


def channel_labels(channels) -> list[str]:
    """Column suffixes of CSV headers for ``channels``: ``mono``; ``r g b``; ``550nm`` ..."""
    if channels == "mono":
        return ["mono"]
    if channels == "rgb":
        return list(_RGB_LABELS)
    return [f"{w:g}nm" for w in channels]


def _float_array(name, a, ndim_shape_desc):
    if a is None:
        raise data_error(name, ndim_shape_desc, "None")
    try:
        arr = np.asarray(a)
    except Exception as e:  # ragged lists etc.
        raise data_error(name, ndim_shape_desc, f"an object numpy cannot convert ({e})") from None
    if arr.dtype == object or not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)) \
            or arr.dtype == bool:
        raise data_error(name, "a real numeric array", f"dtype {arr.dtype}")
    return np.array(arr, dtype=np.float64, copy=True)


def _check_finite(name, a, hint="", rows=None):
    """Raise naming the count and first index of non-finite entries (``rows`` maps a's rows to
    the table's row numbers)."""
    bad = ~np.isfinite(a)
    if bad.any():
        idx = np.argwhere(bad)[0]
        shown = (int(rows[idx[0]]),) + tuple(int(i) for i in idx[1:]) if rows is not None else tuple(int(i) for i in idx)
        raise data_error(name, "finite values", f"{int(bad.sum())} non-finite (first at index {shown}: {a[tuple(idx)]}){hint}")


def _check_dirs(name, a, n):
    if a.ndim != 2 or a.shape[1] != 3 or (n is not None and a.shape[0] != n):
        raise data_error(name, f"shape ({'N' if n is None else n}, 3)", f"shape {a.shape}")
    _check_finite(name, a)
    norms = np.linalg.norm(a, axis=1)
    dev = np.abs(norms - 1.0)
    if a.shape[0] and dev.max() > UNIT_TOL:
        i = int(np.argmax(dev))
        raise data_error(name, f"unit vectors (|norm - 1| <= {UNIT_TOL:g})",
                         f"norm {norms[i]:.6g} at row {i} ({int((dev > UNIT_TOL).sum())} rows off)")


def _per_channel(name, a, n, c):
    arr = _float_array(name, a, f"shape ({n}, {c})")
    if arr.ndim == 1 and arr.shape[0] == n:
        arr = np.repeat(arr[:, None], c, axis=1)
    elif arr.ndim == 2 and arr.shape == (n, 1) and c != 1:
        arr = np.repeat(arr, c, axis=1)
    if arr.shape != (n, c):
        raise data_error(name, f"shape ({n}, {c}) (or ({n},) to share across channels)", f"shape {arr.shape}")
    _check_finite(name, arr)
    return arr


def _json_roundtrip(name, obj):
    try:
        return json.loads(json.dumps(obj, allow_nan=False))
    except (TypeError, ValueError, RecursionError) as e:
        raise data_error(name, "a JSON-serializable dict", f"{type(obj).__name__} ({e})") from None


def _readonly(a):
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class Table:
    """A validated, immutable table of ``N`` BRDF samples.

    Every field is checked and copied on construction: arrays become read-only float64 (``valid``
    bool); a problem raises :class:`~matfit.errors.DataFormatError` naming the field, the expected
    and the found shape or property.

    Attributes
    ----------
    wo, wi : numpy.ndarray, (N, 3)
        Unit vectors to the viewer (detector) and to the light, local frame with normal +z.
    values : numpy.ndarray, (N, C)
        The BRDF in 1/sr (without the cosine), channels on the last axis; ``(N,)`` is accepted
        for one channel. Non-finite values on invalid rows are stored as 0.
    sigma : numpy.ndarray or None, (N, C)
        Standard deviations of ``values`` (same units, > 0 on valid rows); ``(N,)`` or ``(N, 1)``
        is shared by every channel.
    weight : numpy.ndarray or None, (N, C)
        Fitting weights >= 0, instead of ``sigma`` (at most one of the two).
    valid : numpy.ndarray, (N,) bool
        Rows to use (default: all). Invalid rows are kept, so that tables stay aligned with their
        source grid, but never fitted; their values are finite but meaningless (readers write 0).
    channels : str or tuple of float, default "rgb"
        ``"mono"`` (C = 1), ``"rgb"`` (C = 3) or the wavelengths in nm (C = len).
    provenance : dict
        JSON-serializable: the source file, the instrument or scene, the ground truth where
        synthetic, and a ``derivation`` list recording ``select`` / ``subsample`` / ``split``.

    Examples
    --------
    >>> from matfit.table import Table
    >>> t = Table(wo=[[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]], wi=[[0.0, 0.6, 0.8], [0.0, 0.0, 1.0]],
    ...           values=[0.2, 0.3], channels="mono", provenance={"source": "example"})
    >>> t, t.values.shape, t.values.flags.writeable
    (Table(n=2, valid=2, channels='mono'), (2, 1), False)
    >>> Table(wo=[[0.0, 0.0, 2.0]], wi=[[0.0, 0.0, 1.0]], values=[0.2], channels="mono")
    Traceback (most recent call last):
    ...
    matfit.errors.DataFormatError: field 'wo': expected unit vectors (|norm - 1| <= 0.0001), found norm 2 at row 0 (1 rows off)
    """

    wo: np.ndarray
    wi: np.ndarray
    values: np.ndarray
    sigma: np.ndarray | None = None
    weight: np.ndarray | None = None
    valid: np.ndarray | None = None
    channels: str | tuple = "rgb"
    provenance: dict = field(default_factory=dict)

    def __post_init__(self):
        channels = _norm_channels(self.channels)
        c = _n_channels(channels)
        values = _float_array("values", self.values, f"shape (N, {c})")
        if values.ndim == 1 and c == 1:
            values = values[:, None]
        if values.ndim != 2 or values.shape[1] != c:
            raise data_error("values", f"shape (N, {c}) for channels {channels!r}", f"shape {values.shape}")
        n = values.shape[0]
        wo = _float_array("wo", self.wo, f"shape ({n}, 3)")
        _check_dirs("wo", wo, n)
        wi = _float_array("wi", self.wi, f"shape ({n}, 3)")
        _check_dirs("wi", wi, n)
        if self.sigma is not None and self.weight is not None:
            raise data_error("sigma/weight", "at most one of sigma and weight", "both")
        sigma = weight = None
        if self.valid is None:
            valid = np.ones(n, dtype=bool)
        else:
            v = np.asarray(self.valid)
            if v.shape != (n,):
                raise data_error("valid", f"shape ({n},)", f"shape {v.shape}")
            if v.dtype != bool:
                if not (np.issubdtype(v.dtype, np.integer) or np.issubdtype(v.dtype, np.floating)) \
                        or not np.isin(v, (0, 1)).all():
                    raise data_error("valid", "booleans (or 0/1)", f"dtype {v.dtype}")
            valid = np.array(v, dtype=bool, copy=True)
        # Values on invalid rows are never used: non-finite ones there (a NaN marking a missing
        # cell) are stored as 0; on valid rows they are an error that says how to mask them.
        _check_finite("values", values[valid], hint="; mark such rows invalid with valid=... (they are then ignored)",
                      rows=np.flatnonzero(valid))
        values = np.where(valid[:, None] | np.isfinite(values), values, 0.0)
        if self.sigma is not None:
            sigma = _per_channel("sigma", self.sigma, n, c)
            if (sigma < 0).any():
                raise data_error("sigma", "standard deviations >= 0", f"min {sigma.min():.6g}")
            if (sigma[valid] == 0).any():
                raise data_error("sigma", "standard deviations > 0 on valid rows", "zeros")
        if self.weight is not None:
            weight = _per_channel("weight", self.weight, n, c)
            if (weight < 0).any():
                raise data_error("weight", "weights >= 0", f"min {weight.min():.6g}")
        if not isinstance(self.provenance, dict):
            raise data_error("provenance", "a dict", type(self.provenance).__name__)
        prov = _json_roundtrip("provenance", self.provenance)
        for name, val in (("wo", wo), ("wi", wi), ("values", values), ("sigma", sigma), ("weight", weight),
                          ("valid", valid)):
            object.__setattr__(self, name, None if val is None else _readonly(val))
        object.__setattr__(self, "channels", channels)
        object.__setattr__(self, "provenance", prov)

    # ------------------------------------------------------------------ basics
    def __len__(self) -> int:
        return self.values.shape[0]

    @property
    def n_channels(self) -> int:
        """C: the number of channels."""
        return self.values.shape[1]

    @property
    def channel_labels(self) -> list[str]:
        """The channels' names in CSV headers (:func:`channel_labels`)."""
        return channel_labels(self.channels)

    @property
    def n_valid(self) -> int:
        """The number of valid rows."""
        return int(self.valid.sum())

    def effective_weight(self) -> np.ndarray:
        """(N, C) fitting weights, a new writable array: ``weight``, else ``1 / sigma**2``, else 1; zero on invalid rows."""
        if self.weight is not None:
            w = self.weight.copy()
        elif self.sigma is not None:
            with np.errstate(divide="ignore"):
                w = np.where(self.sigma > 0, 1.0 / np.where(self.sigma > 0, self.sigma, 1.0) ** 2, 0.0)
        else:
            w = np.ones_like(self.values)
        w[~self.valid] = 0.0
        return w

    def as_jax(self, dtype=None) -> TableArrays:
        """The arrays as :class:`TableArrays` of ``dtype`` (a floating dtype; default JAX's default
        float; ``valid`` stays bool), with the :meth:`effective_weight`."""
        import jax.numpy as jnp

        if dtype is not None and not np.issubdtype(np.dtype(dtype), np.floating):
            raise data_error("dtype", "a floating dtype (float32 or float64)", repr(dtype))
        f = (lambda a: jnp.asarray(a, dtype=dtype)) if dtype is not None else jnp.asarray
        return TableArrays(f(self.wo), f(self.wi), f(self.values), f(self.effective_weight()),
                           jnp.asarray(self.valid))

    def replace(self, **changes) -> "Table":
        """A new Table with some fields replaced, validated as on construction; ``self`` is unchanged."""
        kw = dict(wo=self.wo, wi=self.wi, values=self.values, sigma=self.sigma, weight=self.weight,
                  valid=self.valid, channels=self.channels, provenance=copy.deepcopy(self.provenance))
        kw.update(changes)
        return Table(**kw)

    # ------------------------------------------------------------------ subsets
    def _take(self, idx, op: dict) -> "Table":
        prov = copy.deepcopy(self.provenance)
        prov.setdefault("derivation", []).append(op)
        return Table(wo=self.wo[idx], wi=self.wi[idx], values=self.values[idx],
                     sigma=None if self.sigma is None else self.sigma[idx],
                     weight=None if self.weight is None else self.weight[idx],
                     valid=self.valid[idx], channels=self.channels, provenance=prov)

    def select(self, mask) -> "Table":
        """Rows where the boolean ``mask`` (N,) is true, or the rows at the integer indices ``mask``
        (1-D, in ``[-N, N)``); the derivation gains ``{"op": "select", "n": ...}``."""
        m = np.asarray(mask)
        if m.dtype == bool:
            if m.shape != (len(self),):
                raise data_error("mask", f"boolean shape ({len(self)},)", f"shape {m.shape}")
            idx = np.flatnonzero(m)
        elif np.issubdtype(m.dtype, np.integer) and m.ndim == 1:
            if m.size and (m.min() < -len(self) or m.max() >= len(self)):
                raise data_error("mask", f"indices in [-{len(self)}, {len(self)})", f"range [{m.min()}, {m.max()}]")
            idx = m
        else:
            raise data_error("mask", "a boolean mask or 1-D integer indices", f"dtype {m.dtype}, shape {m.shape}")
        return self._take(idx, {"op": "select", "n": int(len(idx))})

    def subsample(self, n: int, seed: int = 0, valid_only: bool = True) -> "Table":
        """``n`` rows drawn without replacement (from the valid rows by default), in their original
        order; the derivation records ``n``, the ``seed`` and ``valid_only``."""
        pool = np.flatnonzero(self.valid) if valid_only else np.arange(len(self))
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0 or n > pool.size:
            raise data_error("n", f"an integer in [0, {pool.size}] ({'valid ' if valid_only else ''}rows available)", repr(n))
        rng = np.random.default_rng(seed)
        idx = np.sort(rng.choice(pool, size=int(n), replace=False))
        return self._take(idx, {"op": "subsample", "n": int(n), "seed": int(seed), "valid_only": bool(valid_only)})

    def split(self, frac: float, seed: int = 0) -> tuple["Table", "Table"]:
        """Random split into ``(fit, holdout)``: ``fit`` gets ``round(frac * N)`` rows, ``frac`` in
        (0, 1); disjoint, both non-empty, each in the original order."""
        n = len(self)
        if not (isinstance(frac, (float, int)) and 0.0 < float(frac) < 1.0):
            raise data_error("frac", "a fraction in (0, 1)", repr(frac))
        k = int(round(float(frac) * n))
        if k < 1 or k > n - 1:
            raise data_error("frac", f"a fraction leaving both parts non-empty (N = {n})", f"{frac} -> {k} rows")
        perm = np.random.default_rng(seed).permutation(n)
        fit_idx, hold_idx = np.sort(perm[:k]), np.sort(perm[k:])
        info = {"frac": float(frac), "seed": int(seed)}
        return (self._take(fit_idx, {"op": "split", "part": "fit", **info}),
                self._take(hold_idx, {"op": "split", "part": "holdout", **info}))

    # ------------------------------------------------------------------ description
    def summary(self) -> str:
        """A few lines: the size, the source, value ranges per channel, the angles covered, the
        uncertainty and the derivation."""
        n, nv = len(self), self.n_valid
        lines = [f"Table: {n} samples ({nv} valid), channels {self.channels if isinstance(self.channels, str) else list(self.channels)}"]
        src = self.provenance.get("source") or self.provenance.get("file")
        if src:
            lines.append(f"  source: {src}")
        for key in ("material", "instrument", "scene", "format"):
            if key in self.provenance:
                lines.append(f"  {key}: {self.provenance[key]}")
        if nv:
            v = self.values[self.valid]
            for j, lab in enumerate(self.channel_labels):
                lines.append(f"  value[{lab}]: min {v[:, j].min():.4g}, median {np.median(v[:, j]):.4g}, "
                             f"max {v[:, j].max():.4g} 1/sr")
            ti = np.degrees(np.arccos(np.clip(self.wi[self.valid, 2], -1, 1)))
            to = np.degrees(np.arccos(np.clip(self.wo[self.valid, 2], -1, 1)))
            lines.append(f"  theta_i: {ti.min():.2f}..{ti.max():.2f} deg, theta_o: {to.min():.2f}..{to.max():.2f} deg")
        lines.append("  uncertainty: " + ("sigma" if self.sigma is not None else "weight" if self.weight is not None
                                          else "none"))
        if "derivation" in self.provenance:
            lines.append("  derivation: " + ", ".join(d.get("op", "?") for d in self.provenance["derivation"]))
        return "\n".join(lines)

    def __repr__(self) -> str:
        return f"Table(n={len(self)}, valid={self.n_valid}, channels={self.channels!r})"

    # ------------------------------------------------------------------ npz
    def save_npz(self, path) -> None:
        """Write an uncompressed ``.npz`` (no pickled objects; provenance and channels as JSON) that
        :meth:`load_npz` reads back."""
        arrays = dict(format=np.array(NPZ_FORMAT), wo=self.wo, wi=self.wi, values=self.values, valid=self.valid,
                      channels=np.array(json.dumps(self.channels if isinstance(self.channels, str)
                                                   else list(self.channels))),
                      provenance=np.array(json.dumps(self.provenance)))
        if self.sigma is not None:
            arrays["sigma"] = self.sigma
        if self.weight is not None:
            arrays["weight"] = self.weight
        with open(path, "wb") as fh:
            np.savez(fh, **arrays)

    @classmethod
    def load_npz(cls, path) -> "Table":
        """Read a Table written by :meth:`save_npz` (a path, or the archive's bytes).

        :class:`~matfit.errors.DataFormatError`, naming the file, for anything but such an archive:
        missing or pickled arrays, a wrong format tag, invalid JSON, a table that does not validate.
        """
        src = path
        try:
            if isinstance(path, (bytes, bytearray)):
                path = _io.BytesIO(bytes(path))
            z = np.load(path, allow_pickle=False)
        except FileNotFoundError:
            raise
        except Exception as e:
            raise data_error("container", "a .npz (zip) archive", f"unreadable ({type(e).__name__}: {e})", file=src) from None
        if not hasattr(z, "files"):
            raise data_error("container", "a .npz archive", "a single .npy array", file=src)
        try:
            with z:
                files = set(z.files)
                need = {"format", "wo", "wi", "values", "valid", "channels", "provenance"}
                missing = sorted(need - files)
                if missing:
                    raise data_error("keys", f"arrays {sorted(need)}", f"missing {missing}", file=src)
                def get(k):
                    try:
                        return z[k]
                    except Exception as e:
                        raise data_error(k, "a plain numeric or string array (no pickles)",
                                         f"unreadable ({type(e).__name__}: {e})", file=src) from None
                fmt = get("format")
                if fmt.dtype.kind != "U" or fmt.shape != () or str(fmt) != NPZ_FORMAT:
                    raise data_error("format", repr(NPZ_FORMAT), repr(fmt.tolist() if fmt.size < 5 else fmt.dtype), file=src)
                jsons = {}
                for k in ("channels", "provenance"):
                    a = get(k)
                    if a.dtype.kind != "U" or a.shape != ():
                        raise data_error(k, "a JSON string (0-d unicode array)", f"dtype {a.dtype}, shape {a.shape}", file=src)
                    try:
                        jsons[k] = json.loads(str(a))
                    except (ValueError, RecursionError) as e:
                        raise data_error(k, "valid JSON", f"invalid JSON ({e})", file=src) from None
                arrs = {}
                for k in ("wo", "wi", "values", "valid", "sigma", "weight"):
                    if k in files:
                        a = get(k)
                        if k == "valid":
                            if a.dtype != bool:
                                raise data_error(k, "dtype bool", f"dtype {a.dtype}", file=src)
                        elif a.dtype.kind != "f":
                            raise data_error(k, "a floating-point array", f"dtype {a.dtype}", file=src)
                        arrs[k] = a
                return cls(channels=jsons["channels"] if isinstance(jsons["channels"], str) else jsons["channels"],
                           provenance=jsons["provenance"], **arrs)
        except DataFormatError as e:
            raise with_file(e, src) from None

    # ------------------------------------------------------------------ csv
    def csv_header(self) -> list[str]:
        """The column names of :meth:`save_csv`: directions, values, sigma or weight, valid."""
        cols = ["wo_x", "wo_y", "wo_z", "wi_x", "wi_y", "wi_z"]
        labs = self.channel_labels
        cols += [f"value_{l}" for l in labs]
        if self.sigma is not None:
            cols += [f"sigma_{l}" for l in labs]
        if self.weight is not None:
            cols += [f"weight_{l}" for l in labs]
        cols.append("valid")
        return cols

    def save_csv(self, path) -> None:
        """Write the CSV layout of docs/data.md: the magic line, ``# channels:`` and ``# provenance:``
        comment lines (JSON), the header, one row per sample; numbers written with ``repr``, so that
        :meth:`load_csv` reads back the same values."""
        with open(path, "w", newline="") as fh:
            fh.write(CSV_MAGIC + "\n")
            ch = self.channels if isinstance(self.channels, str) else list(self.channels)
            fh.write("# channels: " + json.dumps(ch) + "\n")
            fh.write("# provenance: " + json.dumps(self.provenance) + "\n")
            w = csv.writer(fh, lineterminator="\n")
            w.writerow(self.csv_header())
            parts = [self.wo, self.wi, self.values]
            if self.sigma is not None:
                parts.append(self.sigma)
            if self.weight is not None:
                parts.append(self.weight)
            body = np.concatenate(parts, axis=1)
            for row, v in zip(body, self.valid):
                w.writerow([repr(float(x)) for x in row] + [int(v)])

    @classmethod
    def load_csv(cls, path, channels=None) -> "Table":
        """Read a CSV table (a path, or its contents as bytes).

        ``channels`` overrides the ``# channels:`` line and must match the ``value_`` columns; without
        either it is inferred from the header. The provenance is that of the ``# provenance:`` line
        (empty without one). :class:`~matfit.errors.DataFormatError`, naming the file, the field and
        the line, for text that is not UTF-8, a malformed header or row, or a table that does not
        validate.
        """
        src = path
        try:
            if isinstance(path, (bytes, bytearray)):
                text = bytes(path).decode("utf-8")
            else:
                with open(path, "rb") as fh:
                    text = fh.read().decode("utf-8")
        except UnicodeDecodeError as e:
            raise data_error("encoding", "UTF-8 text", f"undecodable bytes ({e.reason} at byte {e.start})", file=src) from None
        try:
            return cls._parse_csv(text, channels)
        except DataFormatError as e:
            raise with_file(e, src) from None

    @classmethod
    def _parse_csv(cls, text: str, channels) -> "Table":
        if not text.strip():
            raise data_error("content", "a header line and data rows", "an empty file")
        lines = text.splitlines()
        meta = {}
        body_start = 0
        for i, line in enumerate(lines):
            s = line.strip()
            if s.startswith("#"):
                if s.startswith("# channels:"):
                    meta["channels"] = s[len("# channels:"):].strip()
                elif s.startswith("# provenance:"):
                    meta["provenance"] = s[len("# provenance:"):].strip()
                body_start = i + 1
                continue
            if s == "":
                body_start = i + 1
                continue
            break
        try:
            rows = list(csv.reader(lines[body_start:]))
        except csv.Error as e:
            raise data_error("content", "CSV text", f"unparsable ({e})") from None
        rows = [(body_start + k + 1, r) for k, r in enumerate(rows) if r and any(x.strip() for x in r)]
        if not rows:
            raise data_error("header", "a header line wo_x,wo_y,wo_z,wi_x,wi_y,wi_z,value_<channel>...", "no header")
        hline, header = rows[0]
        header = [h.strip() for h in header]
        dirs = ["wo_x", "wo_y", "wo_z", "wi_x", "wi_y", "wi_z"]
        if header[:6] != dirs:
            raise data_error("header", ",".join(dirs) + " as the first six columns", ",".join(header[:6]),
                             detail=f"line {hline}")
        if len(set(header)) != len(header):
            raise data_error("header", "distinct column names", ",".join(header), detail=f"line {hline}")
        rest = header[6:]
        has_valid = bool(rest) and rest[-1] == "valid"
        if has_valid:
            rest = rest[:-1]
        groups = {"value": [], "sigma": [], "weight": []}
        for col in rest:
            pre, _, lab = col.partition("_")
            if pre not in groups or not lab:
                raise data_error("header", "columns value_<ch>..., optional sigma_<ch>... or weight_<ch>..., optional valid",
                                 repr(col), detail=f"line {hline}")
            groups[pre].append(lab)
        labs = groups["value"]
        if not labs:
            raise data_error("header", "at least one value_<channel> column", "none", detail=f"line {hline}")
        for g in ("sigma", "weight"):
            if groups[g] and groups[g] != labs:
                raise data_error("header", f"{g}_ columns matching the value_ columns {labs}", groups[g],
                                 detail=f"line {hline}")
        order = ["value"] * len(labs) + ["sigma"] * len(groups["sigma"]) + ["weight"] * len(groups["weight"])
        if [c.partition("_")[0] for c in rest] != order:
            raise data_error("header", "value_ columns, then sigma_ or weight_ columns, then valid",
                             ",".join(rest), detail=f"line {hline}")
        # channels
        inferred = _channels_from_labels(labs)
        if channels is None and "channels" in meta:
            try:
                channels = json.loads(meta["channels"])
            except (ValueError, RecursionError) as e:
                raise data_error("channels", "a JSON value on the '# channels:' line", meta["channels"][:40],
                                 detail=str(e)) from None
        if channels is None:
            channels = inferred
            if channels is None:
                raise data_error("header", "value_ labels mono | r,g,b | <wavelength>nm", labs, detail=f"line {hline}")
        channels = _norm_channels(channels)
        if channel_labels(channels) != labs:
            raise data_error("header", f"value_ columns {channel_labels(channels)} for channels {channels!r}", labs,
                             detail=f"line {hline}")
        prov = {}
        if "provenance" in meta:
            try:
                prov = json.loads(meta["provenance"])
            except (ValueError, RecursionError) as e:
                raise data_error("provenance", "JSON on the '# provenance:' line", meta["provenance"][:40], detail=str(e)) from None
            if not isinstance(prov, dict):
                raise data_error("provenance", "a JSON object", type(prov).__name__)
        ncol = len(header)
        data = rows[1:]
        if not data:
            raise data_error("rows", "at least one data row", "none")
        arr = np.empty((len(data), ncol), dtype=np.float64)
        for k, (ln, r) in enumerate(data):
            if len(r) != ncol:
                raise data_error("row", f"{ncol} columns", f"{len(r)} columns", detail=f"line {ln}")
            for j, x in enumerate(r):
                try:
                    arr[k, j] = float(x)
                except ValueError:
                    raise data_error(header[j], "a number", repr(x[:30]), detail=f"line {ln}") from None
        c = len(labs)
        kw = dict(wo=arr[:, 0:3], wi=arr[:, 3:6], values=arr[:, 6:6 + c])
        pos = 6 + c
        if groups["sigma"]:
            kw["sigma"] = arr[:, pos:pos + c]
            pos += c
        if groups["weight"]:
            kw["weight"] = arr[:, pos:pos + c]
            pos += c
        if has_valid:
            v = arr[:, pos]
            if not np.isin(v, (0.0, 1.0)).all():
                bad = int(np.flatnonzero(~np.isin(v, (0.0, 1.0)))[0])
                raise data_error("valid", "0 or 1", repr(v[bad]), detail=f"line {data[bad][0]}")
            kw["valid"] = v.astype(bool)
        return cls(channels=channels, provenance=prov, **kw)


def _channels_from_labels(labs: Sequence[str]):
    if list(labs) == ["mono"]:
        return "mono"
    if list(labs) == list(_RGB_LABELS):
        return "rgb"
    out = []
    for lab in labs:
        if not lab.endswith("nm"):
            return None
        try:
            out.append(float(lab[:-2]))
        except ValueError:
            return None
    return out
