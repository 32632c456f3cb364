r"""Parameter maps: one fit per texel of a capture, in chunks of bounded memory.

Every texel of an ``H x W`` capture is a small table of ``N`` measurements (one per image) at
directions shared by all texels (distant light and camera) or its own (a flat sample under near
lights). :func:`fit_map` fits a model family to every texel with the batched solver of
:func:`matfit.fitting.fit_arrays`: texels are gathered into chunks of ``chunk`` texels (the last
one padded to the same size, so one compiled program serves the whole map), each texel starts
from its own data-driven guess, and the chunks' results are written into the maps as they come.
Memory is the chunk's working set plus the output maps; ``values`` may be a ``numpy.memmap``,
of which only the rows of the current chunk are read.

Under JAX's multi-process runtime (``jax.distributed.initialize``, :func:`initialize_processes`)
process ``i`` of ``P`` fits chunks ``i, i + P, i + 2P, ...`` and the chunks are gathered onto
every process with :func:`jax.experimental.multihost_utils.process_allgather`; every chunk is
computed by the same program whichever process runs it, so the merged map equals the
one-process map texel for texel.

Noise model: with ``sigma=None`` residuals are relative, :math:`(f - y) / (|y| + \epsilon)` (the
``"relative"`` loss: camera noise grows with the signal, and the specular peak would otherwise
outweigh the diffuse measurements by orders of magnitude), with the noise scale estimated from
each texel's residuals; with ``sigma`` given (absolute, broadcast to ``values``) the weights are
``1 / sigma**2`` and the standard errors use it as known.

False minima (``refit=True``, the default): a texel's end is compared with the map's noise
level, the median over its texels of the residual variance :math:`q = 2F / (n - p)` (1 with
``sigma`` given; floored at a relative RMS of ``NOISE_FLOOR``; none for a map of fewer than
``REFIT_MIN_BATCH`` (16) fitted texels without ``sigma``). A texel whose :math:`q` lies
more than :data:`~matfit.fitting.REFIT_SIGMAS` standard deviations of a :math:`\chi^2` per degree of
freedom above the level (:func:`~matfit.fitting.refit_line`) is solved again, first within its
chunk from :data:`~matfit.fitting.REFIT_STARTS` screened starts (:func:`~matfit.fitting.fit_arrays`),
then from the solutions of its 8 neighbours and of 16 good texels spread over the map (a region of
false minima borrows from the rest), keeping the lowest end. A texel still above
:data:`~matfit.fitting.SUSPECT_FACTOR` (10) times the level is ``suspect``: a false minimum or a
texel the family does not describe; the summary counts them.

Smoothness prior (``smooth > 0``, off by default): each texel's estimate is pulled towards the
mean of its 4 neighbours, weighted by its own precision: a few Jacobi sweeps of
:math:`\theta = (\theta_0 / s^2 + \lambda\,\bar\theta_{nb}) / (1 / s^2 + \lambda)` with
:math:`\theta_0, s` the texel's own fit and standard error (the Laplace approximation of its
likelihood, per parameter), :math:`\lambda` = ``smooth`` in units of 1 / parameter^2. Noisy
texels (large :math:`s`) follow their neighbours; well-measured ones keep their value.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import ParameterError
from ..fitting import REFIT_STARTS, SUSPECT_FACTOR, Problem, fit_arrays, get_family, noise_level, refit_line
from ..parallel import pad_to_power_of_two

#: First-pass starts per texel of a family with a second lobe (``fit_map``'s ``starts``).
LOBE_STARTS = 4

#: Texels per chunk by default: large enough that the batched solver's per-call overhead is
#: small, small enough that a chunk's working set stays well under 1 GB.
DEFAULT_CHUNK = 16384


@dataclass(frozen=True)
class MapResult:
    """Per-texel results of :func:`fit_map`; maps are ``(H, W)``, or ``(H, W, C)`` for per-channel parameters.

    Attributes
    ----------
    family : str
    labels : list of str
        Free parameters, flat (``albedo[0]``, ...), as in :class:`~matfit.fitting.FitResult`.
    params, stderr : dict
        Parameter name -> map of values (fixed parameters included, broadcast) and of standard
        errors of the free parameters; NaN where a texel was not fitted.
    objective : numpy.ndarray, (H, W)
        Half the sum of squared residuals at the solution.
    rel_rmse : numpy.ndarray, (H, W)
        Root mean square of the relative residuals ``(f - y) / y`` over the texel's measurements.
    converged, at_bound, fitted : numpy.ndarray, (H, W) bool
        Solver convergence; some parameter within 0.1 % of its range's ends; texel fitted
        (inside ``mask`` with more usable measurements than free parameters).
    steps, n_measurements : numpy.ndarray, (H, W) int
        Solver iterations, and usable measurements, per texel.
    suspect : numpy.ndarray, (H, W) bool
        Residual variance still above ``SUSPECT_FACTOR`` (10) times the map's noise level after
        every refit (module doc): a false minimum, or a texel the family does not describe (a
        scratch, a sensor defect). Their parameters are not to be trusted.
    refitted : int
        Texels solved again from more starts (each counted once).
    noise_level : float
        The residual variance the ends were judged against (1 with ``sigma``; NaN: none, for a
        map of fewer than 16 fitted texels without ``sigma``).
    wall_time : float
        Seconds of the whole call.
    info : list of str
        Notes: texels left out, the neighbour prior.

    Examples
    --------
    >>> import numpy as np
    >>> from matfit.maps import fit_map
    >>> wo = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, 0.6, 0.8]]); wi = wo[[1, 2, 0]]
    >>> mask = np.array([[True, False]])
    >>> r = fit_map(wo, wi, np.full((1, 2, 3, 3), 0.1), model="lambert", mask=mask)
    >>> r.family, r.shape, r.labels, r.fitted.tolist(), bool(np.isnan(r.params["albedo"][0, 1]).all())
    ('lambert', (1, 2), ['albedo[0]', 'albedo[1]', 'albedo[2]'], [[True, False]], True)
    >>> [round(float(x), 4) for x in r.model_at(0, 0).reflectance]     # albedo = pi * 0.1
    [0.3142, 0.3142, 0.3142]
    """

    family: str
    labels: list
    params: dict
    stderr: dict
    objective: np.ndarray
    rel_rmse: np.ndarray
    converged: np.ndarray
    at_bound: np.ndarray
    fitted: np.ndarray
    steps: np.ndarray
    n_measurements: np.ndarray
    suspect: np.ndarray
    refitted: int
    noise_level: float
    wall_time: float
    info: list = field(default_factory=list)

    @property
    def shape(self):
        """``(H, W)``: the map's size in texels."""
        return self.fitted.shape

    @property
    def texels_per_second(self):
        """Texels fitted per second of :attr:`wall_time`."""
        return float(self.fitted.sum()) / max(self.wall_time, 1e-12)

    def model_at(self, row, col):
        """The family's model with texel ``(row, col)``'s parameters (NaN for a texel not fitted)."""
        fam = get_family(self.family)
        C = next((v.shape[-1] for v in self.params.values() if v.ndim == 3), 1)
        return fam.build({k: v[row, col] for k, v in self.params.items()}, C)

    def summary(self) -> str:
        """A few lines: texels fitted, converged, at a bound, refitted and suspect; median parameters and errors."""
        n = int(self.fitted.sum())
        lines = [f"{self.family} map {self.shape[0]}x{self.shape[1]}: {n} texels fitted in {self.wall_time:.1f} s "
                 f"({self.texels_per_second:.0f} texels/s)",
                 f"  converged {self.converged[self.fitted].mean():.1%}, at a bound {self.at_bound[self.fitted].mean():.1%}, "
                 f"median relative RMSE {np.nanmedian(self.rel_rmse[self.fitted]):.3g}" if n else "  nothing fitted"]
        if n and not np.isfinite(self.noise_level):
            lines.append("  no noise level (fewer than 16 texels and no sigma): the ends are not judged")
        elif n:
            ns = int(self.suspect.sum())
            lines.append(f"  {self.refitted} texels refitted from more starts; " + (
                f"{ns} ({ns / n:.2%}) still end above 10x the map's noise level: suspect (MapResult.suspect), "
                "do not trust them" if ns else "none ends above 10x the map's noise level"))
        fmt = lambda a: " ".join(f"{x:.4g}" for x in np.atleast_1d(a))  # noqa: E731
        for k, v in self.params.items():
            sel = v[self.fitted] if n else v.reshape((-1,) + v.shape[2:])
            s = f"  {k:10s} median {fmt(np.nanmedian(sel, axis=0))}"
            se = self.stderr.get(k)
            if se is not None and n:
                s += f", median stderr {fmt(np.nanmedian(se[self.fitted], axis=0))}"
            lines.append(s)
        lines += [f"  note: {x}" for x in self.info]
        return "\n".join(lines)


