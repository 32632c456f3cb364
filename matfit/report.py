"""Fit reports: a Markdown page, PNG figures and a JSON file of the numbers for one fit.

:func:`write_report` takes a :class:`~matfit.fitting.FitResult` and the table it was fitted to and
writes into ``out_dir``:

=================  ========================================================================
``report.md``      summary, parameter table (value, standard error, posterior, truth), metrics,
                   the figures below
``report.json``    the same numbers, machine-readable
``lobes.png``      in-plane lobes at up to four incidences: the table's rows near the plane of
                   incidence (points) against the fitted model (lines) and, when known, the true
                   model (dashed) on a fine in-plane sweep; ``f cos(theta_o)``, cube-root radius
``residuals.png``  residuals over the Rusinkiewicz angles (theta_h, theta_d): ``(fit - y) / sigma``
                   when the table has ``sigma``, else ``(fit - y) / (|y| + 1e-3)``, channel mean
``loss.png``       the loss history when given, else the objective reached by each start
``corner.png``     pairwise 2-D histograms of a posterior sample (only with ``posterior``)
=================  ========================================================================

Colour difference: every valid row is rendered as the linear sRGB radiance
``pi f cos(theta_i)`` (a white Lambertian at normal incidence gives 1) for the measured and the
fitted values; the mean over the rows is converted to XYZ (sRGB primaries, D65) and CIELAB, and
``colour.delta_E(..., method="CIE 2000")`` gives the difference of the mean appearance. The
per-row CIEDE2000 (median, 95th percentile) is reported as well. Mono tables are rendered grey;
spectral tables have no colour difference (``null`` in the JSON).

The fitted model is evaluated by one jitted call on one array that holds the table's rows and all
sweep directions, so a report compiles each model once (see ``docs/performance.md``).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from .io import dirs_to_half_diff
from .models import measured_model

__all__ = ["write_report", "colour_difference", "in_plane_slices", "param_table", "truth_for_label"]

#: Above this many valid rows, residual maps and colour differences use a random subset.
MAX_ROWS = 100_000
_SWEEP = np.linspace(-89.0, 89.0, 357)  # signed theta_o (degrees) of the in-plane sweeps


# ------------------------------------------------------------------------------------ truth
def _normalize_truth(truth, result, channels):
    """``(params dict or None, model or None)`` from what the caller gave as ``truth``."""
    if truth is None:
        return None, None
    if hasattr(truth, "eval"):
        return None, truth
    if not isinstance(truth, dict):
        raise TypeError(f"write_report: truth must be a dict of parameter values or a model, got {type(truth).__name__}")
    if "params" in truth or ("model" in truth and not isinstance(truth["model"], str)):
        params, model = truth.get("params"), truth.get("model")
        if truth.get("family") not in (None, result.family):
            params = None
    else:
        params, model = truth, None
    if params is not None and model is None:
        from .fitting import get_family

        fam = get_family(result.family)
        if all(p.name in params for p in fam.params):
            import jax.numpy as jnp

            full = {}
            for p in fam.params:
                v = jnp.asarray(params[p.name], dtype=float)
                full[p.name] = jnp.broadcast_to(jnp.atleast_1d(v), (channels,)) if p.per_channel else v
            model = fam.build(full, channels)
    return params, model


def truth_for_label(params, label):
    """The true value behind a parameter label (``"alpha"``, ``"eta[1]"``) in ``params``, or None.

    Parameters
    ----------
    params : dict or None
        True parameter values by name (scalars or per-channel sequences).
    label : str
        A parameter label: a name, or a name with a channel index (``"eta[1]"``).

    Returns
    -------
    float or None
        The value at the label's channel index (a single value serves every channel), or the
        mean of the values for a label without an index; None when ``params`` is empty, lacks
        the name, or the index is out of range.

    Examples
    --------
    >>> truth_for_label({"eta": [1.1, 1.2, 1.3]}, "eta[1]"), truth_for_label({"alpha": 0.2}, "k")
    (1.2, None)
    >>> truth_for_label({"eta": 1.5}, "eta[2]"), truth_for_label({"eta": [1.0, 2.0]}, "eta")
    (1.5, 1.5)
    """
    if not params:
        return None
    name, _, rest = label.partition("[")
    if name not in params:
        return None
    v = np.atleast_1d(np.asarray(params[name], float))
    if rest:
        i = int(rest.rstrip("]"))
        return float(v[i]) if i < v.size else (float(v[0]) if v.size == 1 else None)
    return float(v.mean())


# ------------------------------------------------------------------------------------ geometry
def _sph(w):
    return np.degrees(np.arccos(np.clip(w[:, 2], -1, 1))), np.arctan2(w[:, 1], w[:, 0])


def in_plane_slices(table, n_max=4, tol_theta=2.5, tol_plane=3.0):
    """Up to ``n_max`` incidences of ``table`` with its valid rows near their plane of incidence.

    The incidences are the distinct ``theta_i`` (rounded to 1 degree) of the in-plane rows that
    hold at least 3 of them (all of them when none does), evenly thinned to ``n_max``. Rows at
    normal incidence (``theta_i < 0.5`` degrees) use the x-z plane, with the light from ``-x``.

    Parameters
    ----------
    table : matfit.Table
        The measurements.
    n_max : int, default 4
        Most incidences returned.
    tol_theta : float, default 2.5
        Tolerance on ``theta_i`` (degrees).
    tol_plane : float, default 3.0
        Tolerance on the angle between ``wo`` and the plane of incidence (degrees).

    Returns
    -------
    list of tuple
        ``(theta_i_deg, phi_i_rad, rows, signed_theta_o_deg)`` per incidence: the median
        ``theta_i`` and the mean azimuth of the light (``pi`` at normal incidence), ``rows`` the
        indices of valid rows whose ``theta_i`` lies within ``tol_theta`` degrees of
        ``theta_i_deg`` and whose ``wo`` lies within ``tol_plane`` degrees of the plane through
        the normal and that row's ``wi``, and their signed viewing zenith, positive on the
        specular side (away from the light). Empty when no valid row is near its plane.

    Examples
    --------
    >>> import numpy as np
    >>> from matfit import Table
    >>> t = np.radians(np.arange(-60, 61, 10.0))
    >>> wo = np.stack([np.sin(t), 0 * t, np.cos(t)], -1)  # viewer swept through the x-z plane
    >>> wi = np.tile([-0.5, 0.0, np.sqrt(0.75)], (len(t), 1))  # light at 30 degrees, from -x
    >>> [(th, rows, to)] = [(th, rows, to) for th, _, rows, to in in_plane_slices(
    ...     Table(wo=wo, wi=wi, values=np.full((len(t), 3), 0.1)))]
    >>> round(th, 6), len(rows), np.round(to).astype(int).tolist()
    (30.0, 13, [-60, -50, -40, -30, -20, -10, 0, 10, 20, 30, 40, 50, 60])
    """
    valid = np.flatnonzero(table.valid)
    if valid.size == 0:
        return []
    wo, wi = table.wo[valid], table.wi[valid]
    ti, pi_ = _sph(wi)
    # Plane of incidence: normal n = z x (wi horizontal); distance of wo from it.
    hor = np.stack([np.cos(pi_), np.sin(pi_), 0 * pi_], -1)
    nrm = np.stack([-np.sin(pi_), np.cos(pi_), 0 * pi_], -1)
    off = np.degrees(np.arcsin(np.clip(np.abs(np.sum(wo * nrm, -1)), 0, 1)))
    # Normal incidence has no plane of its own: use the x-z plane (light "from -x").
    off0 = np.degrees(np.arcsin(np.clip(np.abs(wo[:, 1]), 0, 1)))
    near = np.where(ti < 0.5, off0, off) <= tol_plane
    if not near.any():
        return []
    # Candidate incidences: the distinct theta_i (to 1 degree) with the most in-plane rows.
    keys = np.round(ti[near]).astype(int)
    uniq, counts = np.unique(keys, return_counts=True)
    good = uniq[counts >= 3] if (counts >= 3).any() else uniq
    if good.size > n_max:
        good = good[np.round(np.linspace(0, good.size - 1, n_max)).astype(int)]
    out = []
    for t in good:
        sel = near & (np.abs(ti - t) <= tol_theta)
        if not sel.any():
            continue
        th = float(np.median(ti[sel]))
        ph = float(np.angle(np.mean(np.exp(1j * pi_[sel])))) if th >= 0.5 else math.pi
        # signed theta_o: + on the specular side, i.e. wo's horizontal part opposite to wi's
        to = np.degrees(np.arccos(np.clip(np.abs(wo[sel, 2]), -1, 1)))
        side = -np.sign(np.sum(wo[sel] * (hor[sel] if th >= 0.5 else np.array([-1.0, 0, 0])), -1))
        side = np.where(side == 0, 1.0, side)
        out.append((th, ph, valid[sel], side * to))
    return out


def _sweep_dirs(theta_i, phi_i):
    """(wo, wi) along the in-plane sweep: light at (theta_i, phi_i), viewer at signed zenith _SWEEP."""
    t = np.radians(theta_i)
    wi = np.array([np.sin(t) * np.cos(phi_i), np.sin(t) * np.sin(phi_i), np.cos(t)])
    s = np.radians(_SWEEP)
    # specular side: azimuth phi_i + pi
    wo = np.stack([-np.sin(s) * np.cos(phi_i), -np.sin(s) * np.sin(phi_i), np.cos(s)], -1)
    return wo, np.broadcast_to(wi, wo.shape).copy()


_JIT_EVAL = None


def _eval(model, wo, wi):
    """``model.eval`` in one jitted call (compiled once per model structure and shape); (N, C) float64."""
    global _JIT_EVAL
    import jax.numpy as jnp

    if _JIT_EVAL is None:
        import equinox as eqx

        _JIT_EVAL = eqx.filter_jit(lambda m, a, b: m.eval(a, b))
    f = np.asarray(_JIT_EVAL(model, jnp.asarray(wo), jnp.asarray(wi)), dtype=np.float64)
    return np.nan_to_num(f, nan=0.0, posinf=0.0, neginf=0.0)


# ------------------------------------------------------------------------------------ colour
def _to_lab(rgb, channels):
    import colour

    rgb = np.asarray(rgb, float)
    if channels == "mono":
        rgb = np.repeat(rgb[..., :1], 3, axis=-1)
    xyz = colour.RGB_to_XYZ(rgb, colour.RGB_COLOURSPACES["sRGB"], apply_cctf_decoding=False)
    white = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"]
    return colour.XYZ_to_Lab(xyz, white)


def colour_difference(measured, fitted, cos_i, channels):
    """CIEDE2000 between measured and fitted appearance (see the module docstring).

    Parameters
    ----------
    measured, fitted : ndarray (N, C)
        BRDF values of valid rows.
    cos_i : array_like (N,)
        Cosine of the incident zenith angle of each row (its absolute value is used).
    channels : str or sequence
        The table's channels: ``"rgb"``, ``"mono"`` (rendered grey) or spectral.

    Returns
    -------
    dict or None
        ``delta_e_mean_appearance``, ``delta_e_rows_median``, ``delta_e_rows_p95``, the two mean
        linear sRGB triples (``mean_rgb_measured``, ``mean_rgb_fitted``) and their Lab values
        (``lab_measured``, ``lab_fitted``); None for spectral channels.

    Examples
    --------
    >>> import numpy as np
    >>> y = np.full((2, 3), 0.1)
    >>> d = colour_difference(y, y, np.ones(2), "rgb")
    >>> d["delta_e_mean_appearance"], d["mean_rgb_measured"] == [np.pi * 0.1] * 3
    (0.0, True)
    >>> round(colour_difference(y, 1.1 * y, np.ones(2), "rgb")["delta_e_mean_appearance"], 2)
    2.12
    >>> colour_difference(y, y, np.ones(2), ("450nm", "550nm", "650nm")) is None
    True
    """
    import colour

    if channels not in ("rgb", "mono"):
        return None
    c = np.abs(np.asarray(cos_i, float))[:, None]
    rm, rf = np.pi * measured * c, np.pi * fitted * c
    rm_mean, rf_mean = rm.mean(0), rf.mean(0)
    lab_m, lab_f = _to_lab(rm_mean, channels), _to_lab(rf_mean, channels)
    de = float(colour.delta_E(lab_m, lab_f, method="CIE 2000"))
    de_rows = np.asarray(colour.delta_E(_to_lab(np.clip(rm, 0, None), channels), _to_lab(np.clip(rf, 0, None), channels),
                                        method="CIE 2000"))
    return {"delta_e_mean_appearance": de,
            "delta_e_rows_median": float(np.median(de_rows)), "delta_e_rows_p95": float(np.percentile(de_rows, 95)),
            "mean_rgb_measured": rm_mean.tolist(), "mean_rgb_fitted": rf_mean.tolist(),
            "lab_measured": np.asarray(lab_m).tolist(), "lab_fitted": np.asarray(lab_f).tolist()}


# ------------------------------------------------------------------------------------ posterior
def _posterior_samples(posterior):
    chain = np.asarray(posterior.chain, float)
    if chain.ndim == 3:
        chain = chain.reshape(-1, chain.shape[-1])
    elif chain.ndim != 2:
        raise ValueError(f"write_report: posterior.chain must be (steps, walkers, p) or (n, p), got shape {chain.shape}")
    labels = list(getattr(posterior, "labels", [f"p{i}" for i in range(chain.shape[1])]))
    chain = chain[np.all(np.isfinite(chain), axis=1)]
    return chain, labels


def _posterior_summary(samples, labels):
    out = {}
    for j, lab in enumerate(labels):
        x = samples[:, j]
        q = np.percentile(x, [2.5, 50, 97.5]) if x.size else [np.nan] * 3
        out[lab] = {"mean": float(np.mean(x)), "std": float(np.std(x)), "q2.5": float(q[0]), "median": float(q[1]),
                    "q97.5": float(q[2])}
    return out


# ------------------------------------------------------------------------------------ plots
_CH_COLOURS = {"rgb": ("tab:red", "tab:green", "tab:blue"), "mono": ("k",)}


def _plot_lobes(path, slices, meas, fit_sweep, truth_sweep, channels, n_ch):
    import matplotlib.pyplot as plt

    n = max(len(slices), 1)
    fig, axes = plt.subplots(1, n, subplot_kw={"projection": "polar"}, figsize=(4.2 * n, 4.4), squeeze=False)
    axes = axes[0]
    cols = _CH_COLOURS.get(channels) if isinstance(channels, str) else None
    show = range(n_ch) if cols else [None]  # spectral: channel mean
    if not slices:
        axes[0].set_title("no in-plane rows in this table", fontsize=9)
    for ax, (th, _ph, rows, to), ms, fs, ts in zip(axes, slices, meas, fit_sweep, truth_sweep or [None] * n):
        cos_o_pts = np.abs(np.cos(np.radians(to)))[:, None]
        cos_o_sw = np.abs(np.cos(np.radians(_SWEEP)))[:, None]
        for c in show:
            col = cols[c] if cols else "k"
            y_pts = ms * cos_o_pts
            y_fit = fs * cos_o_sw
            sel = (lambda a: a[:, c]) if c is not None else (lambda a: a.mean(-1))
            ax.plot(np.radians(_SWEEP), np.cbrt(np.clip(sel(y_fit), 0, None)), color=col, lw=1.2)
            if ts is not None:
                ax.plot(np.radians(_SWEEP), np.cbrt(np.clip(sel(ts * cos_o_sw), 0, None)), color=col, lw=1, ls="--",
                        alpha=0.7)
            ax.plot(np.radians(to), np.cbrt(np.clip(sel(y_pts), 0, None)), "o", color=col, ms=3, alpha=0.8)
        ax.set_theta_zero_location("N")
        ax.set_theta_direction(-1)
        ax.set_thetamin(-90)
        ax.set_thetamax(90)
        ax.set_yticklabels([])
        ax.set_title(f"theta_i = {th:.1f} deg ({len(rows)} rows)", fontsize=9)
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], color="k", marker="o", ls="", ms=3, label="measured"),
               Line2D([], [], color="k", lw=1.2, label="fitted")]
    if truth_sweep:
        handles.append(Line2D([], [], color="k", lw=1, ls="--", label="truth"))
    axes[0].legend(handles=handles, fontsize=7, loc="lower left")
    fig.suptitle("f cos(theta_o), cube-root radius, plane of incidence; light from the left", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _plot_residuals(path, th, td, res, res_label, logv):
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10.5, 4.2))
    lim = float(np.percentile(np.abs(res), 98)) if res.size else 1.0
    lim = lim if lim > 0 else 1.0
    big = res.size > 20000
    for ax, val, cmap, lab, kw in ((axes[0], res, "RdBu_r", res_label, dict(vmin=-lim, vmax=lim)),
                                   (axes[1], logv, "viridis", "log10 measured f (channel mean)", {})):
        if big:
            bins = [np.linspace(0, 90, 25), np.linspace(0, 90, 25)]  # 3.75 deg: no gaps on coarse grids
            s, _, _ = np.histogram2d(th, td, bins=bins, weights=val)
            c, _, _ = np.histogram2d(th, td, bins=bins)
            with np.errstate(invalid="ignore"):
                m = np.where(c > 0, s / np.maximum(c, 1), np.nan)
            im = ax.pcolormesh(bins[0], bins[1], m.T, cmap=cmap, shading="flat", **kw)
        else:
            im = ax.scatter(th, td, c=val, cmap=cmap, s=14 if res.size < 2000 else 4, edgecolors="none", **kw)
        fig.colorbar(im, ax=ax, label=lab)
        ax.set_xlabel("theta_h (deg)")
        ax.set_ylabel("theta_d (deg)")
        ax.set_xlim(0, 90)
        ax.set_ylim(0, 90)
    axes[0].set_title("fit residual" + (" (binned mean)" if big else ""), fontsize=10)
    axes[1].set_title("measured" + (" (binned mean)" if big else ""), fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _plot_loss(path, result, history):
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.6))
    if history is not None and len(history):
        h = history
        if isinstance(h[0], (list, tuple, np.ndarray)):
            so = np.asarray(result.start_objectives, float)
            best = int(np.nanargmin(np.where(np.isfinite(so), so, np.inf))) if so.size == len(h) else -1
            for i, hh in enumerate(h):
                ax.semilogy(np.arange(len(hh)), np.asarray(hh, float), lw=2.0 if i == best else 1.0,
                            label=f"start {i}" + (" (best)" if i == best else ""))
            ax.legend(fontsize=7)
        else:
            ax.semilogy(np.arange(len(h)), np.asarray(h, float), "-o", ms=2)
        ax.set_xlabel("iteration")
        ax.set_ylabel("objective (0.5 RSS)")
        ax.set_title("loss history", fontsize=10)
    else:
        so = np.asarray(result.start_objectives, float)
        best = int(np.nanargmin(np.where(np.isfinite(so), so, np.inf))) if so.size else -1
        colors = ["tab:orange" if i == best else "tab:gray" for i in range(so.size)]
        ax.bar(np.arange(so.size), np.where(np.isfinite(so), so, np.nan), color=colors)
        if so.size and np.all(np.isfinite(so)) and np.all(so > 0):
            ax.set_yscale("log")
        ax.set_xticks(np.arange(so.size))
        ax.set_xlabel("start")
        ax.set_ylabel("final objective (0.5 RSS)")
        ax.set_title(f"objective per start (best: start {best}, {result.steps} steps)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _plot_corner(path, samples, labels, fit_vals, truth_vals, max_params=10):
    import matplotlib.pyplot as plt

    p = min(samples.shape[1], max_params)
    fig, axes = plt.subplots(p, p, figsize=(1.7 * p + 1, 1.7 * p + 1), squeeze=False)
    for i in range(p):
        for j in range(p):
            ax = axes[i, j]
            if j > i:
                ax.axis("off")
                continue
            if i == j:
                ax.hist(samples[:, i], bins=30, color="tab:blue", histtype="stepfilled", alpha=0.6)
                ax.set_yticks([])
            else:
                ax.hist2d(samples[:, j], samples[:, i], bins=30, cmap="Blues")
                if fit_vals[i] is not None:
                    ax.axhline(fit_vals[i], color="tab:orange", lw=0.8)
                if truth_vals[i] is not None:
                    ax.axhline(truth_vals[i], color="k", lw=0.8, ls="--")
            if fit_vals[j] is not None:
                ax.axvline(fit_vals[j], color="tab:orange", lw=0.8)
            if truth_vals[j] is not None:
                ax.axvline(truth_vals[j], color="k", lw=0.8, ls="--")
            ax.tick_params(labelsize=6)
            if i == p - 1:
                ax.set_xlabel(labels[j], fontsize=8)
            else:
                ax.set_xticklabels([])
            if j == 0 and i > 0:
                ax.set_ylabel(labels[i], fontsize=8)
            elif j > 0:
                ax.set_yticklabels([])
    fig.suptitle("posterior (orange: least-squares fit, dashed: truth)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


# ------------------------------------------------------------------------------------ main entry
def _fmt(x, nd=5):
    if x is None:
        return "-"
    if isinstance(x, float) and not math.isfinite(x):
        return "nan"
    return f"{x:.{nd}g}"


def write_report(result, table, out_dir, posterior=None, truth=None, history=None, title=None, max_rows=MAX_ROWS,
                 seed=0, preview=True, measured="auto") -> dict:
    """Write a fit report (``report.md``, ``report.json``, PNG figures) into ``out_dir``.

    The files are listed in the module docstring. The fitted model is also written as
    ``model.json`` (:func:`matfit.export.save_model`), which ``matfit export`` and
    ``matfit render`` read.

    Parameters
    ----------
    result : matfit.fitting.FitResult
        The fit.
    table : matfit.Table
        The table that was fitted (the full table; a subsampled fit may be reported against it).
    out_dir : str or path-like
        The report's folder, created if needed.
    posterior : matfit.fitting.PosteriorResult, optional
        Or any object with ``.chain`` (steps, walkers, p) or (n, p) and ``.labels``; adds
        posterior columns (mean, standard deviation, 95 % interval of the finite samples) and
        ``corner.png``.
    truth : dict or model, optional
        Known true values: a dict of the family's parameters, a matfit model, or the output of
        :func:`data_synth.truth_from_table` (``{"params": ..., "model": ..., "family": ...}``;
        its ``params`` are ignored when ``family`` is another family); adds a truth column and
        dashed truth lobes (a dict of all the family's parameters builds the true model).
    history : sequence of float, or sequence of sequences, optional
        Objective values per iteration (or one sequence per start), plotted in ``loss.png``;
        without it the objective reached by each start is plotted.
    title : str, optional
        The report's title (default ``"<family> fit"``).
    max_rows : int, default :data:`MAX_ROWS`
        Above this many valid rows, residual maps, metrics and colour difference use a random
        subset of that many.
    seed : int, default 0
        Seed of that row subset.
    preview : bool, default True
        Render spheres under the built-in sky (:func:`matfit.render.render_sphere`): the
        reference (the truth of a synthetic table, else the measured table as a model) | the
        fit | their difference, in ``preview.png``, with the images' mean CIEDE2000; without a
        reference the fitted sphere alone. Models of other than 1 or 3 channels are not rendered.
    measured : "auto", model or None, default "auto"
        The measured table as a model, the preview's reference when there is no truth:
        ``"auto"`` reads it from the file the table's provenance names when that is an RGL
        ``.bsdf`` (:class:`~matfit.models.MeasuredRGL`) or a MERL ``.binary``
        (:class:`~matfit.models.MeasuredMERL`) that still exists; None renders no reference.

    Returns
    -------
    dict
        The numbers written to ``report.json``: ``title``, ``model``, ``preview``, ``family``,
        ``method``, ``loss``, ``converged``, ``steps``, ``wall_time_s``, ``warnings``,
        ``start_objectives``, ``table``, ``params`` (one dict per label: value, standard
        error, and truth and posterior where known), ``fixed``, ``metrics``,
        ``colour_difference`` (see :func:`colour_difference`), ``posterior``,
        ``truth_available``, ``loss_history`` and ``files``.

    Raises
    ------
    matfit.errors.ParameterError
        When ``result`` is not a fit result or ``table`` not a :class:`~matfit.Table`.
    ValueError
        When the table has no valid rows, or ``posterior.chain`` has another shape.
    TypeError
        When ``truth`` is neither a dict nor a model.

    Examples
    --------
    >>> import numpy as np, os, tempfile
    >>> from matfit import Table
    >>> from matfit.fitting import fit
    >>> wo = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, 0.6, 0.8]]); wi = wo[[1, 2, 0]]
    >>> table = Table(wo=wo, wi=wi, values=np.full((3, 3), 0.1))
    >>> r = fit(table, model="lambert", starts=1)
    >>> with tempfile.TemporaryDirectory() as d:
    ...     summary = write_report(r, table, d, truth={"albedo": [np.pi * 0.1] * 3}, preview=False)
    ...     names = sorted(os.listdir(d))
    >>> names
    ['lobes.png', 'loss.png', 'model.json', 'report.json', 'report.md', 'residuals.png']
    >>> summary["params"][0]["label"], round(summary["params"][0]["truth"], 4), summary["truth_available"]
    ('albedo[0]', 0.3142, True)
    >>> round(summary["colour_difference"]["delta_e_mean_appearance"], 3)
    0.0
    """
    from .errors import ParameterError
    from .table import Table

    if not all(hasattr(result, a) for a in ("params", "labels", "values", "stderr", "model", "objective")):
        raise ParameterError(f"write_report: result must be a matfit FitResult (from matfit.fitting.fit), "
                             f"got {type(result).__name__}")
    if not isinstance(table, Table):
        raise ParameterError(f"write_report: table must be a matfit.Table, got {type(table).__name__}")
    import matplotlib

    matplotlib.use("Agg")

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    C = table.n_channels
    t_params, t_model = _normalize_truth(truth, result, C)

    valid = np.flatnonzero(table.valid)
    if valid.size == 0:
        raise ValueError("write_report: the table has no valid rows")
    rows = valid
    if rows.size > max_rows:
        rows = np.sort(np.random.default_rng(seed).choice(valid, size=max_rows, replace=False))
    slices = in_plane_slices(table)
    sweeps = [_sweep_dirs(th, ph) for th, ph, _, _ in slices]

    # One jitted call per model over rows + sweeps.
    wo_all = np.concatenate([table.wo[rows]] + [s[0] for s in sweeps])
    wi_all = np.concatenate([table.wi[rows]] + [s[1] for s in sweeps])
    f_all = _eval(result.model, wo_all, wi_all)
    if f_all.shape[-1] != C:
        f_all = np.broadcast_to(f_all, f_all.shape[:-1] + (C,))
    f_rows = f_all[: rows.size]
    fit_sweep = [f_all[rows.size + i * _SWEEP.size: rows.size + (i + 1) * _SWEEP.size] for i in range(len(sweeps))]
    truth_sweep = None
    if t_model is not None and sweeps:
        g = _eval(t_model, np.concatenate([s[0] for s in sweeps]), np.concatenate([s[1] for s in sweeps]))
        g = np.broadcast_to(g, g.shape[:-1] + (C,))
        truth_sweep = [g[i * _SWEEP.size:(i + 1) * _SWEEP.size] for i in range(len(sweeps))]
    meas = [table.values[r] for _, _, r, _ in slices]

    files = {}
    _plot_lobes(out / "lobes.png", slices, meas, fit_sweep, truth_sweep, table.channels, C)
    files["lobes"] = "lobes.png"

    # Residuals over (theta_h, theta_d).
    y = table.values[rows]
    th, _, td, _ = dirs_to_half_diff(table.wo[rows], table.wi[rows])
    th, td = np.degrees(th), np.degrees(td)
    if table.sigma is not None:
        res = ((f_rows - y) / table.sigma[rows]).mean(-1)
        res_label = "(fit - measured) / sigma"
    else:
        res = ((f_rows - y) / (np.abs(y) + 1e-3)).mean(-1)
        res_label = "(fit - measured) / (|measured| + 1e-3)"
    logv = np.log10(np.maximum(y.mean(-1), 1e-6))
    _plot_residuals(out / "residuals.png", th, td, res, res_label, logv)
    files["residuals"] = "residuals.png"

    _plot_loss(out / "loss.png", result, history)
    files["loss"] = "loss.png"

    # Metrics.
    err = f_rows - y
    rmse = float(np.sqrt(np.mean(err ** 2)))
    rms_y = float(np.sqrt(np.mean(y ** 2)))
    metrics = {
        "n_rows_evaluated": int(rows.size), "n_valid": int(valid.size),
        "rmse": rmse, "relative_rmse": rmse / rms_y if rms_y > 0 else None,
        "median_abs_relative_error": float(np.median(np.abs(err) / (np.abs(y) + 1e-3))),
        "rmse_per_channel": np.sqrt(np.mean(err ** 2, axis=0)).tolist(),
        "objective": float(result.objective), "rss": float(result.rss), "n_residuals": int(result.n_residuals),
        "dof": int(result.dof), "reduced_chi2": float(result.rss / max(result.dof, 1)),
    }
    if table.sigma is not None:
        metrics["chi2_per_row_evaluated"] = float(np.mean(((f_rows - y) / table.sigma[rows]) ** 2))
    cd = colour_difference(y, f_rows, table.wi[rows, 2], table.channels)

    # Parameter table.
    post = None
    post_samples = None
    if posterior is not None:
        post_samples, post_labels = _posterior_samples(posterior)
        post = _posterior_summary(post_samples, post_labels)
    params = []
    for lab, v, s in zip(result.labels, result.values, result.stderr):
        row = {"label": lab, "value": float(v), "stderr": float(s)}
        tv = truth_for_label(t_params, lab)
        if tv is not None:
            row["truth"] = tv
            row["error"] = float(v) - tv
            row["error_in_stderr"] = (float(v) - tv) / float(s) if s > 0 else None
        if post and lab in post:
            row["posterior"] = post[lab]
        params.append(row)
    fixed = {k: np.asarray(v).tolist() for k, v in result.params.items()
             if not any(l == k or l.startswith(k + "[") for l in result.labels)}

    if post_samples is not None and post_samples.shape[0] > 1:
        fv = [next((r["value"] for r in params if r["label"] == lab), None) for lab in post_labels]
        tvs = [truth_for_label(t_params, lab) for lab in post_labels]
        _plot_corner(out / "corner.png", post_samples, post_labels, fv, tvs)
        files["corner"] = "corner.png"

    from .export import describe_model, save_model

    save_model(out / "model.json", result.model, family=result.family)
    files["model"] = "model.json"
    previews = None
    if preview:
        ref = (t_model, "truth") if t_model is not None else (
            (measured_model(table) if isinstance(measured, str) and measured == "auto" else measured), "measured")
        previews = _previews(out, result, ref, files)

    summary = {
        "title": title or f"{result.family} fit",
        "model": describe_model(result.model), "preview": previews,
        "family": result.family, "method": result.method, "loss": result.loss,
        "converged": bool(result.converged), "steps": int(result.steps), "wall_time_s": float(result.wall_time),
        # a chosen fit's appearance warning is among its own warnings already
        "warnings": list(getattr(result, "warnings", [])) + ([previews["warning"]] if previews and previews.get(
            "warning") and getattr(result, "appearance", None) is None else []),
        "choice": result.choice.to_dict() if getattr(result, "choice", None) is not None else None,
        "start_objectives": np.asarray(result.start_objectives, float).tolist(),
        "table": {"n": len(table), "n_valid": int(table.n_valid), "channels": table.channels if isinstance(table.channels, str)
                  else list(table.channels), "source": table.provenance.get("source") or table.provenance.get("scene")},
        "params": params, "fixed": fixed, "metrics": metrics, "colour_difference": cd,
        "posterior": {"n_samples": int(post_samples.shape[0]), "summary": post} if post is not None else None,
        "truth_available": t_params is not None or t_model is not None,
        "loss_history": _history_json(history),
        "files": files,
    }
    files["json"] = "report.json"
    files["markdown"] = "report.md"
    with open(out / "report.json", "w") as fh:
        json.dump(summary, fh, indent=2, allow_nan=True)
    _write_markdown(out / "report.md", summary, table, result, t_params is not None, post is not None, files)
    return summary


def _history_json(history):
    """The loss history as lists (one per start), or None."""
    if history is None or not len(history):
        return None
    if isinstance(history[0], (list, tuple, np.ndarray)):
        return [np.asarray(h, float).tolist() for h in history]
    return [np.asarray(history, float).tolist()]


def _previews(out, result, reference, files):
    """Render ``preview.png``: per judging lighting, reference | fitted | FLIP map (noise-free,
    :mod:`matfit.appearance`), or the fitted spheres alone; ``reference`` is ``(model or None, name)``."""
    from .appearance import JUDGE_LIGHTS, SIZE, appearance_difference, display, lighting, render_lit
    from .render import save_png, srgb_decode

    model = result.model
    if model.channels not in (1, 3):
        return {"skipped": f"{model.channels} channels (previews need 1 or 3)"}
    reference, ref_name = reference
    info = {"renderer": "quadrature over each lighting (noise-free, matfit.appearance)", "size": SIZE,
            "lights": {k: lighting(k).description for k in JUDGE_LIGHTS}}
    if reference is not None and getattr(reference, "channels", 0) in (1, 3):
        judged = getattr(result, "appearance", None)  # a chosen fit was judged already
        diff = judged if judged is not None else appearance_difference(model, reference)
        import matplotlib

        magma = matplotlib.colormaps["magma"]
        rows = [np.concatenate([d.reference, d.fitted, srgb_decode(magma(np.clip(d.flip, 0, 1))[..., :3])], axis=1)
                for d in diff.lights.values()]
        info.update(diff.to_dict(), panels=[ref_name, "fitted", "FLIP"])
        w = diff.warning(ref_name)
        if w:
            info["warning"] = w
        img = np.concatenate(rows, axis=0)
    else:
        info["panels"] = ["fitted"]
        img = np.concatenate([display(render_lit(model, k)[0], lighting(k).exposure) for k in JUDGE_LIGHTS], axis=0)
    # the images are already exposed for display; shown twice as large (nearest pixel)
    save_png(out / "preview.png", np.repeat(np.repeat(img, 2, axis=0), 2, axis=1))
    files["preview"] = "preview.png"
    return info


def _write_markdown(path, s, table, result, has_truth, has_post, files):
    L = [f"# {s['title']}", ""]
    L.append(f"Family **{s['family']}**, method `{s['method']}`, loss `{s['loss']}`: objective {_fmt(s['metrics']['objective'])}, "
             f"{s['steps']} steps, converged = {s['converged']}, {s['wall_time_s']:.2f} s.")
    if s.get("warnings"):
        L += ["", "**Diagnostics** (`matfit.fitting.diagnostics`):", ""] + [f"- {w}" for w in s["warnings"]]
    L += ["", "```", table.summary(), "```", ""] + _choice_markdown(s.get("choice")) + ["## Parameters", ""]
    head = ["parameter", "value", "std. error"]
    if has_post:
        head += ["posterior mean", "posterior std", "95 % interval"]
    if has_truth:
        head += ["truth", "error / std. error"]
    L.append("| " + " | ".join(head) + " |")
    L.append("|" + " --- |" * len(head))
    for r in s["params"]:
        cells = [r["label"], _fmt(r["value"]), _fmt(r["stderr"], 2)]
        if has_post:
            p = r.get("posterior")
            cells += ([_fmt(p["mean"]), _fmt(p["std"], 2), f"[{_fmt(p['q2.5'], 4)}, {_fmt(p['q97.5'], 4)}]"] if p
                      else ["-"] * 3)
        if has_truth:
            cells += [_fmt(r.get("truth")), _fmt(r.get("error_in_stderr"), 3)]
        L.append("| " + " | ".join(cells) + " |")
    if s["fixed"]:
        L += ["", "Fixed: " + ", ".join(f"`{k}` = {v}" for k, v in s["fixed"].items())]
    m = s["metrics"]
    L += ["", "## Fit quality", "",
          "| metric | value |", "| --- | --- |",
          f"| rows evaluated / valid | {m['n_rows_evaluated']} / {m['n_valid']} |",
          f"| RMSE (1/sr) | {_fmt(m['rmse'], 4)} |",
          f"| relative RMSE (RMSE / RMS value) | {_fmt(m['relative_rmse'], 4)} |",
          f"| median abs. relative error | {_fmt(m['median_abs_relative_error'], 4)} |",
          f"| RSS (fit loss) / dof | {_fmt(m['rss'], 5)} / {m['dof']} = {_fmt(m['reduced_chi2'], 4)} |"]
    cd = s["colour_difference"]
    if cd:
        L += [f"| CIEDE2000, mean appearance | {cd['delta_e_mean_appearance']:.3f} |",
              f"| CIEDE2000 per row, median / 95th pct. | {cd['delta_e_rows_median']:.3f} / {cd['delta_e_rows_p95']:.3f} |"]
    else:
        L.append("| CIEDE2000 | n/a (spectral channels) |")
    L += ["", "Appearance: each row rendered as linear sRGB `pi f cos(theta_i)`, averaged over the rows, "
          "converted to CIELAB (D65) and compared with CIEDE2000.", ""]
    L += ["## Figures", "", "In-plane lobes (points: measured, lines: fitted" + (", dashed: truth" if s["truth_available"] else "")
          + "):", "", "![lobes](lobes.png)", "", "Residuals over the Rusinkiewicz angles:", "", "![residuals](residuals.png)",
          "", "Loss:", ""]
    hist = s.get("loss_history")
    if hist:
        hb = min(hist, key=lambda h: h[-1])
        L += [f"Loss history: objective after each solver iteration, {len(hist)} start(s); the best start went "
              f"from {_fmt(hb[0], 4)} to {_fmt(hb[-1], 6)} in {len(hb) - 1} iterations (values per iteration in "
              "`report.json`, `loss_history`).", ""]
    else:
        L += ["No per-iteration history was given: the plot shows the objective each start reached.", ""]
    L += ["![loss](loss.png)", ""]
    if "corner" in files:
        L += ["Posterior:", "", "![corner](corner.png)", ""]
    L += _appearance_markdown(s.get("preview"), files)
    L += ["Numbers: `report.json`. The fitted model: `model.json` (`matfit export model.json --to gltf -o m.gltf`).", ""]
    Path(path).write_text("\n".join(L))


def _appearance_markdown(pv, files):
    if not pv or "preview" not in files:
        return []
    what = " | ".join(pv["panels"])
    L = ["## Appearance", "", f"Spheres rendered noise-free ({pv['renderer']}, {pv['size']} px), one row per lighting: "
         f"{what}{' (FLIP per pixel, magma: black 0, white 1)' if 'FLIP' in pv['panels'] else ''}. Lightings: " + "; ".join(
        f"`{k}`, {v}" for k, v in pv["lights"].items()) + ".", ""]
    if "looks_alike" in pv:
        from .appearance import CIEDE2000_LINE, FLIP_LINE

        L += ["| lighting | mean FLIP | mean CIEDE2000 | mean ΔE_ITP | FLIP near the mirror / at grazing / elsewhere |",
              "| --- | --- | --- | --- | --- |"]
        for k in pv["lights"]:
            m, r = pv[k]["means"], pv[k]["regions"]
            L.append(f"| {k} | {m['flip']:.3f} | {m['ciede2000']:.2f} | {m['itp']:.2f} | "
                     f"{r['near_mirror']:.3f} / {r['grazing']:.3f} / {r['elsewhere']:.3f} |")
        L += ["", (f"The fit looks like its reference: under every lighting mean FLIP <= {FLIP_LINE} and mean CIEDE2000 "
                   f"<= {CIEDE2000_LINE}." if pv["looks_alike"] else f"**{pv.get('warning', '')}**"), ""]
    else:
        L += ["No reference to render beside the fit (neither a truth nor a measured file that matfit reads as a "
              "model).", ""]
    return L + ["![preview](preview.png)", ""]


def _choice_markdown(c):
    if not c:
        return []
    by_image = c["judged_by"] == "appearance"
    L = ["## Why this family", "", f"Chosen by {c['judged_by']}: **{c['chosen']}**, {c['reason']}.", "",
         "| family | parameters | why a candidate | " + (
             "score | worst mean FLIP | worst mean CIEDE2000 |" if by_image else "held-out RMSE |"),
         "|" + " --- |" * (6 if by_image else 4)]
    for r in c["candidates"]:
        if "error" in r:
            L.append(f"| {r['family']} | {r['p']} | {r['why']} | failed: {r['error']} |" + (" | |" if by_image else ""))
        elif "score" in r:
            a = r["appearance"]
            L.append(f"| {r['family']}{' (chosen)' if r['family'] == c['chosen'] else ''} | {r['p']} | {r['why']} | "
                     f"{r['score']:.2f} | {max(v['flip'] for v in a.values()):.3f} | "
                     f"{max(v['ciede2000'] for v in a.values()):.2f} |")
        else:
            L.append(f"| {r['family']}{' (chosen)' if r['family'] == c['chosen'] else ''} | {r['p']} | {r['why']} | "
                     f"{r['holdout_rmse']:.4g} |")
    L.append("")
    if c["missing"]:
        L += ["The data show effects no family here carries: " + "; ".join(c["missing"]) + ".", ""]
    return L


def param_table(result, truth_params=None, posterior=None):
    """The parameter table the CLI and the demo print: value, standard error, and where given the
    posterior median and 90 % interval and the truth with the error in standard errors.

    Parameters
    ----------
    result : matfit.fitting.FitResult
    truth_params : dict, optional
        True parameter values (a synthetic table's).
    posterior : matfit.fitting.PosteriorResult, optional

    Returns
    -------
    str
        A header line and a line per free parameter (an example: ``docs/examples.md``).
    """
    head = f"  {'parameter':14s} {'value':>12s} {'std. error':>11s}"
    post = {}
    if posterior is not None:
        head += f" {'post. median':>12s} {'90% interval':>25s}"
        post = {lab: i for i, lab in enumerate(posterior.labels)}
    if truth_params:
        head += f" {'truth':>12s} {'error/se':>9s}"
    lines = [head]
    for lab, v, se in zip(result.labels, result.values, result.stderr):
        line = f"  {lab:14s} {v:12.6g} {se:11.3g}"
        if posterior is not None:
            i = post.get(lab)
            line += (f" {posterior.median[i]:12.6g} {'[%.5g, %.5g]' % tuple(posterior.ci90[i]):>25s}" if i is not None
                     else f" {'-':>12s} {'-':>25s}")
        if truth_params:
            tv = truth_for_label(truth_params, lab)
            line += (f" {tv:12.6g} {(v - tv) / se if se > 0 else float('nan'):9.2f}" if tv is not None
                     else f" {'-':>12s} {'-':>9s}")
        lines.append(line)
    if posterior is not None:
        for lab in posterior.labels:
            if lab not in result.labels:
                i = post[lab]
                lines.append(f"  {lab:14s} {'-':>12s} {'-':>11s} {posterior.median[i]:12.6g} "
                             f"{'[%.5g, %.5g]' % tuple(posterior.ci90[i]):>25s}")
    return "\n".join(lines)
