r"""Posterior sampling with emcee over the same parameter space as :func:`matfit.fitting.fit`.

The walkers move in the unconstrained ``z`` of :class:`~matfit.fitting.Parametrization` (the
least-squares fit's bijections); every reported quantity is in the natural ``theta(z)``:

.. math::

    \log p(z \mid y) = \log L(\theta(z)) + \log \pi(\theta(z)) + \log\left|\frac{d\theta}{dz}\right|

(up to a constant), evaluated by **one** jitted, ``vmap``-ed JAX function of a batch of walkers
(numpy in, numpy out) that emcee calls with ``vectorize=True``.

Likelihood (Gaussian, independent residuals, full normalization)
    * ``noise="table"``: with the residuals ``r`` of :func:`~matfit.fitting.losses.residuals`
      (weights ``1/sigma^2``), :math:`\log L = \sum_i [-r_i^2/2 - \log\sigma_i - \log(2\pi)/2]`
      over the usable entries: exact for ``loss="l2"`` (``y ~ N(f, sigma^2)``), a pseudo
      likelihood with ``sigma`` in the loss's space for the other losses.
    * ``noise="fit"``: a sampled **relative** noise scale (label ``noise_scale``),
      ``sigma_i = s |t(y_i)| + floor``, ``t(y)`` the measurement in the loss's space (``y`` for
      ``"l2"``, ``y cos(theta_i)`` for ``"cosine"``, ``log(1 + y cos(theta_i))`` for ``"e2"``,
      ``cbrt(y cos(theta_i))`` for ``"cbrt"``, ``y/(|y| + eps)`` for ``"relative"``); ``floor``
      (default ``1e-5 *`` the median ``|t(y)|``) keeps ``sigma > 0`` where ``y = 0``. The table's
      ``sigma``/``weight`` then only selects the usable entries (weight > 0). The walkers move in
      ``log s``, prior uniform in ``log s`` on ``[1e-6, 10]`` (scale invariant).

Priors on the model parameters
    * ``prior="uniform"``: uniform in each natural parameter within its bounds, i.e.
      ``-log(upper - lower)`` per bounded component, plus :meth:`Parametrization.log_jacobian`.
    * ``prior={"alpha": (0.3, 0.1), "eta": (1.5, 0.2), ...}``: independent Gaussians
      ``N(mean, sd)`` truncated to the bounds (unnormalized truncation). Keys are parameter names
      (every component of a per-channel parameter; ``mean``/``sd`` may be per-channel sequences)
      or single labels such as ``"albedo[1]"``; parameters not named keep the uniform prior.

Moves
    ``moves="de"`` (default): differential evolution (80 %) with its snooker variant (20 %)
    (ter Braak 2006; ter Braak & Vrugt 2008): proposals along the difference of two walkers follow
    a correlated, curved posterior (a conductor's ``eta`` and ``k`` on one channel).
    ``moves="stretch"``: Goodman & Weare's affine-invariant stretch move, emcee's default. On the
    demo's gold conductor only DE meets the criterion within 20000 steps (``docs/performance.md``).

Run length
    The walkers start in a small ball around a least-squares fit (``start``; by default
    :func:`~matfit.fitting.fit` runs first). The burn-in runs in chunks until it is at least
    ``burn_factor`` (5) times the largest integrated autocorrelation time estimated on its second
    half; the sampler is then reset and the production run is extended in chunks, re-estimating
    ``tau`` with emcee's ``get_autocorr_time(tol=0)``, until its length exceeds
    ``tau_factor * max(tau)`` (``converged=True``) or the total reaches ``max_steps``
    (``converged=False``). The stored chain is thinned by ``max(1, floor(min(tau) / 2))`` unless
    ``thin`` is given.

Speed
    Each emcee step makes two calls of half the ensemble each; with a table of a few thousand
    rows a CPU step is as much emcee's Python as JAX: call :func:`matfit.parallel.for_small_calls`
    before JAX starts (``docs/performance.md``). Large tables (a full MERL table) want every core.

References
----------
- D. Foreman-Mackey, D. W. Hogg, D. Lang, J. Goodman, "emcee: The MCMC Hammer", PASP 125, 2013.
- J. Goodman, J. Weare, "Ensemble samplers with affine invariance", CAMCoS 5(1), 2010.
- C. J. F. ter Braak, "A Markov Chain Monte Carlo version of the genetic algorithm Differential
  Evolution", Statistics and Computing 16, 2006; C. J. F. ter Braak, J. A. Vrugt, "Differential
  Evolution Markov Chain with snooker updater and fewer chains", Statistics and Computing 18, 2008.
"""

from __future__ import annotations

import functools
import json
import math
import time
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import MatfitError, ParameterError
from ..fast import supports_soa
from ..table import Table
from ._problem import Problem
from .families import DEFAULT_FAMILY
from .losses import DEFAULT_LOSS, prepare_targets, residuals_from_targets

