r"""A sphere of a material under an environment, rendered by importance sampling in JAX.

An orthographic camera looks along -z at a unit sphere; every pixel inside it sees the surface
with normal ``n`` and reflects (or transmits) the environment, one bounce (no self-occlusion: a
sphere does not see itself). The estimator of each pixel, per sample:

- BSDF sampling: ``wi`` from the model's own ``sample``, contribution ``weight * L(wi)``;
- environment sampling: ``wi`` from the map's luminance, contribution ``f |cos| L / p_env``;
- ``"mis"``: both, combined by the power heuristic (Veach 1997); samples from a Dirac lobe
  (which environment sampling cannot reach) keep weight 1.

Only the effects the scene calls for are computed: the furnace (uniform radiance 1) is rendered
by BSDF sampling alone with no environment lookup; a model with only Dirac lobes is never
evaluated (its samples carry their own weights); environment samples below the surface are
evaluated only for models that transmit (:attr:`~matfit.models.AbstractBSDF.transmits`).
Transmitted directions read the environment straight through, as for a thin sheet in the outside
medium (the radiance BTDF's :math:`1/\eta^2` is undone, so a lossless dielectric renders its albedo).

References
----------
- E. Veach, "Robust Monte Carlo Methods for Light Transport Simulation", PhD thesis, 1997, ch. 9.
- M. Pharr, W. Jakob, G. Humphreys, *Physically Based Rendering*, 4th ed., Sec. 12.5 (image
  infinite lights).
"""

from __future__ import annotations

from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..errors import ParameterError
from ..models import AbstractBSDF
from ._env import Environment, load_environment

STRATEGIES = ("mis", "bsdf", "env")


@dataclass(frozen=True)
class RenderStats:
    """What a render computed (counts over all pixels and samples).

    Attributes
    ----------
    bsdf_samples, env_samples : int
        Directions drawn from the model and from the environment.
    evaluations : int
        Pairs the model was asked to evaluate (``eval``) outside its own sampler.
    transmission_evaluations : int
        Of those, pairs with ``wi`` below the surface (zero for models that do not transmit).
    env_lookups : int
        Environment radiance lookups (zero for the furnace).

    Examples
    --------
    >>> from matfit.models import Lambert
    >>> from matfit.render import render_sphere
    >>> _, stats = render_sphere(Lambert(0.5), "furnace", size=8, spp=2, return_stats=True)
    >>> stats.bsdf_samples, stats.env_samples, stats.env_lookups   # 52 pixels inside, 2 samples each
    (104, 0, 0)
    """

    bsdf_samples: int
    env_samples: int
    evaluations: int
    transmission_evaluations: int
    env_lookups: int


def _uses_bsdf(model, strategy, furnace):
    return furnace or strategy != "env" or model.is_delta


def sphere_frames(size):
    """The unit sphere seen along -z in a ``size`` x ``size`` image.

    Parameters
    ----------
    size : int

    Returns
    -------
    inside : numpy.ndarray, (size, size) bool
        The pixels inside the sphere.
    frames : numpy.ndarray, (size, size, 3, 3)
        Each pixel's local frame, rows (tangent, bitangent, normal).
    """
    c = (np.arange(size) + 0.5) / size * 2 - 1
    X, Y = np.meshgrid(c, -c)  # row 0 at the top
    r2 = X**2 + Y**2
    inside = r2 < 1
    n = np.stack([X, Y, np.sqrt(np.clip(1 - r2, 0, 1))], -1)
    up = np.array([0.0, 1.0, 0.0])
    t = np.cross(up, n)
    tn = np.linalg.norm(t, axis=-1, keepdims=True)
    t = np.where(tn > 1e-6, t / np.maximum(tn, 1e-12), np.array([1.0, 0.0, 0.0]))
    b = np.cross(n, t)
    return inside, np.stack([t, b, n], -2)  # (size, size, 3, 3): rows are the local axes


