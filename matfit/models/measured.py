"""Measured BRDF tables as models: a MERL ``.binary`` table and an RGL ``.bsdf`` file, each with
an interpolated ``eval``, a tabulated importance sampler and its ``pdf``, in pure JAX.

The tables are constants: every method reads them through ``jax.lax.stop_gradient`` (the way
equinox marks an array as not trainable), so their gradients are zero. They are array leaves of
the module, so a jitted function taking the model compiles once per table shape and never embeds
the tables as constants.
"""

from __future__ import annotations

import os
from typing import Optional

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._dataerr import data_error
from .._math import COS_EPS, cosine_hemisphere, normalize, safe_atan2, safe_sqrt
from ..errors import ParameterError
from ..io.merl import RES as _MERL_RES
from ..io.merl import MerlBRDF, read_merl
from ..io.rgl import RglBRDF, read_rgl
from ._base import AbstractBSDF
from ._pairs import valid_reflection
from ._params import check_directions, check_u

__all__ = ["MeasuredMERL", "MeasuredRGL", "measured_model"]

_HALF_PI = np.pi / 2
# largest float32 below 1: random numbers are clipped into [1 - _ONE_MINUS_EPS, _ONE_MINUS_EPS]
_ONE_MINUS_EPS = 0.999999940395355225


# ----------------------------------------------------------------------------------------------
# Shared helpers (flat (N, 3) arrays)
# ----------------------------------------------------------------------------------------------
def _const(x):
    """A table read as a constant (zero gradient)."""
    return jax.lax.stop_gradient(x)


def _elevation(d):
    """acos(d_z) for unit d, accurate near the pole: 2 asin(|d - z| / 2)."""
    # double where: finite gradients at the pole (sqrt) and at the antipode (asin' = inf at 1)
    half = 0.5 * safe_sqrt(d[..., 0] ** 2 + d[..., 1] ** 2 + (d[..., 2] - 1) ** 2)
    inner = half < 1
    return 2 * jnp.where(inner, jnp.arcsin(jnp.where(inner, half, 0)), jnp.pi / 2)


def _reflect(w, m):
    return 2 * jnp.sum(w * m, -1, keepdims=True) * m - w


def _flatten(wo, other):
    """Broadcast ``wo`` (..., 3) and ``other`` (..., n) and flatten them to (N, 3), (N, n)."""
    batch = jnp.broadcast_shapes(wo.shape[:-1], other.shape[:-1])
    dtype = jnp.result_type(wo, other, float)
    a = jnp.broadcast_to(jnp.asarray(wo, dtype), batch + (3,)).reshape(-1, 3)
    b = jnp.broadcast_to(jnp.asarray(other, dtype), batch + (other.shape[-1],)).reshape(-1, other.shape[-1])
    return batch, a, b


def _bisect(fetch, hi, target, strict):
    """Largest index ``i`` in ``[0, hi]`` with ``fetch(i) < target`` (``<=`` unless ``strict``),
    for non-decreasing ``fetch`` with ``fetch(0) <= target``; ``fetch`` maps (N,) int32 indices
    to (N,) values. A fixed number of halvings (no data-dependent control flow)."""
    def step(_, bounds):
        lo, up = bounds
        mid = (lo + up + 1) // 2
        v = fetch(mid)
        go = (v < target) if strict else (v <= target)
        return jnp.where(go, mid, lo), jnp.where(go, up, mid - 1)

    lo = jnp.zeros(target.shape, jnp.int32)
    up = jnp.full(target.shape, hi, jnp.int32)
    # one loop body (a small program to compile); ceil(log2(hi + 1)) halvings reach lo == up
    lo, _ = jax.lax.fori_loop(0, max(1, int(np.ceil(np.log2(hi + 1)))), step, (lo, up))
    return lo


def _solve_linear_density(a, b, s):
    """``t`` in [0, 1] with ``a t + (b - a) t^2 / 2 = s``: the inverse CDF of the density that
    runs linearly from ``a`` to ``b`` on [0, 1] (written without cancellation for any a, b >= 0)."""
    disc = jnp.maximum(a * a + 2 * s * (b - a), 0)
    den = a + jnp.sqrt(disc)
    return jnp.clip(jnp.where(den > 0, 2 * s / jnp.where(den > 0, den, 1), 0), 0, 1)


def _lerp(a, b, t):
    return a + (b - a) * t


def _check_dtype(owner, dtype):
    if dtype is None:
        return jnp.result_type(float)
    dt = np.dtype(dtype)
    if dt not in (np.float32, np.float64):
        raise ParameterError(f"{owner}: dtype must be float32 or float64 (or None), got {dtype!r}")
    return jnp.dtype(dt) if (dt == np.float32 or jax.config.jax_enable_x64) else jnp.dtype(np.float32)


class _Info:
    """Descriptive metadata of a model (file, material): a static field that compares equal to
    any other ``_Info``, so that two tables of the same shapes share their compiled programs."""

    def __init__(self, **items):
        self.__dict__.update(items)

    def __eq__(self, other):
        return isinstance(other, _Info)

    def __hash__(self):
        return 0

    def __repr__(self):
        return "_Info(" + ", ".join(f"{k}={v!r}" for k, v in self.__dict__.items()) + ")"


