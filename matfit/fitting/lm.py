r"""Levenberg-Marquardt on the normal equations with a grouped forward-difference Jacobian.

The fast solver behind ``fit(..., method="lm_fd")`` for large tables (a full MERL table has
about 1.1 million valid cells, 3.3 million residuals) and for many small batched fits. One call
is one XLA ``while_loop``; every iteration costs a few evaluations of the model on the table and
a :math:`p \times p` solve, never an :math:`N \times p` factorization. This docstring describes
the algorithm, which :class:`LevenbergMarquardtFD` implements in one loop; :func:`lm_fd`
documents its options.

Jacobian (``_jacobian``, :func:`normal_equations`)
    By forward differences, :math:`J_{:,j} \approx (r(z + h_j e_j) - r(z))/h_j` with
    :math:`h_j = \sqrt{\epsilon}\,\max(1, |z_j|)` (the rule of ``scipy.optimize.least_squares``
    and MINPACK), or central differences (``eps^(1/3)`` steps, two evaluations per group) in
    float32. Columns are grouped (Curtis, Powell & Reid 1974): the per-channel parameters of one
    name (``albedo[0..C-1]``, ``eta[0..C-1]``) affect disjoint colour channels (every model's
    channels are independent in ``eval``), so one evaluation perturbs all of them at once. A
    family with ``G`` parameter names needs ``G`` extra evaluations per Jacobian (forward
    differences), whatever ``C``. Forward-mode AD (``jax.jacfwd``) gives the same matrix to
    rounding but compiles on XLA's CPU backend into many partly recomputed loops, much slower
    than the evaluations it replaces (see ``docs/performance.md``).

Channel-split residuals
    ``fn`` may return the residuals as one ``(N, C)`` array or as a tuple of ``C`` arrays
    ``(n,)``, one per colour channel (``fit`` does so for the models :mod:`matfit.fast` lays
    out as structures of arrays). Split, every evaluation is ``C`` single-output loops, the ``G``
    perturbed points are evaluated one after the other instead of under ``vmap``, and each
    channel's Gram matrix of ``[K_0 .. K_{G-1}, r]`` is a blocked reduction, which a full MERL
    conductor iteration runs several times faster (``docs/performance.md``). On a small table
    (:data:`SMALL_TABLE`) the ``G`` points are the iterations of one loop, so the model is
    compiled once instead of ``G`` times: there compilation, not the solve, is the fit's time.

Normal equations (:func:`normal_equations`)
    With the compressed differences :math:`K_c` (rows x groups) of channel ``c`` and the map
    :math:`E_c` from groups to parameters (``1/h_j`` where parameter ``j`` of group ``g`` acts
    on channel ``c``): :math:`J^T J = \sum_c E_c^T (K_c^T K_c) E_c`,
    :math:`J^T r = \sum_c E_c^T K_c^T r_c`.

Steps (``_step``, ``_damping``)
    After Nielsen 1999 and Madsen, Nielsen & Tingleff 2004, Alg. 3.16, with Marquardt's scaling:
    :math:`(J^TJ + \mu D)\,\delta = -J^Tr`, :math:`D` the largest diagonal of :math:`J^TJ` seen
    so far (Moré 1978: a parameter whose sensitivity vanishes, e.g. at a bound, keeps a finite
    damping), :math:`\mu = \tau`, :math:`\nu = 2` at the start; the gain ratio
    :math:`\rho = (F(z) - F(z+\delta)) / (\tfrac12\delta^T(\mu D\delta - J^Tr))` accepts the step
    when positive and updates :math:`\mu \leftarrow \mu\max(1/3, 1-(2\rho-1)^3)`,
    :math:`\nu \leftarrow 2`, else :math:`\mu \leftarrow \mu\nu`, :math:`\nu \leftarrow 2\nu`.
    Every iteration is one trial step and, when it was accepted, the Jacobian at the point it
    reached (one flat loop, fast under ``vmap``); the first iteration evaluates the start itself,
    so that the model's residuals and Jacobian appear once each in the compiled program. No
    coordinate of ``z`` moves by more than ``max_step`` (default 3) in one step (a coordinate
    that would go further is held at ``max_step`` and the others are solved again given it,
    :func:`_box_step`; the gain ratio uses the general predicted decrease
    :math:`-g^T\delta - \tfrac12\delta^TJ^TJ\delta`): a sigmoid-mapped parameter whose
    Gauss-Newton step would throw it deep into saturation, where its derivative vanishes for
    good, gets there only if the objective keeps agreeing (on a full MERL conductor table the
    unlimited first step set ``k`` to exactly 0 and ended 0.2 % above the minimum found with the
    cap). With ``extrapolate=True`` (``fit`` sets it for the solves of a large table) an accepted
    step whose gain ratio exceeds 1.25 is followed by one evaluation at the minimum of the
    parabola through :math:`F(z)`, :math:`g^T\delta` and :math:`F(z+\delta)` along the step
    (factor in [1, 4]), kept when lower (:func:`_extrapolated`): a large-residual problem's
    Gauss-Newton model can overestimate the curvature, and its steps then go part of the way.

Secant model (``secant=True``, which ``fit`` also sets for a large table)
    The Hessian of :math:`F` is :math:`J^TJ + S`, :math:`S = \sum_i r_i \nabla^2 r_i`; Gauss-
    Newton drops :math:`S`, and where the residuals stay large (a measured table that no model of
    the family fits to its noise) it converges only linearly. As NL2SOL (Dennis, Gay & Welsch
    1981) the solver keeps a secant estimate of :math:`S`, updated after every accepted step so
    that :math:`S\delta = y^\#`, :math:`y^\# = g_{new} - g - J^TJ\delta` (the change of the
    gradient that :math:`J^TJ` does not explain), and steps with :math:`J^TJ + S` while that
    model predicted the last decrease better than :math:`J^TJ` alone and its damped matrix is
    positive definite. On a full MERL plastic table (white-paint) the whole-table solve took 29
    accepted steps in float64 without it and 11-12 with it, to a lower objective. ``fit`` starts
    that solve with the damping and the secant model of its subset solution (``warm``; ``S``
    scaled by the ratio of the two ``J^T J`` traces, both sums over rows): 4 steps.

Stopping (``_stops``)
    ``converged`` after an accepted step with gain ratio above 1/4 that lowered the objective by at
    most ``max(rtol, 4 eps) * F + atol`` or moved ``z`` by at most ``rtol (rtol + |z|)`` (2-norms):
    the ``ftol``/``xtol`` rule of ``scipy.optimize.least_squares``, either one sufficing (a
    parameter drifting towards a bound through a saturating sigmoid keeps taking steps of constant
    length while the objective has stopped changing); after the first trial step from a point,
    accepted or not, whose actual and predicted changes of the objective are both within
    ``max(rtol, 4 eps) * F + atol`` (MINPACK's ``ftol`` test, Moré 1978: the quadratic model has
    nothing left to gain; in float32 a converged fit's next trial steps are rejected for
    rounding, and would otherwise run on to ``max_reject``); after a rejected trial step no longer
    than ``t (t + |z|)``, ``t = max(rtol, 4 eps)`` (scipy's ``xtol`` test, which it applies while
    its trust region shrinks: the damping has made the step too short to move ``z``); when the
    gradient's largest entry is at most ``atol`` (at the start too); or when no decrease is
    possible any more (``max_reject`` consecutive rejected steps: the objective is at its
    floating-point floor). Otherwise the loop stops after ``max_steps`` Jacobians.

References
----------
- K. Levenberg, Q. Appl. Math. 2(2), 1944; D. W. Marquardt, J. SIAM 11(2), 1963.
- H. B. Nielsen, "Damping parameter in Marquardt's method", IMM-REP-1999-05, DTU, 1999.
- K. Madsen, H. B. Nielsen, O. Tingleff, "Methods for Non-Linear Least Squares Problems", 2004.
- J. J. Moré, "The Levenberg-Marquardt algorithm: implementation and theory", Numerical
  Analysis, Lecture Notes in Mathematics 630, 1978.
- A. R. Curtis, M. J. D. Powell, J. K. Reid, "On the estimation of sparse Jacobian matrices",
  J. Inst. Maths Applics 13, 1974.
- J. E. Dennis, D. M. Gay, R. E. Welsch, "An adaptive nonlinear least-squares algorithm",
  ACM Trans. Math. Software 7(3), 1981 (NL2SOL).
- S. S. Oren, D. G. Luenberger, "Self-scaling variable metric (SSVM) algorithms", Management
  Science 20(5), 1974.
"""

