"""Environments for previews: a uniform furnace, a procedural sky, or an equirectangular map, with
importance sampling of the map by its luminance (piecewise-constant 2D distribution).

World frame: the camera looks along -z from +z, image right is +x, image up (and the sky's zenith)
is +y. An equirectangular map of shape (H, W, 3) has row ``i`` at polar angle
``theta = (i + 0.5) pi / H`` from +y and column ``j`` at ``phi = (j + 0.5) 2 pi / W`` measured from +x
towards +z: ``d = (sin theta cos phi, cos theta, sin theta sin phi)``."""

from __future__ import annotations

from pathlib import Path

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..errors import DataFormatError, ParameterError

#: Resolution (H, W) of the rasterized procedural sky.
SKY_SHAPE = (128, 256)
#: Direction of the sky's sun (unit, world frame) and its angular radius in radians.
SUN_DIRECTION = np.array([0.45, 0.75, 0.48]) / np.linalg.norm([0.45, 0.75, 0.48])
SUN_RADIUS = 0.06
#: Linear radiance of the sky's sun.
SUN_RADIANCE = np.array([60.0, 55.0, 45.0])


def _dirs(H, W):
    th = (np.arange(H) + 0.5) * np.pi / H
    ph = (np.arange(W) + 0.5) * 2 * np.pi / W
    T, P = np.meshgrid(th, ph, indexing="ij")
    return np.stack([np.sin(T) * np.cos(P), np.cos(T), np.sin(T) * np.sin(P)], -1)


def sky_map(shape=SKY_SHAPE, sun=True):
    """The built-in procedural sky as an (H, W, 3) float32 equirectangular map of linear radiance: a
    blue zenith fading to a pale horizon, a dim brown ground, and a small sun far brighter than the sky.

    Parameters
    ----------
    shape : tuple of int, default SKY_SHAPE
        ``(H, W)`` of the map.
    sun : bool, default True
        Rasterize the sun (:data:`SUN_DIRECTION`, :data:`SUN_RADIUS`); False: sky and ground alone,
        for renderers that treat the sun as a light of its own.

    Returns
    -------
    numpy.ndarray, (H, W, 3) float32
    """
    d = _dirs(*shape)
    up = d[..., 1]
    t = np.clip(up, 0, 1)[..., None]
    sky = (1 - t) * np.array([1.0, 0.97, 0.92]) + t * np.array([0.25, 0.45, 0.95])
    ground = np.array([0.18, 0.14, 0.1]) * (0.6 + 0.4 * np.clip(-up, 0, 1))[..., None]
    env = np.where(up[..., None] >= 0, sky, ground)
    if sun:
        env = env + (np.arccos(np.clip(d @ SUN_DIRECTION, -1, 1)) < SUN_RADIUS)[..., None] * SUN_RADIANCE
    return env.astype(np.float32)


def load_environment(environment):
    """``None`` for the furnace, else an (H, W, 3) float32 map.

    Parameters
    ----------
    environment : "furnace", "sky", array_like or str or Path
        The uniform furnace, the built-in sky (:func:`sky_map`), an (H, W, 3) or (H, W, 4)
        equirectangular map (alpha dropped), or a file holding one (``.npy``, or ``.hdr``/``.exr``
        through ``imageio``).

    Returns
    -------
    numpy.ndarray, (H, W, 3) float32, or None

    Raises
    ------
    ParameterError
        A missing file, an unsupported extension, or ``imageio`` missing for .hdr / .exr.
    DataFormatError
        A map that is not (H, W, 3) with H, W >= 2, not numeric, or with non-finite or
        negative values.
    """
    if isinstance(environment, str) and environment == "furnace":
        return None
    if isinstance(environment, str) and environment == "sky":
        return sky_map()
    if isinstance(environment, (str, Path)):
        p = Path(environment)
        if not p.exists():
            raise ParameterError(f"environment: {p}: no such file (or use 'furnace', 'sky' or an (H, W, 3) array)")
        if p.suffix.lower() == ".npy":
            a = np.load(p, allow_pickle=False)
        elif p.suffix.lower() in (".hdr", ".exr"):
            try:
                import imageio.v3 as iio
            except ImportError:
                raise ParameterError(f"environment: reading {p.suffix} files needs imageio (pip install imageio)") from None
            a = iio.imread(p)
        else:
            raise ParameterError(f"environment: {p}: expected a .npy, .hdr or .exr file, found {p.suffix!r}")
        return _check_map(a, str(p))
    return _check_map(environment, "environment")


def _check_map(a, where):
    a = np.asarray(a)
    if a.ndim != 3 or a.shape[-1] not in (3, 4) or a.shape[0] < 2 or a.shape[1] < 2:
        raise DataFormatError(f"{where}: expected an (H, W, 3) equirectangular map, found shape {a.shape}")
    if a.dtype.kind not in "fiu":
        raise DataFormatError(f"{where}: expected numbers, found dtype {a.dtype}")
    a = a[..., :3].astype(np.float32)
    if not np.all(np.isfinite(a)) or np.any(a < 0):
        raise DataFormatError(f"{where}: expected finite radiance values >= 0")
    return a