def _no_such_file(path):
    if isinstance(path, (str, os.PathLike)) and not os.path.isfile(path):
        raise data_error("file", "an existing file", "no such file", file=path)


# ----------------------------------------------------------------------------------------------
# RGL: 2-D warps of bilinear densities, linearly interpolated over the incidence angles
# ----------------------------------------------------------------------------------------------
class _Warp(eqx.Module):
    """A bilinear density on a ``ny x nx`` node grid of the unit square per parameter slice, with
    the marginal-conditional warp of Dupuy & Jakob's scheme (continuous CDFs, linear inside a
    patch) and linear interpolation over up to two parameters. Positions are ``(x, y)`` with
    ``x`` along the grid's last axis."""

    data: jax.Array  # (S, ny * nx[, C]); normalized to unit integral when the warp samples
    cond: Optional[jax.Array]  # (S, ny * nx): integral along x from 0 to each node
    marg: Optional[jax.Array]  # (S, ny): integral from y = 0 to each row
    params: tuple  # parameter nodes, one (n_p,) array per parameter, the last varying fastest
    nx: int = eqx.field(static=True)
    ny: int = eqx.field(static=True)

    @staticmethod
    def build(data, params=(), sampling=True, dtype=None):
        d = np.asarray(data, np.float64)
        pv = tuple(np.asarray(p, np.float64) for p in params)
        s = int(np.prod([len(p) for p in pv])) if pv else 1
        chan = d.ndim == len(pv) + 3  # a channel axis before the grid (the rgb / spectra table)
        if chan:
            c = d.shape[len(pv)]
            ny, nx = d.shape[-2:]
            d = np.moveaxis(d.reshape(s, c, ny, nx), 1, -1)  # (S, ny, nx, C)
        else:
            ny, nx = d.shape[-2:]
            d = d.reshape(s, ny, nx)
        cond = marg = None
        if sampling:
            cond = np.zeros_like(d)
            cond[:, :, 1:] = np.cumsum(0.5 * (d[:, :, :-1] + d[:, :, 1:]), axis=2) / (nx - 1)
            marg = np.zeros((s, ny))
            marg[:, 1:] = np.cumsum(0.5 * (cond[:, :-1, -1] + cond[:, 1:, -1]), axis=1) / (ny - 1)
            norm = 1.0 / np.where(marg[:, -1] > 0, marg[:, -1], 1.0)
            d, cond, marg = d * norm[:, None, None], cond * norm[:, None, None], marg * norm[:, None]
            cond = jnp.asarray(cond.reshape(s, -1), dtype)
            marg = jnp.asarray(marg, dtype)
        flat = d.reshape((s, ny * nx) + d.shape[3:])
        return _Warp(jnp.asarray(flat, dtype), cond, marg, tuple(jnp.asarray(p, dtype) for p in pv), nx, ny)

    def _slices(self, params, n):
        """Corner slices (N, K) and their weights (N, K) for per-point parameters."""
        sizes = [p.shape[0] for p in self.params]
        slices = jnp.zeros((n, 1), jnp.int32)
        w = jnp.ones((n, 1), self.data.dtype)
        for dim, vals in enumerate(self.params):
            if sizes[dim] == 1:
                continue
            vals = _const(vals)
            stride = int(np.prod(sizes[dim + 1:]))
            p = jnp.broadcast_to(params[dim], (n,)).astype(vals.dtype)
            i = jnp.clip(jnp.searchsorted(vals, p, side="right") - 1, 0, sizes[dim] - 2).astype(jnp.int32)
            w1 = jnp.clip((p - vals[i]) / (vals[i + 1] - vals[i]), 0, 1)
            idx = jnp.stack([i, i + 1], 1) * stride
            k = 2 * slices.shape[1]  # explicit: reshape(n, -1) cannot infer it for n == 0
            slices = (slices[:, :, None] + idx[:, None, :]).reshape(n, k)
            w = (w[:, :, None] * jnp.stack([1 - w1, w1], 1)[:, None, :]).reshape(n, k)
        return slices, w

    @staticmethod
    def _at(table, slices, w, idx):
        """sum_k w[:, k] table[slices[:, k], idx] for idx (N,)."""
        v = _const(table)[slices, idx[:, None]]  # (N, K[, C])
        return jnp.einsum("nk,nk...->n...", w, v)

    def _patch(self, pos):
        p = jnp.clip(pos, 0, 1) * jnp.array([self.nx - 1, self.ny - 1], pos.dtype)
        col = jnp.clip(jnp.floor(p[:, 0]), 0, self.nx - 2).astype(jnp.int32)
        row = jnp.clip(jnp.floor(p[:, 1]), 0, self.ny - 2).astype(jnp.int32)
        return col, row, p[:, 0] - col, p[:, 1] - row

    def eval(self, pos, params=()):
        """The bilinear value at positions (N, 2): (N,) or (N, C)."""
        n = pos.shape[0]
        slices, w = self._slices(params, n)
        col, row, tx, ty = self._patch(pos)
        i = row * self.nx + col
        if self.data.ndim == 3:
            tx, ty = tx[:, None], ty[:, None]
        D = lambda k: self._at(self.data, slices, w, k)  # noqa: E731
        return _lerp(_lerp(D(i), D(i + 1), tx), _lerp(D(i + self.nx), D(i + self.nx + 1), tx), ty)

    def invert(self, pos, params=()):
        """The uniform point (N, 2) that :meth:`sample` maps to ``pos``, and the density there."""
        nx, ny = self.nx, self.ny
        slices, w = self._slices(params, pos.shape[0])
        col, row, tx, ty = self._patch(pos)
        i = row * nx + col
        D = lambda k: self._at(self.data, slices, w, k)  # noqa: E731
        Cc = lambda k: self._at(self.cond, slices, w, k)  # noqa: E731
        c0 = _lerp(D(i), D(i + nx), ty)
        c1 = _lerp(D(i + 1), D(i + nx + 1), ty)
        pdf = _lerp(c0, c1, tx)
        x = _lerp(Cc(i), Cc(i + nx), ty) + tx * (c0 + 0.5 * tx * (c1 - c0)) / (nx - 1)
        r0, r1 = Cc(row * nx + nx - 1), Cc(row * nx + 2 * nx - 1)
        den = _lerp(r0, r1, ty)
        ux = jnp.where(den > 0, x / jnp.where(den > 0, den, 1), 0)
        uy = self._at(self.marg, slices, w, row) + ty * (r0 + 0.5 * ty * (r1 - r0)) / (ny - 1)
        return jnp.stack([ux, uy], 1), pdf

    def sample(self, u, params=()):
        """Warp uniform points (N, 2) to the density: positions (N, 2) and the density there."""
        nx, ny = self.nx, self.ny
        u = jnp.clip(u, 1 - _ONE_MINUS_EPS, _ONE_MINUS_EPS)
        slices, w = self._slices(params, u.shape[0])
        D = lambda k: self._at(self.data, slices, w, k)  # noqa: E731
        Cc = lambda k: self._at(self.cond, slices, w, k)  # noqa: E731
        M = lambda k: self._at(self.marg, slices, w, k)  # noqa: E731
        uy = u[:, 1]
        row = _bisect(M, ny - 2, uy, strict=True)
        r0, r1 = Cc(row * nx + nx - 1), Cc(row * nx + 2 * nx - 1)
        ty = _solve_linear_density(r0, r1, (uy - M(row)) * (ny - 1))
        target = u[:, 0] * _lerp(r0, r1, ty)
        F = lambda k: _lerp(Cc(row * nx + k), Cc(row * nx + nx + k), ty)  # noqa: E731
        col = _bisect(F, nx - 2, target, strict=True)
        i = row * nx + col
        c0 = _lerp(D(i), D(i + nx), ty)
        c1 = _lerp(D(i + 1), D(i + nx + 1), ty)
        tx = _solve_linear_density(c0, c1, (target - F(col)) * (nx - 1))
        pos = jnp.stack([(col + tx) / (nx - 1), (row + ty) / (ny - 1)], 1)
        return pos, _lerp(c0, c1, tx)


