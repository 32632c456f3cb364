"""Measurement geometries: arrays of (wo, wi) unit-vector pairs in the local frame (normal +z).

``wi`` (the light) always lies in the upper hemisphere. ``wo`` (the detector) lies in the upper
hemisphere for reflection and in the lower one for transmission; each builder takes
``reflection`` / ``transmission`` flags and produces **only** the pairs asked for, so a
reflection-only scene never holds a pair that could reach a transmission lobe.

Every builder returns ``(wo, wi, valid, info)`` with ``wo, wi`` of shape (N, 3), ``valid`` (N,) bool
(rows that are kept for the layout of a grid but must not be evaluated, e.g. MERL cells below the
horizon) and ``info`` a JSON-able description stored in the table's provenance. Angles are in degrees.
"""
from __future__ import annotations

import numpy as np

from matfit.io import merl as _merl
from matfit.io._halfdiff import half_diff_to_dirs


def sph(theta_deg, phi_deg):
    """Unit vectors from zenith ``theta`` and azimuth ``phi`` (degrees), broadcast."""
    t, p = np.radians(np.asarray(theta_deg, float)), np.radians(np.asarray(phi_deg, float))
    t, p = np.broadcast_arrays(t, p)
    v = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _out(wo, wi, valid=None, **info):
    wo = np.ascontiguousarray(wo, dtype=np.float64).reshape(-1, 3)
    wi = np.ascontiguousarray(wi, dtype=np.float64).reshape(-1, 3)
    valid = np.ones(len(wo), bool) if valid is None else np.asarray(valid, bool).reshape(-1)
    return wo, wi, valid, info


def _flip(w):
    w = np.array(w, copy=True)
    w[..., 2] *= -1
    return w


def inplane(theta_i=(0.0, 30.0, 60.0), theta_o_step=5.0, theta_o_max=85.0, phi_i=0.0,
            reflection=True, transmission=False):
    """In-plane sweeps: for each light zenith ``theta_i`` (at azimuth ``phi_i + 180``), the detector
    sweeps the incidence plane from ``-theta_o_max`` to ``+theta_o_max`` (signed zenith; positive on the
    specular side) in steps of ``theta_o_step``. Transmission mirrors the sweep below the surface."""
    to = np.arange(-theta_o_max, theta_o_max + 1e-9, theta_o_step)
    blocks_o, blocks_i = [], []
    for ti in theta_i:
        wi = sph(ti, phi_i + 180.0)
        wo_up = sph(np.abs(to), np.where(to >= 0, phi_i, phi_i + 180.0))
        if reflection:
            blocks_o.append(wo_up)
            blocks_i.append(np.broadcast_to(wi, wo_up.shape))
        if transmission:
            blocks_o.append(_flip(wo_up))
            blocks_i.append(np.broadcast_to(wi, wo_up.shape))
    return _out(np.concatenate(blocks_o), np.concatenate(blocks_i), kind="inplane",
                theta_i=[float(t) for t in theta_i], theta_o=[float(to[0]), float(to[-1]), float(theta_o_step)],
                phi_i=float(phi_i), reflection=reflection, transmission=transmission)


def hemisphere(theta_i=(0.0, 30.0, 60.0), n_theta=9, n_phi=24, theta_o_max=85.0, phi_i=0.0,
               reflection=True, transmission=False):
    """Full hemispherical grids: for each light zenith, the detector visits ``n_theta`` zeniths
    (cell centres of [0, theta_o_max]) x ``n_phi`` azimuths (cell centres of [0, 360)); the lower
    hemisphere (mirror image) is added for transmission."""
    tg = (np.arange(n_theta) + 0.5) / n_theta * theta_o_max
    pg = (np.arange(n_phi) + 0.5) / n_phi * 360.0
    T, P = np.meshgrid(tg, pg, indexing="ij")
    wo_up = sph(T.ravel(), P.ravel())
    blocks_o, blocks_i = [], []
    for ti in theta_i:
        wi = sph(ti, phi_i + 180.0)
        for on, wo in ((reflection, wo_up), (transmission, _flip(wo_up))):
            if on:
                blocks_o.append(wo)
                blocks_i.append(np.broadcast_to(wi, wo.shape))
    return _out(np.concatenate(blocks_o), np.concatenate(blocks_i), kind="hemisphere",
                theta_i=[float(t) for t in theta_i], n_theta=int(n_theta), n_phi=int(n_phi),
                theta_o_max=float(theta_o_max), reflection=reflection, transmission=transmission)


def merl_grid(n_theta_h=90, n_theta_d=90, n_phi_d=180, reflection=True, transmission=False):
    """The MERL half/difference cell-centre grid (Matusik et al. 2003), optionally coarser.

    theta_h = ((i+1/2)/n_theta_h)^2 pi/2, theta_d = (j+1/2)/n_theta_d pi/2, phi_d = (k+1/2)/n_phi_d pi,
    phi_h = 0, mapped by matfit.io._halfdiff.half_diff_to_dirs; with (90, 90, 180) this is exactly the
    geometry of ``MerlBRDF.to_table()``. Rows in C-order (theta_h, theta_d, phi_d); cells with a
    direction below the horizon are kept (invalid, never evaluated). Reflection only."""
    if (n_theta_h, n_theta_d, n_phi_d) == _merl.RES:
        th, td, pd = _merl.cell_centres()
    else:
        th = ((np.arange(n_theta_h) + 0.5) / n_theta_h) ** 2 * (np.pi / 2)
        td = (np.arange(n_theta_d) + 0.5) / n_theta_d * (np.pi / 2)
        pd = (np.arange(n_phi_d) + 0.5) / n_phi_d * np.pi
    TH, TD, PD = np.meshgrid(th, td, pd, indexing="ij")
    wo, wi = half_diff_to_dirs(TH.ravel(), TD.ravel(), PD.ravel())
    valid = (wo[:, 2] > 1e-6) & (wi[:, 2] > 1e-6)
    return _out(wo, wi, valid, kind="merl", n_theta_h=int(n_theta_h), n_theta_d=int(n_theta_d),
                n_phi_d=int(n_phi_d), reflection=True, transmission=False)


