r"""Levenberg-Marquardt on the normal equations with a grouped forward-difference Jacobian.

The fast solver behind ``fit(..., method="lm_fd")`` for large tables (a full MERL table has
about 1.1 million valid cells, 3.3 million residuals) and for many small batched fits. One call
is one XLA ``while_loop``; every iteration costs a few evaluations of the model on the table and
a :math:`p \times p` solve, never an :math:`N \times p` factorization.

Jacobian
    By forward differences, :math:`J_{:,j} \approx (r(z + h_j e_j) - r(z))/h_j` with
    :math:`h_j = \sqrt{\epsilon}\,\max(1, |z_j|)` (the rule of ``scipy.optimize.least_squares``
    and MINPACK), or central differences (``eps^(1/3)`` steps) in float32. Columns are grouped
    (Curtis, Powell & Reid 1974): the per-channel parameters of one name (``albedo[0..C-1]``,
    ``eta[0..C-1]``) affect disjoint colour channels (every model's channels are independent in
    ``eval``), so one evaluation perturbs all of them at once. A family with ``G`` parameter
    names needs ``G`` extra evaluations per Jacobian (forward differences), whatever ``C``.
    Forward-mode AD (``jax.jacfwd``) gives the same matrix to rounding but compiles on XLA's CPU
    backend into many partly recomputed loops, much slower than the evaluations it replaces
    (see ``docs/performance.md``).

Channel-split residuals
    ``fn`` may return the residuals as one ``(N, C)`` array or as a tuple of ``C`` arrays
    ``(n,)``, one per colour channel (``fit`` does so for the models :mod:`matfit.fast` lays
    out as structures of arrays). Split, every evaluation is ``C`` single-output loops, the ``G``
    perturbed points are evaluated one after the other instead of under ``vmap``, and each
    channel's Gram matrix of ``[K_0 .. K_{G-1}, r]`` is a blocked reduction, which a full MERL
    conductor iteration runs several times faster (``docs/performance.md``).

Normal equations
    With the compressed differences :math:`K_c` (rows x groups) of channel ``c`` and the map
    :math:`E_c` from groups to parameters (``1/h_j`` where parameter ``j`` of group ``g`` acts
    on channel ``c``): :math:`J^T J = \sum_c E_c^T (K_c^T K_c) E_c`,
    :math:`J^T r = \sum_c E_c^T K_c^T r_c`.

Steps (Nielsen 1999; Madsen, Nielsen & Tingleff 2004, Alg. 3.16, with Marquardt's scaling)
    :math:`(J^TJ + \mu D)\,\delta = -J^Tr`, :math:`D` the largest diagonal of :math:`J^TJ` seen
    so far (Moré 1978: a parameter whose sensitivity vanishes, e.g. at a bound, keeps a finite
    damping); the gain ratio
    :math:`\rho = (F(z) - F(z+\delta)) / (\tfrac12\delta^T(\mu D\delta - J^Tr))` accepts the step
    when positive and updates :math:`\mu \leftarrow \mu\max(1/3, 1-(2\rho-1)^3)`, else
    :math:`\mu \leftarrow \mu\nu`, :math:`\nu \leftarrow 2\nu`. Every iteration is one trial step
    and, when it was accepted, the Jacobian at the point it reached (one flat loop, fast under
    ``vmap``). No coordinate of ``z`` moves by more than ``max_step`` (default 3) in one step
    (a coordinate that would go further is held at ``max_step`` and the others are solved again
    given it, :func:`_box_step`; the gain ratio uses the general predicted decrease
    :math:`-g^T\delta - \tfrac12\delta^TJ^TJ\delta`): a sigmoid-mapped parameter
    whose Gauss-Newton step would throw it deep into saturation, where its derivative vanishes
    for good, gets there only if the objective keeps agreeing (on a full MERL conductor table the
    unlimited first step set ``k`` to exactly 0 and ended 0.2 % above the minimum found with the cap).
    With ``extrapolate=True`` (``fit`` sets it for the full solve of a large table) an accepted
    step whose gain ratio exceeds 1.25 is followed by one evaluation at the minimum of the
    parabola through :math:`F(z)`, :math:`g^T\delta` and :math:`F(z+\delta)` along the step
    (factor in [1, 4]), kept when lower (:func:`_extrapolated`): a large-residual problem's
    Gauss-Newton model can overestimate the curvature, and its steps then go part of the way.

Stopping
    ``converged`` after an accepted step with gain ratio above 1/4 that lowered the objective by at
    most ``max(rtol, 4 eps) * F + atol`` or moved ``z`` by at most ``rtol (rtol + |z|)`` (2-norms):
    the ``ftol``/``xtol`` rule of ``scipy.optimize.least_squares``, either one sufficing (a
    parameter drifting towards a bound through a saturating sigmoid keeps taking steps of constant
    length while the objective has stopped changing); after the first trial step from a point,
    accepted or not, whose actual and predicted changes of the objective are both within
    ``max(rtol, 4 eps) * F + atol`` (MINPACK's ``ftol`` test, Moré 1978: the quadratic model has
    nothing left to gain; in float32 a converged fit's next trial steps are rejected for
    rounding, and would otherwise run on to ``max_reject``); when the gradient's largest entry
    is at most ``atol``; or when no decrease is possible any more (``max_reject`` consecutive
    rejected steps: the objective is at its floating-point floor). Otherwise the loop stops
    after ``max_steps`` Jacobians.

References
----------
- K. Levenberg, Q. Appl. Math. 2(2), 1944; D. W. Marquardt, J. SIAM 11(2), 1963.
- H. B. Nielsen, "Damping parameter in Marquardt's method", IMM-REP-1999-05, DTU, 1999.
- K. Madsen, H. B. Nielsen, O. Tingleff, "Methods for Non-Linear Least Squares Problems", 2004.
- J. J. Moré, "The Levenberg-Marquardt algorithm: implementation and theory", Numerical
  Analysis, Lecture Notes in Mathematics 630, 1978.
- A. R. Curtis, M. J. D. Powell, J. K. Reid, "On the estimation of sparse Jacobian matrices",
  J. Inst. Maths Applics 13, 1974.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["column_groups", "jacobian", "lm_fd", "LMResult", "normal_equations", "GRAM_BLOCK"]

#: Column block of the channel-split Gram reductions; channel-split residuals padded to a
#: multiple of it take the blocked path (:func:`_gram`).
GRAM_BLOCK = 512
#: Residual count up to which a table counts as small: perturbed points evaluated one by one and
#: moments summed elementwise (:func:`_differences`, :func:`_moments`).
SMALL_TABLE = 4096


def column_groups(par):
    """Seeds and channel masks of the grouped Jacobian for a :class:`Parametrization`.

    Returns ``(seeds, owner)``: ``seeds`` (G, p) has a 1 for every parameter perturbed by
    evaluation ``g`` (one group per parameter name), ``owner`` (C, p) a 1 where parameter ``j``
    acts on channel ``c`` (all channels for shared or tied parameters, channel ``i`` only for
    ``name[i]``).
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

    ``stacked``: ``K`` is one array (G, N, C) from one vmapped evaluation of the G perturbed
    points (the model appears once in the program, and what depends only on the table's
    directions is computed once: large tables). Else ``K`` is a list of G arrays (N, C), the
    points evaluated one after the other (small tables, :data:`SMALL_TABLE`: under ``vmap``
    the stacked layout was measured slower, ``docs/performance.md``)."""
    seeds = jnp.asarray(seeds, z.dtype)
    owner = jnp.asarray(owner, z.dtype)
    if r is None:
        r = fn(z, args)
    h = _steps(z, central)
    D = seeds * h
    diff = (lambda d: fn(z + d, args) - fn(z - d, args)) if central else (lambda d: fn(z + d, args) - r)
    K = jax.vmap(diff)(D) if stacked else [diff(d) for d in D]
    return K, _group_map(seeds, owner, h, central), r


def _shifted(z, seed, h):
    """``z + seed * h`` for a 0/1 group ``seed`` (a constant), assembled from slices of ``z``: the
    coordinates outside the group are then ``z``'s own slices, and XLA recognizes what the
    perturbed evaluations share with each other (a rough conductor's lobe, which depends on
    ``alpha`` only, is computed once for the ``eta`` and ``k`` groups instead of once per group).
    A ``seed`` whose values are unknown while tracing takes the plain ``z + seed * h``."""
    try:
        on = np.asarray(seed) != 0
    except jax.errors.TracerArrayConversionError:
        return z + jnp.asarray(seed, z.dtype) * h
    cuts = np.flatnonzero(np.diff(on.astype(int))) + 1
    parts = []
    for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, on.size]):
        parts.append(z[lo:hi] + h[lo:hi] if on[lo] else z[lo:hi])
    return jnp.concatenate(parts)


def _group_map(seeds, owner, h, central):
    """``E`` (C, G, p): column ``j`` of channel ``c`` is ``K[g] / h_j`` for the group ``g`` of ``j``."""
    return seeds[None, :, :] * owner[:, None, :] / ((2 * h) if central else h)


def _gram(xs):
    """Gram matrix ``[x_i . x_j]`` (m, m) of ``m`` arrays (n,), one product per pair ``i <= j``,
    each summed over blocks of ``GRAM_BLOCK`` lanes first (n a multiple of it): on a full MERL
    table faster than XLA's CPU dot or a stack of the arrays followed by one reduction
    (``docs/performance.md``)."""
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
    """``x`` in float64 when x64 is on (else unchanged): for moments read by covariances."""
    return x.astype(jnp.promote_types(x.dtype, jnp.float64)) if jax.config.read("jax_enable_x64") else x


def _channel_moments(fn, z, args, seeds, owner, central, r, wide=False):
    """Channel-split residuals (a tuple of C arrays (n,)): ``M`` (C, G, G), ``v`` (C, G), ``E``, ``r``.

    The G perturbed points are evaluated one after the other (no vmap: each channel stays one
    single-output loop), their differences are materialized (an optimization barrier: otherwise
    XLA fuses the model into every product of the Gram matrix and recomputes it there), and each
    channel's Gram matrix of ``[K_0 .. K_{G-1}, r]`` is one blocked reduction."""
    if r is None:
        r = tuple(fn(z, args))
    h = _steps(z, central)
    K = []
    for seed in seeds:
        plus = fn(_shifted(z, seed, h), args)
        base = fn(_shifted(z, seed, -h), args) if central else r
        K.append(tuple(a - b for a, b in zip(plus, base)))
    K, r = jax.lax.optimization_barrier((K, tuple(r)))
    G = len(K)
    cast = widen if wide else (lambda x: x)
    P = jnp.stack([_gram([cast(Kg[c]) for Kg in K] + [cast(r[c])]) for c in range(len(r))])
    E = _group_map(jnp.asarray(seeds, z.dtype), jnp.asarray(owner, z.dtype), h, central)
    return P[:, :G, :G], P[:, :G, G], E, r