class _AbstractMeasured(AbstractBSDF):
    """A measured table as a model: ``eval``, ``pdf`` and ``sample`` check their input, flatten
    the batch to ``(N, 3)`` rows (:func:`_flatten`) and call the model's ``_eval``, ``_pdf`` and
    ``_sample`` on them."""

    def eval(self, wo, wi):
        check_directions(f"{type(self).__name__}.eval", wo=wo, wi=wi)
        batch, o, i = _flatten(wo, wi)
        return self._eval(o, i).reshape(batch + (self.channels,))

    def pdf(self, wo, wi):
        check_directions(f"{type(self).__name__}.pdf", wo=wo, wi=wi)
        batch, o, i = _flatten(wo, wi)
        return self._pdf(o, i).reshape(batch)

    def sample(self, wo, u):
        check_directions(f"{type(self).__name__}.sample", wo=wo)
        check_u(f"{type(self).__name__}.sample", u, 3)
        batch, o, uu = _flatten(wo, u)
        wi, weight, pdf = self._sample(o, uu)
        return wi.reshape(batch + (3,)), weight.reshape(batch + (self.channels,)), pdf.reshape(batch)

    def _flat_weighted(self, wo, wi, pdf, ok):
        """``(wi, weight, pdf)`` of flat samples: ``weight = f cos(theta_i) / pdf``, both 0 where not ``ok``."""
        f = self._eval(wo, wi)
        weight = jnp.where(ok[:, None], f * wi[:, 2:3] / jnp.where(ok, pdf, 1)[:, None], 0)
        return wi, weight, jnp.where(ok, pdf, 0)


def _theta2u(t):
    return safe_sqrt(t * (2 / jnp.pi))


def _phi2u(p):
    return (p + jnp.pi) / (2 * jnp.pi)