def _check_inputs(wo, wi, values, mask, valid, sigma):
    v = values if isinstance(values, np.ndarray) else np.asarray(values)
    if v.ndim != 4:
        raise ParameterError(f"fit_map: values must be (H, W, N, C), found shape {v.shape}")
    if v.dtype.kind != "f":
        raise ParameterError(f"fit_map: values must be floating point, found dtype {v.dtype}")
    H, W, N, C = v.shape
    dirs = []
    for name, d in (("wo", wo), ("wi", wi)):
        d = np.asarray(d)
        if d.shape not in ((N, 3), (H, W, N, 3)):
            raise ParameterError(f"fit_map: {name} must be (N, 3) = ({N}, 3) shared by every texel or (H, W, N, 3) = "
                                 f"({H}, {W}, {N}, 3), found shape {d.shape}")
        if d.ndim == 2:  # per-texel directions (possibly a memmap) are checked a chunk at a time
            _check_unit(name, d)
        dirs.append(d)
    if mask is not None:
        mask = np.asarray(mask)
        if mask.shape != (H, W) or mask.dtype != bool:
            raise ParameterError(f"fit_map: mask must be a boolean (H, W) = ({H}, {W}) array, found {mask.dtype} "
                                 f"{mask.shape}")
    if valid is not None:
        valid = np.asarray(valid)
        if valid.shape != (H, W, N) or valid.dtype != bool:
            raise ParameterError(f"fit_map: valid must be a boolean (H, W, N) = ({H}, {W}, {N}) array, found "
                                 f"{valid.dtype} {valid.shape}")
    if sigma is not None:
        s = np.asarray(sigma, float)
        try:
            np.broadcast_shapes(s.shape, v.shape)
        except ValueError:
            raise ParameterError(f"fit_map: sigma of shape {s.shape} does not broadcast to values {v.shape}") from None
        if not np.all(np.isfinite(s)) or np.any(s <= 0):
            raise ParameterError("fit_map: sigma must be finite and > 0")
    return dirs[0], dirs[1], v, mask, valid