def _moments(K, r):
    """``M = [K_g . K_h]`` (C, G, G) and ``v = [K_g . r]`` (C, G) per channel, for differences ``K``
    and residuals ``r`` (N, C).

    ``K`` stacked (G, N, C) (large tables) takes XLA's dot. ``K`` a list of G arrays (N, C)
    (small tables, the texels of ``fit_batch``, where this runs under ``vmap``) takes one
    elementwise product and sum per pair, after an optimization barrier (else XLA may fuse the
    model into every product): XLA's CPU batched dot of such tiny matrices was measured slower
    than the products, while on a full MERL table the dot is faster than the elementwise form
    (``docs/performance.md``, "Batched texel fits")."""
    if not isinstance(K, (list, tuple)):
        return jnp.einsum("gnc,hnc->cgh", K, K), jnp.einsum("gnc,nc->cg", K, r)
    K, r = jax.lax.optimization_barrier((list(K), r))
    M = _pairwise(K, lambda a, b: jnp.sum(a * b, axis=0))
    return M, jnp.stack([jnp.sum(k * r, axis=0) for k in K], -1)


def _split(r):
    """True for channel-split residuals (a tuple of per-channel arrays)."""
    return isinstance(r, (tuple, list))


def normal_equations(fn, z, args, seeds, owner, central=False, r=None, F=None, wide=False):
    """``(F, J^T J, J^T r, r)`` at ``z`` for residuals ``fn(z, args)``.

    The residuals are one array (N, C), or a tuple of ``C`` arrays (n,) (one per colour channel:
    the channel-split layout of :mod:`matfit.fast`, which XLA compiles into single-output loops).
    ``F = 0.5 |r|^2``; the Jacobian is the grouped forward (or central) difference of the module
    docstring. ``r`` (and ``F``) may be passed when already known at ``z``. ``wide``: the
    moments are summed in float64 (when x64 is on) and ``A``, ``g`` returned so, for covariances.
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
    return (_half_sq(r) if F is None else F), A, g, r


def _half_sq(r):
    """0.5 |r|^2, summed in float64 when available (a float32 sum over millions of residuals
    loses the digits that decide whether a step is accepted); returned in r's dtype."""
    if _split(r):
        return sum(_half_sq(rc) for rc in r)
    acc = jnp.promote_types(r.dtype, jnp.float64) if jax.config.read("jax_enable_x64") else r.dtype
    rr = r.astype(acc)
    return (0.5 * jnp.sum(rr * rr)).astype(r.dtype)