class MeasuredRGL(_AbstractMeasured):
    r"""An RGL material-database measurement (``.bsdf`` tensor file) as a model.

    ``eval(wo, wi)`` is :meth:`matfit.io.RglBRDF.eval` in JAX, with ``wi`` (the light) in the
    file's incidence role: the RGL scheme (Dupuy & Jakob 2018; powitacq, Mitsuba 3's
    ``measured``) maps the half vector to unit coordinates, inverts the VNDF warp to the sample
    space, reads the bilinear ``rgb``/``spectra`` table (linear over the incidence angles) and
    multiplies by ``ndf / (4 sigma)``. ``sample(wo, u)`` uses the file's own warps with ``wo`` as
    the warp's incidence (by Helmholtz reciprocity, the measured lobe seen from ``wo``): the
    ``luminance`` warp, the VNDF warp, then the mirror of ``wo`` about the half vector (as
    Mitsuba's plugin samples). ``pdf`` is the two warps' densities over the Jacobian of the map
    to solid angle:

    .. math:: p(\omega_i) = \frac{p_\mathrm{vndf}(u_m)\,p_\mathrm{lum}(s)}
              {\max(2\pi^2 u_{m,1} \sin\theta_m, 10^{-6})\ 4\,(\omega_o\cdot m)}

    with ``m`` the half vector, ``u_m`` its unit coordinates and ``s`` the sample-space point.

    Parameters
    ----------
    brdf : RglBRDF; not differentiable
        The parsed file (:func:`matfit.io.read_rgl`); :meth:`from_file` reads one from a path.
    dtype : {None, "float32", "float64"}, default None; not differentiable
        Floating type of the stored tables (None: float64 when ``jax_enable_x64`` is on).

    Attributes
    ----------
    description : str
        The material's description.
    source : str or None
        The file read.
    isotropic : bool
        At most two azimuths of incidence (the relative azimuth of the half vector is used).
    jacobian : bool
        Whether the values are multiplied by ``ndf / (4 sigma)``.

    Raises
    ------
    ParameterError
        ``brdf`` is not an :class:`~matfit.io.RglBRDF`.

    References
    ----------
    - J. Dupuy, W. Jakob, "An Adaptive Parameterization for Efficient Material Acquisition and
      Rendering", ACM ToG 37(6), 2018.

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.io.rgl import read_rgl, tensor_file_bytes, uniform_fields
    >>> from matfit.models import MeasuredRGL
    >>> m = MeasuredRGL(read_rgl(tensor_file_bytes(uniform_fields(0.5))))
    >>> wo, wi = jnp.array([0.0, 0.6, 0.8]), jnp.array([0.0, -0.6, 0.8])
    >>> round(float(m.eval(wo, wi)[0] * 0.8), 6), m.channels   # f cos(theta_o) = 0.5 / 4
    (0.125, 3)
    """

    vndf: _Warp
    luminance: _Warp
    spectra: _Warp
    ndf: _Warp
    sigma: _Warp
    info: _Info = eqx.field(static=True)
    isotropic: bool = eqx.field(static=True)
    jacobian: bool = eqx.field(static=True)
    n_channels: int = eqx.field(static=True)

    def __init__(self, brdf, dtype=None):
        if not isinstance(brdf, RglBRDF):
            raise ParameterError(f"MeasuredRGL: brdf must be a matfit.io.RglBRDF (read_rgl), got "
                                 f"{type(brdf).__name__}; MeasuredRGL.from_file reads a path")
        dt = _check_dtype("MeasuredRGL", dtype)
        par = (brdf.phi_i, brdf.theta_i)
        self.vndf = _Warp.build(brdf.vndf, par, True, dt)
        self.luminance = _Warp.build(brdf.luminance, par, True, dt)
        self.spectra = _Warp.build(brdf.spectral_data, par, False, dt)
        self.ndf = _Warp.build(brdf.ndf, (), False, dt)
        self.sigma = _Warp.build(brdf.sigma, (), False, dt)
        self.info = _Info(description=brdf.description, source=brdf.source)
        self.isotropic = bool(brdf.isotropic)
        self.jacobian = bool(brdf.jacobian)
        self.n_channels = int(brdf.n_channels)

    @classmethod
    def from_file(cls, path, dtype=None) -> "MeasuredRGL":
        """Read an RGL ``.bsdf`` file (a path or its bytes) into a model; ``dtype`` as for the
        constructor. A missing or malformed file raises :class:`~matfit.errors.DataFormatError`
        naming the file and the field."""
        _no_such_file(path)
        return cls(read_rgl(path), dtype=dtype)

    @property
    def channels(self):
        return self.n_channels

    @property
    def description(self) -> str:
        """The material's description (the file's ``description`` field)."""
        return self.info.description

    @property
    def source(self) -> Optional[str]:
        """The file read (None for bytes)."""
        return self.info.source

    # ------------------------------------------------------------------------------------------
    def _angles(self, w):
        """(theta, phi) of the incidence direction and its unit coordinates u_w (N, 2)."""
        theta, phi = _elevation(w), safe_atan2(w[:, 1], w[:, 0])
        return theta, phi, jnp.stack([_theta2u(theta), _phi2u(phi)], 1)

    def _u_m(self, m, phi_inc):
        theta_m, phi_m = _elevation(m), safe_atan2(m[:, 1], m[:, 0])
        uy = _phi2u(phi_m - phi_inc if self.isotropic else phi_m)
        return jnp.stack([_theta2u(theta_m), uy - jnp.floor(uy)], 1)

    def eval_cos(self, wo, wi):
        """``f(wo, wi) cos(theta_o)``, what the RGL tables store (``wi`` the file's incidence); 0
        unless both directions are above the surface."""
        check_directions("MeasuredRGL.eval_cos", wo=wo, wi=wi)
        batch, o, i = _flatten(wo, wi)
        return self._eval_cos(o, i).reshape(batch + (self.n_channels,))

    def _invert(self, wo, wi, incident):
        """The pairs' half vector ``m``, seen with ``incident`` (``wo`` or ``wi``) as the warps'
        incidence: ``(m, par, u_inc, u_m, sample, p_vndf)``: the incidence's warp parameters
        ``(phi, theta)`` and unit coordinates, ``m``'s unit coordinates, and the VNDF warp's
        inverse at them (the sample-space point and its density)."""
        m = normalize(wo + wi)
        theta, phi, u_inc = self._angles(incident)
        u_m = self._u_m(m, phi)
        sample, p_vndf = self.vndf.invert(u_m, (phi, theta))
        return m, (phi, theta), u_inc, u_m, sample, p_vndf

    def _eval_cos(self, wo, wi):
        ok = valid_reflection(wo, wi)
        _, par, u_wi, u_m, sample, _ = self._invert(wo, wi, wi)
        spec = jnp.maximum(self.spectra.eval(sample, par), 0)
        if self.jacobian:
            spec = spec * (self.ndf.eval(u_m) / (4 * self.sigma.eval(u_wi)))[:, None]
        return jnp.where(ok[:, None], spec, 0)

    def _eval(self, wo, wi):
        ok = valid_reflection(wo, wi)
        return jnp.where(ok[:, None], self._eval_cos(wo, wi) / jnp.where(ok, wo[:, 2], 1)[:, None], 0)

    def _jac(self, u_m, wo, m):
        sin_m = jnp.sin(u_m[:, 0] ** 2 * _HALF_PI)
        return jnp.maximum(2 * np.pi ** 2 * u_m[:, 0] * sin_m, 1e-6) * 4 * jnp.sum(wo * m, -1)

    def _pdf(self, wo, wi):
        ok = valid_reflection(wo, wi)
        m, par, _, u_m, sample, p_vndf = self._invert(wo, wi, wo)
        p_lum = self.luminance.eval(sample, par)
        jac = self._jac(u_m, wo, m)
        p = p_vndf * p_lum / jnp.where(jac > 0, jac, 1)
        return jnp.where(ok & (jac > 0), jnp.maximum(p, 0), 0)

    def _sample(self, wo, u):
        theta_o, phi_o, _ = self._angles(wo)
        s, p_lum = self.luminance.sample(u[:, 1:3], (phi_o, theta_o))
        u_m, p_vndf = self.vndf.sample(s, (phi_o, theta_o))
        theta_m = u_m[:, 0] ** 2 * _HALF_PI
        phi_m = (2 * u_m[:, 1] - 1) * jnp.pi + (phi_o if self.isotropic else 0)
        st = jnp.sin(theta_m)
        m = jnp.stack([st * jnp.cos(phi_m), st * jnp.sin(phi_m), jnp.cos(theta_m)], 1)
        wi = normalize(_reflect(wo, m))
        jac = self._jac(u_m, wo, m)
        pdf = p_vndf * p_lum / jnp.where(jac > 0, jac, 1)
        return self._flat_weighted(wo, wi, pdf, valid_reflection(wo, wi) & (jac > 0) & (pdf > 0))


