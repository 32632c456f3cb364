"""Captures: images of a flat material sample under known lights, turned into BRDF measurements per texel.

A capture is a folder holding the images and a document ``capture.json`` (or ``capture.toml``)::

    {"format": "matfit-capture", "version": 1,
     "images": ["img_000.png", "img_001.png"],      # N files, relative to the folder
     "geometry": "directions",                      # or "positions"; default "directions"
     "lights": [[0.3, 0.0, 0.95], [-0.2, 0.1, 0.97]],
     "camera": [0.0, 0.0, 1.0],                     # or "cameras": N entries
     "scale": 1.0,                                  # exposure factor, a number or N numbers
     "irradiance": 1.0,                             # directions mode; "intensity" in positions mode
     "color_space": "srgb",                         # default: srgb for PNG, linear for EXR
     "flat_field": "flat.png"}                      # optional vignetting image, divided out

Geometry. The sample lies in the plane z = 0 with its normal +z (the library's local frame).
``"directions"``: ``lights`` and ``cameras`` are directions (normalized here) from the sample to
the light and to the camera, the same for every texel (distant light and camera); ``irradiance``
is the light's irradiance E at the sample, normal to the light. ``"positions"``: ``lights`` and
``cameras`` are points above the sample (z > 0), ``intensity`` is the point light's intensity I,
and ``sample_size = [width, height]`` the physical size of the sample, centred at the origin:
texel (row r, column c) of an H x W image sits at ``x = (c + 0.5) / W * width - width / 2``,
``y = height / 2 - (r + 0.5) / H * height``; its ``wo``, ``wi`` point from it to the camera and
the light, and E = I / d^2 with d its distance to the light.

Radiometry. A linear pixel is ``scale_j * flat(x) * f(wo, wi) * cos(theta_i) * E_j``, so the
loader's values are ``f = pixel / (scale_j * flat(x) * cos(theta_i) * E_j)``. PNG pixels in the
``srgb`` colour space are decoded with colour-science's sRGB EOTF; the flat field is read as
linear values. Measurements that cannot be used are marked invalid rather than raising: PNG
pixels at the largest code in any channel (saturated), ``cos(theta_i) <= 0.01`` or
``cos(theta_o) <= 0.01`` (grazing), and texels where the flat field is zero.

Every malformed capture raises :class:`CaptureError` (a :class:`~matfit.errors.DataFormatError`)
with one message naming the file and the field.

Large captures. The measurements of an H x W capture of N images take ``H W N (4 C + 1)`` bytes
(4.8 GB of values for 4096 x 4096 x 24 RGB images, as much again for each of ``wo`` and ``wi`` in
``"positions"`` geometry). ``load_capture(path, out=folder)`` writes them to C-order ``.npy`` files
(``values``, ``valid``, and ``wo``, ``wi`` in positions geometry; replaced if present) a band of
rows (about 32 MiB) at a time with ``os.pwrite``, reading all the images together by rows, and
returns read-only memory maps of them, which :func:`matfit.maps.fit_map` reads a chunk at a time:
memory stays bounded by a band plus the decoders' buffers, not the capture, and the numbers equal
the in-memory load's bit for bit. Files are written as ``NAME.partial`` and renamed when all are
complete; on any error they are removed and the error is the in-memory load's (every image header
is checked before any file is started, so with several faults the two may name different ones
first). Bounded for non-interlaced PNG and EXR (OpenEXR's ``InputFile``); an interlaced PNG is
decoded whole by pypng and holds about twice its codes in memory during the load.
"""
from __future__ import annotations

import functools
import json
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import DataFormatError
from ._images import open_image_rows, read_image_codes

__all__ = ["Capture", "CaptureError", "load_capture", "write_capture_document", "CAPTURE_KEYS",
           "DOCUMENT_NAMES", "COS_MIN"]

#: File names of the capture document, looked for in this order inside a capture folder.
DOCUMENT_NAMES = ("capture.json", "capture.toml")

