"""Readers and writers of measured-BRDF files; every reader produces a :class:`matfit.table.Table`.

``load(path)`` dispatches on the extension:

========== ============================================== ===========================
extension  format                                          native object
========== ============================================== ===========================
``.npz``   matfit Table archive (``Table.save_npz``)       --
``.csv``   matfit Table CSV (``Table.save_csv``)           --
``.binary`` MERL 2003 table (:mod:`matfit.io.merl`)        :class:`MerlBRDF`
``.bsdf``  RGL tensor file (:mod:`matfit.io.rgl`)          :class:`RglBRDF`
``.alta``  ALTA text data (:mod:`matfit.io.alta`)          :class:`AltaData`
========== ============================================== ===========================

Malformed input raises :class:`matfit.errors.DataFormatError` naming the file, field, expected and found.
"""
from __future__ import annotations

import os

from .._dataerr import data_error
from ..errors import ParameterError
from ..table import Table
from ._halfdiff import dirs_to_half_diff, half_diff_to_dirs
from .alta import AltaData, read_alta
from .merl import MerlBRDF, read_merl, write_merl
from .rgl import RglBRDF, read_rgl, read_tensor_file, write_tensor_file

__all__ = ["load", "save", "read_merl", "write_merl", "read_rgl", "read_alta", "read_tensor_file",
           "write_tensor_file", "MerlBRDF", "RglBRDF", "AltaData", "EXTENSIONS", "dirs_to_half_diff",
           "half_diff_to_dirs"]

EXTENSIONS = (".npz", ".csv", ".binary", ".bsdf", ".alta")


def load(path, *, return_native: bool = False, **options):
    """Read ``path`` into a Table, choosing the reader by the file's extension.

    Parameters
    ----------
    path : str or PathLike
        A file with one of the :data:`EXTENSIONS` (the table in the module docstring).
    return_native : bool, default False
        Also return the format's own object (:class:`MerlBRDF`, :class:`RglBRDF`,
        :class:`AltaData`; None for .npz / .csv).
    **options
        Passed to the native object's ``to_table`` (``drop_invalid`` for MERL, ``theta_d`` /
        ``phi_d`` for ALTA slices) or to :meth:`Table.load_csv` (``channels``).

    Returns
    -------
    Table or (Table, native)

    Raises
    ------
    DataFormatError
        An unknown extension or a malformed file, naming the file.

    Examples
    --------
    >>> import os, tempfile
    >>> from matfit.io import load, save
    >>> from matfit.table import Table
    >>> t = Table(wo=[[0.0, 0.0, 1.0]], wi=[[0.0, 0.6, 0.8]], values=[[0.2]], channels="mono")
    >>> with tempfile.TemporaryDirectory() as d:
    ...     save(os.path.join(d, "t.csv"), t)
    ...     back, native = load(os.path.join(d, "t.csv"), return_native=True)
    >>> back.values.tolist(), native
    ([[0.2]], None)
    """
    ext = os.path.splitext(os.fspath(path))[1].lower()
    if ext not in EXTENSIONS:
        raise data_error("extension", " or ".join(EXTENSIONS), repr(ext), file=path)
    native = None
    if ext == ".npz":
        table = Table.load_npz(path)
    elif ext == ".csv":
        table = Table.load_csv(path, **options)
    else:
        native = {".binary": read_merl, ".bsdf": read_rgl, ".alta": read_alta}[ext](path)
        table = native.to_table(**options)
    return (table, native) if return_native else table


def save(path, table: Table) -> None:
    """Write a Table as ``.npz`` (:meth:`Table.save_npz`) or ``.csv`` (:meth:`Table.save_csv`), by extension.

    Parameters
    ----------
    path : str or PathLike
    table : Table

    Raises
    ------
    ParameterError
        ``table`` is not a Table.
    DataFormatError
        Another extension.
    """
    if not isinstance(table, Table):
        raise ParameterError(f"save: table must be a matfit.Table, got {type(table).__name__} (call save(path, table))")
    ext = os.path.splitext(os.fspath(path))[1].lower()
    if ext == ".npz":
        table.save_npz(path)
    elif ext == ".csv":
        table.save_csv(path)
    else:
        raise data_error("extension", ".npz or .csv", repr(ext), file=path)