# ----------------------------------------------------------------------------------------------
# MERL
# ----------------------------------------------------------------------------------------------
def _rot_z(v, c, s):
    return jnp.stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1], v[:, 2]], 1)


def _rot_y(v, c, s):
    return jnp.stack([c * v[:, 0] + s * v[:, 2], v[:, 1], -s * v[:, 0] + c * v[:, 2]], 1)


def _merl_coords(wo, wi):
    """Continuous cell coordinates (x_h, x_d, x_p) of MERL's grid (cell centres at integers)."""
    h = normalize(wo + wi)
    theta_h = _elevation(h)
    rxy = safe_sqrt(h[:, 0] ** 2 + h[:, 1] ** 2)
    has_az = rxy > 0
    cph = jnp.where(has_az, h[:, 0] / jnp.where(has_az, rxy, 1), 1)
    sph = jnp.where(has_az, h[:, 1] / jnp.where(has_az, rxy, 1), 0)
    # the difference vector: wi rotated by -phi_h about z, then by -theta_h about y
    d = _rot_y(_rot_z(wi, cph, -sph), h[:, 2], -rxy)
    theta_d = _elevation(normalize(d))
    phi_d = safe_atan2(d[:, 1], d[:, 0])
    nh, nd, npd = _MERL_RES
    x_h = safe_sqrt(theta_h / _HALF_PI) * nh - 0.5
    x_d = theta_d / _HALF_PI * nd - 0.5
    x_p = jnp.mod(phi_d, jnp.pi) / jnp.pi * npd - 0.5
    return x_h, x_d, x_p