#: The top-level keys of a capture document; any other key is refused (typos must not pass).
#: ``notes`` is free-form (provenance, ground truth) and is not interpreted.
CAPTURE_KEYS = ("format", "version", "images", "geometry", "lights", "cameras", "camera", "scale",
                "irradiance", "intensity", "sample_size", "color_space", "flat_field", "notes")

#: Measurements with cos(theta_i) or cos(theta_o) at or below this are marked invalid (grazing).
COS_MIN = 0.01

FORMAT_NAME = "matfit-capture"
VERSION = 1


class CaptureError(DataFormatError):
    """A capture folder or document is malformed; the message names the file and the field.

    Parameters
    ----------
    *args : object
        The message: the capture document (or image), the key or entry, expected vs found.

    Examples
    --------
    >>> import tempfile
    >>> from matfit.maps import CaptureError, load_capture
    >>> with tempfile.TemporaryDirectory() as d:
    ...     try:
    ...         load_capture(d)
    ...     except CaptureError as e:
    ...         print(str(e).replace(d, "<folder>"))
    <folder>: no capture.json or capture.toml in the capture folder
    """


@dataclass(frozen=True, eq=False)
class Capture:
    """BRDF measurements per texel of a capture (see the module docstring for the format).

    Attributes
    ----------
    wo, wi : ndarray, float32
        Unit directions to the camera and to the light: ``(N, 3)`` when all texels share them
        (``"directions"`` geometry), else ``(H, W, N, 3)``.
    values : ndarray, float32, (H, W, N, C)
        BRDF values f(wo, wi) in 1/sr (without the cosine); meaningless where ``valid`` is False
        (0 where the denominator is unusable).
    valid : ndarray, bool, (H, W, N)
        False for saturated pixels, grazing directions and a zero flat field.
    files : tuple of Path
        The N image files, in the document's order.
    meta : dict
        The parsed capture document.

    Examples
    --------
    >>> import tempfile
    >>> import numpy as np
    >>> from matfit.maps import load_capture, write_capture_document, write_exr
    >>> with tempfile.TemporaryDirectory() as d:
    ...     write_exr(f"{d}/a.exr", np.full((2, 3), 0.2)); write_exr(f"{d}/b.exr", np.full((2, 3), 0.1))
    ...     _ = write_capture_document(d, {"images": ["a.exr", "b.exr"], "lights": [[0, 0, 1], [0.6, 0, 0.8]],
    ...                                    "camera": [0, 0, 1]})
    ...     cap = load_capture(d)
    >>> cap.shape, cap.n_images, cap.n_channels, cap.shared_directions, cap.wi.shape
    ((2, 3), 2, 1, True, (2, 3))
    >>> [round(float(v), 6) for v in cap.values[0, 0, :, 0]]     # pixel / cos(theta_i)
    [0.2, 0.125]
    """

    wo: np.ndarray
    wi: np.ndarray
    values: np.ndarray
    valid: np.ndarray
    files: tuple
    meta: dict

    @property
    def shape(self):
        """``(H, W)``: the image size in texels."""
        return tuple(self.values.shape[:2])

    @property
    def n_images(self):
        """N: the number of images (measurements per texel)."""
        return int(self.values.shape[2])

    @property
    def n_channels(self):
        """C: the number of colour channels."""
        return int(self.values.shape[3])

    @property
    def shared_directions(self):
        """True when every texel has the same ``wo``, ``wi`` (arrays of shape ``(N, 3)``)."""
        return self.wo.ndim == 2


# --- the document ------------------------------------------------------------------------------


