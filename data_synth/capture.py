"""Synthetic captures: images of a flat sample with per-texel parameter maps, in the format read by
:func:`matfit.maps._capture.load_capture`.

:func:`capture_directions` designs a fixed set of light / camera directions that samples the
specular peak of GGX lobes from narrow (alpha 0.05) to broad (alpha 0.6): a few cameras, and for
each a sweep of lights whose half vector makes increasing angles with the normal, plus a few
lights far from the mirror direction for the diffuse part. :func:`render_capture` renders a
model family of :mod:`matfit.fitting.families` with parameter maps into such a capture folder.

Radiometry (the loader's convention): a linear pixel is
``scale_j * flat(x) * f(wo, wi) * cos(theta_i) * E_j``. The renderer uses ``E_j = 1``
(directions) or ``E = I / d^2`` with ``I = D^2`` for lights at distance ``D`` (positions), so the
irradiance at the sample's centre is about 1.
"""
from __future__ import annotations

import functools
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from matfit.errors import ParameterError
from matfit.fitting.families import get_family
from matfit.maps import write_capture_document
from matfit.maps import write_exr, write_png

from .geometry import sph

__all__ = ["capture_directions", "render_capture", "ramp_maps", "THETA_H", "FORMATS"]

#: Half-vector zeniths (degrees) swept for every camera: dense near the normal for narrow lobes,
#: sparse further out for broad ones.
THETA_H = (0.0, 1.5, 3.0, 5.0, 8.0, 12.0, 18.0, 25.0, 35.0, 50.0)

#: Smallest cos(theta) of a designed direction (the brief asks for > 0.15; a margin is kept).
DESIGN_COS_MIN = 0.17

#: Image formats of :func:`render_capture`: (extension, bit depth or None, colour space).
FORMATS = {"png16": (".png", 16, "srgb"), "png8": (".png", 8, "srgb"), "exr": (".exr", None, "linear")}

#: Texels evaluated per call of the vmapped model (bounds the memory of the evaluation).
CHUNK = 1 << 16

#: Brightest pixel of every rendered image after the exposure scale (below 1: nothing saturates).
PEAK = 0.9

#: Light and camera distance in "positions" geometry, in units of the sample's larger side.
DISTANCE = 10.0

#: Flat-field value at the image corners when ``vignetting=True`` (1 at the centre).
CORNER_FLAT = 0.7


def _reflect(wo, h):
    return 2.0 * np.dot(wo, h) * h - wo


def _specular_light(wo, phi_o, theta_h, phi_rel):
    """The light ``wi`` whose half vector with ``wo`` has zenith ``theta_h`` and azimuth
    ``phi_o + phi_rel``; where that leaves ``wi`` too low, the azimuth is turned towards the camera's
    (which keeps ``wi`` highest), then the zenith lowered. Returns ``wi``."""
    for th in np.arange(theta_h, -1e-9, -0.5):
        for s in np.linspace(1.0, 0.0, 21):
            wi = _reflect(wo, sph(th, phi_o + s * phi_rel))
            if wi[2] >= DESIGN_COS_MIN:
                return wi / np.linalg.norm(wi)
    raise AssertionError("the mirror direction of a camera above the horizon is above the horizon")