def _merl_value(values, mask, wo, wi):
    """Trilinear interpolation of the MERL table (flat (90*90*180, C) values, (90*90*180,) mask)
    at direction pairs (N, 3); the weights of invalid cells are dropped and the rest renormalized."""
    nh, nd, npd = _MERL_RES
    x_h, x_d, x_p = _merl_coords(wo, wi)
    ih = jnp.clip(jnp.floor(x_h), 0, nh - 2).astype(jnp.int32)
    th = jnp.clip(x_h - ih, 0, 1)
    idd = jnp.clip(jnp.floor(x_d), 0, nd - 2).astype(jnp.int32)
    td = jnp.clip(x_d - idd, 0, 1)
    fp = jnp.floor(x_p)
    tp = x_p - fp
    ip0 = jnp.mod(fp.astype(jnp.int32), npd)
    ip1 = jnp.mod(ip0 + 1, npd)
    acc = 0.0
    wsum = 0.0
    for a, wa in ((ih, 1 - th), (ih + 1, th)):
        for b, wb in ((idd, 1 - td), (idd + 1, td)):
            for c, wc in ((ip0, 1 - tp), (ip1, tp)):
                k = (a * nd + b) * npd + c
                wk = wa * wb * wc * mask[k]
                acc = acc + wk[:, None] * values[k]
                wsum = wsum + wk
    return jnp.where((wsum > 0)[:, None], acc / jnp.where(wsum > 0, wsum, 1)[:, None], 0)


_merl_value_jit = jax.jit(_merl_value)