def _hemi_from_unit(u1, u2, distribution):
    """Upper-hemisphere directions from uniforms: equal-area ("uniform") or cosine-weighted."""
    z = 1.0 - u1 if distribution == "uniform" else np.sqrt(1.0 - u1)
    z = np.clip(z, 1e-6, 1.0)
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    p = 2 * np.pi * u2
    v = np.stack([r * np.cos(p), r * np.sin(p), z], -1)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _apply_sides(wo, side_u, reflection, transmission):
    if reflection and transmission:
        return np.where((side_u < 0.5)[:, None], wo, _flip(wo))
    return wo if reflection else _flip(wo)


def random_pairs(n=1000, seed=0, distribution="uniform", reflection=True, transmission=False):
    """``n`` independent random pairs: ``wi`` and ``wo`` uniform in solid angle ("uniform") or
    cosine-weighted ("cosine"); with reflection and transmission, ``wo`` is below with probability 1/2."""
    rng = np.random.default_rng(seed)
    u = rng.random((n, 5))
    wi = _hemi_from_unit(u[:, 0], u[:, 1], distribution)
    wo = _apply_sides(_hemi_from_unit(u[:, 2], u[:, 3], distribution), u[:, 4], reflection, transmission)
    return _out(wo, wi, kind="random", n=int(n), distribution=distribution, seed=int(seed),
                reflection=reflection, transmission=transmission)


def stratified_pairs(n=1000, seed=0, distribution="uniform", reflection=True, transmission=False):
    """``n`` pairs from a 5-D Latin hypercube (each coordinate stratified into ``n`` equal strata,
    jittered within its stratum), mapped like :func:`random_pairs`: every marginal is stratified."""
    rng = np.random.default_rng(seed)
    u = np.empty((n, 5))
    for d in range(5):
        u[:, d] = (rng.permutation(n) + rng.random(n)) / n
    wi = _hemi_from_unit(u[:, 0], u[:, 1], distribution)
    wo = _apply_sides(_hemi_from_unit(u[:, 2], u[:, 3], distribution), u[:, 4], reflection, transmission)
    return _out(wo, wi, kind="stratified", n=int(n), distribution=distribution, seed=int(seed),
                reflection=reflection, transmission=transmission)


def mirror_biased_pairs(n=24, seed=0, near=1 / 3, spread=0.05):
    """``n`` random pairs (cosines of both directions uniform in (0.05, 1), azimuths uniform) of
    which the first ``int(near * n)`` have ``wi`` within a few degrees of ``wo``'s mirror direction
    (``spread``: the standard deviation of the perturbation of the mirror vector, ~3 degrees): a
    gonioreflectometer or a capture that looks at the highlight. ``seed`` may be a
    ``numpy.random.Generator``, which is drawn from (and advanced)."""
    rng = np.random.default_rng(seed)

    def dirs(m):
        u = rng.random((m, 2))
        ct = np.sqrt(u[:, 0]) * 0.95 + 0.05
        st, ph = np.sqrt(1 - ct**2), 2 * np.pi * u[:, 1]
        return np.stack([st * np.cos(ph), st * np.sin(ph), ct], -1)

    wo, wi = dirs(n), dirs(n)
    m = int(near * n)
    wi[:m] = np.array([-1, -1, 1]) * wo[:m] + rng.normal(0, spread, (m, 3))
    wi[:m, 2] = np.abs(wi[:m, 2]) + 0.02
    wi[:m] /= np.linalg.norm(wi[:m], axis=1, keepdims=True)
    return _out(wo, wi, kind="mirror_biased", n=int(n), near=float(near), spread=float(spread))


#: The default sparse pattern (theta_i, phi_i, theta_o, phi_o) in degrees: a few views as a
#: hand-held or multi-flash capture would give (near-normal, specular, back-scatter, off-plane).
DEFAULT_SPARSE_VIEWS = (
    (0.0, 0.0, 0.0, 0.0),
    (15.0, 180.0, 15.0, 0.0),
    (30.0, 180.0, 30.0, 0.0),
    (45.0, 180.0, 45.0, 0.0),
    (60.0, 180.0, 60.0, 0.0),
    (45.0, 180.0, 0.0, 0.0),
    (30.0, 0.0, 30.0, 0.0),
    (60.0, 0.0, 50.0, 0.0),
    (45.0, 90.0, 45.0, 0.0),
    (20.0, 180.0, 60.0, 30.0),
)


def sparse(views=DEFAULT_SPARSE_VIEWS, reflection=True, transmission=False):
    """A few explicit views ``(theta_i, phi_i, theta_o, phi_o)`` in degrees; ``theta_o > 90`` is a
    transmission view (only allowed with transmission, checked by the scene parser)."""
    v = np.asarray(views, dtype=np.float64).reshape(-1, 4)
    wi = sph(v[:, 0], v[:, 1])
    wo = sph(v[:, 2], v[:, 3])
    return _out(wo, wi, kind="sparse", views=v.tolist(), reflection=reflection, transmission=transmission)


BUILDERS = {
    "inplane": inplane,
    "hemisphere": hemisphere,
    "merl": merl_grid,
    "random": random_pairs,
    "stratified": stratified_pairs,
    "sparse": sparse,
}