def capture_directions(n=24, seed=0):
    """Light and camera directions for a capture of ``n`` images.

    Cameras: 1 to 3 directions at zeniths 10 to 40 degrees (2 for ``n = 24``). For each camera, a
    block of lights whose half vectors have zeniths :data:`THETA_H` (interpolated to the block's
    size) at azimuths that advance by the golden angle; about ``n / 6`` lights on the camera's
    side, far from the mirror direction, for the diffuse part. Every direction has cos > 0.15.

    Parameters
    ----------
    n : int, >= 4
        Number of images (light / camera pairs).
    seed : int
        Seeds the azimuths.

    Returns
    -------
    lights, cameras : ndarray, (n, 3)
        Unit vectors from the sample to the light and to the camera.

    Examples
    --------
    >>> from data_synth.capture import capture_directions
    >>> lights, cameras = capture_directions(24)
    >>> lights.shape, cameras.shape, bool(min(lights[:, 2].min(), cameras[:, 2].min()) > 0.15)
    ((24, 3), (24, 3), True)
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 4:
        raise ParameterError(f"capture_directions: n must be an integer >= 4, got {n!r}")
    rng = np.random.default_rng(seed)
    n_diffuse = max(1, int(round(n / 6)))
    m = n - n_diffuse
    n_cam = 1 if m < 12 else (2 if m < 30 else 3)
    cam_theta = {1: (25.0,), 2: (20.0, 40.0), 3: (10.0, 25.0, 40.0)}[n_cam]
    cam_phi = rng.uniform(0.0, 360.0) + 360.0 * np.arange(n_cam) / n_cam
    lights, cameras = [], []
    for c, block in enumerate(np.array_split(np.arange(m), n_cam)):
        wo = sph(cam_theta[c], cam_phi[c])
        targets = np.interp(np.linspace(0, len(THETA_H) - 1, len(block)), np.arange(len(THETA_H)), THETA_H)
        phi0 = rng.uniform(-180.0, 180.0)
        for k, th in enumerate(targets):
            # azimuth of the half vector relative to the camera's, in (-180, 180]
            phi_rel = (phi0 + 137.50776 * k + 180.0) % 360.0 - 180.0
            lights.append(_specular_light(wo, cam_phi[c], th, phi_rel))
            cameras.append(wo)
    # diffuse lights: on the side of the most oblique camera, so that their half vectors are far
    # (about 40 to 60 degrees) from the normal
    wo = sph(cam_theta[-1], cam_phi[-1])
    for k, ti in enumerate(np.linspace(45.0, 75.0, n_diffuse)):
        dphi = (15.0 + 30.0 * rng.uniform()) * (1 if k % 2 == 0 else -1)
        lights.append(sph(ti, cam_phi[-1] + dphi))
        cameras.append(wo)
    return np.asarray(lights, np.float64), np.asarray(cameras, np.float64)


@functools.partial(jax.jit, static_argnames=("model", "channels"))
def _eval_texels(theta, wo, wi, model, channels):
    """f for a chunk of texels: ``theta`` maps names to (T,) or (T, C); ``wo``/``wi`` are (N, 3)
    shared or (T, N, 3) per texel. Returns (T, N, C_model)."""
    fam = get_family(model)

    def one(p, a, b):
        return fam.build(p, channels).eval(a, b)

    axis = 0 if wo.ndim == 3 else None
    return jax.vmap(one, in_axes=(0, axis, axis))(theta, wo, wi)


def _check_params(fam, params, channels):
    """Parameter maps as float32 arrays (H, W) or (H, W, C), checked against the family's bounds."""
    if not isinstance(params, dict):
        raise ParameterError(f"render_capture: params must be a dict of parameter maps, got {type(params).__name__}")
    names = [p.name for p in fam.params]
    missing = [n for n in names if n not in params]
    extra = sorted(set(params) - set(names))
    if missing or extra:
        raise ParameterError(f"render_capture: family {fam.name!r} takes parameters {names}; "
                             f"missing {missing}, unknown {extra}")
    out, shape = {}, None
    for p in fam.params:
        a = np.asarray(params[p.name], dtype=np.float64)
        hw = a.shape[:2]
        if a.ndim == 3 and a.shape[2] in (1, channels if p.per_channel else 1):
            a = np.broadcast_to(a, hw + ((channels,) if p.per_channel else (1,)))
            a = a if p.per_channel else a[..., 0]
        elif a.ndim == 2:
            a = np.broadcast_to(a[..., None], hw + (channels,)) if p.per_channel else a
        else:
            want = "(H, W) or (H, W, C)" if p.per_channel else "(H, W)"
            raise ParameterError(f"render_capture: params[{p.name!r}] must have shape {want}, found {a.shape}")
        if shape is None:
            shape = hw
        if hw != shape or min(hw) < 1:
            raise ParameterError(f"render_capture: params[{p.name!r}] has size {hw}, expected {shape} "
                                 f"like params[{names[0]!r}] (and at least 1 x 1)")
        if not np.all(np.isfinite(a)) or a.min() < p.lower or a.max() > p.upper:
            raise ParameterError(f"render_capture: params[{p.name!r}] must be finite and in "
                                 f"[{p.lower}, {p.upper}], found [{a.min()}, {a.max()}]")
        out[p.name] = np.ascontiguousarray(a, dtype=np.float32)
    return out, shape


def _unit_dirs(what, v, n=None):
    a = np.asarray(v, dtype=np.float64)
    if a.ndim == 1:
        a = a[None]
    if a.ndim != 2 or a.shape[1] != 3 or (n is not None and len(a) not in (1, n)) or not np.all(np.isfinite(a)):
        want = "(N, 3)" if n is None else f"(3,) or ({n}, 3)"
        raise ParameterError(f"render_capture: {what} must be finite directions of shape {want}, found {np.shape(v)}")
    norm = np.linalg.norm(a, axis=-1, keepdims=True)
    if np.any(norm == 0) or np.any(a[:, 2] <= 0):
        raise ParameterError(f"render_capture: {what} must be non-zero directions above the horizon (z > 0)")
    a = a / norm
    return a if n is None else np.broadcast_to(a, (n, 3)).copy()


