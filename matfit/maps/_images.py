"""Reading and writing the images of a capture: 8- and 16-bit PNG (pypng) and float EXR (OpenEXR).

PNG goes through pypng because Pillow truncates 16-bit colour PNG to 8 bits; EXR goes through
the ``OpenEXR.File`` API. PNG codes are returned divided by the largest code (values in [0, 1],
no colour decoding); EXR values are returned as stored (linear floats). Every error is a
:class:`~matfit.errors.DataFormatError` naming the file.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import DataFormatError

__all__ = ["read_image", "write_png", "write_exr"]

#: Image file extensions understood by :func:`read_image`, and their format names.
EXTENSIONS = {".png": "png", ".exr": "exr"}


def _format_of(path):
    fmt = EXTENSIONS.get(Path(path).suffix.lower())
    if fmt is None:
        raise DataFormatError(f"{path}: unsupported image extension {Path(path).suffix!r}; "
                              f"expected one of {sorted(EXTENSIONS)}")
    return fmt


def _read_png_codes(path):
    """The integer codes ``(H, W, C)`` (uint8 or uint16) of an 8- or 16-bit PNG and its bit depth."""
    import png

    try:
        reader = png.Reader(filename=str(path))
        reader.preamble()
    except Exception as e:  # pypng raises FormatError, zlib or EOF errors on damaged files
        raise DataFormatError(f"{path}: not a readable PNG file ({type(e).__name__}: {e})") from None
    # palette images hold indices, not intensities; low bit depths are not used for captures
    if reader.color_type == 3:
        raise DataFormatError(f"{path}: palette PNG images are not supported; expected an 8- or 16-bit "
                              f"greyscale or RGB(A) PNG, found a {reader.bitdepth}-bit palette image")
    if reader.bitdepth not in (8, 16):
        raise DataFormatError(f"{path}: expected 8- or 16-bit PNG, found {reader.bitdepth}-bit")
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


def _read_exr(path):
    """The float32 pixels ``(H, W, C)`` of an EXR file (R, G, B[, A] or Y) and its bit depth."""
    import OpenEXR

    try:
        with OpenEXR.File(str(path), separate_channels=True) as f:
            channels = {name: (ch.pixels, ch.type()) for name, ch in f.channels().items()}
    except Exception as e:
        raise DataFormatError(f"{path}: not a readable EXR file ({type(e).__name__}: {e})") from None
    names = set(channels)
    if {"R", "G", "B"} <= names:
        order = ["R", "G", "B"] + (["A"] if "A" in names else [])
    elif "Y" in names:
        order = ["Y"] + (["A"] if "A" in names else [])
    else:
        raise DataFormatError(f"{path}: expected EXR channels R, G, B or Y, found {sorted(names)}")
    kinds = {channels[n][1] for n in order}
    if not kinds <= {OpenEXR.HALF, OpenEXR.FLOAT}:
        raise DataFormatError(f"{path}: expected HALF or FLOAT EXR channels, found {sorted(str(k) for k in kinds)}")
    pixels = np.stack([np.asarray(channels[n][0], dtype=np.float32) for n in order], axis=-1)
    return pixels, (32 if OpenEXR.FLOAT in kinds else 16)


def read_image_codes(path):
    """Like :func:`read_image`, but PNG pixels stay integer codes (uint8 or uint16); EXR pixels
    are float32. Used by the capture loader to decode sRGB through a lookup table."""
    fmt = _format_of(path)
    if not os.path.isfile(path):
        raise DataFormatError(f"{path}: image file not found")
    if fmt == "png":
        codes, depth = _read_png_codes(path)
        return codes, {"bit_depth": depth, "format": "png", "max_code": (1 << depth) - 1}
    pixels, depth = _read_exr(path)
    return pixels, {"bit_depth": depth, "format": "exr", "max_code": None}


def read_image(path):
    """Read an 8- or 16-bit PNG or a float EXR image.

    Parameters
    ----------
    path : str or Path
        A ``.png`` (8- or 16-bit greyscale, greyscale + alpha, RGB or RGBA; palette images and
        1-, 2-, 4-bit depths are refused) or ``.exr`` (channels R, G, B[, A] or Y[, A]) file.

    Returns
    -------
    pixels : ndarray, float32, (H, W, C)
        PNG: codes divided by the largest code, in [0, 1] (no colour decoding). EXR: the stored
        values.
    info : dict
        ``"bit_depth"`` (8 or 16 for PNG; 32 for FLOAT EXR, 16 for HALF EXR), ``"format"``
        (``"png"`` or ``"exr"``) and ``"max_code"`` (255, 65535, or None for EXR).

    Raises
    ------
    DataFormatError
        Missing file, unsupported extension, damaged file or unsupported bit depth; the message
        names the file.

    Examples
    --------
    >>> import tempfile, os, numpy as np
    >>> from matfit.maps._images import read_image, write_png
    >>> path = os.path.join(tempfile.mkdtemp(), "gray.png")
    >>> write_png(path, np.full((2, 3), 0.5), bit_depth=8)
    >>> pixels, info = read_image(path)
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


def write_png(path, array, bit_depth=16):
    """Write values in [0, 1] as an 8- or 16-bit PNG (codes rounded to the nearest integer).

    Parameters
    ----------
    path : str or Path
    array : array_like, (H, W) or (H, W, C) with C in 1..4
        1: greyscale, 2: greyscale + alpha, 3: RGB, 4: RGBA. Values outside [0, 1] are clipped.
        No colour encoding is applied: encode sRGB before calling if wanted.
    bit_depth : {8, 16}

    Examples
    --------
    >>> import tempfile, os, numpy as np
    >>> from matfit.maps._images import read_image, write_png
    >>> path = os.path.join(tempfile.mkdtemp(), "rgb.png")
    >>> write_png(path, np.ones((4, 5, 3)))
    >>> float(read_image(path)[0].min())
    1.0
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


def write_exr(path, array):
    """Write a float32 EXR image (ZIP compression): channels R, G, B for 3 channels, Y for 1.

    Parameters
    ----------
    path : str or Path
    array : array_like, (H, W), (H, W, 1) or (H, W, 3)
        Linear values, stored as FLOAT (32-bit).

    Examples
    --------
    >>> import tempfile, os, numpy as np
    >>> from matfit.maps._images import read_image, write_exr
    >>> path = os.path.join(tempfile.mkdtemp(), "hdr.exr")
    >>> write_exr(path, np.full((2, 2, 3), 7.25))
    >>> pixels, info = read_image(path)
    >>> float(pixels[1, 1, 2]), info["bit_depth"], info["format"]
    (7.25, 32, 'exr')
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