from __future__ import annotations

from typing import NamedTuple, Optional

import equinox as eqx
import jax
import jax.export
import jax.numpy as jnp
import numpy as np

__all__ = ["column_groups", "jacobian", "lm_fd", "Solution", "normal_equations", "GRAM_BLOCK", "half_sq", "LevenbergMarquardtFD",
           "widen"]

#: Column block of the channel-split Gram reductions; channel-split residuals padded to a
#: multiple of it take the blocked path (:func:`_gram`).
GRAM_BLOCK = 512
#: Residual count up to which a table counts as small: perturbed points evaluated one by one and
#: moments summed elementwise (:func:`_differences`, :func:`_moments`); channel-split, its column
#: groups evaluated in a loop (:func:`_channel_moments`: the model compiled once, not once per group).
SMALL_TABLE = 4096


def column_groups(par):
    """Seeds and channel masks of the grouped Jacobian for a :class:`~matfit.fitting.Parametrization`.

    Parameters
    ----------
    par : Parametrization

    Returns
    -------
    seeds : numpy.ndarray (G, p)
        A 1 for every parameter perturbed by evaluation ``g`` (one group per parameter name).
    owner : numpy.ndarray (C, p)
        A 1 where parameter ``j`` acts on channel ``c`` (all channels for shared or tied
        parameters, channel ``i`` only for ``name[i]``).

    Examples
    --------
    >>> from matfit.fitting import Parametrization
    >>> from matfit.fitting.lm import column_groups
    >>> seeds, owner = column_groups(Parametrization("plastic", 3))
    >>> seeds.tolist()
    [[1.0, 1.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 0.0, 1.0]]
    >>> owner[1].tolist()
    [0.0, 1.0, 0.0, 1.0, 1.0]
    """
    C, p = par.channels, par.size
    seeds, owner, i = [], np.ones((C, p)), 0
    for prm, n in zip(par.free, par.sizes):
        s = np.zeros(p)
        s[i:i + n] = 1
        seeds.append(s)
        if n == C and C > 1:
            owner[:, i:i + n] = np.eye(C)
        i += n
    return np.array(seeds), owner


def _steps(z, central):
    eps = jnp.finfo(z.dtype).eps
    base = eps ** (1 / 3) if central else jnp.sqrt(eps)
    return base * jnp.maximum(1.0, jnp.abs(z))