def jacobian(fn, z, args, seeds, owner, central=None):
    """``(r, J)``: residuals (N, C) and the grouped-difference Jacobian (N, C, p) at ``z``
    (channel-split residuals are stacked to (n, C))."""
    central = (z.dtype == jnp.float32) if central is None else bool(central)
    if _split(jax.eval_shape(fn, z, args)):
        fn = _stacked(fn)
    K, E, r = _differences(fn, z, args, seeds, owner, central, None)
    return r, jnp.einsum("gnc,cgp->ncp", K, E)


def _stacked(fn):
    return lambda z, args: jnp.stack(fn(z, args), axis=-1)


def _spd_solve(B, b):
    """``B^{-1} b`` for a small symmetric positive definite ``B`` (p, p): Cholesky, unrolled over
    the static ``p``. Under ``vmap`` (a batch of texel fits) it is a few fused elementwise loops
    over the batch; ``jnp.linalg.solve`` calls LAPACK once per member there (one call per texel
    per solve). Cholesky needs no pivoting on such a
    matrix (Golub & Van Loan, Matrix Computations, 4th ed., 4.2)."""
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
    """The damped Gauss-Newton step ``B delta = -g`` with no coordinate beyond ``cap``.

    A coordinate whose solution leaves the box ``|delta_j| <= cap`` is held on the box's face
    (``sign * cap``) and the others are solved again given it (an active-set projection,
    ``passes`` rounds; a coordinate once held stays held). Scaling the whole step down instead
    (its direction kept) lets one saturated parameter, whose vanishing derivative asks for a
    huge step, freeze all the others: on a full MERL nickel table that stopped the fit after one
    step at 1e-5 above the minimum. Whatever is still outside the box after the passes is scaled
    into it. Should the damped model ``g.d + d.B.d / 2`` not fall along the result, the whole
    step scaled into the box (which always descends) is taken instead."""
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