def _find_document(path):
    p = Path(path)
    if p.is_dir():
        found = [p / n for n in DOCUMENT_NAMES if (p / n).is_file()]
        if not found:
            raise CaptureError(f"{p}: no {' or '.join(DOCUMENT_NAMES)} in the capture folder")
        if len(found) > 1:
            raise CaptureError(f"{p}: both {found[0].name} and {found[1].name} in the capture folder; "
                               f"expected one capture document")
        return found[0]
    if not p.exists():
        raise CaptureError(f"{p}: capture folder or document not found")
    if p.suffix.lower() not in (".json", ".toml"):
        raise CaptureError(f"{p}: expected a capture folder or a .json / .toml capture document, "
                           f"found a {p.suffix or 'suffix-less'} file")
    return p


def _parse_document(doc_path):
    try:
        text = doc_path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise CaptureError(f"{doc_path}: cannot read the capture document ({type(e).__name__}: {e})") from None
    if doc_path.suffix.lower() == ".toml":
        import tomllib

        try:
            doc = tomllib.loads(text)
        except tomllib.TOMLDecodeError as e:
            raise CaptureError(f"{doc_path}: not valid TOML ({e})") from None
    else:
        try:
            doc = json.loads(text)
        except json.JSONDecodeError as e:
            raise CaptureError(f"{doc_path}: not valid JSON ({e})") from None
    if not isinstance(doc, dict):
        raise CaptureError(f"{doc_path}: expected a JSON object / TOML table at the top level, "
                           f"found {type(doc).__name__}")
    return doc


def _check_keys(where, doc):
    unknown = sorted(set(doc) - set(CAPTURE_KEYS))
    if unknown:
        raise CaptureError(f"{where}: unknown key{'s' if len(unknown) > 1 else ''} "
                           f"{', '.join(repr(k) for k in unknown)}; known keys are {', '.join(CAPTURE_KEYS)}")


def _is_real(v):
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _entry(key, i):
    """How an entry is named in messages: ``lights[3]``, or ``camera`` for the one shared camera."""
    return key if key == "camera" else f"{key}[{i}]"


def _vector(where, key, i, v):
    """A list of 3 finite numbers as a float64 array."""
    if not (isinstance(v, (list, tuple)) and len(v) == 3 and all(_is_real(x) for x in v)):
        raise CaptureError(f"{where}: {_entry(key, i)}: expected 3 finite numbers [x, y, z], found {v!r}")
    return np.asarray(v, dtype=np.float64)


def _vectors(where, key, v, n, geometry):
    """N entries of ``key``: unit directions above the horizon, or points above the sample."""
    if not isinstance(v, (list, tuple)):
        raise CaptureError(f"{where}: {key}: expected a list of {n} [x, y, z] entries, found {type(v).__name__}")
    if len(v) != n:
        raise CaptureError(f"{where}: {n} images but {len(v)} {key}")
    out = np.stack([_vector(where, key, i, x) for i, x in enumerate(v)]) if n else np.zeros((0, 3))
    for i, x in enumerate(out):
        if geometry == "directions":
            if not np.linalg.norm(x) > 0:
                raise CaptureError(f"{where}: {_entry(key, i)}: expected a non-zero direction, found {v[i]!r}")
            if x[2] <= 0:
                raise CaptureError(f"{where}: {_entry(key, i)}: direction below the horizon "
                                   f"(expected z > 0, found z = {x[2]:g})")
        elif x[2] <= 0:
            raise CaptureError(f"{where}: {_entry(key, i)}: position must be above the sample plane "
                               f"(expected z > 0, found z = {x[2]:g})")
    if geometry == "directions":
        out = out / np.linalg.norm(out, axis=-1, keepdims=True)
    return out


def _per_image(where, doc, key, n):
    """A positive number or a list of N positive numbers (default 1) as a float64 (N,) array."""
    v = doc.get(key, 1.0)
    if _is_real(v):
        v = [v] * n
    elif not isinstance(v, (list, tuple)):
        raise CaptureError(f"{where}: {key}: expected a number or a list of {n} numbers, found {v!r}")
    if len(v) != n:
        raise CaptureError(f"{where}: {n} images but {len(v)} {key} values")
    for i, x in enumerate(v):
        if not (_is_real(x) and x > 0):
            raise CaptureError(f"{where}: {key}[{i}]: expected a finite number > 0, found {x!r}")
    return np.asarray(v, dtype=np.float64)