def _differences(fn, z, args, seeds, owner, central, r, stacked=True):
    """Compressed differences ``K``, the group-to-parameter map ``E`` (C, G, p) and ``r``.

    ``stacked``: ``K`` is one array (G, N, C) from one vmapped evaluation of the G perturbed points
    (large tables: the model appears once in the program, what depends only on the directions is
    computed once). Else a list of G arrays (N, C) evaluated one after the other (small tables,
    where the stacked layout under ``vmap`` was measured slower, ``docs/performance.md``).
    """
    seeds = jnp.asarray(seeds, z.dtype)
    owner = jnp.asarray(owner, z.dtype)
    if r is None:
        r = fn(z, args)
    h = _steps(z, central)
    D = seeds * h
    diff = (lambda d: fn(z + d, args) - fn(z - d, args)) if central else (lambda d: fn(z + d, args) - r)
    K = jax.vmap(diff)(D) if stacked else [diff(d) for d in D]
    return K, group_map(seeds, owner, h, central), r


def _shifted(z, seed, h):
    """``z + seed * h`` for a constant 0/1 group ``seed``, assembled from slices of ``z``, so that XLA
    sees what the perturbed evaluations share (a rough conductor's lobe, which depends on ``alpha``
    only, is computed once for the ``eta`` and ``k`` groups). A traced ``seed`` takes the plain sum.
    """
    try:
        on = np.asarray(seed) != 0
    except jax.errors.TracerArrayConversionError:
        return z + jnp.asarray(seed, z.dtype) * h
    cuts = np.flatnonzero(np.diff(on.astype(int))) + 1
    parts = []
    for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, on.size]):
        parts.append(z[lo:hi] + h[lo:hi] if on[lo] else z[lo:hi])
    return jnp.concatenate(parts)


def group_map(seeds, owner, h, central):
    """``E`` (C, G, p): column ``j`` of channel ``c`` is ``K[g] / h_j`` for the group ``g`` of ``j``."""
    return seeds[None, :, :] * owner[:, None, :] / ((2 * h) if central else h)


def _gram(xs):
    """Gram matrix ``[x_i . x_j]`` (m, m) of ``m`` arrays (n,), each product summed over blocks of
    ``GRAM_BLOCK`` lanes first (n a multiple of it): on a full MERL table faster than XLA's CPU dot
    or one reduction over the stacked arrays (``docs/performance.md``).
    """
    if xs[0].shape[0] % GRAM_BLOCK:
        X = jnp.stack(xs)
        return X @ X.T
    return _pairwise([x.reshape(-1, GRAM_BLOCK) for x in xs], lambda a, b: jnp.sum(jnp.sum(a * b, axis=0)))


def _pairwise(xs, prod):
    """The symmetric matrix ``[prod(x_i, x_j)]`` over the arrays ``xs``, each product computed once
    (``i <= j``), on the last two axes (leading axes: those of ``prod``'s result)."""
    m = len(xs)
    v = {(i, j): prod(xs[i], xs[j]) for i in range(m) for j in range(i, m)}
    return jnp.stack([jnp.stack([v[min(i, j), max(i, j)] for j in range(m)], -1) for i in range(m)], -2)


def widen(x):
    """``x`` in float64 when x64 is on (else unchanged): for moments read by covariances.

    Parameters
    ----------
    x : jax.Array

    Returns
    -------
    jax.Array
    """
    return x.astype(jnp.promote_types(x.dtype, jnp.float64)) if jax.config.read("jax_enable_x64") else x


def _channel_moments(fn, z, args, seeds, owner, central, r, wide=False):
    """Channel-split residuals (a tuple of C arrays (n,)): ``M`` (C, G, G), ``v`` (C, G), ``E``, ``r``.

    The G perturbed points are evaluated one after the other (no vmap: each channel stays one
    single-output loop; a small table's in a ``lax.map``, one copy of the model in the program,
    else unrolled, where XLA shares what the points have in common); their differences are
    materialized (an optimization barrier: else XLA fuses the model into every product of the Gram
    matrix and recomputes it there), and each channel's Gram matrix of ``[K_0 .. K_{G-1}, r]`` is
    one blocked reduction.
    """
    if r is None:
        r = tuple(fn(z, args))
    h = _steps(z, central)
    G = len(seeds)
    cast = widen if wide else (lambda x: x)
    if r[0].shape[0] * len(r) <= SMALL_TABLE:
        # a small table: the groups one after the other in a loop, so that the model is compiled
        # once, not once per group (compilation is most of a small fit's time)
        def one(seed):
            plus = fn(z + seed * h, args)
            base = fn(z - seed * h, args) if central else r
            return jnp.stack([a - b for a, b in zip(plus, base)])

        K = jax.lax.map(one, jnp.asarray(seeds, z.dtype))  # (G, C, n): K[g][c] as below
    else:
        K = []
        for seed in seeds:
            plus = fn(_shifted(z, seed, h), args)
            base = fn(_shifted(z, seed, -h), args) if central else r
            K.append(tuple(a - b for a, b in zip(plus, base)))
        K, r = jax.lax.optimization_barrier((K, tuple(r)))
    P = jnp.stack([_gram([cast(K[g][c]) for g in range(G)] + [cast(r[c])]) for c in range(len(r))])
    E = group_map(jnp.asarray(seeds, z.dtype), jnp.asarray(owner, z.dtype), h, central)
    return P[:, :G, :G], P[:, :G, G], E, r