def _check_unit(name, d):
    """Directions must be finite unit vectors."""
    if not np.all(np.isfinite(d)):
        raise ParameterError(f"fit_map: {name} has non-finite directions")
    norm = np.linalg.norm(d, axis=-1)
    if np.any(np.abs(norm - 1) > 1e-3):
        raise ParameterError(f"fit_map: {name} must be unit vectors (lengths {norm.min():.4g}..{norm.max():.4g})")


def _progress_bar(progress, total):
    if not progress:
        return None
    if callable(progress):
        return progress
    from tqdm.auto import tqdm

    bar = tqdm(total=total, desc="fit-map", unit="texel", unit_scale=True, smoothing=0.3)

    def update(done, total_, elapsed):
        bar.update(done - bar.n)
        if done >= total_:
            bar.close()

    return update


def fit_map(wo, wi, values, model="diffuse_specular", mask=None, sigma=None, *, valid=None, fixed=None, tied=(),
            chunk=DEFAULT_CHUNK, max_steps=64, smooth=0.0, dtype=None, progress=False, refit=True,
            starts=None) -> MapResult:
    """Fit ``model`` to every texel of a capture.

    Parameters
    ----------
    wo, wi : array_like
        Unit directions to the camera and to the light, ``(N, 3)`` shared by every texel, or
        ``(H, W, N, 3)`` per texel.
    values : array_like, (H, W, N, C)
        BSDF values (1/sr, without the cosine) of every texel in every image
        (:func:`matfit.maps.load_capture` turns images into them). A ``numpy.memmap`` is read one
        chunk at a time.
    model : str
        A family of :data:`matfit.fitting.FAMILIES`; default ``"diffuse_specular"`` (albedo,
        F0 and GGX alpha per texel).
    mask : (H, W) bool, optional
        Texels to fit (default: all). Others are NaN in the maps.
    sigma : float or array_like, optional
        Absolute noise standard deviation of the values (broadcast to ``values``). Default:
        relative residuals with the noise scale estimated per texel (see the module doc).
    valid : (H, W, N) bool, optional
        Usable measurements (saturated or shadowed ones False): left out of the fit.
    fixed, tied
        As in :func:`matfit.fitting.fit`.
    chunk : int
        Texels per solver call.
    max_steps : int
        Solver iterations per texel.
    smooth : float
        Strength of the neighbour prior (0: off; see the module doc).
    dtype : None, "float32" or "float64"
    progress : bool or callable
        A progress bar on stderr, or ``progress(done, total, elapsed_s)`` after every chunk.
    refit : bool, default True
        Solve texels that end far above the map's noise level again, from more starts and from
        their neighbours' solutions (module doc); False: one solve per texel.
    starts : int, optional
        Starts per texel in the first pass (the data-driven one and the best screened
        candidates). Default: :data:`LOBE_STARTS` (4) for a family with a second lobe of its own
        width (a ``ratio_2`` parameter: ``lobes2``, ``lobes3``, ``metal2``, ``film``), whose lobes
        trade weight and width into shallow false minima that no noise test can tell
        (``docs/robustness.md``: lobes2 at 24 pairs, 18 such texels in 1024 with one start, 1
        with four, in the same time); 1 otherwise.

    Returns
    -------
    MapResult
        The parameter maps (an example: ``docs/examples.md``).
    """
    t0 = time.perf_counter()
    wo, wi, values, mask, valid = _check_inputs(wo, wi, values, mask, valid, sigma)
    H, W, N, C = values.shape
    if isinstance(chunk, bool) or not isinstance(chunk, (int, np.integer)) or chunk < 1:
        raise ParameterError(f"fit_map: chunk must be an integer >= 1, got {chunk!r}")
    if not (isinstance(smooth, (int, float)) and math.isfinite(smooth) and smooth >= 0):
        raise ParameterError(f"fit_map: smooth must be a finite number >= 0, got {smooth!r}")
    par = Problem.of(model, C, fixed, tied).par  # the loss is chosen per chunk below; the parametrization is the same
    family = par.family.name
    if starts is None:
        starts = LOBE_STARTS if any(p.name == "ratio_2" for p in par.family.params) else 1
    shared = wo.ndim == 2 and wi.ndim == 2
    flat_v = values.reshape(H * W, N, C)
    flat_valid = None if valid is None else valid.reshape(H * W, N)
    # texels to fit: inside the mask, with more usable measurements than free parameters
    n_meas = np.full(H * W, N, np.int64) if flat_valid is None else flat_valid.sum(axis=1)
    cand = np.arange(H * W) if mask is None else np.flatnonzero(mask.reshape(-1))
    enough = n_meas[cand] * C > par.size
    todo = cand[enough]
    info = []
    if (~enough).any():
        info.append(f"{int((~enough).sum())} texels have too few usable measurements (need > {par.size} values) "
                    "and were not fitted")
    # a map smaller than a chunk is solved in the next power of two of its texel count (padded):
    # maps of nearby sizes share one compiled program
    chunk = int(min(chunk, 1 << max(len(todo) - 1, 0).bit_length()))
    n_chunks = -(-len(todo) // chunk) if len(todo) else 0

    read_rows = _row_reader(values, flat_v)
    # per-texel directions (a streamed capture's memmaps) are read like the values
    read_dirs = [None if d.ndim == 2 else _row_reader(d, d.reshape(H * W, N, 3)) for d in (wo, wi)]
    sig = None if sigma is None else np.broadcast_to(np.asarray(sigma, float), values.shape)
    p = par.size
    out_v = np.full((H * W, p), np.nan, np.float32)
    out_se = np.full((H * W, p), np.nan, np.float32)
    out_obj = np.full(H * W, np.nan, np.float32)
    out_rel = np.full(H * W, np.nan, np.float32)
    out_steps = np.zeros(H * W, np.int32)
    out_ok = np.zeros(H * W, bool)
    out_dof = np.ones(H * W, np.int64)
    out_refit = np.zeros(H * W, bool)
    lower, upper = par.lower_upper()

    def run_chunk(k):
        idx = todo[k * chunk:(k + 1) * chunk]
        return run_rows(pad_to_power_of_two(idx, chunk), refit=refit, starts=starts)

    def run_rows(idx, **kw):
        """Fit texels ``idx`` (flat indices); ``kw`` goes to fit_arrays (the refit's starts)."""
        n_rows = len(idx)
        v = read_rows(idx)
        ok = np.ones(v.shape[:2], bool) if flat_valid is None else np.asarray(flat_valid[idx])
        bad = ~np.isfinite(v) & ok[..., None]
        if bad.any():
            t = idx[np.flatnonzero(bad.any(axis=(1, 2)))[0]]
            raise ParameterError(f"fit_map: non-finite values at texel (row {t // W}, col {t % W}); mark them "
                                 "invalid (valid=...) or mask the texel")
        v = np.where(ok[..., None], v, 0.0)
        if sigma is None:
            w = np.broadcast_to(ok[..., None], v.shape).astype(np.float64)
            loss = "relative"
        else:
            s = sig[idx // W, idx % W]  # indexes the broadcast view: no copy of the whole array
            w = np.where(ok[..., None], 1.0 / s**2, 0.0)
            loss = "l2"
        o, i = wo, wi
        if not shared:
            o, i = (np.broadcast_to(d, (n_rows, N, 3)) if read is None else read(idx)
                    for d, read in zip((wo, wi), read_dirs))
            for name, d, read in (("wo", o, read_dirs[0]), ("wi", i, read_dirs[1])):
                if read is not None:
                    _check_unit(name, d)
        r = fit_arrays(o, i, v, w, model=family, loss=loss, fixed=fixed, tied=tied, max_steps=max_steps,
                       dtype=dtype, valid=ok, known_sigma=sigma is not None, where="fit_map", **kw)
        # relative residuals at the solution, for the diagnostics map
        n_use = np.maximum(np.count_nonzero(w, axis=(1, 2)), 1)
        rel = np.sqrt(2 * r.objective / n_use) if sigma is None else np.full(n_rows, np.nan)
        return {"values": r.values.astype(np.float32), "stderr": r.stderr.astype(np.float32),
                "objective": r.objective.astype(np.float32), "rel": rel.astype(np.float32),
                "steps": r.steps.astype(np.int32), "converged": r.converged,
                "refitted": r.refitted, "dof": np.maximum(n_use - p, 1)}

    def store(k, res):
        idx = todo[k * chunk:(k + 1) * chunk]
        n = len(idx)
        out_v[idx], out_se[idx] = res["values"][:n], res["stderr"][:n]
        out_obj[idx], out_rel[idx] = res["objective"][:n], res["rel"][:n]
        out_steps[idx], out_ok[idx] = res["steps"][:n], res["converged"][:n]
        out_dof[idx], out_refit[idx] = res["dof"][:n], res["refitted"][:n]

    bar = _progress_bar(progress, len(todo))
    P, me = _processes()
    mine = list(range(me, n_chunks, P))
    local = []
    for j, k in enumerate(mine):
        res = run_chunk(k)
        if P == 1:
            store(k, res)
        else:
            local.append(res)
        if bar:
            done = min(len(todo), (j + 1) * chunk * P)
            bar(done, len(todo), time.perf_counter() - t0)
    if P > 1 and n_chunks:
        _gather(local, n_chunks, P, chunk, p, store)
    if bar and not n_chunks:
        bar(0, 0, time.perf_counter() - t0)

    fitted = np.zeros(H * W, bool)
    fitted[todo] = True
    # the map's noise level (its texels share a camera): tables far above it are refitted from
    # their neighbours' solutions and from solutions spread over the map, then flagged
    q = 2 * out_obj.astype(float) / out_dof
    level = noise_level(q[fitted], sigma is not None)  # relative residuals: the floor's scale is 1
    judged = fitted & np.isfinite(level)
    with np.errstate(invalid="ignore"):
        above = judged & ~(q <= refit_line(out_dof) * level)
    redo = np.flatnonzero(above)
    if redo.size and refit:
        good = fitted & ~above
        for lo in range(0, redo.size, chunk):
            part = redo[lo:lo + chunk]
            sel = pad_to_power_of_two(part)
            init = _neighbour_starts(out_v, good, sel, H, W)
            res = run_rows(sel, starts=REFIT_STARTS, init=init, refit=False, level=level)
            n = part.size
            better = np.flatnonzero(res["objective"][:n] < out_obj[part])
            t = part[better]
            out_v[t], out_se[t], out_obj[t], out_rel[t] = (res["values"][better], res["stderr"][better],
                                                           res["objective"][better], res["rel"][better])
            out_steps[t], out_ok[t] = out_steps[t] + res["steps"][better], res["converged"][better]
        out_refit[redo] = True
        q = 2 * out_obj.astype(float) / out_dof
    with np.errstate(invalid="ignore"):
        out_suspect = judged & ~(q <= SUSPECT_FACTOR * level)
    refitted = int(out_refit.sum())  # distinct texels, whichever passes refitted them
    span = upper - lower
    near = np.where(np.isfinite(span), 1e-3 * span, 1e-3)
    with np.errstate(invalid="ignore"):
        at_bound = np.any((out_v - lower < near) | (upper - out_v < near), axis=1) & fitted
    values_map, se_map = _to_maps(par, out_v, out_se, H, W)
    if smooth > 0:
        values_map = _smooth(values_map, se_map, fitted.reshape(H, W), float(smooth))
        info.append(f"neighbour prior: smooth={smooth:g}")
    return MapResult(
        family=family, labels=par.labels, params=values_map, stderr=se_map, objective=out_obj.reshape(H, W),
        rel_rmse=out_rel.reshape(H, W), converged=out_ok.reshape(H, W), at_bound=at_bound.reshape(H, W),
        fitted=fitted.reshape(H, W), steps=out_steps.reshape(H, W), n_measurements=n_meas.reshape(H, W).astype(np.int32),
        suspect=out_suspect.reshape(H, W), refitted=refitted, noise_level=level, wall_time=time.perf_counter() - t0, info=info)


def _neighbour_starts(out_v, good, idx, H, W, pool=16):
    """Candidate starts of texels ``idx`` (n, 8 + pool, p): the solutions of their 8 neighbours
    where those are good (else NaN), and of ``pool`` good texels spread over the map (every
    k-th in raster order: a region of false minima borrows from the rest of the map)."""
    r, c = idx // W, idx % W
    nb = []
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if dr or dc:
                rr, cc = r + dr, c + dc
                inside = (rr >= 0) & (rr < H) & (cc >= 0) & (cc < W)
                j = np.where(inside, rr, 0) * W + np.where(inside, cc, 0)
                ok = inside & good[j]
                nb.append(np.where(ok[:, None], out_v[j], np.nan))
    g = np.flatnonzero(good)
    spread = out_v[g[np.linspace(0, g.size - 1, pool).astype(int)]] if g.size else np.full((pool, out_v.shape[1]), np.nan)
    return np.concatenate([np.stack(nb, axis=1), np.broadcast_to(spread, (len(idx),) + spread.shape)], axis=1)


def _row_reader(values, flat_v):
    """``read(idx)``: float64 rows ``idx`` of ``flat_v``, the texel-flat view ``(H W, ...)`` of
    ``values``. A ``numpy.memmap``
    (C order) is read with ``os.pread`` of the chunk's span of the file instead of through the
    mapping: pages touched through a mapping stay in the process's resident set, so a map larger
    than memory would fill it; read this way only the chunk is ever resident."""
    if not (isinstance(values, np.memmap) and values.flags.c_contiguous and getattr(values, "filename", None)):
        return lambda idx: np.asarray(flat_v[idx], np.float64)
    import os

    item = values.dtype.itemsize
    fh = open(values.filename, "rb")  # closed with the reader
    row_bytes = int(np.prod(flat_v.shape[1:])) * item

    def read(idx):
        lo, hi = int(idx.min()), int(idx.max()) + 1
        if hi - lo > 8 * len(idx):  # a sparse mask: the mapping is cheaper than a wide span
            return np.asarray(flat_v[idx], np.float64)
        buf = os.pread(fh.fileno(), (hi - lo) * row_bytes, values.offset + lo * row_bytes)
        block = np.frombuffer(buf, values.dtype).reshape((hi - lo,) + flat_v.shape[1:])
        return block[idx - lo].astype(np.float64)

    return read


def _to_maps(par, out_v, out_se, H, W):
    """Flat ``(H W, p)`` values and errors to per-parameter maps (fixed parameters broadcast)."""
    vals, ses, i = {}, {}, 0
    for q, n in zip(par.free, par.sizes):
        shape = (H, W, par.channels) if q.per_channel else (H, W)
        v, s = out_v[:, i:i + n], out_se[:, i:i + n]
        if q.per_channel:
            v, s = np.broadcast_to(v, (H * W, par.channels)), np.broadcast_to(s, (H * W, par.channels))
        vals[q.name] = np.ascontiguousarray(v.reshape(shape))
        ses[q.name] = np.ascontiguousarray(s.reshape(shape))
        i += n
    for q in par.family.params:
        if q.name in par.fixed:
            f = np.asarray(par.fixed[q.name], np.float32)
            shape = (H, W, par.channels) if q.per_channel else (H, W)
            vals[q.name] = np.broadcast_to(f, shape).astype(np.float32)
    return {q.name: vals[q.name] for q in par.family.params}, ses


def _smooth(values, stderr, fitted, lam, sweeps=20):
    """Jacobi sweeps of the precision-weighted neighbour prior (module doc)."""
    out = {}
    for k, v0 in values.items():
        if k not in stderr:
            out[k] = v0
            continue
        s = stderr[k]
        prec = np.where(np.isfinite(s) & (s > 0), 1.0 / np.maximum(s, 1e-12) ** 2, 0.0)
        f = fitted if v0.ndim == 2 else fitted[..., None]
        prec = np.where(f, prec, 0.0)
        x0 = np.where(f, v0, 0.0).astype(np.float64)
        x = x0.copy()
        widths = [(1, 1), (1, 1)] + [(0, 0)] * (x.ndim - 2)
        fp = np.pad(f.astype(float), widths, mode="constant")  # which neighbours are fitted
        cnt = fp[:-2, 1:-1] + fp[2:, 1:-1] + fp[1:-1, :-2] + fp[1:-1, 2:]
        for _ in range(sweeps):
            pad = np.pad(x, widths, mode="edge")
            nb = pad[:-2, 1:-1] * fp[:-2, 1:-1] + pad[2:, 1:-1] * fp[2:, 1:-1] + pad[1:-1, :-2] * fp[1:-1, :-2] + \
                pad[1:-1, 2:] * fp[1:-1, 2:]
            mean = np.where(cnt > 0, nb / np.maximum(cnt, 1), x0)
            x = (prec * x0 + lam * mean) / (prec + lam)
        out[k] = np.where(f, x, np.nan).astype(np.float32)
    return out


# ---------------------------------------------------------------------------------------------
def _processes():
    """``(process count, this process's index)`` of JAX's multi-process runtime (1, 0 alone)."""
    import jax

    return jax.process_count(), jax.process_index()


def _gather(local, n_chunks, P, chunk, p, store):
    """Every process's chunk results onto every process (padded to equal counts: the collective
    needs equal shapes), stored into the maps in chunk order."""
    from jax.experimental import multihost_utils

    per = -(-n_chunks // P)
    blank = {"values": np.zeros((chunk, p), np.float32), "stderr": np.zeros((chunk, p), np.float32),
             "objective": np.zeros(chunk, np.float32), "rel": np.zeros(chunk, np.float32),
             "steps": np.zeros(chunk, np.int32), "converged": np.zeros(chunk, bool),
             "refitted": np.zeros(chunk, bool), "dof": np.ones(chunk, np.int64)}
    stacked = {k: np.stack([r[k] for r in local] + [blank[k]] * (per - len(local))) for k in blank}
    gathered = multihost_utils.process_allgather(stacked)  # leaves (P, per, chunk, ...)
    for q in range(P):
        for j, k in enumerate(range(q, n_chunks, P)):
            store(k, {name: np.asarray(a[q, j]) for name, a in gathered.items()})


def initialize_processes(coordinator, num_processes, process_id, timeout=120) -> None:
    """Join JAX's multi-process runtime (``jax.distributed.initialize``) before any JAX work, so that
    :func:`fit_map` splits its chunks over ``num_processes`` processes.

    Parameters
    ----------
    coordinator : str
        ``host:port`` of process 0 (e.g. ``"127.0.0.1:12355"``).
    num_processes, process_id : int
        The number of processes (>= 1) and this one's index (from 0); out of range, or a
        malformed ``coordinator``, raises ParameterError.
    timeout : int
        Seconds to wait for every process to join.
    """
    for name, v, lo in (("num_processes", num_processes, 1), ("process_id", process_id, 0)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
            raise ParameterError(f"{name} must be an integer >= {lo}, got {v!r}")
    if process_id >= num_processes:
        raise ParameterError(f"process_id must be < num_processes = {num_processes}, got {process_id}")
    if not isinstance(coordinator, str) or ":" not in coordinator:
        raise ParameterError(f"coordinator must be 'host:port', got {coordinator!r}")
    import jax

    kw = {"coordinator_bind_address": coordinator} if process_id == 0 else {}
    jax.distributed.initialize(coordinator_address=coordinator, num_processes=int(num_processes),
                               process_id=int(process_id), initialization_timeout=int(timeout), **kw)