def ramp_maps(height, width, rows=None):
    """Smooth ``diffuse_specular`` parameter maps of a test capture: alpha 0.05 to 0.6 across the
    columns, albedo 0.15-0.75 / 0.4-0.6 / 0.2-0.5 and F0 0.3-0.8 / 0.4-0.6 / 0.25-0.55 per channel
    in ramps along the rows and columns.

    Parameters
    ----------
    height, width : int
        Size of the whole map.
    rows : (start, stop), optional
        Only these rows (a band of a map too large to hold whole).

    Returns
    -------
    dict
        ``{"alpha": (h, W), "albedo": (h, W, 3), "f0": (h, W, 3)}``.

    Examples
    --------
    >>> from data_synth.capture import ramp_maps
    >>> m = ramp_maps(4, 8)
    >>> m["alpha"].shape, m["f0"].shape, round(float(m["alpha"].min()), 4)
    ((4, 8), (4, 8, 3), 0.0844)
    """
    r0, r1 = (0, height) if rows is None else rows
    yy, xx = np.mgrid[r0:r1, 0:width]
    u, v = (xx + 0.5) / width, (yy + 0.5) / height
    return {"alpha": 0.05 + 0.55 * u,
            "albedo": np.stack([0.15 + 0.6 * v, 0.4 + 0.2 * u, 0.5 - 0.3 * v], -1),
            "f0": np.stack([0.3 + 0.5 * v, 0.6 - 0.2 * u, 0.25 + 0.3 * u * v], -1)}


def flat_field(shape):
    """Vignetting (H, W): cos^4 of an off-axis angle that grows with the distance from the image
    centre, 1 at the centre and :data:`CORNER_FLAT` at the image corners."""
    h, w = shape
    y = (np.arange(h) + 0.5) - h / 2
    x = (np.arange(w) + 0.5) - w / 2
    r = np.hypot(x[None, :], y[:, None]) / np.hypot(w / 2, h / 2)
    tan_corner = np.sqrt(CORNER_FLAT ** -0.5 - 1.0)  # cos^4 = CORNER_FLAT at r = 1
    return (1.0 + (r * tan_corner) ** 2) ** -2.0