def _moments(K, r):
    """``M = [K_g . K_h]`` (C, G, G) and ``v = [K_g . r]`` (C, G) per channel.

    ``K`` stacked (G, N, C) takes XLA's dot (faster on a full MERL table). ``K`` a list (small
    tables, the texels of ``fit_batch`` under ``vmap``) takes one elementwise product and sum per
    pair after an optimization barrier (else XLA may fuse the model into every product): XLA's CPU
    batched dot of such tiny matrices was measured slower (``docs/performance.md``, "Batched texel
    fits").
    """
    if not isinstance(K, (list, tuple)):
        return jnp.einsum("gnc,hnc->cgh", K, K), jnp.einsum("gnc,nc->cg", K, r)
    K, r = jax.lax.optimization_barrier((list(K), r))
    M = _pairwise(K, lambda a, b: jnp.sum(a * b, axis=0))
    return M, jnp.stack([jnp.sum(k * r, axis=0) for k in K], -1)


def _split(r):
    """True for channel-split residuals (a tuple of per-channel arrays)."""
    return isinstance(r, (tuple, list))


def normal_equations(fn, z, args, seeds, owner, central=False, r=None, F=None, wide=False):
    """``(F, J^T J, J^T r, r)`` at ``z``: the grouped differences of the module docstring reduced
    straight to the moments (never an ``N x p`` matrix).

    Parameters
    ----------
    fn, args, seeds, owner
        As for :func:`lm_fd`.
    z : jax.Array (p,)
        The point.
    central : bool, default False
        Central differences.
    r, F : optional
        The residuals (and ``F = 0.5 |r|^2``) at ``z`` when already known.
    wide : bool, default False
        As for :func:`lm_fd` (``g`` is summed so too).

    Returns
    -------
    F : jax.Array
        ``0.5 |r|^2``.
    A, g : jax.Array (p, p), (p,)
        ``J^T J`` and ``J^T r``.
    r : jax.Array or tuple
        The residuals, in ``fn``'s layout.
    """
    r_like = r if r is not None else jax.eval_shape(fn, z, args)
    if _split(r_like):
        M, v, E, r = _channel_moments(fn, z, args, seeds, owner, central, r, wide)
    else:
        N, C = r_like.shape[-2:]
        K, E, r = _differences(fn, z, args, seeds, owner, central, r, stacked=N * C > SMALL_TABLE)
        M, v = _moments(*(jax.tree_util.tree_map(widen, (K, r)) if wide else (K, r)))
    if wide:
        E = widen(E)
    A = jnp.einsum("cgp,cgh,chq->pq", E, M, E)
    g = jnp.einsum("cgp,cg->p", E, v)
    return (half_sq(r) if F is None else F), A, g, r


def half_sq(r):
    """``0.5 |r|^2`` of residuals in either layout, summed in float64 when available (a float32 sum
    over millions of residuals loses the digits that decide whether a step is accepted).

    Parameters
    ----------
    r : jax.Array or tuple of jax.Array
        One array, or one per channel.

    Returns
    -------
    jax.Array
        A scalar in ``r``'s dtype.
    """
    if _split(r):
        return sum(half_sq(rc) for rc in r)
    acc = jnp.promote_types(r.dtype, jnp.float64) if jax.config.read("jax_enable_x64") else r.dtype
    rr = r.astype(acc)
    return (0.5 * jnp.sum(rr * rr)).astype(r.dtype)


def jacobian(fn, z, args, seeds, owner, central=None):
    """The residuals and the grouped-difference Jacobian at ``z``, materialized (for tests and small
    problems; solvers use :func:`normal_equations`).

    Parameters
    ----------
    fn, args, seeds, owner, central
        As for :func:`lm_fd` (channel-split residuals are stacked to (n, C)).
    z : jax.Array (p,)
        The point.

    Returns
    -------
    r : jax.Array (N, C)
    J : jax.Array (N, C, p)
    """
    central = (z.dtype == jnp.float32) if central is None else bool(central)
    if _split(jax.eval_shape(fn, z, args)):
        fn = _stacked(fn)
    K, E, r = _differences(fn, z, args, seeds, owner, central, None)
    return r, jnp.einsum("gnc,cgp->ncp", K, E)


def _stacked(fn):
    return lambda z, args: jnp.stack(fn(z, args), axis=-1)


def _spd_solve(B, b):
    """``B^{-1} b`` for a small symmetric positive definite ``B``: Cholesky (no pivoting needed, Golub
    & Van Loan 4.2), unrolled over the static ``p``. Under ``vmap`` it is a few fused elementwise
    loops; ``jnp.linalg.solve`` calls LAPACK once per member (one call per texel per solve).
    """
    p = B.shape[-1]
    tiny = jnp.finfo(B.dtype).tiny
    L = {}
    for j in range(p):
        d = jnp.sqrt(jnp.maximum(B[j, j] - sum((L[j, k] ** 2 for k in range(j)), 0.0), tiny))
        L[j, j] = d
        for i in range(j + 1, p):
            L[i, j] = (B[i, j] - sum((L[i, k] * L[j, k] for k in range(j)), 0.0)) / d
    y = []
    for i in range(p):
        y.append((b[i] - sum((L[i, k] * y[k] for k in range(i)), 0.0)) / L[i, i])
    x = [None] * p
    for i in reversed(range(p)):
        x[i] = (y[i] - sum((L[k, i] * x[k] for k in range(i + 1, p)), 0.0)) / L[i, i]
    return jnp.stack(x)