def _parse(where, doc):
    """Validate a parsed document; returns the geometry as arrays (no image is read)."""
    _check_keys(where, doc)
    if doc.get("format") != FORMAT_NAME:
        raise CaptureError(f"{where}: key 'format': expected {FORMAT_NAME!r}, found {doc.get('format')!r}")
    version = doc.get("version")
    if not (isinstance(version, int) and not isinstance(version, bool) and version == VERSION):
        raise CaptureError(f"{where}: key 'version': expected {VERSION}, found {version!r}")
    images = doc.get("images")
    if not (isinstance(images, list) and images and all(isinstance(s, str) and s for s in images)):
        raise CaptureError(f"{where}: key 'images': expected a non-empty list of file names, found {images!r}")
    n = len(images)
    geometry = doc.get("geometry", "directions")
    if geometry not in ("directions", "positions"):
        raise CaptureError(f"{where}: key 'geometry': expected 'directions' or 'positions', found {geometry!r}")
    # keys that belong to the other geometry are refused, not silently ignored
    other = ("intensity", "sample_size") if geometry == "directions" else ("irradiance",)
    for k in other:
        if k in doc:
            raise CaptureError(f"{where}: key {k!r} does not apply to geometry {geometry!r}")
    if "lights" not in doc:
        raise CaptureError(f"{where}: missing key 'lights' ({n} light {geometry})")
    lights = _vectors(where, "lights", doc["lights"], n, geometry)
    if ("cameras" in doc) == ("camera" in doc):
        found = "both" if "cameras" in doc else "neither"
        raise CaptureError(f"{where}: expected exactly one of 'cameras' ({n} entries) or 'camera' (one shared), "
                           f"found {found}")
    if "camera" in doc:
        cameras = np.repeat(_vectors(where, "camera", [doc["camera"]], 1, geometry), n, axis=0)
    else:
        cameras = _vectors(where, "cameras", doc["cameras"], n, geometry)
    scale = _per_image(where, doc, "scale", n)
    power = _per_image(where, doc, "irradiance" if geometry == "directions" else "intensity", n)
    sample_size = None
    if geometry == "positions":
        if "sample_size" not in doc:
            raise CaptureError(f"{where}: missing key 'sample_size' ([width, height] of the sample), "
                               f"required by geometry 'positions'")
        s = doc["sample_size"]
        if not (isinstance(s, (list, tuple)) and len(s) == 2 and all(_is_real(x) and x > 0 for x in s)):
            raise CaptureError(f"{where}: key 'sample_size': expected [width, height], two finite numbers > 0, "
                               f"found {s!r}")
        sample_size = (float(s[0]), float(s[1]))
    color_space = doc.get("color_space")
    if color_space not in (None, "srgb", "linear"):
        raise CaptureError(f"{where}: key 'color_space': expected 'srgb' or 'linear', found {color_space!r}")
    flat = doc.get("flat_field")
    if flat is not None and not (isinstance(flat, str) and flat):
        raise CaptureError(f"{where}: key 'flat_field': expected an image file name, found {flat!r}")
    return dict(images=images, geometry=geometry, lights=lights, cameras=cameras, scale=scale, power=power,
                sample_size=sample_size, color_space=color_space, flat_field=flat)


# --- the pixels ---------------------------------------------------------------------------------


@functools.lru_cache(maxsize=4)
def _srgb_table(max_code):
    """Linear value of every code 0..max_code under the sRGB EOTF (colour-science), float32."""
    import colour

    return np.asarray(colour.models.eotf_sRGB(np.arange(max_code + 1, dtype=np.float64) / max_code),
                      dtype=np.float32)