class MeasuredMERL(_AbstractMeasured):
    r"""A MERL table (Matusik et al. 2003, ``.binary``) as a model.

    ``eval`` interpolates trilinearly between the cell centres of MERL's
    (theta_h, theta_d, phi_d) grid, linear in ``sqrt(theta_h)`` (the grid's own spacing) and
    periodic in phi_d (period pi, MERL's reciprocity fold); cells flagged invalid (below the
    horizon) leave the interpolation and the others' weights are renormalized (0 where all eight
    neighbours are invalid). Reciprocal by construction.

    ``sample``: for ``n_theta_o`` polar angles of ``wo``, a piecewise-constant distribution of
    the half vector over ``n_theta_h x n_phi_h`` cells (edges ``theta_h = (i / n)^2 pi/2``,
    uniform in phi relative to ``wo``'s azimuth), the cells' probabilities proportional to the
    integral of ``f cos(theta_i)`` over them, uniform in solid angle inside a cell; the slices of
    the two polar angles around ``wo``'s are mixed linearly, and a fraction ``diffuse_fraction``
    of the samples is cosine-weighted (defensive sampling: the density is positive wherever
    ``f`` can be). ``pdf`` is that mixture's density:

    .. math:: p(\omega_i) = c\,\frac{\cos\theta_i}{\pi} + (1 - c)\,
              \frac{\sum_s w_s(\theta_o)\,P_s(\mathrm{cell}(h)) / \Omega(\mathrm{cell}(h))}
              {4\,(\omega_o\cdot h)}

    Parameters
    ----------
    table : MerlBRDF; not differentiable
        The table (:func:`matfit.io.read_merl`, :meth:`matfit.io.MerlBRDF.from_values`);
        :meth:`from_file` reads a path.
    n_theta_o : int, default 24; >= 2; static, not differentiable
        Polar angles of ``wo`` (evenly spaced over [0, 90] deg) at which the sampling
        distribution is tabulated.
    n_theta_h : int, default 64; >= 2; static, not differentiable
        Half-vector polar cells of a slice (edges ``theta_h = (i / n)^2 pi / 2``).
    n_phi_h : int, default 64; >= 2; static, not differentiable
        Half-vector azimuth cells of a slice (uniform over 2 pi, relative to ``wo``'s azimuth).
    diffuse_fraction : float, default 0.1; (0, 1); static, not differentiable
        Probability of a cosine-weighted sample (keeps the density positive wherever ``f`` is).
    dtype : {None, "float32", "float64"}, default None; not differentiable
        Floating type of the stored tables (None: float64 when ``jax_enable_x64`` is on).

    Attributes
    ----------
    source : str or None
        The file read.

    Raises
    ------
    ParameterError
        ``table`` is not a :class:`~matfit.io.MerlBRDF`, or an option out of range.

    References
    ----------
    - W. Matusik, H. Pfister, M. Brand, L. McMillan, "A Data-Driven Reflectance Model", ACM ToG
      22(3), 2003.
    - S. Rusinkiewicz, "A New Change of Variables for Efficient BRDF Representation", EGWR 1998.

    Examples
    --------
    >>> import jax.numpy as jnp, numpy as np
    >>> from matfit.io import MerlBRDF
    >>> from matfit.models import MeasuredMERL
    >>> m = MeasuredMERL(MerlBRDF.from_values(np.full((3, 90, 90, 180), 0.2)), n_theta_o=4)
    >>> wo, wi = jnp.array([0.0, 0.6, 0.8]), jnp.array([0.36, -0.48, 0.8])
    >>> round(float(m.eval(wo, wi)[1]), 6), m.channels
    (0.2, 3)
    """

    values: jax.Array  # (90 * 90 * 180, 3): BRDF in 1/sr, 0 in invalid cells
    mask: jax.Array  # (90 * 90 * 180,): 1 for valid cells, 0 for invalid ones
    s_edges: jax.Array  # (n_theta_h + 1,): sin^2(theta_h / 2) at the polar cell edges
    cell_prob: jax.Array  # (n_theta_o, n_theta_h, n_phi_h): probability of each half-vector cell
    inv_area: jax.Array  # (n_theta_h,): 1 / solid angle of a cell of each polar band
    marg: jax.Array  # (n_theta_o, n_theta_h + 1): CDF over the polar bands
    cond: jax.Array  # (n_theta_o * n_theta_h, n_phi_h + 1): CDF over the azimuth cells of a band
    n_theta_o: int = eqx.field(static=True)
    n_theta_h: int = eqx.field(static=True)
    n_phi_h: int = eqx.field(static=True)
    diffuse_fraction: float = eqx.field(static=True)
    info: _Info = eqx.field(static=True)

    def __init__(self, table, n_theta_o=24, n_theta_h=64, n_phi_h=64, diffuse_fraction=0.1, dtype=None):
        owner = "MeasuredMERL"
        if not isinstance(table, MerlBRDF):
            raise ParameterError(f"{owner}: table must be a matfit.io.MerlBRDF (read_merl, MerlBRDF.from_values), "
                                 f"got {type(table).__name__}; MeasuredMERL.from_file reads a path")
        for name, v in (("n_theta_o", n_theta_o), ("n_theta_h", n_theta_h), ("n_phi_h", n_phi_h)):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 2:
                raise ParameterError(f"{owner}: {name} must be an integer >= 2, got {v!r}")
        if isinstance(diffuse_fraction, bool) or not isinstance(diffuse_fraction, (int, float, np.floating)) \
                or not 0 < float(diffuse_fraction) < 1:
            raise ParameterError(f"{owner}: diffuse_fraction must be a number in (0, 1), got {diffuse_fraction!r}")
        dt = _check_dtype(owner, dtype)
        valid = table.valid
        vals = np.where(valid[None], table.values, 0.0).reshape(3, -1).T
        self.values = jnp.asarray(vals, dt)
        self.mask = jnp.asarray(valid.ravel().astype(np.float64), dt)
        self.n_theta_o, self.n_theta_h, self.n_phi_h = int(n_theta_o), int(n_theta_h), int(n_phi_h)
        self.diffuse_fraction = float(diffuse_fraction)
        self.info = _Info(source=table.source)
        self._tabulate(dt)

    def _tabulate(self, dt):
        """The sampling tables: per slice of theta_o, the integral of f cos(theta_i) over each
        half-vector cell (2 x 2 midpoint rule in (cos theta_h, phi_h))."""
        K, nu, nphi = self.n_theta_o, self.n_theta_h, self.n_phi_h
        th_edges = (np.arange(nu + 1) / nu) ** 2 * _HALF_PI
        s_edges = np.sin(th_edges / 2) ** 2
        area = 2 * np.diff(s_edges) * (2 * np.pi / nphi)  # solid angle of a cell: d omega = 2 ds dphi
        q = np.array([0.25, 0.75])
        s = (s_edges[:-1, None] + np.diff(s_edges)[:, None] * q).ravel()  # (2 nu,)
        phi = ((np.arange(nphi)[:, None] + q) * (2 * np.pi / nphi)).ravel()  # (2 nphi,)
        S, P = np.meshgrid(s, phi, indexing="ij")
        st = 2 * np.sqrt(S * (1 - S))
        h = np.stack([st * np.cos(P), st * np.sin(P), 1 - 2 * S], -1).reshape(-1, 3)
        theta_o = np.minimum(np.linspace(0, _HALF_PI, K), np.radians(89.5))
        W = np.empty((K, nu, nphi))
        for k, t in enumerate(theta_o):
            wo = np.array([np.sin(t), 0.0, np.cos(t)])
            cos_oh = h @ wo
            wi = 2 * cos_oh[:, None] * h - wo
            wi /= np.linalg.norm(wi, axis=1, keepdims=True)
            ok = (cos_oh > 0) & (wi[:, 2] > COS_EPS)
            f = np.asarray(_merl_value_jit(self.values, self.mask, jnp.asarray(np.broadcast_to(wo, wi.shape), dt),
                                           jnp.asarray(wi, dt)), np.float64)
            g = np.where(ok, f.mean(-1) * np.clip(wi[:, 2], 0, None) * 4 * np.clip(cos_oh, 0, None), 0.0)
            W[k] = g.reshape(nu, 2, nphi, 2).mean(axis=(1, 3)) * area[:, None]
        tot = W.sum(axis=(1, 2))
        W = np.where((tot > 0)[:, None, None], W, area[None, :, None])  # a black table: uniform half vectors
        prob = W / W.sum(axis=(1, 2), keepdims=True)
        band = prob.sum(-1)
        marg = np.concatenate([np.zeros((K, 1)), np.cumsum(band, 1)], 1)
        marg /= marg[:, -1:]
        cond = np.concatenate([np.zeros((K, nu, 1)), np.cumsum(prob, 2)], 2)
        cond = cond / np.where(cond[:, :, -1:] > 0, cond[:, :, -1:], 1.0)
        self.s_edges = jnp.asarray(s_edges, dt)
        self.cell_prob = jnp.asarray(prob, dt)
        self.inv_area = jnp.asarray(1.0 / area, dt)
        self.marg = jnp.asarray(marg, dt)
        self.cond = jnp.asarray(cond.reshape(K * nu, nphi + 1), dt)

    @classmethod
    def from_file(cls, path, **options) -> "MeasuredMERL":
        """Read a MERL ``.binary`` file (a path or its bytes) into a model; ``options`` are the
        constructor's. A missing or malformed file raises :class:`~matfit.errors.DataFormatError`
        naming the file and the field."""
        _no_such_file(path)
        return cls(read_merl(path), **options)

    @property
    def channels(self):
        return 3

    @property
    def source(self) -> Optional[str]:
        """The file read (None for a table built in memory or read from bytes)."""
        return self.info.source

    def _eval(self, wo, wi):
        ok = valid_reflection(wo, wi)
        f = _merl_value(_const(self.values), _const(self.mask), wo, wi)
        return jnp.where(ok[:, None], f, 0)

    def _slice_weights(self, wo):
        t = _elevation(wo) / _HALF_PI * (self.n_theta_o - 1)
        k0 = jnp.clip(jnp.floor(t), 0, self.n_theta_o - 2).astype(jnp.int32)
        return k0, jnp.clip(t - k0, 0, 1)

    def _pdf(self, wo, wi):
        ok = valid_reflection(wo, wi)
        h = normalize(wo + wi)
        # sin^2(theta_h / 2) without cancellation, and the polar band of MERL's sqrt spacing
        s = (h[:, 0] ** 2 + h[:, 1] ** 2) / (2 * (1 + h[:, 2]))
        u = safe_sqrt(2 * jnp.arcsin(safe_sqrt(jnp.clip(s, 0, 1))) / _HALF_PI)
        band = jnp.clip(jnp.floor(u * self.n_theta_h), 0, self.n_theta_h - 1).astype(jnp.int32)
        phi_rel = jnp.mod(safe_atan2(h[:, 1], h[:, 0]) - safe_atan2(wo[:, 1], wo[:, 0]), 2 * jnp.pi)
        cell = jnp.clip(jnp.floor(phi_rel / (2 * jnp.pi) * self.n_phi_h), 0, self.n_phi_h - 1).astype(jnp.int32)
        k0, t = self._slice_weights(wo)
        prob = _const(self.cell_prob)
        p_h = _lerp(prob[k0, band, cell], prob[k0 + 1, band, cell], t) * _const(self.inv_area)[band]
        cos_oh = jnp.sum(wo * h, -1)
        p_tab = jnp.where(cos_oh > 0, p_h / (4 * jnp.where(cos_oh > 0, cos_oh, 1)), 0)
        c = self.diffuse_fraction
        p = c * jnp.maximum(wi[:, 2], 0) / jnp.pi + (1 - c) * p_tab
        return jnp.where(ok, p, 0)

    def _sample(self, wo, u):
        c = self.diffuse_fraction
        u = jnp.clip(u, 0, _ONE_MINUS_EPS)
        nu, nphi = self.n_theta_h, self.n_phi_h
        k0, t = self._slice_weights(wo)
        v = (u[:, 0] - c) / (1 - c)
        k = jnp.where(v < 1 - t, k0, k0 + 1)
        marg, cond, s_edges = _const(self.marg), _const(self.cond), _const(self.s_edges)
        u1, u2 = u[:, 1], u[:, 2]
        band = _bisect(lambda i: marg[k, i], nu - 1, u1, strict=False)
        m0, m1 = marg[k, band], marg[k, band + 1]
        r1 = jnp.clip((u1 - m0) / jnp.where(m1 > m0, m1 - m0, 1), 0, 1)
        rowc = k * nu + band
        cell = _bisect(lambda i: cond[rowc, i], nphi - 1, u2, strict=False)
        c0, c1 = cond[rowc, cell], cond[rowc, cell + 1]
        r2 = jnp.clip((u2 - c0) / jnp.where(c1 > c0, c1 - c0, 1), 0, 1)
        s = _lerp(s_edges[band], s_edges[band + 1], r1)
        phi = (cell + r2) * (2 * jnp.pi / nphi) + safe_atan2(wo[:, 1], wo[:, 0])
        st = 2 * jnp.sqrt(jnp.maximum(s * (1 - s), 0))
        h = jnp.stack([st * jnp.cos(phi), st * jnp.sin(phi), 1 - 2 * s], 1)
        wi_tab = normalize(_reflect(wo, h))
        wi_cos = cosine_hemisphere(u1, u2)
        wi = jnp.where((u[:, 0] < c)[:, None], wi_cos, wi_tab)
        pdf = self._pdf(wo, wi)
        return self._flat_weighted(wo, wi, pdf, pdf > 0)


def measured_model(table):
    """The measured table as a model, where its provenance names an RGL ``.bsdf`` or MERL
    ``.binary`` file that still exists (:class:`MeasuredRGL`, :class:`MeasuredMERL`); else None.

    Parameters
    ----------
    table : matfit.Table

    Returns
    -------
    AbstractBSDF or None
    """
    prov = getattr(table, "provenance", None) or {}
    cls = {"rgl-tensor": MeasuredRGL, "merl": MeasuredMERL}.get(prov.get("format"))
    src = prov.get("source")
    if cls is None or not isinstance(src, str) or not os.path.isfile(src):
        return None
    return cls.from_file(src)