@eqx.filter_jit
def _render(model, env, frames, key, spp, strategy, furnace):
    P = frames.shape[0]
    wo_world = jnp.array([0.0, 0.0, 1.0], frames.dtype)
    wo = jnp.einsum("pij,j->pi", frames, wo_world)
    wo = wo / jnp.linalg.norm(wo, axis=-1, keepdims=True)
    use_env = (not furnace) and strategy in ("mis", "env") and not model.is_delta
    use_bsdf = _uses_bsdf(model, strategy, furnace)
    transmits = model.transmits

    def radiance(d_world):
        return jnp.ones(d_world.shape[:-1] + (3,), frames.dtype) if furnace else env.lookup(d_world)

    def to_world(w):
        return jnp.einsum("pij,pi->pj", frames, w)

    def one(acc, k):
        k1, k2, k3 = jax.random.split(k, 3)
        total = jnp.zeros((P, 3), frames.dtype)
        if use_bsdf:
            u = jax.random.uniform(k1, (P, 3), frames.dtype)
            wi, weight, pdf = model.sample(wo, u)
            L = radiance(to_world(wi))
            w = jnp.ones_like(pdf)
            if use_env:
                p_cont = model.pdf(wo, wi)
                delta = jnp.abs(pdf - p_cont) > 1e-4 * jnp.maximum(pdf, 1e-30) if model.has_delta_lobe else False
                p_e = env.pdf(to_world(wi))
                w = jnp.where(delta, 1.0, pdf**2 / jnp.maximum(pdf**2 + p_e**2, 1e-30))
            # thin sheet: the environment behind is in the outside medium (undo the radiance BTDF's 1/eta^2)
            ef = model.energy_factor(wo, wi)[..., None] if transmits else 1.0
            total = total + weight * ef * L * w[..., None]
        if use_env:
            d, p_e = env.sample(jax.random.uniform(k2, (P,)), jax.random.uniform(k3, (P,)))
            d = jnp.broadcast_to(d, (P, 3)) if d.ndim == 1 else d
            wi = jnp.einsum("pij,pj->pi", frames, d)
            below = wi[..., 2] <= 0
            keep = jnp.ones_like(below) if transmits else ~below
            safe = jnp.where(keep[..., None], wi, jnp.array([0.0, 0.0, 1.0], wi.dtype))
            f = model.eval(wo, safe)
            f = jnp.broadcast_to(f, (P, f.shape[-1]))
            ef = model.energy_factor(wo, safe)[..., None] if transmits else 1.0
            contrib = f * ef * jnp.abs(safe[..., 2])[..., None] * env.lookup(d) / jnp.maximum(p_e, 1e-30)[..., None]
            if strategy == "mis":
                p_b = model.pdf(wo, safe)
                contrib = contrib * (p_e**2 / jnp.maximum(p_e**2 + p_b**2, 1e-30))[..., None]
            total = total + jnp.where(keep[..., None], contrib, 0)
        return acc + total.astype(acc.dtype), None

    keys = jax.random.split(key, spp)
    acc, _ = jax.lax.scan(one, jnp.zeros((P, 3), frames.dtype), keys)
    return acc / spp