def _linear(pixels, info, color_space):
    """Linear float32 pixels from PNG codes or EXR floats."""
    if info["format"] == "png":
        if color_space == "srgb":
            return _srgb_table(info["max_code"])[pixels]
        return pixels.astype(np.float32) / np.float32(info["max_code"])
    if color_space == "srgb":
        import colour

        return np.asarray(colour.models.eotf_sRGB(pixels), dtype=np.float32)
    return pixels


def _read(where, path, name):
    if not path.is_file():
        raise CaptureError(f"{where}: image {name!r} not found ({path})")
    try:
        pixels, info = read_image_codes(path)
    except DataFormatError as e:
        raise CaptureError(f"{where}: {e}") from None
    if info["format"] == "exr":
        bad = ~np.isfinite(pixels)
        if bad.any():
            raise CaptureError(f"{where}: {path}: {int(bad.sum())} non-finite pixel values (NaN or inf); "
                               f"expected finite values")
        neg = pixels < 0
        if neg.any():
            raise CaptureError(f"{where}: {path}: {int(neg.sum())} negative pixel values (min {pixels.min():g}); "
                               f"expected values >= 0")
    return pixels, info


def _texel_points(shape, sample_size, rows=slice(None)):
    """Points (H, W, 3) of the texel centres on the sample, centred at the origin in z = 0
    (``rows``: a slice, those rows only, the same numbers)."""
    h, w = shape
    width, height = sample_size
    x = (np.arange(w) + 0.5) / w * width - width / 2
    y = (height / 2 - (np.arange(h) + 0.5) / h * height)[rows]
    p = np.zeros((len(y), w, 3))
    p[..., 0] = x[None, :]
    p[..., 1] = y[:, None]
    return p


def _check_like_first(where, f, shape, info, f0, shape0, info0):
    """Image ``f`` has the size, channels, format and bit depth of the first image ``f0``."""
    if shape != shape0:
        raise CaptureError(f"{where}: {f}: shape {shape} (H, W, C) differs from {f0}: {shape0}")
    if (info["format"], info["bit_depth"]) != (info0["format"], info0["bit_depth"]):
        raise CaptureError(f"{where}: {f}: {info['bit_depth']}-bit {info['format'].upper()} differs from "
                           f"{f0}: {info0['bit_depth']}-bit {info0['format'].upper()}; expected all images "
                           f"of one format and bit depth")


def _check_flat(where, flat_path, shape, image_shape):
    h, w, c = image_shape
    if shape[:2] != (h, w) or shape[2] not in (1, c):
        raise CaptureError(f"{where}: flat field {flat_path}: shape {shape} does not match the "
                           f"images' {image_shape}; expected {(h, w, 1)} or {(h, w, c)}")


def _measure(g, j, pixels, info, color_space, flat, points):
    """Image ``j``'s measurements over a band of rows (or the whole image).

    ``pixels`` (R, W, C) codes or floats of those rows, ``flat`` (R, W, 1 or C) linear or None,
    ``points`` (R, W, 3) texel centres (``"positions"``) or None. Returns ``values`` (R, W, C)
    float32, ``valid`` (R, W) and, in positions mode, ``wo``, ``wi`` (R, W, 3) (else None).
    Every number depends on its texel alone, so bands give the numbers of the whole image.
    """
    rows, w = pixels.shape[:2]
    ok = np.ones((rows, w), bool)
    if info["format"] == "png":
        ok &= ~np.any(pixels == info["max_code"], axis=-1)  # saturated in some channel
    linear = _linear(pixels, info, color_space)

    wo = wi = None
    if g["geometry"] == "positions":
        to_light = g["lights"][j] - points
        dist = np.linalg.norm(to_light, axis=-1)
        wi = to_light / dist[..., None]
        to_cam = g["cameras"][j] - points
        wo = to_cam / np.linalg.norm(to_cam, axis=-1, keepdims=True)
        cos_i, cos_o = wi[..., 2], wo[..., 2]
        irradiance = g["power"][j] / dist ** 2
    else:
        cos_i = np.full((rows, w), g["lights"][j, 2])
        cos_o = np.full((rows, w), g["cameras"][j, 2])
        irradiance = np.full((rows, w), g["power"][j])
    ok &= (cos_i > COS_MIN) & (cos_o > COS_MIN)
    denom = (g["scale"][j] * np.maximum(cos_i, 0.0) * irradiance)[..., None].astype(np.float32)
    if flat is not None:
        ok &= np.all(flat > 0, axis=-1)
        denom = denom * flat
    usable = denom > 0
    values = np.where(usable, linear / np.where(usable, denom, 1.0), 0.0)
    return values, ok, wo, wi