def _box_step(B, g, cap, passes=3):
    """The damped step ``B delta = -g`` with no coordinate beyond ``cap``: an active-set projection.

    A coordinate outside the box is held on its face (``sign * cap``) and the others are solved
    again given it (``passes`` rounds; once held, held); what is still outside is then scaled in.
    Scaling the whole step instead lets one saturated parameter, whose vanishing derivative asks
    for a huge step, freeze all the others (on a full MERL nickel table the fit stopped after one
    step at 1e-5 above the minimum). Where the damped model ``g.d + d.B.d / 2`` does not fall
    along the result, the whole step scaled into the box (which always descends) is taken.
    """
    eye = jnp.eye(B.shape[-1], dtype=B.dtype)
    delta = _spd_solve(B, -g)
    if not np.isfinite(cap):
        return delta

    def hold(c):
        i, d = c
        held = jnp.abs(d) >= cap * (1 - 1e-6)
        face = jnp.where(held, jnp.clip(d, -cap, cap), 0)
        # rows of held coordinates become delta_j = face_j; the free rows move B's held columns
        # to the right-hand side
        Bh = jnp.where(held[:, None], eye, jnp.where(held[None, :], 0, B))
        return i + 1, _spd_solve(Bh, jnp.where(held, face, -g - B @ face))

    def outside(c):  # a pass only while some coordinate is outside (under vmap: of any member)
        i, d = c
        return (i < passes) & jnp.any(jnp.abs(d) > cap * (1 + 1e-6))

    def into_box(d):
        return d * jnp.minimum(1, cap / jnp.maximum(jnp.max(jnp.abs(d)), jnp.finfo(B.dtype).tiny))

    boxed = into_box(jax.lax.while_loop(outside, hold, (0, delta))[1])
    # Holding coordinates can, with strongly coupled ones, give a step along which the damped
    # model rises; the shortened step (direction kept) always descends: take it then.
    descends = jnp.dot(g, boxed) + 0.5 * jnp.dot(boxed, B @ boxed) < 0
    return jnp.where(descends, boxed, into_box(delta))


class _State(NamedTuple):
    z: jax.Array
    F: jax.Array
    A: jax.Array
    g: jax.Array
    r: jax.Array
    mu: jax.Array
    nu: jax.Array
    steps: jax.Array
    evals: jax.Array
    done: jax.Array
    ok: jax.Array
    rejects: jax.Array
    D: jax.Array
    S: jax.Array
    aug: jax.Array
    fresh: jax.Array


def _extrapolated(fn, args, s, delta, z_new, r_new, F_new, try_it, cap):
    """The line extrapolation after a step that beat the model (module docstring, "Steps"):
    ``alpha`` clipped to [1, 4] and to the step cap, one evaluation, only where tried
    (``lax.cond``); returns ``(z, r, F)``. On a full MERL plastic table every step had gone half the
    way (gain ratio 1.49, steps halving) and the fit took 10 full-table iterations.
    """
    slope = jnp.dot(s.g, delta).astype(F_new.dtype)
    curv = F_new - s.F - slope
    alpha = jnp.where(curv > 0, -slope / (2 * jnp.where(curv > 0, curv, 1)), 1)
    top = cap / jnp.maximum(jnp.max(jnp.abs(delta)), jnp.finfo(delta.dtype).tiny)
    alpha = jnp.clip(alpha, 1, jnp.minimum(4, top)).astype(delta.dtype)

    def tried():
        z2 = s.z + alpha * delta
        r2 = fn(z2, args)
        F2 = half_sq(r2)
        better = jnp.isfinite(F2) & (F2 < F_new)
        return jax.tree_util.tree_map(lambda a, b: jnp.where(better, a, b), (z2, r2, F2), (z_new, r_new, F_new))

    return jax.lax.cond(try_it & (alpha > 1), tried, lambda: (z_new, r_new, F_new))


def _secant_update(s, step, g_new, F_new, accepted):
    """The secant model after a step (module docstring, "Secant model"): ``(S, aug)``, ``aug`` whether
    ``J^T J + S`` predicted this step's decrease better than ``J^T J`` (NL2SOL's model switch).

    ``S`` is sized by Oren & Luenberger's factor ``min(1, |d.y#| / |d.S.d|)`` and updated by the
    Dennis-Gay-Welsch formula. NL2SOL forms ``y#`` as ``(J_new - J)^T r_new``; with only the normal
    equations, ``y - J^T J d`` is its first-order equivalent. Skipped after a rejected step or where
    ``y.d`` is not positive.
    """
    d = step
    y = g_new - s.g
    ys = jnp.dot(y, d)
    dSd = jnp.dot(d, s.S @ d)
    ysharp = y - s.A @ d
    size = jnp.minimum(1, jnp.abs(jnp.dot(d, ysharp)) / jnp.where(dSd != 0, jnp.abs(dSd), 1))
    S = jnp.where(dSd != 0, size, 1) * s.S
    w = ysharp - S @ d
    ok = accepted & (ys > 1e-6 * jnp.linalg.norm(y) * jnp.linalg.norm(d)) & jnp.all(jnp.isfinite(w))
    ys = jnp.where(ok, ys, 1)
    S = S + (jnp.outer(w, y) + jnp.outer(y, w)) / ys - jnp.dot(w, d) * jnp.outer(y, y) / ys ** 2
    actual = s.F - F_new
    pred_gn = -jnp.dot(s.g, d) - 0.5 * jnp.dot(d, s.A @ d)
    pred_aug = pred_gn - 0.5 * dSd
    aug = jnp.where(accepted, jnp.abs(pred_aug - actual) < jnp.abs(pred_gn - actual), s.aug)
    return jnp.where(ok, S, s.S), aug


