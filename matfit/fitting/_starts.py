"""Where fits start: the data-driven guess (diffuse floor, peak height and width, and what the
family itself knows), the screened extra starts (among them the widths of the distribution of
normals extracted from the table's retro-reflection, Dupuy et al. 2015), and the jitted helpers
that map starts to and from the unconstrained space.

The generic guess: the floor is the 10th percentile of each channel over the valid rows (times
pi: a Lambertian albedo); the peak is the row of largest ``f cos(theta_i)``; the width is the
largest half-vector angle among rows above half the peak's excess over the floor, as a GGX alpha
(``D(theta_h)/D(0) = 1/2  <=>  tan(theta_h) = alpha sqrt(sqrt(2) - 1)``); the peak's reflectance
is its excess times ``4 pi alpha^2 cos^2`` (``f ~ F / (4 pi alpha^2 cos^2)`` at ``theta_h ~ 0``).
A family then adds its constant starts and its ``refine`` hook (:class:`~matfit.fitting.Family`;
the rough conductors refine the width from the lobe's shape and read ``eta``, ``k`` per channel
off the Fresnel curve). Every guess is clipped strictly inside its bounds (the bijection
saturates at a bound); a parameter without a guess starts mid-range.

References
----------
- J. Dupuy, E. Heitz, J.-C. Iehl, P. Poulin, V. Ostromoukhov, "Extracting Microfacet-based BRDF
  Parameters from Arbitrary Materials with Power Iterations", CGF 34(4):21-30, 2015.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import ParameterError
from ..microfacet import ndf_start
from ..parallel import shard_batch
from ..table import Table
from .params import Parametrization
from ._result import FitError
from ._solver import batched_run

__all__ = ["initial_guess", "initial_guesses", "guesses_from_arrays", "percentile10", "SCREEN_PER_START", "candidates",
           "fit_starts", "screened_starts", "compiled_helpers", "ndf_widths", "NDF_CANDIDATE", "WIDTH_ENTRIES"]

#: :func:`fit_starts` adds the start of :func:`ndf_widths` to the screened candidates (set False
#: to compare with the starts without it).
NDF_CANDIDATE = True
#: The entries of the generic guess that are microfacet widths (``widths`` of :func:`guesses_from_arrays`).
WIDTH_ENTRIES = ("alpha", "alpha_base", "alpha_coat")


def initial_guess(table: Table, par: Parametrization):
    """Data-driven starting values: diffuse floor, specular peak height and width (the rules are in
    the module docstring).

    Parameters
    ----------
    table, par : matfit.Table, Parametrization
        The table (at least one valid row); the family, channels and fixed parameters.

    Returns
    -------
    dict
        Parameter name -> value (scalar or per channel), every one strictly inside its bounds.

    Examples
    --------
    >>> import numpy as np
    >>> from matfit import Table
    >>> from matfit.fitting import Parametrization, initial_guess
    >>> wo = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]]); wi = wo[::-1].copy()
    >>> g = initial_guess(Table(wo=wo, wi=wi, values=np.full((2, 3), 0.2)), Parametrization("lambert", 3))
    >>> np.round(g["albedo"], 3).tolist()  # pi * the floor
    [0.628, 0.628, 0.628]
    """
    return {k: v[0] for k, v in initial_guesses([table], par).items()}


def percentile10(v, valid):
    """``np.percentile(v[b][valid[b]], 10, axis=0)`` for every b at once (linear interpolation)."""
    if v.shape[0] == 1:  # one (large) table: numpy's partition, not a sort of every row
        return np.percentile(v[0] if valid[0].all() else v[0][valid[0]], 10, axis=0)[None]
    n = valid.sum(axis=1)  # (B,)
    srt = np.sort(np.where(valid[..., None], v, np.inf), axis=1)  # invalid rows last
    pos = 0.1 * (n - 1)
    lo = np.floor(pos).astype(int)
    hi = np.minimum(lo + 1, n - 1)
    a = np.take_along_axis(srt, lo[:, None, None], axis=1)[:, 0]
    b = np.take_along_axis(srt, hi[:, None, None], axis=1)[:, 0]
    return a + (pos - lo)[:, None] * (b - a)


def initial_guesses(tables, par: Parametrization, widths=None):
    """:func:`initial_guess` for many tables of one shape at once (vectorized: a texel map's guesses
    are a few array operations, not a loop over the texels).

    Parameters
    ----------
    tables : sequence of matfit.Table
        Tables of one shape (rows and channels).
    par, widths
        As for :func:`guesses_from_arrays`.

    Returns
    -------
    dict
        Parameter name -> array with a leading table axis ``(B,)`` or ``(B, C)``.
    """
    WO, WI, V, M = _stacked(tables)
    return guesses_from_arrays(WO, WI, V, M, par, one=len(tables) == 1, widths=widths)


def _stacked(tables):
    """``(WO, WI, V, M)`` of tables of one shape, stacked along a leading axis (one table: no copy)."""
    stack = (lambda xs: np.asarray(xs[0])[None]) if len(tables) == 1 else np.stack
    V = stack([np.asarray(t.values, float) for t in tables])
    M = stack([np.asarray(t.valid, bool) for t in tables])
    WO = stack([np.asarray(t.wo, float) for t in tables])
    WI = stack([np.asarray(t.wi, float) for t in tables])
    return WO, WI, V, M


def table_features(WO, WI, V, M, one=False):
    """What :func:`guesses_from_arrays` reads off a stack of tables before any family's own starts
    (module docstring): ``{"floor": (B, C), "alpha": (B,), "r0": (B, C)}``. ``one``: a single
    table, for the error message. Raises FitError when a table has no valid row."""
    V = np.asarray(V, float)
    empty = np.flatnonzero(~M.any(axis=1))
    if empty.size:
        raise FitError("the table has no valid rows" if one else f"tables {empty[:10].tolist()} have no valid rows")
    rows = np.arange(V.shape[0])
    floor = percentile10(V, M)  # (B, C)
    mean = np.einsum("bnc->bn", V) / V.shape[2]  # (einsum: numpy's mean over a short last axis is slower)
    s = WO + WI
    hz = s[..., 2] / np.maximum(np.sqrt(np.einsum("bni,bni->bn", s, s)), 1e-12)  # the half vector's cosine
    excess = np.where(M, mean - np.where(M, mean, np.inf).min(axis=1, keepdims=True), -np.inf)
    emax = excess.max(axis=1, keepdims=True)
    top = M & np.where(emax > 0, excess >= 0.5 * emax, True)
    # the largest theta_h among the top rows: arccos of their smallest cosine
    th = np.arccos(np.clip(np.where(top, hz, np.inf).min(axis=1), -1, 1))
    alpha = np.clip(np.tan(np.minimum(th, 1.3)) / np.sqrt(np.sqrt(2) - 1), 0.02, 0.8)
    ipk = np.argmax(np.where(M, mean * np.abs(WI[..., 2]), -np.inf), axis=1)
    peak = V[rows, ipk] - floor
    co = np.maximum(np.abs(WO[rows, ipk, 2]), 0.05)
    r0 = np.clip(peak * (4 * np.pi * alpha**2 * co**2)[:, None], 0.02, 0.9)
    return {"floor": floor, "alpha": alpha, "r0": r0}


def guesses_from_arrays(WO, WI, V, M, par: Parametrization, one=False, widths=None, features=None):
    """:func:`initial_guesses` of a stack of tables given as arrays.

    Parameters
    ----------
    WO, WI : numpy.ndarray (B, N, 3)
        Directions to the viewer and to the light (broadcast views are fine: shared directions
        cost no copy).
    V, M : numpy.ndarray (B, N, C) and bool (B, N)
        Values; rows that may seed the guess.
    par : Parametrization
        The family, channels and fixed parameters.
    one : bool, default False
        The stack is a single table (its error messages say "the table").
    widths : mapping, optional
        Entries of :data:`WIDTH_ENTRIES` (scalar or ``(B,)``) replacing the generic widths, before
        the family's constant starts and its refinement (which then starts from them): e.g.
        :func:`ndf_widths`.
    features : dict, optional
        :func:`table_features` of these arrays, when already computed (a second guess of the same
        table, with other widths, then costs only the family's refinement).

    Returns
    -------
    dict
        Parameter name -> array ``(B,)`` or ``(B, C)``, every value strictly inside its bounds.

    Raises
    ------
    FitError
        When a table has no valid row.
    ParameterError
        For a ``widths`` entry that is not one of :data:`WIDTH_ENTRIES`.
    """
    V = np.asarray(V, float)
    f = table_features(WO, WI, V, M, one) if features is None else features
    B = V.shape[0]
    alpha, r0 = f["alpha"], f["r0"]
    k = 2 * np.sqrt(r0 / (1 - r0))
    ones = np.ones_like(r0)
    guess = {
        "albedo": np.clip(np.pi * f["floor"], 0.01, 0.95),
        "alpha": alpha.copy(), "alpha_base": alpha.copy(), "alpha_coat": np.maximum(alpha / 2, 0.02),
        "eta": ones.copy(),
        "k": k.copy(), "eta_base": ones, "k_base": k, "eta_coat": np.full(B, 1.5), "f0": r0.copy(),
    }
    for name, value in (widths or {}).items():
        if name not in WIDTH_ENTRIES:
            raise ParameterError(f"guesses_from_arrays: widths entry {name!r} is not a width of the guess; use one of "
                                 f"{list(WIDTH_ENTRIES)}")
        guess[name] = np.broadcast_to(np.asarray(value, float), (B,)).copy()
    # what the family itself knows: constant starts, then its data-driven refinement
    for p in par.family.params:
        if p.name in par.family.starts:
            guess[p.name] = np.full((B, V.shape[2]) if p.per_channel else B, float(par.family.starts[p.name]))
    if par.family.refine is not None:
        par.family.refine(WO, WI, V, M, guess, par.family)
    # Every guess strictly inside its bounds (the bijection saturates at a bound).
    out = {}
    for p in par.free:
        lo, hi = p.lower, p.upper
        span = (hi - lo) if np.isfinite(hi) else 1.0
        # a parameter without a data-driven guess (a user-defined family's) starts mid-range
        g = guess.get(p.name)
        if g is None:
            mid = 0.5 * (lo + hi) if np.isfinite(hi) else lo + 1.0
            g = np.full((B, V.shape[2]) if p.per_channel else B, mid)
        out[p.name] = np.clip(g, lo + 1e-3 * span, hi - 1e-3 * span if np.isfinite(hi) else np.inf)
    return out


#: Candidates screened per extra start (see :func:`screened_starts`).
SCREEN_PER_START = 8


def candidates(par, base, n_extra, seed, extra=None):
    """``SCREEN_PER_START * n_extra + 1`` candidate starts per table, (B, K + 1, p): half of the
    first K the data-driven start plus N(0, 1) steps in the unconstrained space, half spread over
    the whole parameter box (bounded parameters uniform in (2 %, 98 %) of their range, others
    N(0, 1) in z); the last ones are ``extra`` (B, k, p), other data-driven starts in the
    unconstrained space (:func:`fit_starts`' extracted widths), or ``base`` again where there is
    none (:func:`screened_starts` then never picks it). The slot is always there, so that the
    screening's compiled shape does not depend on whether a table gives the extra start."""
    K = SCREEN_PER_START * n_extra
    rng = np.random.default_rng(seed)
    local = rng.normal(0, 1.0, (K - K // 2, par.size))
    u = rng.uniform(0.02, 0.98, (K // 2, par.size))
    bounded = np.isfinite(par.lower_upper()[1])
    spread = np.where(bounded, np.log(u) - np.log1p(-u), rng.normal(0, 1.0, u.shape))
    base = np.asarray(base)
    slot = base[:, None, :] if extra is None else np.asarray(extra, base.dtype).reshape(base.shape[0], -1, base.shape[1])
    return np.concatenate([base[:, None, :] + local.astype(base.dtype)[None],
                           np.broadcast_to(spread.astype(base.dtype), (base.shape[0],) + spread.shape), slot], axis=1)


def ndf_widths(table, diffuse=0.0):
    """Microfacet widths (entries of :data:`WIDTH_ENTRIES`, floats) from the distribution of normals
    extracted off the table's retro-reflection (:func:`~matfit.microfacet.ndf_start`, Dupuy et al.
    2015), after subtracting a ``diffuse`` floor (1/sr); None for a table without enough rows near
    backscattering or nothing above the floor there.

    ``alpha`` is the GGX width of least misfit and ``alpha_base`` = ``alpha_coat`` = ``alpha``;
    where the extraction suggests two lobes, ``alpha`` and ``alpha_coat`` are the narrow lobe's width
    (the peak, which dominates a least-squares fit; a clear coat over a rougher layer) and
    ``alpha_base`` the wide one's. Only the rows near backscattering are read (a few percent of a
    MERL table, one dot product per row)."""
    try:
        # a start needs no 1e-6 fixed point: fewer iterations bound the cost on noisy tables
        s = ndf_start(table, diffuse=diffuse, max_iter=30, tol=1e-5)
    except ParameterError:  # no (or too few) rows near backscattering, nothing above the floor
        return None
    alpha = float(s["alpha"])
    narrow, wide = (float(a) for a in s["two_lobe"]["alpha"]) if s["lobes"] == 2 else (alpha, alpha)
    if not np.all(np.isfinite([alpha, narrow, wide])):
        return None
    return {"alpha": narrow, "alpha_base": wide, "alpha_coat": narrow}


def fit_starts(table, par, n, seed, objective, arrays, init=None):
    """The ``n`` starts that :func:`~matfit.fitting.fit` runs: the data-driven guess (``init``'s
    values replacing its entries), then the best screened candidates (:func:`screened_starts`).
    With ``n > 1`` and :data:`NDF_CANDIDATE`, one more candidate, screened like the others, is the
    guess with the widths of :func:`ndf_widths`, where the table gives them, the family reads them
    and the start differs from the first.

    Parameters
    ----------
    table, par : matfit.Table, Parametrization
        The table; the family, channels and fixed parameters.
    n, seed : int
        Number of starts; seed of the candidates.
    objective : callable
        ``objective(zs, arrays)``: the fit's objective for a stack of ``z``.
    arrays : tuple
        The table's ``(wo, wi, values, weight)`` as JAX arrays.
    init : mapping, optional
        Values replacing entries of the data-driven guess.

    Returns
    -------
    jax.Array (n, p)
        Unconstrained starts, the data-driven one first.
    """
    # the table's arrays and features once: the ndf candidate below is a second guess of them
    arrays_np = _stacked([table])
    features = table_features(*arrays_np, one=True)
    g = {k: v[0] for k, v in guesses_from_arrays(*arrays_np, par, one=True, features=features).items()}
    if init is not None:
        g.update(init)
    to_z = compiled_helpers(par)["z_from_theta"]
    base = np.asarray(to_z(g)).astype(arrays[0].dtype)[None]
    extra = None
    reads_widths = par.family.refine is not None or any(p.name in WIDTH_ENTRIES for p in par.free)
    if n > 1 and NDF_CANDIDATE and reads_widths:
        widths = ndf_widths(table, np.asarray(g["albedo"], float) / np.pi if "albedo" in g else 0.0)
        if widths is not None:
            gn = {k: v[0] for k, v in guesses_from_arrays(*arrays_np, par, one=True, widths=widths,
                                                          features=features).items()}
            gn.update(init or {})
            zn = np.asarray(to_z(gn)).astype(base.dtype)[None]
            if np.all(np.isfinite(zn)) and not np.allclose(zn, base):
                extra = zn[:, None, :]
    return screened_starts(objective, par, base, n, seed, arrays, extra=extra)[0]


def screened_starts(objective, par, base, n, seed, arrays, batched=False, extra=None):
    """Starts per table, (B, n, p): the data-driven start ``base`` (B, p) first, then the ``n - 1``
    candidates of :func:`candidates` (``extra`` (B, k, p) more of them, where given) with the
    lowest objective on the table (one vectorized evaluation of the fit's own objective; multi-start without the cost of
    ``n`` full solves from blind perturbations, which for layered and metal families mostly end at
    a bound)."""
    base = np.asarray(base)
    if n <= 1:
        return jnp.asarray(base[:, None, :])
    cand = candidates(par, base, n - 1, seed, extra)  # numpy: no eager JAX operations to dispatch
    if batched:
        (c, a), nb = shard_batch((jnp.asarray(cand), arrays))
        obj = np.asarray(batched_run(objective)(c, a)[:nb])
    else:
        obj = np.asarray(objective(jnp.asarray(cand[0]), arrays))[None]
    obj = np.where(np.isfinite(obj), obj, np.inf)
    if extra is None:  # the empty extra slot (a copy of base) is never a start
        obj[:, -1] = np.inf
    best = np.argsort(obj, axis=1, kind="stable")[:, : n - 1]
    return jnp.asarray(np.concatenate([base[:, None, :], np.take_along_axis(cand, best[:, :, None], axis=1)], axis=1))


@functools.lru_cache(maxsize=64)
def compiled_helpers(par):
    """Jitted helpers of a (cached) :class:`Parametrization`: ``z_from_theta`` and ``post(zb, z,
    zs)`` -> the natural values of ``zb``, the diagonal of their Jacobian in ``z``, the natural
    values of the starts ``z`` and ``zs``, every parameter's value and the model at ``zb``. One
    compiled call each, instead of dozens of small eagerly dispatched operations per fit."""

    def post(zb, z, zs):
        return {"values": par.theta_vector(zb), "dtheta": jnp.diag(jax.jacfwd(par.theta_vector)(zb)),
                "starts": par.theta_vector(z), "sub_starts": par.theta_vector(zs),
                "theta": par.full(par.theta(zb)), "model": par.model(zb)}

    return {"z_from_theta": jax.jit(par.z_from_theta), "post": jax.jit(post)}