def load_capture(path, out=None) -> Capture:
    """Load a capture folder as BRDF measurements per texel (the module docstring's format and radiometry).

    Parameters
    ----------
    path : str or Path
        The capture folder (holding ``capture.json`` or ``capture.toml``) or the document itself.
    out : str or Path, optional
        A folder (created if missing) to write the measurements to instead of holding them in
        memory (module docstring, "Large captures").

    Returns
    -------
    Capture
        ``values`` (H, W, N, C) float32 and ``valid`` (H, W, N), ``wo``/``wi`` (N, 3)
        (``"directions"``) or (H, W, N, 3) (``"positions"``); with ``out``, memory maps of its
        files (``wo``/``wi`` of shape (N, 3) stay in memory).

    Raises
    ------
    CaptureError
        A malformed document or image; the message names the file.
    OSError
        ``out`` cannot be created or written (a file in the way, a full disk).

    Examples
    --------
    >>> import os, tempfile, numpy as np
    >>> from matfit.maps import load_capture, write_capture_document, write_exr
    >>> tmp = tempfile.TemporaryDirectory(); folder = tmp.name
    >>> write_exr(f"{folder}/a.exr", np.full((2, 3, 3), 0.5))
    >>> _ = write_capture_document(folder, {"images": ["a.exr"], "lights": [[0, 0, 2]], "camera": [0, 0, 1],
    ...                                     "irradiance": 2.0})
    >>> on_disk = load_capture(folder, out=f"{folder}/measured")    # pixel / (cos(theta_i) E)
    >>> type(on_disk.values).__name__, sorted(os.listdir(f"{folder}/measured")), float(on_disk.values[0, 0, 0, 0])
    ('memmap', ['valid.npy', 'values.npy'], 0.25)
    >>> del on_disk; tmp.cleanup()
    """
    doc_path = _find_document(path)
    where = str(doc_path)
    doc = _parse_document(doc_path)
    g = _parse(where, doc)
    folder = doc_path.parent
    files = tuple(folder / name for name in g["images"])
    n = len(files)

    if out is not None:
        return _load_to_folder(where, doc, g, folder, files, Path(out))

    # the first image fixes the size, channels, format and bit depth of all
    first, info0 = _read(where, files[0], g["images"][0])
    h, w, c = first.shape
    color_space = g["color_space"] or ("srgb" if info0["format"] == "png" else "linear")

    flat = None
    if g["flat_field"] is not None:
        flat_path = folder / g["flat_field"]
        flat_pixels, flat_info = _read(where, flat_path, g["flat_field"])
        _check_flat(where, flat_path, flat_pixels.shape, first.shape)
        flat = _linear(flat_pixels, flat_info, "linear")

    points = None
    if g["geometry"] == "positions":
        points = _texel_points((h, w), g["sample_size"])
        wo_all = np.empty((h, w, n, 3), np.float32)
        wi_all = np.empty((h, w, n, 3), np.float32)
    else:
        wo_all = g["cameras"].astype(np.float32)
        wi_all = g["lights"].astype(np.float32)
    values = np.empty((h, w, n, c), np.float32)
    valid = np.empty((h, w, n), bool)

    for j, (f, name) in enumerate(zip(files, g["images"])):
        pixels, info = (first, info0) if j == 0 else _read(where, f, name)
        _check_like_first(where, f, pixels.shape, info, files[0], first.shape, info0)
        values[:, :, j], valid[:, :, j], wo, wi = _measure(g, j, pixels, info, color_space, flat, points)
        if points is not None:
            wo_all[:, :, j], wi_all[:, :, j] = wo, wi
    return Capture(wo=wo_all, wi=wi_all, values=values, valid=valid, files=files, meta=doc)