__all__ = ["PosteriorResult", "LogProb", "SamplingError", "make_log_prob", "sample_posterior", "NOISE_MODES"]

NOISE_MODES = ("table", "fit")
#: Bounds of the noise scale ``s`` for ``noise="fit"`` (prior uniform in ``log s`` between them).
NOISE_SCALE_BOUNDS = (1e-6, 10.0)
NOISE_LABEL = "noise_scale"
_LOG2PI = math.log(2 * math.pi)
NPZ_FORMAT = "matfit.posterior/1"


class SamplingError(MatfitError):
    """The sampler cannot run as asked (no finite starting point, ...); its message as for
    :class:`~matfit.errors.MatfitError`.

    Examples
    --------
    >>> from matfit.errors import MatfitError
    >>> from matfit.fitting.mcmc import SamplingError
    >>> issubclass(SamplingError, MatfitError)
    True
    """


# --------------------------------------------------------------------------------------------
# The compiled log-probability (cached per configuration: new tables of the same shape, new
# priors and new noise floors do not recompile).
@functools.lru_cache(maxsize=32)
def _compiled(problem, noise):
    par, loss = problem.par, problem.loss
    p = par.size
    lo, hi = par.lower_upper()
    uni = np.where(np.isfinite(hi), -np.log(np.where(np.isfinite(hi), hi - lo, 1.0)), 0.0)
    ls_lo, ls_hi = (math.log(b) for b in NOISE_SCALE_BOUNDS)
    # Models of matfit.fast's structure-of-arrays path take the fit's channel-split residuals
    # (one single-output kernel per channel, an isotropic lobe on cosines only), faster than the
    # (N, C) layout. Their per-element arrays are laid out (C, n) then.
    soa = supports_soa(par.model(jnp.zeros(p)))
    split_prepare, split_fn = problem.split_residuals if soa else (None, None)

    def one(x, args):
        # data, target, factor: the directions and the data's part of the residuals
        # (losses.prepare_targets), and t the residual of a zero prediction: they depend on the
        # table only, so make_log_prob computes them once.
        data, target, factor, t, usable, floor, pmask, pmean, psd, logw_sum, n = args
        z = x[:p]
        if soa:  # tuples over the channels
            r = split_fn(z, (data, target, factor))
            t, usable = tuple(t), tuple(usable)
        else:
            wo, wi = data
            r = (residuals_from_targets(par.model(z).eval(wo, wi), target, factor, wi[..., 2], loss),)
            t, usable = (t,), (usable,)
        if noise == "table":
            ll = -0.5 * sum(jnp.sum(rc * rc) for rc in r) + 0.5 * logw_sum - 0.5 * n * _LOG2PI
            lp_noise = 0.0
        else:
            logs = x[p]

            def ll_part(rc, tc, uc):
                sig = jnp.where(uc, jnp.exp(logs) * tc + floor, 1.0)
                return jnp.sum(jnp.where(uc, -0.5 * (rc / sig) ** 2 - jnp.log(sig), 0.0))

            ll = sum(ll_part(*parts) for parts in zip(r, t, usable)) - 0.5 * n * _LOG2PI
            lp_noise = jnp.where((logs >= ls_lo) & (logs <= ls_hi), -math.log(ls_hi - ls_lo), -jnp.inf)
        theta = par.theta_vector(z)
        gauss = -0.5 * ((theta - pmean) / psd) ** 2 - jnp.log(psd) - 0.5 * _LOG2PI
        lprior = jnp.sum(jnp.where(pmask, gauss, jnp.asarray(uni, theta.dtype)))
        tot = ll + lp_noise + lprior + par.log_jacobian(z)
        return jnp.where(jnp.isfinite(tot), tot, -jnp.inf)

    batched = jax.jit(jax.vmap(one, in_axes=(0, None)))
    to_natural = jax.jit(par.theta_vector)
    prepare = jax.jit(split_prepare) if soa else None
    return par, batched, to_natural, prepare


@functools.lru_cache(maxsize=64)
def _packed(batched, treedef, specs):
    """``batched(X, args)`` taking ``args`` as one flat vector (:func:`_pack`): a jitted call
    flattens, checks and transfers each argument leaf, a cost per leaf that one vector pays once
    (the A/B is in ``docs/performance.md``). Cached on the structure and the leaves' shapes, so
    tables of one shape share one compilation."""
    sizes = [math.prod(shape) for shape, _ in specs]
    offsets = np.cumsum([0] + sizes)

    def call(X, flat):
        leaves = [flat[o:o + n].reshape(shape).astype(dtype)
                  for o, n, (shape, dtype) in zip(offsets[:-1], sizes, specs)]
        return batched(X, jax.tree_util.tree_unflatten(treedef, leaves))

    return jax.jit(call)


