"""Reading and writing the images of a capture: 8- and 16-bit PNG (pypng) and float EXR (OpenEXR).

PNG goes through pypng because Pillow truncates 16-bit colour PNG to 8 bits; EXR goes through
the ``OpenEXR.File`` API. PNG codes are returned divided by the largest code (values in [0, 1],
no colour decoding); EXR values are returned as stored (linear floats). Every error is a
:class:`~matfit.errors.DataFormatError` naming the file: reading, a missing file, an unsupported
extension, a damaged file, a palette PNG or a bit depth other than 8 / 16, EXR channels other than
R, G, B[, A] / Y[, A] or not HALF / FLOAT; writing, a bit depth other than 8 / 16, a non-numeric,
non-finite or wrongly shaped array (PNG 1 to 4 channels, EXR 1 or 3), a file that cannot be written.

:func:`open_image_rows` reads an image a band of rows at a time, for loaders that must stay
bounded in memory: non-interlaced PNG rows come from pypng's lazy row iterator, EXR scanline
ranges from OpenEXR's ``InputFile.channels(names, type, y1, y2)``. Interlaced PNGs cannot be
read by rows (pypng decodes them whole on the first row) and an OpenEXR without ``InputFile``
is read whole: both are accepted, holding that image's pixels in memory until closed. The errors
are those of :func:`read_image_codes`, word for word: on any problem the file is read whole
again to raise the same message.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import DataFormatError

__all__ = ["read_image", "read_image_codes", "open_image_rows", "ImageRows", "write_png", "write_exr"]

#: Image file extensions understood by :func:`read_image`, and their format names.
EXTENSIONS = {".png": "png", ".exr": "exr"}


def _format_of(path):
    fmt = EXTENSIONS.get(Path(path).suffix.lower())
    if fmt is None:
        raise DataFormatError(f"{path}: unsupported image extension {Path(path).suffix!r}; "
                              f"expected one of {sorted(EXTENSIONS)}")
    return fmt


def _png_reader(path, file=None):
    """A ``png.Reader`` past the header of an 8- or 16-bit non-palette PNG (``file``: an open
    binary file to read from instead of ``path``)."""
    import png

    try:
        reader = png.Reader(filename=str(path)) if file is None else png.Reader(file=file)
        reader.preamble()
    except Exception as e:  # pypng raises FormatError, zlib or EOF errors on damaged files
        raise DataFormatError(f"{path}: not a readable PNG file ({type(e).__name__}: {e})") from None
    # palette images hold indices, not intensities; low bit depths are not used for captures
    if reader.color_type == 3:
        raise DataFormatError(f"{path}: palette PNG images are not supported; expected an 8- or 16-bit "
                              f"greyscale or RGB(A) PNG, found a {reader.bitdepth}-bit palette image")
    if reader.bitdepth not in (8, 16):
        raise DataFormatError(f"{path}: expected 8- or 16-bit PNG, found {reader.bitdepth}-bit")
    return reader


def _read_png_codes(path):
    """The integer codes ``(H, W, C)`` (uint8 or uint16) of an 8- or 16-bit PNG and its bit depth."""
    reader = _png_reader(path)
    try:
        # read() applies no conversion (asDirect would rescale to an sBIT depth)
        width, height, rows, info = reader.read()
        dtype = np.uint16 if info["bitdepth"] == 16 else np.uint8
        codes = np.vstack([np.frombuffer(row, dtype=dtype) for row in rows])
    except Exception as e:
        raise DataFormatError(f"{path}: corrupt PNG pixel data ({type(e).__name__}: {e})") from None
    planes = int(info["planes"])
    if codes.shape != (height, width * planes):
        raise DataFormatError(f"{path}: corrupt PNG: expected {height} rows of {width * planes} values, "
                              f"found shape {codes.shape}")
    return codes.reshape(height, width, planes), int(info["bitdepth"])


def _exr_order(path, names):
    """The channels read from an EXR with channels ``names``, in pixel order: R, G, B[, A] or Y[, A]."""
    names = set(names)
    if {"R", "G", "B"} <= names:
        return ["R", "G", "B"] + (["A"] if "A" in names else [])
    if "Y" in names:
        return ["Y"] + (["A"] if "A" in names else [])
    raise DataFormatError(f"{path}: expected EXR channels R, G, B or Y, found {sorted(names)}")


def _read_exr(path):
    """The float32 pixels ``(H, W, C)`` of an EXR file (R, G, B[, A] or Y) and its bit depth."""
    import OpenEXR

    try:
        with OpenEXR.File(str(path), separate_channels=True) as f:
            channels = {name: (ch.pixels, ch.type()) for name, ch in f.channels().items()}
    except Exception as e:
        raise DataFormatError(f"{path}: not a readable EXR file ({type(e).__name__}: {e})") from None
    order = _exr_order(path, channels)
    kinds = {channels[n][1] for n in order}
    if not kinds <= {OpenEXR.HALF, OpenEXR.FLOAT}:
        raise DataFormatError(f"{path}: expected HALF or FLOAT EXR channels, found {sorted(str(k) for k in kinds)}")
    pixels = np.stack([np.asarray(channels[n][0], dtype=np.float32) for n in order], axis=-1)
    return pixels, (32 if OpenEXR.FLOAT in kinds else 16)


def read_image_codes(path):
    """Like :func:`read_image`, but PNG pixels stay integer codes (uint8 or uint16); EXR pixels are
    float32. Used by the capture loader to decode sRGB through a lookup table.
    """
    fmt = _format_of(path)
    if not os.path.isfile(path):
        raise DataFormatError(f"{path}: image file not found")
    if fmt == "png":
        codes, depth = _read_png_codes(path)
        return codes, {"bit_depth": depth, "format": "png", "max_code": (1 << depth) - 1}
    pixels, depth = _read_exr(path)
    return pixels, {"bit_depth": depth, "format": "exr", "max_code": None}


def _canonical_error(path, what):
    """Raise the error :func:`read_image_codes` gives for ``path`` (reading it whole); if that
    read succeeds (the file changed meanwhile), raise one naming ``what``."""
    read_image_codes(path)
    raise DataFormatError(f"{path}: {what}, yet the file reads whole without error (did it change meanwhile?)")


class ImageRows:
    """Bands of rows of one image, read in order from the top (made by :func:`open_image_rows`); a context manager.

    ``read(y, n)`` gives rows ``y .. y + n - 1`` (``n < 0``: check the end of the data) and
    ``close`` releases the file. ``shape`` is ``(H, W, C)`` and ``info`` the dict of
    :func:`read_image_codes`; ``position`` counts the rows read; ``interlaced`` marks an
    interlaced PNG, decoded whole on the first read and held in memory until closed.
    """

    def __init__(self, path, shape, info, read, close=None):
        self.path, self.shape, self.info = Path(path), tuple(shape), info
        self.position = 0
        self.interlaced = False
        self._read, self._close = read, close

    def read(self, n):
        """The next ``n`` rows ``(m, W, C)``, ``m = min(n, rows left)``: PNG codes or EXR float32; errors as :func:`read_image_codes`."""
        n = max(0, min(int(n), self.shape[0] - self.position))
        rows = self._read(self.position, n)
        self.position += n
        return rows

    def finish(self) -> None:
        """Check the data ends after the last row and close: ValueError if rows are left unread,
        DataFormatError (as :func:`read_image_codes`) if data follows or the stream is damaged.
        """
        if self.position < self.shape[0]:
            raise ValueError(f"{self.path}: {self.shape[0] - self.position} rows not read")
        self._read(self.shape[0], -1)
        self.close()

    def close(self) -> None:
        """Release the file (idempotent)."""
        if self._close is not None:
            close, self._close = self._close, None
            close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _png_rows(path):
    fh = open(path, "rb")
    try:
        reader = _png_reader(path, file=fh)
        try:
            width, height, rows, info = reader.read()  # lazy: only the header is read here
        except Exception:
            _canonical_error(path, "corrupt PNG pixel data")
    except BaseException:
        fh.close()
        raise
    planes, depth = int(info["planes"]), int(info["bitdepth"])
    dtype = np.uint16 if depth == 16 else np.uint8
    rows = iter(rows)

    def read(y, n):
        if n < 0:  # the end: nothing may follow the last row (errors in the last chunks show here)
            try:
                extra = next(rows, None)
            except Exception:
                extra = True
            if extra is not None:
                _canonical_error(path, "corrupt PNG pixel data after the last row")
            return None
        try:
            codes = np.vstack([np.frombuffer(next(rows), dtype=dtype) for _ in range(n)]) if n else \
                np.zeros((0, width * planes), dtype)
        except Exception:  # a damaged stream, a short row or too few rows
            _canonical_error(path, f"corrupt PNG pixel data in rows {y} to {y + n - 1}")
        if codes.shape != (n, width * planes):
            _canonical_error(path, f"corrupt PNG pixel data in rows {y} to {y + n - 1}")
        return codes.reshape(n, width, planes)

    info = {"bit_depth": depth, "format": "png", "max_code": (1 << depth) - 1}
    out = ImageRows(path, (height, width, planes), info, read, fh.close)
    out.interlaced = bool(reader.interlace)
    return out


def _exr_rows(path):
    import OpenEXR

    if not hasattr(OpenEXR, "InputFile"):  # no scanline API: read whole, serve bands from memory
        pixels, depth = _read_exr(path)
        info = {"bit_depth": depth, "format": "exr", "max_code": None}
        return ImageRows(path, pixels.shape, info, lambda y, n: pixels[y:y + n] if n >= 0 else None)
    import Imath

    try:
        f = OpenEXR.InputFile(str(path))
    except Exception:
        _canonical_error(path, "not a readable EXR file")
    try:
        header = f.header()
        channels = header["channels"]
        window = header["dataWindow"]
        order = _exr_order(path, channels)
        kinds = {str(channels[n].type) for n in order}
        if not kinds <= {"HALF", "FLOAT"}:
            _canonical_error(path, f"expected HALF or FLOAT EXR channels, found {sorted(kinds)}")
    except Exception:
        f.close()
        raise
    y0, width = window.min.y, window.max.x - window.min.x + 1
    height = window.max.y - window.min.y + 1
    as_float = Imath.PixelType(Imath.PixelType.FLOAT)

    def read(y, n):
        if n <= 0:
            return None if n < 0 else np.zeros((0, width, len(order)), np.float32)
        try:
            planes = f.channels(order, as_float, y0 + y, y0 + y + n - 1)
            return np.stack([np.frombuffer(b, np.float32).reshape(n, width) for b in planes], axis=-1)
        except Exception:
            _canonical_error(path, f"corrupt EXR pixel data in rows {y} to {y + n - 1}")

    info = {"bit_depth": 32 if "FLOAT" in kinds else 16, "format": "exr", "max_code": None}
    return ImageRows(path, (height, width, len(order)), info, read, f.close)


def open_image_rows(path):
    """Open an image to read it a band of rows at a time (top to bottom): an :class:`ImageRows`.

    Pixels and errors are those of :func:`read_image_codes`. Non-interlaced PNGs are decoded as their
    rows are read; EXR reads only the scanlines asked for (OpenEXR's ``InputFile``); an interlaced PNG
    is decoded whole on its first read and held until closed.
    """
    fmt = _format_of(path)
    if not os.path.isfile(path):
        raise DataFormatError(f"{path}: image file not found")
    return _png_rows(path) if fmt == "png" else _exr_rows(path)


def read_image(path):
    """Read an 8- or 16-bit PNG or a float EXR image.

    Parameters
    ----------
    path : str or Path
        A ``.png`` (8- or 16-bit greyscale, greyscale + alpha, RGB or RGBA; palette images and
        1-, 2-, 4-bit depths are refused) or ``.exr`` (channels R, G, B[, A] or Y[, A], HALF or FLOAT).

    Returns
    -------
    pixels : ndarray, float32, (H, W, C)
        PNG: codes divided by the largest code, in [0, 1] (no colour decoding). EXR: as stored.
    info : dict
        ``"bit_depth"`` (8 or 16 for PNG; 32 for FLOAT EXR, 16 for HALF), ``"format"``
        (``"png"`` or ``"exr"``) and ``"max_code"`` (255, 65535, or None for EXR).

    Examples
    --------
    >>> import tempfile, os, numpy as np
    >>> from matfit.maps import read_image, write_png
    >>> with tempfile.TemporaryDirectory() as d:
    ...     write_png(os.path.join(d, "gray.png"), np.full((2, 3), 0.5), bit_depth=8)
    ...     pixels, info = read_image(os.path.join(d, "gray.png"))
    >>> pixels.shape, info["bit_depth"], info["max_code"], round(float(pixels[0, 0, 0]) * 255)
    ((2, 3, 1), 8, 255, 128)
    """
    pixels, info = read_image_codes(path)
    if info["format"] == "png":
        pixels = pixels.astype(np.float32) / np.float32(info["max_code"])
    return pixels, info


def _as_image(what, path, array):
    a = np.asarray(array)
    if a.dtype.kind not in "iuf":
        raise DataFormatError(f"{path}: {what} expects real pixel values, found dtype {a.dtype}")
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3 or a.shape[0] < 1 or a.shape[1] < 1:
        raise DataFormatError(f"{path}: {what} expects an array of shape (H, W) or (H, W, C), found {a.shape}")
    if not np.all(np.isfinite(a)):
        raise DataFormatError(f"{path}: {what}: {int(np.sum(~np.isfinite(a)))} non-finite pixel values")
    return a


def write_png(path, array, bit_depth=16) -> None:
    """Write values in [0, 1] (clipped) as an 8- or 16-bit PNG, codes rounded to the nearest integer.

    No colour encoding is applied: encode sRGB before calling if wanted.

    Parameters
    ----------
    path : str or Path
        Replaced if present.
    array : array_like, (H, W) or (H, W, C) with C in 1..4
        1: greyscale, 2: greyscale + alpha, 3: RGB, 4: RGBA.
    bit_depth : {8, 16}
    """
    import png

    if bit_depth not in (8, 16):
        raise DataFormatError(f"{path}: bit_depth must be 8 or 16, got {bit_depth!r}")
    a = _as_image("write_png", path, array)
    h, w, c = a.shape
    if c not in (1, 2, 3, 4):
        raise DataFormatError(f"{path}: write_png expects 1 to 4 channels, found {c}")
    top = (1 << bit_depth) - 1
    codes = np.rint(np.clip(a.astype(np.float64), 0.0, 1.0) * top).astype(np.uint16 if bit_depth == 16 else np.uint8)
    writer = png.Writer(w, h, greyscale=c in (1, 2), alpha=c in (2, 4), bitdepth=bit_depth)
    try:
        with open(path, "wb") as f:
            writer.write(f, codes.reshape(h, w * c))
    except OSError as e:
        raise DataFormatError(f"{path}: cannot write the PNG file ({e})") from None


def write_exr(path, array) -> None:
    """Write a float32 EXR image (ZIP compression): channels R, G, B for 3 channels, Y for 1.

    Parameters
    ----------
    path : str or Path
        Replaced if present.
    array : array_like, (H, W), (H, W, 1) or (H, W, 3)
        Linear values, stored as FLOAT (32-bit).
    """
    import OpenEXR

    a = _as_image("write_exr", path, array).astype(np.float32)
    c = a.shape[-1]
    if c == 3:
        channels = {"R": a[..., 0].copy(), "G": a[..., 1].copy(), "B": a[..., 2].copy()}
    elif c == 1:
        channels = {"Y": a[..., 0].copy()}
    else:
        raise DataFormatError(f"{path}: write_exr expects 1 (Y) or 3 (RGB) channels, found {c}")
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    try:
        with OpenEXR.File(header, channels) as f:
            f.write(str(path))
    except Exception as e:
        raise DataFormatError(f"{path}: cannot write the EXR file ({type(e).__name__}: {e})") from None