def _extrapolated(fn, args, s, delta, z_new, r_new, F_new, try_it, cap):
    """After an accepted step whose decrease beat the model's prediction by more than 25 %, try
    the minimum of the parabola through ``F(z)``, the slope ``g . delta`` and ``F(z + delta)``
    along the same direction (``alpha`` clipped to [1, 4] and to the step cap) and keep it when
    it is lower. The Gauss-Newton model of a large-residual problem can overestimate the
    curvature: on a full MERL plastic table every step went half the way (gain ratio 1.49, steps
    halving) and the fit took 10 full-table iterations. Returns ``(z, r, F)``; one evaluation,
    only where tried (``lax.cond``)."""
    slope = jnp.dot(s.g, delta).astype(F_new.dtype)
    curv = F_new - s.F - slope
    alpha = jnp.where(curv > 0, -slope / (2 * jnp.where(curv > 0, curv, 1)), 1)
    top = cap / jnp.maximum(jnp.max(jnp.abs(delta)), jnp.finfo(delta.dtype).tiny)
    alpha = jnp.clip(alpha, 1, jnp.minimum(4, top)).astype(delta.dtype)

    def tried():
        z2 = s.z + alpha * delta
        r2 = fn(z2, args)
        F2 = _half_sq(r2)
        better = jnp.isfinite(F2) & (F2 < F_new)
        return jax.tree_util.tree_map(lambda a, b: jnp.where(better, a, b), (z2, r2, F2), (z_new, r_new, F_new))

    return jax.lax.cond(try_it & (alpha > 1), tried, lambda: (z_new, r_new, F_new))