def _pack(args, dtype):
    """``(treedef, specs, flat)``: the leaves of ``args`` raveled into one ``dtype`` vector (bool
    leaves as 0/1, exact), with what :func:`_packed` needs to rebuild them."""
    leaves, treedef = jax.tree_util.tree_flatten(args)
    specs = tuple((tuple(int(d) for d in jnp.shape(x)), jnp.result_type(x).name) for x in leaves)
    flat = jnp.concatenate([jnp.ravel(jnp.asarray(x)).astype(dtype) for x in leaves])
    return treedef, specs, flat


def _prior_arrays(prior, par):
    """(mask, mean, sd) vectors over the free parameters for a prior spec, and a description."""
    p = par.size
    mask, mean, sd = np.zeros(p, bool), np.zeros(p), np.ones(p)
    if isinstance(prior, str):
        if prior != "uniform":
            raise ParameterError(f"sample_posterior: prior must be 'uniform' or a dict of (mean, sd), got {prior!r}")
        return mask, mean, sd, "uniform"
    if not isinstance(prior, dict):
        raise ParameterError(f"sample_posterior: prior must be 'uniform' or a dict of (mean, sd), "
                             f"got {type(prior).__name__}")
    labels = par.labels
    slices, i = {}, 0
    for prm, n in zip(par.free, par.sizes):
        slices[prm.name] = slice(i, i + n)
        i += n
    desc = {}
    for key, spec in prior.items():
        if key in slices:
            sl = slices[key]
        elif key in labels:
            j = labels.index(key)
            sl = slice(j, j + 1)
        else:
            raise ParameterError(f"sample_posterior: prior names {key!r}, which is not a free parameter "
                                 f"(free: {labels})")
        try:
            m, s = spec
            m = np.broadcast_to(np.asarray(m, float), (sl.stop - sl.start,))
            s = np.broadcast_to(np.asarray(s, float), (sl.stop - sl.start,))
        except (TypeError, ValueError):
            raise ParameterError(f"sample_posterior: prior[{key!r}] must be a (mean, sd) pair of numbers or "
                                 f"per-channel sequences, got {spec!r}") from None
        if not (np.all(np.isfinite(m)) and np.all(np.isfinite(s)) and np.all(s > 0)):
            raise ParameterError(f"sample_posterior: prior[{key!r}] needs a finite mean and sd > 0, got {spec!r}")
        mask[sl], mean[sl], sd[sl] = True, m, s
        desc[key] = [m.tolist(), s.tolist()]
    return mask, mean, sd, "gaussian " + json.dumps(desc)


class LogProb:
    """The vectorized log-posterior of one table: ``lp(X)`` maps an (n, d) numpy array of walkers
    (``z`` and, with ``noise="fit"``, ``log s`` last) to (n,) float64 log-probabilities.

    Calls are evaluated in fixed-size blocks (``block`` rows, padded) so that the jitted function
    compiles once per configuration and block size. A single point (d,) gives a scalar; points with
    another number of coordinates than ``ndim`` raise :class:`~matfit.errors.ParameterError`. Built
    by :func:`make_log_prob` (from the jitted ``batched(X, args)`` and ``z -> theta`` maps), not
    directly.

    Attributes
    ----------
    par : matfit.fitting.Parametrization
        The parametrization of the free parameters.
    args : tuple
        The table's data and the prior's arrays, the second argument of ``batched``.
    noise, prior : str
        The noise model; ``"uniform"`` or ``"gaussian {...}"``.
    block : int
        Points per compiled call (:func:`sample_posterior` sets half the ensemble).
    dtype : numpy.dtype
        Float dtype of the computation.
    ndim : int
        Coordinates per point: the free parameters, plus ``log s`` with ``noise="fit"``.
    labels : list of str
        Names of the coordinates (``noise_scale`` last with ``noise="fit"``).
    noise_floor : float
        The relative noise model's absolute floor (0 unless ``noise="fit"``).

    Examples
    --------
    ``docs/examples.md`` finds a table's mode with one. With ``noise="fit"``, ``log s`` is the last
    coordinate:

    >>> import numpy as np
    >>> from matfit import Table
    >>> from matfit.fitting import make_log_prob
    >>> wo = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, 0.6, 0.8]])
    >>> mono = Table(wo=wo, wi=wo[::-1], values=np.full((3, 1), 0.1), channels="mono")
    >>> lp = make_log_prob(mono, model="lambert", noise="fit")
    >>> lp.labels, lp.ndim, lp(np.zeros((5, 2))).shape, np.ndim(lp(np.zeros(2)))
    (['albedo[0]', 'noise_scale'], 2, (5,), 0)
    """

    def __init__(self, par, batched, to_natural, args, noise, prior_desc, block, dtype):
        self.par, self._to_natural, self.args = par, to_natural, args
        treedef, specs, self._flat = _pack(args, dtype)
        self._call = _packed(batched, treedef, specs)
        self.noise, self.prior = noise, prior_desc
        self.block = int(block)
        self.dtype = np.dtype(dtype)
        self.ndim = par.size + (noise == "fit")
        self.labels = list(par.labels) + ([NOISE_LABEL] if noise == "fit" else [])

    def __call__(self, X):
        X = np.asarray(X, dtype=np.float64)
        single = X.ndim == 1
        X = np.atleast_2d(X)
        if X.shape[-1] != self.ndim:
            raise ParameterError(f"log-probability: expected points with {self.ndim} coordinates, got shape {X.shape}")
        b = self.block
        if len(X) == b and not single:  # emcee's half-ensemble: one call, no copies (the common case)
            return np.asarray(self._call(X.astype(self.dtype, copy=False), self._flat), dtype=np.float64)
        out = np.empty(len(X))
        for i in range(0, len(X), b):
            part = X[i:i + b]
            k = len(part)
            if k < b:
                part = np.concatenate([part, np.repeat(part[-1:], b - k, axis=0)])
            res = self._call(part.astype(self.dtype, copy=False), self._flat)
            out[i:i + k] = np.asarray(res, dtype=np.float64)[:k]
        return out[0] if single else out

    def to_natural(self, X):
        """Natural parameters ``theta(z)`` (float64) of walkers (..., d); ``s`` last with ``noise="fit"``."""
        X = np.asarray(X, dtype=np.float64)
        p = self.par.size
        th = np.asarray(self._to_natural(jnp.asarray(X[..., :p], dtype=self.dtype)), dtype=np.float64)
        if self.noise == "fit":
            th = np.concatenate([th, np.exp(X[..., p:])], axis=-1)
        return th