class Solution(NamedTuple):
    """What a solver returns (:func:`lm_fd`, every :class:`~matfit.fitting.methods.AbstractSolver`,
    and a fit's compiled multi-start program). Fields a solver does not compute are None.

    Attributes
    ----------
    z : jax.Array (p,)
        The solution.
    steps : jax.Array
        Accepted steps.
    converged : jax.Array of bool
        Whether a stopping test (not ``max_steps``) ended the loop.
    F : jax.Array
        ``0.5 |r|^2`` there.
    A : jax.Array (p, p)
        ``J^T J`` at ``z`` (for covariances).
    evals : jax.Array
        Model evaluations.
    r : jax.Array or tuple
        The residuals at ``z``, in ``fn``'s layout (flat in a multi-start solution).
    mu : jax.Array
        The damping at the end.
    S : jax.Array (p, p)
        The secant model of the second-order term (zeros without ``secant``).
    aug : jax.Array of bool
        Whether the next step would have used ``J^T J + S``.
    best : jax.Array
        A multi-start solution's lowest end: ``z``, ``steps``, ``converged`` and ``F`` are per
        start (leading axis), ``r`` and ``A`` are the best start's.
    sub : tuple or None
        A multi-start solution of a large table: ``(F, z)`` of the starts on its subset.

    Examples
    --------
    >>> import numpy as np, jax.numpy as jnp
    >>> from matfit.fitting.lm import lm_fd
    >>> res = lm_fd(lambda z, a: (z - a)[None, :], jnp.zeros(1), jnp.ones(1), np.eye(1), np.ones((1, 1)))
    >>> float(res.F) < 1e-12, bool(res.converged), res.best is None
    (True, True, True)
    """

    z: jax.Array
    steps: jax.Array
    converged: jax.Array
    F: Optional[jax.Array] = None
    A: Optional[jax.Array] = None
    evals: Optional[jax.Array] = None
    r: object = None
    mu: Optional[jax.Array] = None
    S: Optional[jax.Array] = None
    aug: Optional[jax.Array] = None
    best: Optional[jax.Array] = None
    sub: Optional[tuple] = None


# a compiled solve's traced program, which returns a Solution, is kept across processes
# (matfit.cache.persistent_jit: jax.export serializes only the pytree types it was told of)
jax.export.register_namedtuple_serialization(Solution, serialized_name="matfit.fitting.lm.Solution")