class LMResult(NamedTuple):
    """What :func:`lm_fd` returns: the solution ``z``, ``F = 0.5 |r|^2`` there, the number of
    accepted ``steps``, whether a stopping test (not ``max_steps``) ended the loop
    (``converged``), ``A = J^T J`` at ``z`` (for covariances), the number of model ``evals`` and
    the residuals ``r`` at ``z`` (in ``fn``'s layout)."""

    z: jax.Array
    F: jax.Array
    steps: jax.Array
    converged: jax.Array
    A: jax.Array
    evals: jax.Array
    r: object


def lm_fd(fn, z0, args, seeds, owner, max_steps=100, rtol=1e-8, atol=1e-10, central=None, max_reject=12,
          tau=1e-3, max_step=3.0, wide=False, extrapolate=False):
    """Minimize ``0.5 |fn(z, args)|^2`` from ``z0`` (see the module docstring).

    Parameters
    ----------
    fn : callable ``(z, args) -> (N, C)`` residuals, or a tuple of ``C`` arrays ``(n,)``
        (channel-split); traceable by JAX.
    z0 : (p,) starting point.  args : pytree passed through to ``fn``.
    seeds, owner : from :func:`column_groups`.
    max_steps : maximum number of Jacobians (accepted steps).
    rtol, atol : stopping tolerances.  central : central differences (default: float32 only).
    max_reject : consecutive rejected steps after which the objective counts as minimal.
    tau : initial damping, relative to the diagonal of ``J^T J``.
    max_step : largest change of any coordinate of ``z`` in one step (``np.inf``: no limit).
    wide : sum the moments ``J^T J``, ``J^T r`` in float64 (when x64 is on) at every Jacobian, and
        return ``A`` so: a float32 fit's ``A`` then serves covariances as a float64 one does.
    extrapolate : after an accepted step that beat its predicted decrease by more than 25 %, try
        the line minimum along it (:func:`_extrapolated`; one more evaluation there). For single
        large fits; under ``vmap`` every member would pay the evaluation.

    Returns
    -------
    LMResult
        ``(z, F, steps, converged, A, evals, r)``.

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
    z0 = jnp.asarray(z0)
    dt = z0.dtype
    central = (dt == jnp.float32) if central is None else bool(central)
    G = len(seeds)
    per_jac = 2 * G if central else G
    F0, A0, g0, r0 = normal_equations(fn, z0, args, seeds, owner, central, wide=wide)
    mu0 = jnp.asarray(tau, dt)  # relative to diag(J^T J) (Marquardt's scaling)
    s = _State(z0, F0, A0, g0, r0, mu0, jnp.asarray(2.0, dt), jnp.asarray(0), jnp.asarray(1 + per_jac),
               jnp.asarray(False), jnp.asarray(False), jnp.asarray(0),
               jnp.maximum(jnp.diag(A0), jnp.finfo(dt).eps * jnp.max(jnp.diag(A0)) + jnp.finfo(dt).tiny))
    p = z0.shape[0]
    eye = jnp.eye(p, dtype=A0.dtype)
    f_tol = max(rtol, 4 * float(jnp.finfo(dt).eps))

    # One flat loop: every iteration is one trial step and the Jacobian at the (possibly
    # unchanged) point. Under vmap (batched fits) a nested loop of rejections would make every
    # member wait for the slowest one's rejections at every step; the flat loop costs at most
    # the largest number of iterations of any member.
    def cond(s):
        return (~s.done) & (s.steps < max_steps) & (s.evals < (4 * max_steps + 1) * (1 + per_jac))

    def body(s):
        delta = _box_step(s.A + s.mu * s.D * eye, s.g, max_step).astype(dt)
        r_new = fn(s.z + delta, args)
        F_new = _half_sq(r_new)
        pred = (-jnp.dot(s.g, delta) - 0.5 * jnp.dot(delta, s.A @ delta)).astype(dt)
        rho = (s.F - F_new) / jnp.where(pred > 0, pred, jnp.inf)
        acc = jnp.isfinite(F_new) & (F_new < s.F) & (rho > 0) & jnp.all(jnp.isfinite(delta))
        mu = jnp.where(acc, s.mu * jnp.maximum(1 / 3, 1 - (2 * rho - 1) ** 3), s.mu * s.nu)
        nu = jnp.where(acc, 2.0, 2 * s.nu)
        z_new = jnp.where(acc, s.z + delta, s.z)
        if extrapolate:
            z_new, r_new, F_new = _extrapolated(fn, args, s, delta, z_new, r_new, F_new, acc & (rho > 1.25), max_step)
        # A rejected step leaves z, and so the Jacobian, unchanged (under vmap both branches run).
        F_c, A, g, r = jax.lax.cond(
            acc, lambda: normal_equations(fn, z_new, args, seeds, owner, central, r=r_new, F=F_new, wide=wide),
            lambda: (s.F, s.A, s.g, s.r))
        # Either test ends the loop after a step the quadratic model predicted well (scipy's
        # ftol/xtol rule); the objective's test cannot ask for less than the dtype resolves.
        small_f = (s.F - F_c) <= f_tol * s.F + atol
        small_z = jnp.linalg.norm(delta) <= rtol * (rtol + jnp.linalg.norm(s.z))
        small_g = jnp.max(jnp.abs(g)) <= atol
        rejects = jnp.where(acc, 0, s.rejects + 1)
        # MINPACK's ftol test (More 1978) on the first trial step from a point, accepted or not:
        # the actual and the predicted change both within the tolerance, so the quadratic model
        # has nothing left to gain (in float32 the rejected steps of a converged fit would
        # otherwise run up to max_reject). Not after rejections: a damping raised by them shrinks
        # the predicted change of any point.
        flat_f = (s.rejects == 0) & (jnp.abs(s.F - F_new) <= f_tol * s.F + atol) & (pred <= f_tol * s.F + atol)
        stop = (acc & (((small_f | small_z) & (rho > 0.25)) | small_g)) | flat_f | (rejects >= max_reject)
        return _State(z_new, F_c, A, g, r, mu, nu, s.steps + acc.astype(s.steps.dtype), s.evals + 1 + acc * per_jac,
                      stop, stop, rejects, jnp.maximum(s.D, jnp.diag(A)))

    small_g0 = jnp.max(jnp.abs(g0)) <= atol
    s = s._replace(done=small_g0, ok=small_g0)
    s = jax.lax.while_loop(cond, body, s)
    return LMResult(s.z, s.F, s.steps, s.ok, s.A, s.evals, s.r)