def make_log_prob(table, model=DEFAULT_FAMILY, fixed=None, tied=(), loss=DEFAULT_LOSS, noise="table", prior="uniform",
                  noise_floor=None, block=None, dtype=None) -> LogProb:
    """The log-posterior :class:`LogProb` that :func:`sample_posterior` hands to emcee (the
    likelihood, priors and noise models are in the module docstring).

    Parameters
    ----------
    table, model, fixed, tied, loss, noise, prior, dtype
        As for :func:`sample_posterior`.
    noise_floor : float, optional
        Absolute floor of the relative noise model (``noise="fit"`` only); default ``1e-5`` times
        the median ``|t(y)|`` of the usable entries, ``1e-12`` when that is 0.
    block : int, optional
        Points per compiled call (inputs are padded to it); default 8.

    Returns
    -------
    LogProb
        The log-posterior, with its ``noise_floor`` set.

    Raises
    ------
    matfit.errors.ParameterError
        When an argument is invalid, ``noise="table"`` meets a table without ``sigma``, or the table
        has no more usable residuals than sampled parameters.
    """
    if not isinstance(table, Table):
        raise ParameterError(f"sample_posterior: table must be a matfit.Table, got {type(table).__name__}")
    if isinstance(tied, str):
        tied = (tied,)
    problem = Problem.of(model, table.n_channels, fixed, tied, loss)
    if noise not in NOISE_MODES:
        raise ParameterError(f"sample_posterior: noise must be one of {list(NOISE_MODES)}, got {noise!r}")
    if noise == "table" and table.sigma is None:
        raise ParameterError("sample_posterior: noise='table' needs a table with sigma (standard deviations); "
                             "use noise='fit' to sample a relative noise scale instead")
    par, batched, to_natural, prepare = _compiled(problem, noise)
    pmask, pmean, psd, pdesc = _prior_arrays(prior, par)
    weight = table.effective_weight()
    n_res = int(np.count_nonzero(weight > 0))
    if n_res <= par.size + (noise == "fit"):
        raise ParameterError(f"sample_posterior: the table has {n_res} usable residuals for "
                             f"{par.size + (noise == 'fit')} free parameters")
    a = table.as_jax(dtype)
    dt = a.values.dtype
    usable = weight > 0
    # noise="table": r = sqrt(w) (T(f) - T(y)); noise="fit": unit weights on the usable rows, and
    # t = |r| at a zero prediction, the scale of the relative noise model
    w = a.weight if noise == "table" else jnp.asarray(usable, dt)
    target, factor = prepare_targets(a.values, w, a.wi[:, 2], loss)
    t_zero = jnp.abs(residuals_from_targets(jnp.zeros_like(a.values), target, factor, a.wi[:, 2], loss))
    floor = 0.0
    if noise == "fit":
        if noise_floor is None:
            floor = 1e-5 * float(np.median(np.asarray(t_zero)[usable]))
            floor = floor if floor > 0 else 1e-12
        else:
            floor = float(noise_floor)
            if not (math.isfinite(floor) and floor > 0):
                raise ParameterError(f"sample_posterior: noise_floor must be finite and > 0, got {noise_floor!r}")
    elif noise_floor is not None:
        raise ParameterError("sample_posterior: noise_floor is only used with noise='fit'")
    # sum of log(1 / sigma^2) over the usable residuals: the same for every point, computed once
    logw_sum = float(np.sum(np.log(weight[usable])))
    usable = jnp.asarray(usable)
    data = (a.wo, a.wi)
    if prepare is not None:  # the structure-of-arrays layout, (C, n_padded) per-element arrays
        data, target, factor = prepare((a.wo, a.wi, a.values, w))
        pad = ((0, data.n_padded - a.wo.shape[0]), (0, 0))
        t_zero, usable = jnp.pad(t_zero, pad).T, jnp.pad(usable, pad).T
    args = (data, target, factor, t_zero, usable, jnp.asarray(floor, dt), jnp.asarray(pmask),
            jnp.asarray(pmean, dt), jnp.asarray(psd, dt), jnp.asarray(logw_sum, dt), jnp.asarray(n_res, dt))
    lp = LogProb(par, batched, to_natural, args, noise, pdesc, block or 8, dt)
    lp.noise_floor = floor
    return lp