# --- loading to files ---------------------------------------------------------------------------

# Target size in bytes of one band of rows that ``load_capture(path, out=...)`` assembles in
# memory (values, valid and directions of every image) before writing it; at least one row.
_BAND_BYTES = 32 << 20


class _NpyFile:
    """A C-order ``.npy`` file written a band of rows at a time with ``os.pwrite``, never through a
    memory mapping (pages written through a mapping count in the process's resident memory).
    It is written as ``NAME.partial`` and renamed to ``NAME`` by :meth:`commit`."""

    def __init__(self, path, dtype, shape):
        self.path = path
        self.partial = path.with_name(path.name + ".partial")
        dtype = np.dtype(dtype)
        self.shape = tuple(shape)
        self.row_bytes = math.prod(self.shape[1:]) * dtype.itemsize
        self.file = open(self.partial, "w+b")
        np.lib.format.write_array_header_1_0(self.file, {"descr": np.lib.format.dtype_to_descr(dtype),
                                                         "fortran_order": False, "shape": self.shape})
        self.file.flush()
        self.offset = self.file.tell()
        self.file.truncate(self.offset + self.shape[0] * self.row_bytes)  # sparse until written

    def write_rows(self, row, band) -> None:
        """Write ``band`` (rows ``row ...`` of the array: one contiguous range of the file)."""
        assert band.shape[1:] == self.shape[1:] and band.flags.c_contiguous
        buf = memoryview(band).cast("B")
        pos = self.offset + row * self.row_bytes
        while len(buf):
            done = os.pwrite(self.file.fileno(), buf, pos)
            buf, pos = buf[done:], pos + done

    def commit(self) -> None:
        """Close the file and rename it to its final name."""
        self.file.close()
        os.replace(self.partial, self.path)

    def discard(self) -> None:
        """Close the file and delete it."""
        self.file.close()
        self.partial.unlink(missing_ok=True)


def _open_rows(where, path, name):
    if not path.is_file():
        raise CaptureError(f"{where}: image {name!r} not found ({path})")
    try:
        return open_image_rows(path)
    except DataFormatError as e:
        raise CaptureError(f"{where}: {e}") from None


def _read_rows(where, src, name, n):
    """The next ``n`` rows of an image, checked as :func:`_read` checks whole images."""
    try:
        pixels = src.read(n)
    except DataFormatError as e:
        raise CaptureError(f"{where}: {e}") from None
    if src.info["format"] == "exr" and not (np.isfinite(pixels).all() and (pixels >= 0).all()):
        _read(where, src.path, name)  # the whole image, for the message of the in-memory load
        raise CaptureError(f"{where}: {src.path}: non-finite or negative pixel values in rows {src.position - n} "
                           f"to {src.position - 1}, not found on reading it whole (did the file change?)")
    return pixels


def _finish(where, src):
    try:
        src.finish()
    except DataFormatError as e:
        raise CaptureError(f"{where}: {e}") from None