def render_capture(folder, params, model="conductor", lights=None, cameras=None, noise=0.01, vignetting=False,
                   fmt="png16", seed=0, geometry="directions", sample_size=None):
    """Render parameter maps of a model family into a capture folder.

    Parameters
    ----------
    folder : str or Path
        Created if missing; receives ``img_000.png`` ... (or ``.exr``), ``flat.png`` when
        ``vignetting`` and ``capture.json``.
    params : dict
        Parameter maps of the family ``model``: name -> (H, W), or (H, W, 3) for per-channel
        parameters ((H, W) ones are shared by the channels).
    model : str
        A family of :func:`matfit.fitting.families.get_family` (e.g. ``"conductor"``, ``"plastic"``).
    lights, cameras : array_like, optional
        Unit directions (N, 3) to the light and camera; cameras may be one (3,) direction. Both
        default to :func:`capture_directions` (24 images); lights without cameras use the normal.
    noise : float
        Relative Gaussian noise: each linear pixel is multiplied by ``1 + noise * N(0, 1)``.
    vignetting : bool
        Multiply by :func:`flat_field`, written as ``flat.png`` (16-bit, linear) and recorded in
        the document as ``"flat_field"``.
    fmt : {"png16", "png8", "exr"}
        16- or 8-bit sRGB PNG, or linear float EXR.
    seed : int
        Seeds the noise.
    geometry : {"directions", "positions"}
        ``"positions"`` places the lights and cameras at :data:`DISTANCE` times the sample's larger
        side along the given directions, with intensity ``D^2``, and records ``sample_size``.
    sample_size : (width, height), optional
        Physical size of the sample for ``"positions"``; default ``(1, H / W)`` (square texels).

    Returns
    -------
    Path
        The capture folder. Each image is exposed (``scale``) so that its brightest pixel is 0.9.

    Examples
    --------
    >>> import tempfile, numpy as np
    >>> from data_synth.capture import render_capture
    >>> from matfit.maps import load_capture
    >>> maps = {"albedo": np.full((4, 4, 3), 0.5)}
    >>> folder = render_capture(tempfile.mkdtemp(), maps, model="lambert", noise=0.0)
    >>> cap = load_capture(folder)
    >>> cap.values.shape, bool(np.allclose(cap.values, 0.5 / np.pi, rtol=1e-3))
    ((4, 4, 24, 3), True)
    """
    if fmt not in FORMATS:
        raise ParameterError(f"render_capture: fmt must be one of {sorted(FORMATS)}, got {fmt!r}")
    if geometry not in ("directions", "positions"):
        raise ParameterError(f"render_capture: geometry must be 'directions' or 'positions', got {geometry!r}")
    if not (isinstance(noise, (int, float)) and np.isfinite(noise) and noise >= 0):
        raise ParameterError(f"render_capture: noise must be a finite number >= 0, got {noise!r}")
    channels = 3
    fam = get_family(model)
    theta, (h, w) = _check_params(fam, params, channels)

    if lights is None:
        if cameras is not None:
            raise ParameterError("render_capture: cameras were given without lights")
        lights, cameras = capture_directions(24)
    lights = _unit_dirs("lights", lights)
    n = len(lights)
    cameras = _unit_dirs("cameras", [0.0, 0.0, 1.0] if cameras is None else cameras, n)

    # directions per texel (positions) or shared (directions), and the irradiance E
    doc = {"geometry": geometry}
    if geometry == "positions":
        if sample_size is None:
            sample_size = (1.0, h / w)
        sample_size = tuple(float(s) for s in sample_size)
        if len(sample_size) != 2 or not all(np.isfinite(s) and s > 0 for s in sample_size):
            raise ParameterError(f"render_capture: sample_size must be (width, height) > 0, got {sample_size!r}")
        dist = DISTANCE * max(sample_size)
        light_pos, cam_pos, intensity = lights * dist, cameras * dist, dist ** 2
        x = (np.arange(w) + 0.5) / w * sample_size[0] - sample_size[0] / 2
        y = sample_size[1] / 2 - (np.arange(h) + 0.5) / h * sample_size[1]
        pts = np.stack(np.broadcast_arrays(x[None, :], y[:, None], 0.0), -1).reshape(-1, 1, 3)
        to_l, to_c = light_pos[None] - pts, cam_pos[None] - pts              # (T, N, 3)
        d2 = np.sum(to_l ** 2, -1)
        wi = (to_l / np.sqrt(d2)[..., None]).astype(np.float32)
        wo = (to_c / np.linalg.norm(to_c, axis=-1, keepdims=True)).astype(np.float32)
        irradiance = intensity / d2                                           # (T, N)
        cos_i = wi[..., 2].astype(np.float64)
        doc.update(lights=light_pos, cameras=cam_pos, intensity=intensity, sample_size=list(sample_size))
    else:
        wi, wo = lights.astype(np.float32), cameras.astype(np.float32)
        irradiance = np.ones((1, n))
        cos_i = lights[None, :, 2]
        doc.update(lights=lights, cameras=cameras, irradiance=1.0)

    # f for all texels, in chunks of CHUNK (the last one padded: one compilation per chunk size)
    t = h * w
    flat_theta = {k: v.reshape((t,) + v.shape[2:]) for k, v in theta.items()}
    size = min(t, CHUNK)
    f = np.empty((t, n, channels), np.float32)
    for s in range(0, t, size):
        e = min(s + size, t)
        idx = np.minimum(np.arange(s, s + size), e - 1)  # padding repeats the chunk's last texel
        th = {k: jnp.asarray(v[idx]) for k, v in flat_theta.items()}
        a, b = (wo[idx], wi[idx]) if wo.ndim == 3 else (wo, wi)
        out = np.asarray(_eval_texels(th, jnp.asarray(a), jnp.asarray(b), model=fam.name, channels=channels))
        f[s:e] = np.broadcast_to(out[: e - s], (e - s, n, channels))
    linear = f.astype(np.float64) * (np.maximum(cos_i, 0.0) * irradiance)[..., None]
    linear = linear.reshape(h, w, n, channels)

    rng = np.random.default_rng(seed)
    if noise > 0:
        linear = np.maximum(linear * (1.0 + noise * rng.standard_normal(linear.shape)), 0.0)

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    if vignetting:
        # the loader reads flat.png's codes: render with the same quantized values
        flat = np.rint(flat_field((h, w)) * 65535.0) / 65535.0
        write_png(folder / "flat.png", flat, bit_depth=16)
        linear = linear * flat[:, :, None, None]
        doc["flat_field"] = "flat.png"

    peak = linear.max(axis=(0, 1, 3))
    scale = np.where(peak > 0, PEAK / np.where(peak > 0, peak, 1.0), 1.0)
    ext, depth, color_space = FORMATS[fmt]
    names = [f"img_{j:03d}{ext}" for j in range(n)]
    if color_space == "srgb":
        import colour
    for j, name in enumerate(names):
        img = linear[:, :, j] * scale[j]
        if fmt == "exr":
            write_exr(folder / name, img)
        else:
            write_png(folder / name, colour.models.eotf_inverse_sRGB(img), bit_depth=depth)
    doc.update(images=names, scale=scale, color_space=color_space,
               notes={"generator": "data_synth.capture.render_capture", "model": fam.name, "noise": float(noise),
                      "vignetting": bool(vignetting), "fmt": fmt, "seed": int(seed)})
    write_capture_document(folder, doc)
    return folder