def render_sphere(model, environment="sky", size=256, spp=64, seed=0, strategy="mis", return_stats=False,
                  progress=False):
    """Render a sphere of ``model`` under ``environment``.

    Parameters
    ----------
    model : matfit.models.AbstractBSDF
        1 or 3 channels.
    environment : "furnace", "sky", (H, W, 3) array, or path to a .npy/.hdr/.exr map
        ``"furnace"``: uniform radiance 1; ``"sky"``: :func:`~matfit.render.sky_map`.
    size, spp, seed : int
        Image width and height in pixels; samples per pixel (each a BSDF sample and, with
        ``"mis"``, an environment sample); the random seed.
    strategy : {"mis", "bsdf", "env"}
        BSDF sampling, environment sampling, or both with multiple importance sampling.
    return_stats, progress : bool
        Also return :class:`RenderStats`; show a progress bar (tqdm) over blocks of samples.

    Returns
    -------
    numpy.ndarray, shape (size, size, 3), float32
        Linear radiance; pixels outside the sphere show the environment behind it.

    Examples
    --------
    >>> from matfit.models import Lambert
    >>> img = render_sphere(Lambert(1.0), "furnace", size=16, spp=4)
    >>> img.shape, round(float(img[8, 8, 0]), 2)
    ((16, 16, 3), 1.0)
    """
    if not isinstance(model, AbstractBSDF):
        raise ParameterError(f"render_sphere: model must be a matfit model, got {type(model).__name__}")
    for name, v in (("size", size), ("spp", spp)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
            raise ParameterError(f"render_sphere: {name} must be a positive integer, got {v!r}")
    if strategy not in STRATEGIES:
        raise ParameterError(f"render_sphere: strategy must be one of {STRATEGIES}, got {strategy!r}")
    if model.channels not in (1, 3):
        raise ParameterError(f"render_sphere: the model has {model.channels} channels; previews need 1 or 3")
    img = load_environment(environment)
    furnace = img is None
    env = Environment.of(np.ones((2, 2, 3), np.float32) if furnace else img)
    inside, frames = sphere_frames(int(size))
    fr = jnp.asarray(frames[inside], jnp.float32)
    key = jax.random.PRNGKey(seed)
    blocks = max(1, min(int(spp), 8)) if progress else 1
    per = [int(spp) // blocks + (1 if b < int(spp) % blocks else 0) for b in range(blocks)]
    acc = np.zeros((fr.shape[0], 3), np.float64)
    it = range(blocks)
    if progress:
        from tqdm.auto import tqdm

        it = tqdm(it, desc="render", unit="block")
    for b in it:
        if per[b] == 0:
            continue
        out = _render(model, env, fr, jax.random.fold_in(key, b), per[b], strategy, furnace)
        acc += np.asarray(out, np.float64) * per[b]
    val = (acc / int(spp)).astype(np.float32)
    out = np.zeros((size, size, 3), np.float32)
    if furnace:
        out[:] = 1.0
    else:
        # behind the sphere: the environment seen along the camera ray (-z from the camera)
        out[:] = np.asarray(env.lookup(jnp.array([0.0, 0.0, -1.0])))
    out[inside] = val
    if not np.all(np.isfinite(out)):
        raise ParameterError(f"render_sphere: the render of {type(model).__name__} has non-finite pixels")
    if not return_stats:
        return out
    n = int(inside.sum()) * int(spp)
    use_env = (not furnace) and strategy in ("mis", "env") and not model.is_delta
    stats = RenderStats(
        bsdf_samples=n if _uses_bsdf(model, strategy, furnace) else 0,
        env_samples=n if use_env else 0,
        evaluations=n if use_env else 0,
        transmission_evaluations=_below_count(env, fr, int(spp), seed) if (use_env and model.transmits) else 0,
        env_lookups=0 if furnace else n * (2 if use_env else 1),
    )
    return out, stats


def _below_count(env, frames, spp, seed):
    """Environment samples that fall below the surface (what a transmitting model evaluates)."""
    key = jax.random.PRNGKey(seed + 1)
    d, _ = env.sample(jax.random.uniform(key, (frames.shape[0],)), jax.random.uniform(jax.random.fold_in(key, 1),
                                                                                        (frames.shape[0],)))
    z = jnp.einsum("pj,pj->p", frames[:, 2, :], d)
    return int(jnp.sum(z <= 0)) * spp


def tonemap(img, exposure=1.0):
    """Linear radiance times ``exposure``, clipped to [0, 1] and sRGB-encoded, as 8-bit codes.

    Parameters
    ----------
    img : array_like, (H, W, 3)
    exposure : float, default 1

    Returns
    -------
    numpy.ndarray, (H, W, 3) uint8
    """
    return np.round(srgb_encode(np.clip(np.asarray(img, np.float64) * exposure, 0, 1)) * 255).astype(np.uint8)


def srgb_encode(x):
    """The sRGB transfer function (IEC 61966-2-1): linear values in [0, 1] to codes in [0, 1].

    Parameters
    ----------
    x : array_like

    Returns
    -------
    numpy.ndarray
    """
    x = np.asarray(x, np.float64)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(np.maximum(x, 0.0031308), 1 / 2.4) - 0.055)


def srgb_decode(c):
    """The inverse of :func:`srgb_encode`: sRGB codes in [0, 1] to linear values.

    Parameters
    ----------
    c : array_like

    Returns
    -------
    numpy.ndarray
    """
    c = np.asarray(c, np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((np.maximum(c, 0.04045) + 0.055) / 1.055) ** 2.4)


def save_png(path, img, exposure=1.0):
    """Write a :func:`tonemap` PNG of linear ``img`` (matplotlib's writer; parent folders are created).

    Parameters
    ----------
    path : str or PathLike
    img : array_like, (H, W, 3)
    exposure : float, default 1

    Returns
    -------
    Path
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from pathlib import Path

    Path(path).parent.mkdir(parents=True, exist_ok=True)
    plt.imsave(str(path), tonemap(img, exposure))
    return Path(path)


def image_ciede2000(a, b):
    """Mean CIEDE2000 (``colour.delta_E``) between two linear sRGB images (G. Sharma, W. Wu,
    E. N. Dalal, Color Research & Application 30(1), 2005).

    Parameters
    ----------
    a, b : array_like, (..., 3)
        Linear sRGB (negative values clipped to 0), converted to CIE L*a*b* through XYZ.

    Returns
    -------
    float
    """
    import colour

    def lab(x):
        x = np.clip(np.asarray(x, np.float64), 0, None)
        xyz = colour.RGB_to_XYZ(x, colour.RGB_COLOURSPACES["sRGB"], apply_cctf_decoding=False)
        return colour.XYZ_to_Lab(xyz)

    return float(np.mean(colour.delta_E(lab(a), lab(b), method="CIE 2000")))