# --------------------------------------------------------------------------------------------
@dataclass
class PosteriorResult:
    """The outcome of :func:`sample_posterior` (all values in natural units).

    Attributes
    ----------
    family, loss, noise, prior : str
        The model family, the likelihood's loss, the noise model (``"table"`` or ``"fit"``) and
        the prior (``"uniform"`` or ``"gaussian {...}"``).
    labels : list of str
        Names of the sampled parameters (``noise_scale`` last with ``noise="fit"``).
    chain : ndarray (steps, walkers, p)
        Production chain after burn-in, thinned by ``thin``.
    log_prob : ndarray (steps, walkers)
        Log-posterior of the stored samples.
    median, mean, std : ndarray (p,)
        Of the stored samples (``std`` with ``ddof=1``).
    ci90, ci68 : ndarray (p, 2)
        The 5th/95th and 16th/84th percentiles.
    acceptance_fraction : ndarray (walkers,)
        Production acceptance fraction of each walker.
    autocorr_time : ndarray (p,)
        Integrated autocorrelation time of the production run (in steps).
    n_effective : ndarray (p,)
        ``walkers * production steps / autocorr_time``.
    burn_in, n_steps, thin, n_walkers : int
        Steps discarded, production steps (before thinning), thinning, walkers.
    tau_factor, converged : float, bool
        The run-length target; whether ``n_steps > tau_factor * max(autocorr_time)``.
    wall_time : float
        Seconds.
    noise_floor : float, default 0.0
        The relative noise model's absolute floor (0 unless ``noise="fit"``).
    fixed, tied : dict and tuple of str, default {} and ()
        The parameters held fixed (as arrays); the tied per-channel parameters.
    moves : str, default "stretch"
        emcee's moves (:data:`MOVES`); files written before the field read as ``"stretch"``.

    Examples
    --------
    >>> import numpy as np
    >>> from matfit import Table
    >>> wo = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, 0.6, 0.8]]); wi = wo[[1, 2, 0]]
    >>> table = Table(wo=wo, wi=wi, values=np.full((3, 3), 0.1), sigma=np.full((3, 3), 0.01))
    >>> from matfit.fitting import fit, sample_posterior
    >>> start = fit(table, model="lambert", starts=1)  # without it, sample_posterior runs fit itself
    >>> post = sample_posterior(table, model="lambert", start=start, max_steps=200, chunk=50, tau_factor=10,
    ...                         progress=False)
    >>> post.labels, post.chain.shape, post.samples.shape, post.n_steps, post.thin
    (['albedo[0]', 'albedo[1]', 'albedo[2]'], (50, 12, 3), (600, 3), 50, 1)
    >>> post.burn_in + post.n_steps <= 200  # max_steps caps burn-in and production together
    True
    >>> bool(np.all(abs(post.median - np.pi * 0.1) < 3 * post.std))  # the albedo of f = 0.1
    True
    >>> lo, hi = post.interval(0.5)[0]  # a central 50 % interval, inside the 90 % one
    >>> bool(post.ci90[0, 0] < lo < post.median[0] < hi < post.ci90[0, 1])
    True
    >>> print(post.summary().splitlines()[0].split(":")[0])
    lambert posterior (l2, noise=table, prior=uniform, moves=de)
    """

    family: str
    loss: str
    noise: str
    prior: str
    labels: list
    chain: np.ndarray
    log_prob: np.ndarray
    median: np.ndarray
    mean: np.ndarray
    std: np.ndarray
    ci90: np.ndarray
    ci68: np.ndarray
    acceptance_fraction: np.ndarray
    autocorr_time: np.ndarray
    n_effective: np.ndarray
    burn_in: int
    n_steps: int
    thin: int
    n_walkers: int
    tau_factor: float
    converged: bool
    wall_time: float
    noise_floor: float = 0.0
    fixed: dict = field(default_factory=dict)
    tied: tuple = ()
    moves: str = "stretch"

    @property
    def samples(self):
        """The chain flattened to (steps * walkers, p)."""
        return self.chain.reshape(-1, self.chain.shape[-1])

    def interval(self, level=0.9):
        """Central credible interval (p, 2) of :attr:`samples`; ``level`` in (0, 1), else ParameterError."""
        if not 0 < level < 1:
            raise ParameterError(f"interval: level must be in (0, 1), got {level!r}")
        q = 50 * (1 - level)
        return np.percentile(self.samples, [q, 100 - q], axis=0).T

    def summary(self) -> str:
        """A text table: one line on the run, then per parameter the median, 5/95 % and 16/84 %
        percentiles, ``tau`` and ``n_eff``."""
        lines = [f"{self.family} posterior ({self.loss}, noise={self.noise}, prior={self.prior}, moves={self.moves}): "
                 f"{self.n_walkers} walkers, burn-in {self.burn_in}, {self.n_steps} steps (thin {self.thin}), "
                 f"acceptance {np.mean(self.acceptance_fraction):.2f}, converged={self.converged} "
                 f"(tau_factor {self.tau_factor:g}), {self.wall_time:.1f} s",
                 f"  {'parameter':14s} {'median':>11s} {'5%':>11s} {'95%':>11s} {'16%':>11s} {'84%':>11s} "
                 f"{'tau':>7s} {'n_eff':>7s}"]
        for i, lab in enumerate(self.labels):
            lines.append(f"  {lab:14s} {self.median[i]:11.5g} {self.ci90[i, 0]:11.5g} {self.ci90[i, 1]:11.5g} "
                         f"{self.ci68[i, 0]:11.5g} {self.ci68[i, 1]:11.5g} {self.autocorr_time[i]:7.1f} "
                         f"{self.n_effective[i]:7.0f}")
        return "\n".join(lines)

    _ARRAYS = ("chain", "log_prob", "median", "mean", "std", "ci90", "ci68", "acceptance_fraction",
               "autocorr_time", "n_effective")
    _SCALARS = ("family", "loss", "noise", "prior", "burn_in", "n_steps", "thin", "n_walkers", "tau_factor",
                "converged", "wall_time", "noise_floor", "fixed", "tied", "moves")

    def save(self, path, **extra) -> None:
        """Write the chains and summaries to ``path`` (``.npz``, no pickle; :func:`numpy.savez`
        appends ``.npz``); ``**extra`` JSON-serializable entries go to the metadata's ``"extra"``."""
        meta = {k: getattr(self, k) for k in self._SCALARS}
        meta["fixed"] = {k: np.asarray(v, float).tolist() for k, v in self.fixed.items()}
        meta["tied"] = list(self.tied)
        meta["format"] = NPZ_FORMAT
        meta["extra"] = extra
        arrays = {k: np.asarray(getattr(self, k)) for k in self._ARRAYS}
        np.savez(path, labels=np.asarray(self.labels, dtype=str), meta=np.asarray(json.dumps(meta)), **arrays)

    @classmethod
    def load(cls, path) -> "PosteriorResult":
        """Read a file of :meth:`save` (not ``extra``); ParameterError if not ``matfit.posterior/1``."""
        with np.load(path, allow_pickle=False) as f:
            meta = json.loads(str(f["meta"]))
            if meta.get("format") != NPZ_FORMAT:
                raise ParameterError(f"{path}: not a {NPZ_FORMAT} file (format {meta.get('format')!r})")
            kw = {k: f[k].copy() for k in cls._ARRAYS}
            labels = [str(s) for s in f["labels"]]
        kw.update({k: meta[k] for k in cls._SCALARS if k != "moves"})
        kw["moves"] = meta.get("moves", "stretch")  # files written before the field: emcee's stretch move
        kw["tied"] = tuple(kw["tied"])
        return cls(labels=labels, **kw)