class LevenbergMarquardtFD(eqx.Module):
    """Levenberg-Marquardt on streamed normal equations: the algorithm of the module docstring
    (Jacobian, steps, damping, stopping) in one solver; its options are its fields, described
    at :func:`lm_fd`.

    Parameters
    ----------
    rtol, atol : float
    max_steps : int, default 100
    central : bool, optional
    max_reject : int, default 12
    tau : float, default 1e-3
    max_step : float, default 3.0
    wide, extrapolate, secant : bool, default False
        As for :func:`lm_fd`.

    Examples
    --------
    >>> import numpy as np, jax.numpy as jnp
    >>> from matfit.fitting.lm import LevenbergMarquardtFD
    >>> x = jnp.linspace(0.0, 1.0, 20)
    >>> res = LevenbergMarquardtFD(1e-8, 1e-10).minimise(lambda z, x: (z[0] * x - 2 * x)[:, None], jnp.array([0.0]), x,
    ...                                                  np.eye(1), np.ones((1, 1)))
    >>> round(float(res.z[0]), 6), bool(res.converged)
    (2.0, True)
    """

    rtol: float = eqx.field(static=True)
    atol: float = eqx.field(static=True)
    max_steps: int = eqx.field(default=100, static=True)
    central: Optional[bool] = eqx.field(default=None, static=True)
    max_reject: int = eqx.field(default=12, static=True)
    tau: float = eqx.field(default=1e-3, static=True)
    max_step: float = eqx.field(default=3.0, static=True)
    wide: bool = eqx.field(default=False, static=True)
    extrapolate: bool = eqx.field(default=False, static=True)
    secant: bool = eqx.field(default=False, static=True)

    def is_central(self, dtype) -> bool:
        """Whether differences are central for parameters of ``dtype`` (default: in float32)."""
        return (jnp.dtype(dtype) == jnp.float32) if self.central is None else bool(self.central)

    def evaluations(self, n_groups, dtype) -> int:
        """Model evaluations per Jacobian beyond the point's residuals (twice ``n_groups`` when central)."""
        return 2 * n_groups if self.is_central(dtype) else n_groups

    def _jacobian(self, fn, z, args, seeds, owner, r=None, F=None):
        """``(F, J^T J, J^T r, r)`` at ``z`` by grouped differences (module docstring, "Jacobian")."""
        return normal_equations(fn, z, args, seeds, owner, self.is_central(z.dtype), r=r, F=F, wide=self.wide)

    def _step(self, A, mu, D, g):
        """The damped Gauss-Newton step ``(J^T J + mu D) delta = -J^T r``, no coordinate beyond ``max_step``."""
        eye = jnp.eye(A.shape[-1], dtype=A.dtype)
        return _box_step(A + mu * D * eye, g, self.max_step)

    def _damping(self, mu, nu, accepted, rho):
        """Nielsen's (1999) ``(mu, nu)`` after a trial step, ``accepted`` or not, of gain ratio ``rho``."""
        mu = jnp.where(accepted, mu * jnp.maximum(1 / 3, 1 - (2 * rho - 1) ** 3), mu * nu)
        return mu, jnp.where(accepted, 2.0, 2 * nu)

    def _stops(self, s, delta, F_new, F_c, pred, rho, accepted, g, rejects):
        """Whether the loop ends after this trial step (module docstring, "Stopping")."""
        f_tol = max(self.rtol, 4 * float(jnp.finfo(s.z.dtype).eps))
        # Either test ends the loop after a step the quadratic model predicted well (scipy's
        # ftol/xtol rule); the objective's test cannot ask for less than the dtype resolves.
        step, size = jnp.linalg.norm(delta), jnp.linalg.norm(s.z)
        small_f = (s.F - F_c) <= f_tol * s.F + self.atol
        small_z = step <= self.rtol * (self.rtol + size)
        small_g = jnp.max(jnp.abs(g)) <= self.atol
        # MINPACK's ftol test (More 1978) on the first trial step from a point, accepted or not:
        # the actual and the predicted change both within the tolerance, so the quadratic model
        # has nothing left to gain (in float32 the rejected steps of a converged fit would
        # otherwise run up to max_reject). Not after rejections: a damping raised by them shrinks
        # the predicted change of any point.
        flat_f = (s.rejects == 0) & (jnp.abs(s.F - F_new) <= f_tol * s.F + self.atol) & (pred <= f_tol * s.F + self.atol)
        # scipy's xtol test on a rejected step too (its trust region shrinking below xtol): the
        # damping has shrunk the step below what z resolves, so no later trial can move it.
        tiny_step = ~accepted & (step <= f_tol * (f_tol + size))
        return ((accepted & (((small_f | small_z) & (rho > 0.25)) | small_g)) | flat_f | tiny_step
                | (rejects >= self.max_reject))

    def minimise(self, fn, z0, args, seeds, owner, warm=None) -> Solution:
        """Minimize ``0.5 |fn(z, args)|^2`` from ``z0`` (the arguments as for :func:`lm_fd`)."""
        z0 = jnp.asarray(z0)
        dt = z0.dtype
        max_steps = self.max_steps
        per_jac = self.evaluations(len(seeds), dt)
        # The start's normal equations are computed by the loop's first pass (``fresh``), in the
        # same evaluations as every accepted step's: the model appears in the compiled program
        # once per evaluation site, and compilation, not the solve, is most of a small fit's time.
        F0, A0, g0, r0 = jax.eval_shape(lambda: self._jacobian(fn, z0, args, seeds, owner))
        blank = lambda x: jnp.zeros(x.shape, x.dtype)  # noqa: E731  (overwritten by the first pass)
        mu0, nu0 = jnp.asarray(self.tau, dt), jnp.asarray(2.0, dt)
        if warm is not None:
            mu0 = jnp.asarray(warm.mu, mu0.dtype)
        s = _State(z0, jnp.asarray(jnp.inf, F0.dtype), blank(A0), blank(g0), jax.tree_util.tree_map(blank, r0), mu0, nu0,
                   jnp.asarray(0), jnp.asarray(0), jnp.asarray(False), jnp.asarray(False), jnp.asarray(0),
                   jnp.ones(A0.shape[0], A0.dtype), blank(A0), jnp.asarray(False), jnp.asarray(True))

        # One flat loop: every iteration is one trial step and the Jacobian at the (possibly
        # unchanged) point. Under vmap (batched fits) a nested loop of rejections would make every
        # member wait for the slowest one's rejections at every step; the flat loop costs at most
        # the largest number of iterations of any member.
        def cond(s):
            # the first pass (the start's own evaluation) always runs
            return s.fresh | ((~s.done) & (s.steps < max_steps) & (s.evals < (4 * max_steps + 1) * (1 + per_jac)))

        def body(s):
            H = s.A
            if self.secant:  # the augmented model where it is chosen and its damped matrix is definite
                Ha = s.A + s.S
                H = jnp.where(s.aug & (jnp.linalg.eigvalsh(Ha + s.mu * jnp.diag(s.D))[0] > 0), Ha, s.A)
            # the first pass evaluates the start itself (no step) and takes its normal equations
            delta = jnp.where(s.fresh, 0, self._step(H, s.mu, s.D, s.g)).astype(dt)
            r_new = fn(s.z + delta, args)
            F_new = half_sq(r_new)
            pred = (-jnp.dot(s.g, delta) - 0.5 * jnp.dot(delta, H @ delta)).astype(dt)
            rho = (s.F - F_new) / jnp.where(pred > 0, pred, jnp.inf)
            step_ok = ~s.fresh & jnp.isfinite(F_new) & (F_new < s.F) & (rho > 0) & jnp.all(jnp.isfinite(delta))
            acc = step_ok | s.fresh
            mu, nu = self._damping(s.mu, s.nu, step_ok, rho)
            mu, nu = jnp.where(s.fresh, s.mu, mu), jnp.where(s.fresh, s.nu, nu)
            z_new = jnp.where(acc, s.z + delta, s.z)
            if self.extrapolate:
                z_new, r_new, F_new = _extrapolated(fn, args, s, delta, z_new, r_new, F_new, step_ok & (rho > 1.25),
                                                    self.max_step)
            # A rejected step leaves z, and so the Jacobian, unchanged (under vmap both branches run).
            F_c, A, g, r = jax.lax.cond(
                acc, lambda: self._jacobian(fn, z_new, args, seeds, owner, r=r_new, F=F_new),
                lambda: (s.F, s.A, s.g, s.r))
            rejects = jnp.where(acc, 0, s.rejects + 1)
            stop = jnp.where(s.fresh, jnp.max(jnp.abs(g)) <= self.atol,  # a start already at the minimum
                             self._stops(s, delta, F_new, F_c, pred, rho, step_ok, g, rejects))
            S, aug = s.S, s.aug
            if self.secant:
                S, aug = _secant_update(s, z_new - s.z, g, F_c, step_ok)
            if warm is not None:
                # a subset's S and J^T J both sum over its rows: S scales with the traces' ratio
                ratio = jnp.trace(A) / jnp.maximum(jnp.trace(warm.A), jnp.finfo(warm.A.dtype).tiny)
                S = jnp.where(s.fresh, (warm.S * ratio).astype(A.dtype), S)
                aug = jnp.where(s.fresh, jnp.asarray(warm.aug), aug)
            dA = jnp.diag(A)
            D = jnp.where(s.fresh, jnp.maximum(dA, jnp.finfo(dt).eps * jnp.max(dA) + jnp.finfo(dt).tiny),
                          jnp.maximum(s.D, dA))
            return _State(z_new, F_c, A, g, r, mu, nu, s.steps + step_ok.astype(s.steps.dtype),
                          s.evals + 1 + acc * per_jac, stop, stop, rejects, D, S, aug, jnp.asarray(False))

        s = jax.lax.while_loop(cond, body, s)
        return Solution(s.z, s.steps, s.ok, F=s.F, A=s.A, evals=s.evals, r=s.r, mu=s.mu, S=s.S, aug=s.aug)