class Environment(eqx.Module):
    """An equirectangular map with its sampling tables (marginal over rows, conditional over columns).

    Build one with :meth:`Environment.of`. Directions are drawn with a density proportional to the
    pixels' luminance times their solid angle, plus a small floor so that every pixel can be drawn,
    uniformly in solid angle inside the pixel.

    Attributes
    ----------
    image : jax.Array, (H, W, 3) float32
        The map (world frame of the module docstring).
    row_cdf : jax.Array, (H + 1,)
        Cumulative probabilities of the rows.
    col_cdf : jax.Array, (H, W + 1)
        Cumulative probabilities of the columns within each row.
    pixel_p : jax.Array, (H, W)
        Probability of drawing each pixel.

    References
    ----------
    M. Pharr, W. Jakob, G. Humphreys, *Physically Based Rendering*, 4th ed., Sec. 12.5.

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> import numpy as np
    >>> from matfit.render import Environment
    >>> image = np.zeros((4, 8, 3), np.float32); image[1, 2] = 100.0    # one bright pixel
    >>> env = Environment.of(image)
    >>> d, pdf = env.sample(jnp.array([0.5]), jnp.array([0.5]))        # directions and their density
    >>> env.lookup(d).tolist(), bool(jnp.allclose(pdf, env.pdf(d)))
    ([[100.0, 100.0, 100.0]], True)
    """

    image: jnp.ndarray  # (H, W, 3)
    row_cdf: jnp.ndarray  # (H + 1,)
    col_cdf: jnp.ndarray  # (H, W + 1)
    pixel_p: jnp.ndarray  # (H, W) discrete probabilities

    @classmethod
    def of(cls, image):
        """The environment of an (H, W, 3) map of linear radiance, finite and >= 0, with its sampling tables."""
        img = np.asarray(image, np.float64)
        H, W = img.shape[:2]
        th = (np.arange(H) + 0.5) * np.pi / H
        lum = img @ np.array([0.2126, 0.7152, 0.0722])
        w = (lum + 1e-3 * max(lum.mean(), 1e-12)) * np.sin(th)[:, None]  # every pixel samplable
        p = w / w.sum()
        rows = p.sum(axis=1)
        row_cdf = np.concatenate([[0.0], np.cumsum(rows)])
        cond = p / np.maximum(rows[:, None], 1e-300)
        col_cdf = np.concatenate([np.zeros((H, 1)), np.cumsum(cond, axis=1)], axis=1)
        row_cdf[-1] = 1.0
        col_cdf[:, -1] = 1.0
        return cls(jnp.asarray(img, jnp.float32), jnp.asarray(row_cdf), jnp.asarray(col_cdf), jnp.asarray(p))

    def _pixel(self, d):
        """Row and column ``(i, j)`` of the pixels seen in world directions ``d`` (..., 3)."""
        H, W = self.image.shape[:2]
        th = jnp.arccos(jnp.clip(d[..., 1], -1, 1))
        ph = jnp.mod(jnp.arctan2(d[..., 2], d[..., 0]), 2 * jnp.pi)
        i = jnp.clip((th / jnp.pi * H).astype(jnp.int32), 0, H - 1)
        j = jnp.clip((ph / (2 * jnp.pi) * W).astype(jnp.int32), 0, W - 1)
        return i, j

    def _density(self, i, j):
        """Solid-angle density of drawing pixel ``(i, j)``: its probability over its solid angle."""
        H, W = self.image.shape[:2]
        # a pixel spans d(cos theta) d(phi) of solid angle
        t0, t1 = i * (jnp.pi / H), (i + 1) * (jnp.pi / H)
        area = (jnp.cos(t0) - jnp.cos(t1)) * (2 * jnp.pi / W)
        return self.pixel_p[i, j] / area

    def lookup(self, d):
        """Radiance (..., 3) of the pixels that world directions ``d`` (..., 3) fall in."""
        i, j = self._pixel(d)
        return self.image[i, j]

    def pdf(self, d):
        """Solid-angle density (1/sr) of :meth:`sample` at world directions ``d`` (..., 3)."""
        return self._density(*self._pixel(d))

    def sample(self, u1, u2):
        """``(d, pdf)``: world directions drawn by luminance and their solid-angle density; of
        uniform ``u1`` (picks the row) and ``u2`` (the column)."""
        H, W = self.image.shape[:2]
        i = jnp.clip(jnp.searchsorted(self.row_cdf, u1, side="right") - 1, 0, H - 1)
        r0, r1 = self.row_cdf[i], self.row_cdf[i + 1]
        v1 = jnp.clip((u1 - r0) / jnp.maximum(r1 - r0, 1e-30), 0, 1)
        cdf = self.col_cdf[i]
        j = jnp.clip(jax_searchsorted_rows(cdf, u2) - 1, 0, W - 1)
        c0 = jnp.take_along_axis(cdf, j[..., None], -1)[..., 0]
        c1 = jnp.take_along_axis(cdf, (j + 1)[..., None], -1)[..., 0]
        v2 = jnp.clip((u2 - c0) / jnp.maximum(c1 - c0, 1e-30), 0, 1)
        # uniform in solid angle inside the pixel: cos(theta) linear, phi linear
        t0, t1 = i * (jnp.pi / H), (i + 1) * (jnp.pi / H)
        ct = jnp.cos(t0) + v1 * (jnp.cos(t1) - jnp.cos(t0))
        st = jnp.sqrt(jnp.maximum(1 - ct * ct, 0))
        ph = (j + v2) * (2 * jnp.pi / W)
        d = jnp.stack([st * jnp.cos(ph), ct, st * jnp.sin(ph)], -1)
        return d, self._density(i, j)


def jax_searchsorted_rows(cdf, u):
    """Per-element ``searchsorted(cdf[k], u[k], side="right")`` for rows ``cdf`` (..., W + 1):
    how many entries of each row are <= its value."""
    return jnp.sum(cdf <= u[..., None], axis=-1)