# --------------------------------------------------------------------------------------------
def _check_int(name, v, lo):
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
        raise ParameterError(f"sample_posterior: {name} must be an integer >= {lo}, got {v!r}")
    return int(v)


def _tau(sampler, discard=0):
    tau = np.asarray(sampler.get_autocorr_time(tol=0, discard=discard, quiet=True), float)
    return np.where(np.isfinite(tau) & (tau > 0), tau, 1.0)


#: emcee's moves by name (see the module docstring): a name -> a function returning the
#: ``moves`` argument of :class:`emcee.EnsembleSampler`.
MOVES = {
    "de": lambda emcee: [(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)],
    "stretch": lambda emcee: emcee.moves.StretchMove(),
}


def sample_posterior(table, model=DEFAULT_FAMILY, fixed=None, tied=(), loss=DEFAULT_LOSS, noise="table", prior="uniform",
                     n_walkers=None, max_steps=20000, tau_factor=50, start=None, seed=0, progress=True,
                     chunk=200, burn_factor=5, thin=None, noise_floor=None, dtype=None,
                     moves="de") -> PosteriorResult:
    """Sample the posterior of a model family's parameters given a table, with emcee.

    Parameters
    ----------
    table : matfit.Table
        The measurements; with ``noise="table"`` it must have ``sigma``.
    model, fixed, tied : optional
        Family name (default ``"plastic"``), parameters held at given values, per-channel parameters
        shared by all channels: as for :func:`matfit.fitting.fit`.
    loss : str, default "l2"
        As for :func:`matfit.fitting.fit` (no robust losses).
    noise : {"table", "fit"}, default "table"
        The table's ``sigma`` is the noise, or a relative noise scale ``s`` is sampled as well.
    prior : "uniform" or dict, default "uniform"
        Uniform within the bounds, or Gaussian ``(mean, sd)`` per parameter name or label.
    n_walkers : int, optional
        Even, at least twice the number ``d`` of sampled parameters (``noise_scale`` included);
        default ``4 d`` (at least 8).
    max_steps : int, default 20000
        Cap on all steps (burn-in and production), at least 100; the burn-in takes at most half.
    tau_factor, burn_factor : float, default 50 and 5
        The production run's target length and the burn-in's least length, in autocorrelation
        times (module docstring); ``burn_factor >= 0``.
    start : matfit.fitting.FitResult, optional
        A fit of the same family and free parameters (default: :func:`matfit.fitting.fit` is run).
        The walkers start around ``start.z``, radius a tenth of its standard errors in ``z`` clipped
        to ``[1e-5, 0.5]`` (``1e-3`` where not finite); with ``noise="fit"`` ``log s`` starts at the
        best of a profile of the log-probability over ``log s`` at ``start.z``.
    seed, progress : int and bool, default 0 and True
        Seed of the starting ball and of emcee's random state; emcee's progress bar per chunk.
    chunk : int, default 200
        Minimum number of steps per chunk, at least 10.
    thin : int, optional
        Thinning of the stored chain (default ``max(1, floor(min(tau) / 2))``), at most half the
        production steps.
    noise_floor : float, optional
        The relative noise model's absolute floor (``noise="fit"`` only; :func:`make_log_prob`).
    dtype : dtype, optional
        JAX float dtype of the computation (default: JAX's default float).
    moves : {"de", "stretch"}, default "de"
        emcee's proposal moves (:data:`MOVES`).

    Returns
    -------
    PosteriorResult
        The thinned production chain and its summaries, in natural units (an example there).

    Raises
    ------
    matfit.errors.ParameterError
        When an argument is invalid, or ``start`` is not a :class:`~matfit.fitting.FitResult` of
        ``model`` with the same free parameters.
    SamplingError
        When no finite log-probability is found near the start.
    """
    import emcee

    from .fit import FitResult, fit

    t0 = time.perf_counter()
    if not isinstance(table, Table):
        raise ParameterError(f"sample_posterior: table must be a matfit.Table, got {type(table).__name__}")
    max_steps = _check_int("max_steps", max_steps, 100)
    chunk = _check_int("chunk", chunk, 10)
    if isinstance(tau_factor, bool) or not isinstance(tau_factor, (int, float)) or not tau_factor > 0:
        raise ParameterError(f"sample_posterior: tau_factor must be a number > 0, got {tau_factor!r}")
    if isinstance(burn_factor, bool) or not isinstance(burn_factor, (int, float)) or not burn_factor >= 0:
        raise ParameterError(f"sample_posterior: burn_factor must be a number >= 0, got {burn_factor!r}")
    if thin is not None:
        thin = _check_int("thin", thin, 1)
    if not isinstance(moves, str) or moves not in MOVES:
        raise ParameterError(f"sample_posterior: moves must be one of {sorted(MOVES)}, got {moves!r}")
    if isinstance(tied, str):
        tied = (tied,)
    lp = make_log_prob(table, model, fixed, tied, loss, noise, prior, noise_floor, None, dtype)
    par, d = lp.par, lp.ndim
    if n_walkers is None:
        n_walkers = max(4 * d, 8)
        n_walkers += n_walkers % 2
    n_walkers = _check_int("n_walkers", n_walkers, 2 * d)
    if n_walkers % 2:
        raise ParameterError(f"sample_posterior: n_walkers must be even, got {n_walkers}")
    lp.block = n_walkers // 2  # emcee's stretch and DE moves evaluate half the ensemble at a time

    if start is None:
        start = fit(table, model=model, loss=loss, fixed=fixed, tied=tied, dtype=dtype)
    if not isinstance(start, FitResult):
        raise ParameterError(f"sample_posterior: start must be a FitResult, got {type(start).__name__}")
    if start.family != model or list(start.labels) != list(par.labels) or start.z is None:
        raise ParameterError(f"sample_posterior: start is a {start.family!r} fit with parameters {start.labels}, "
                             f"expected {model!r} with {par.labels}")

    rng = np.random.default_rng(seed)
    z0 = np.asarray(start.z, float)
    dth = np.abs(np.asarray(jax.jacfwd(par.theta_vector)(jnp.asarray(z0))).diagonal())
    with np.errstate(divide="ignore", invalid="ignore"):
        se_z = np.asarray(start.stderr, float) / dth
    radius = np.where(np.isfinite(se_z) & (se_z > 0), np.clip(0.1 * se_z, 1e-5, 0.5), 1e-3)
    center = z0
    if noise == "fit":
        # Profile the noise scale at the fitted parameters on a log grid, then refine.
        ls_lo, ls_hi = (math.log(b) for b in NOISE_SCALE_BOUNDS)
        grid = np.linspace(ls_lo, ls_hi, 64)
        for _ in range(2):
            vals = lp(np.column_stack([np.repeat(z0[None], len(grid), 0), grid]))
            best = grid[int(np.argmax(vals))]
            step = grid[1] - grid[0]
            grid = np.linspace(max(best - step, ls_lo), min(best + step, ls_hi), 64)
        center = np.append(z0, best)
        radius = np.append(radius, 0.02)
    p0 = center + radius * rng.standard_normal((n_walkers, d))
    lp0 = lp(p0)
    for _ in range(20):
        bad = ~np.isfinite(lp0)
        if not bad.any():
            break
        radius = radius / 2
        p0[bad] = center + radius * rng.standard_normal((int(bad.sum()), d))
        lp0[bad] = lp(p0[bad])
    if not np.all(np.isfinite(lp0)):
        raise SamplingError(f"sample_posterior: no finite log-probability near the start {start.values}")

    sampler = emcee.EnsembleSampler(n_walkers, d, lp, vectorize=True, moves=MOVES[moves](emcee))
    state = emcee.State(p0, log_prob=lp0, random_state=np.random.RandomState(seed).get_state())

    # ---- burn-in: at least burn_factor * tau (tau estimated on the second half)
    total = 0
    burn_target = min(chunk, max_steps // 2)
    while True:
        n = burn_target - total
        if n > 0:
            state = sampler.run_mcmc(state, n, progress=progress, progress_kwargs={"desc": "burn-in"})
            total += n
        tau_b = _tau(sampler, discard=total // 2)
        need = int(math.ceil(burn_factor * tau_b.max()))
        if total >= need or total >= max_steps // 2:
            break
        burn_target = min(max(need + need // 10, total + chunk // 2), max_steps // 2)
    burn_in = total
    sampler.reset()

    # ---- production: until n > tau_factor * max(tau) or max_steps
    n_prod = 0
    step = chunk
    while True:
        step = min(step, max_steps - total)
        if step <= 0:
            break
        state = sampler.run_mcmc(state, step, progress=progress, progress_kwargs={"desc": "production"})
        n_prod += step
        total += step
        tau = _tau(sampler)
        need = tau_factor * tau.max()
        if n_prod > need:
            break
        step = max(int(math.ceil(1.1 * need)) - n_prod, chunk // 2)
    tau = _tau(sampler)
    converged = bool(n_prod > tau_factor * tau.max())
    if thin is None:
        thin = max(1, int(tau.min() // 2))
    thin = min(thin, max(1, n_prod // 2))
    zchain = sampler.get_chain(thin=thin)
    chain = lp.to_natural(zchain)
    logp = sampler.get_log_prob(thin=thin)
    flat = chain.reshape(-1, d)
    q = np.percentile(flat, [5, 16, 50, 84, 95], axis=0)
    return PosteriorResult(
        family=model, loss=loss, noise=noise, prior=lp.prior, labels=lp.labels, chain=chain, log_prob=logp,
        median=q[2], mean=flat.mean(axis=0), std=flat.std(axis=0, ddof=1),
        ci90=np.stack([q[0], q[4]], axis=1), ci68=np.stack([q[1], q[3]], axis=1),
        acceptance_fraction=np.asarray(sampler.acceptance_fraction, float), autocorr_time=tau,
        n_effective=n_walkers * n_prod / tau, burn_in=burn_in, n_steps=n_prod, thin=int(thin),
        n_walkers=n_walkers, tau_factor=float(tau_factor), converged=converged,
        wall_time=time.perf_counter() - t0, noise_floor=float(lp.noise_floor),
        fixed={k: np.asarray(v, float) for k, v in (fixed or {}).items()}, tied=tuple(tied), moves=moves,
    )