def lm_fd(fn, z0, args, seeds, owner, max_steps=100, rtol=1e-8, atol=1e-10, central=None, max_reject=12,
          tau=1e-3, max_step=3.0, wide=False, extrapolate=False, secant=False, warm=None) -> Solution:
    """Minimize ``0.5 |fn(z, args)|^2`` from ``z0`` with a :class:`LevenbergMarquardtFD` of these
    options (the algorithm: the module docstring). This is where the solver's options are
    described; the solver and ``method="lm_fd"`` refer here.

    Parameters
    ----------
    fn : callable
        ``fn(z, args)``: ``(N, C)`` residuals, or a tuple of ``C`` arrays ``(n,)``
        (channel-split); traceable by JAX.
    z0 : array_like (p,)
        Starting point.
    args : pytree
        Passed through to ``fn``.
    seeds, owner : numpy.ndarray
        The column groups, from :func:`column_groups`.
    max_steps : int, default 100
        Maximum number of Jacobians (accepted steps).
    rtol, atol : float
        Stopping tolerances (module docstring, "Stopping").
    central : bool, optional
        Central differences (``eps^(1/3)`` steps); default: in float32 only.
    max_reject : int, default 12
        Consecutive rejected steps after which the objective counts as minimal.
    tau : float, default 1e-3
        Initial damping, relative to the diagonal of ``J^T J`` (Marquardt's scaling).
    max_step : float, default 3.0
        Largest change of any coordinate of ``z`` in one step (``np.inf``: no limit).
    wide : bool, default False
        Sum the moments ``J^T J``, ``J^T r`` in float64 (when x64 is on) at every Jacobian, and
        return ``A`` so: a float32 fit's ``A`` then serves covariances as a float64 one does.
    extrapolate : bool, default False
        After an accepted step that beat its predicted decrease by more than 25 %, try the line
        minimum along it (one more evaluation there). For single large fits; under ``vmap`` every
        member would pay the evaluation.
    secant : bool, default False
        Keep a secant estimate ``S`` of the second-order term that Gauss-Newton drops and step with
        ``J^T J + S`` while that model predicts the decreases better (NL2SOL): superlinear instead
        of linear convergence on a large-residual problem. For single large fits (a small symmetric
        eigenvalue problem per iteration checks that the damped model is definite).
    warm : Solution, optional
        A solution of the same problem on a subset of its rows (``fit``'s subset starts): its
        damping, and its secant model scaled by the ratio of the two ``J^T J`` traces, start this
        solve instead of ``tau`` and ``S = 0``.

    Returns
    -------
    Solution

    Examples
    --------
    >>> import numpy as np, jax.numpy as jnp
    >>> from matfit.fitting.lm import lm_fd
    >>> x = jnp.linspace(0.0, 2.0, 50)
    >>> fn = lambda z, x: (z[0] * jnp.exp(-z[1] * x) - 2.0 * jnp.exp(-1.5 * x))[:, None]
    >>> res = lm_fd(fn, jnp.array([1.0, 1.0]), x, np.eye(2), np.ones((1, 2)))
    >>> np.round(np.asarray(res.z), 6).tolist(), bool(res.converged)
    ([2.0, 1.5], True)
    """
    solver = LevenbergMarquardtFD(rtol, atol, max_steps, central, max_reject, tau, max_step, wide, extrapolate, secant)
    return solver.minimise(fn, z0, args, seeds, owner, warm=warm)