def _load_to_folder(where, doc, g, folder, files, out):
    """``load_capture(path, out=out)``: the measurements written band by band into ``out``."""
    names, n = g["images"], len(files)
    positions = g["geometry"] == "positions"
    opened, written = [], {}
    try:
        # every header first: no big file is started for a capture that is malformed up front
        first = _open_rows(where, files[0], names[0])
        opened.append(first)
        h, w, c = first.shape
        color_space = g["color_space"] or ("srgb" if first.info["format"] == "png" else "linear")
        flat = None
        if g["flat_field"] is not None:
            flat_path = folder / g["flat_field"]
            flat = _open_rows(where, flat_path, g["flat_field"])
            opened.append(flat)
            _check_flat(where, flat_path, flat.shape, first.shape)
        images = [first]
        for f, name in zip(files[1:], names[1:]):
            src = _open_rows(where, f, name)
            opened.append(src)
            _check_like_first(where, f, src.shape, src.info, files[0], first.shape, first.info)
            images.append(src)

        out.mkdir(parents=True, exist_ok=True)
        arrays = {"valid": (bool, (h, w, n))}
        if positions:
            arrays.update(wo=(np.float32, (h, w, n, 3)), wi=(np.float32, (h, w, n, 3)))
        arrays["values"] = (np.float32, (h, w, n, c))
        for key, (dtype, shape) in arrays.items():
            written[key] = _NpyFile(out / f"{key}.npy", dtype, shape)

        row_bytes = w * n * (4 * c + 1 + (24 if positions else 0))
        band = max(1, min(h, _BAND_BYTES // row_bytes))
        for y in range(0, h, band):
            r = min(band, h - y)
            flat_band = None if flat is None else _linear(_read_rows(where, flat, g["flat_field"], r), flat.info,
                                                          "linear")
            points = _texel_points((h, w), g["sample_size"], slice(y, y + r)) if positions else None
            values = np.empty((r, w, n, c), np.float32)
            valid = np.empty((r, w, n), bool)
            if positions:
                wo_band = np.empty((r, w, n, 3), np.float32)
                wi_band = np.empty((r, w, n, 3), np.float32)
            for j, (src, name) in enumerate(zip(images, names)):
                pixels = _read_rows(where, src, name, r)
                values[:, :, j], valid[:, :, j], wo, wi = _measure(g, j, pixels, src.info, color_space, flat_band,
                                                                   points)
                if positions:
                    wo_band[:, :, j], wi_band[:, :, j] = wo, wi
            written["values"].write_rows(y, values)
            written["valid"].write_rows(y, valid)
            if positions:
                written["wo"].write_rows(y, wo_band)
                written["wi"].write_rows(y, wi_band)
        for src in opened:  # the data must end after the last row, as when read whole
            _finish(where, src)
        for key in list(written):  # values.npy last: its presence means the load completed
            written[key].commit()
            del written[key]
    except BaseException:
        for f in written.values():
            f.discard()
        raise
    finally:
        for src in opened:
            src.close()

    def mapped(key):
        return np.load(out / f"{key}.npy", mmap_mode="r")

    if positions:
        wo_all, wi_all = mapped("wo"), mapped("wi")
    else:
        wo_all, wi_all = g["cameras"].astype(np.float32), g["lights"].astype(np.float32)
    return Capture(wo=wo_all, wi=wi_all, values=mapped("values"), valid=mapped("valid"), files=files, meta=doc)


def _plain(v):
    """JSON-serializable copy of ``v`` (numpy arrays and scalars become lists and numbers)."""
    if isinstance(v, dict):
        return {str(k): _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if isinstance(v, np.ndarray):
        return _plain(v.tolist())
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, os.PathLike):
        return os.fspath(v)
    return v


def write_capture_document(folder, doc):
    """Write ``doc`` as ``capture.json`` in ``folder`` (created if missing); returns its Path.

    ``"format"`` and ``"version"`` are filled in when absent; numpy arrays become lists. Unknown
    keys raise :class:`CaptureError`, as :func:`load_capture` would.

    Parameters
    ----------
    folder : str or Path
    doc : dict
        The capture document (the module docstring).

    Returns
    -------
    Path
    """
    folder = Path(folder)
    out = {"format": FORMAT_NAME, "version": VERSION}
    out.update(_plain(dict(doc)))
    path = folder / DOCUMENT_NAMES[0]
    _check_keys(str(path), out)
    folder.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")
    return path
