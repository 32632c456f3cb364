"""The built-in demo: evaluate and sample every core model (lobes, albedos), then the main job on the
built-in scene ``data_synth/scenes/demo.toml``: synthesize a measurement, fit it, sample the posterior,
compare model families, write a report and print the true against the recovered parameters."""

from __future__ import annotations

import csv
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from .models import Lambert, RoughConductor, RoughDielectric, SmoothConductor, SmoothDielectric

#: Gold's complex index at roughly R, G, B wavelengths (Johnson & Christy 1972).
GOLD_ETA = (0.143, 0.374, 1.442)
GOLD_K = (3.983, 2.385, 1.603)


def demo_materials():
    """The built-in scene's materials, by name.

    Returns
    -------
    dict
        Material name -> matfit model: a white Lambertian, rough gold (GGX, Beckmann and an
        anisotropic GGX), frosted glass, polished gold and clear glass (gold's index:
        :data:`GOLD_ETA`, :data:`GOLD_K`).

    Examples
    --------
    >>> from matfit.demo import demo_materials
    >>> mats = demo_materials()
    >>> len(mats), [name for name, m in mats.items() if m.is_delta]
    (7, ['polished gold', 'clear glass (1.5)'])
    """
    eta, k = jnp.array(GOLD_ETA), jnp.array(GOLD_K)
    return {
        "white diffuse": Lambert(0.8),
        "rough gold (GGX 0.2)": RoughConductor(0.2, eta, k),
        "rough gold (Beckmann 0.2)": RoughConductor(0.2, eta, k, distribution="beckmann"),
        "brushed gold (GGX 0.05 x 0.3)": RoughConductor(0.05, eta, k, alpha_y=0.3),
        "frosted glass (GGX 0.3, 1.5)": RoughDielectric(0.3, 1.5),
        "polished gold": SmoothConductor(eta, k),
        "clear glass (1.5)": SmoothDielectric(1.5),
    }


def _in_plane(theta_deg, phi=0.0):
    t = np.radians(theta_deg)
    return np.stack([np.sin(t) * np.cos(phi), np.sin(t) * np.sin(phi) + 0 * t, np.cos(t)], -1)


def run_demo(out: Path, fit_flow: bool = True) -> None:
    """Write ``lobes.png`` and ``albedo.csv`` into ``out``; with ``fit_flow``, also the fitting job
    (``demo_synth.npz``, ``report/``, ``compare.json``).

    ``lobes.png`` shows the in-plane lobes of the non-delta materials of :func:`demo_materials`
    at three incidences; ``albedo.csv`` holds each material's directional albedo at three
    viewing angles by quadrature and by importance sampling (also printed).

    Parameters
    ----------
    out : str or path-like
        Output folder, created if needed.
    fit_flow : bool, default True
        Also run :func:`run_fit_demo` into ``out``.

    Examples
    --------
    >>> import contextlib, io, os, tempfile
    >>> from matfit.demo import run_demo
    >>> with tempfile.TemporaryDirectory() as d:  # doctest: +SKIP
    ...     with contextlib.redirect_stdout(io.StringIO()):  # the albedo table
    ...         run_demo(d, fit_flow=False)
    ...     sorted(os.listdir(d))
    ['albedo.csv', 'lobes.png']
    """
    out = Path(out)
    _models_tour(out)
    if fit_flow:
        run_fit_demo(out)


def _models_tour(out: Path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    mats = demo_materials()
    thetas_in = (0.0, 30.0, 60.0)
    # In-plane lobes: wi (light) fixed, wo swept over the whole circle of the incidence plane.
    sweep = np.linspace(-180, 180, 721)
    wo_sweep = jnp.asarray(np.stack([np.sin(np.radians(sweep)), 0 * sweep, np.cos(np.radians(sweep))], -1))
    rough = {k: v for k, v in mats.items() if not v.is_delta}
    fig, axes = plt.subplots(1, len(rough), subplot_kw={"projection": "polar"}, figsize=(4 * len(rough), 4.2))
    for ax, (name, m) in zip(axes, rough.items()):
        for th in thetas_in:
            wi = jnp.broadcast_to(jnp.asarray(_in_plane(-th)), wo_sweep.shape)
            f = np.asarray(m.eval(wo_sweep, wi) * jnp.abs(wo_sweep[:, 2:3]))
            ax.plot(np.radians(sweep), np.cbrt(f.mean(axis=-1)), label=f"{th:.0f} deg")
        ax.set_theta_zero_location("N")
        ax.set_theta_direction(-1)
        ax.set_title(name, fontsize=9)
        ax.set_yticklabels([])
    axes[0].legend(fontsize=7, loc="lower left")
    fig.suptitle("f cos (cube root), plane of incidence; light from the left")
    fig.tight_layout()
    fig.savefig(out / "lobes.png", dpi=90)
    plt.close(fig)

    # Directional albedo by quadrature and by importance sampling, side by side.
    rows = []
    for name, m in mats.items():
        for th in (0.0, 45.0, 75.0):
            wo = jnp.asarray(_in_plane(th))
            e_mc = np.asarray(m.albedo(wo, method="mc", n=2**15, key=jax.random.PRNGKey(1)))
            e_q = np.asarray(m.albedo(wo, method="quadrature", n=64))
            rows.append((name, th, float(e_q.mean()), float(e_mc.mean())))
    with open(out / "albedo.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["material", "theta_o_deg", "albedo_quadrature", "albedo_sampled"])
        w.writerows(rows)
    print(f"{'material':34s} {'theta_o':>7s} {'E quad':>8s} {'E sampled':>9s}")
    for name, th, q, s in rows:
        print(f"{name:34s} {th:7.0f} {q:8.4f} {s:9.4f}")
    print(f"wrote {out / 'lobes.png'} and {out / 'albedo.csv'}")


def run_fit_demo(out: Path, scene="demo", family="conductor", mcmc_steps=30000, compare=("lambert", "conductor")):
    """Synthesize the built-in scene, then run the main job on it (:func:`matfit.pipeline.run_pipeline`).

    Parameters
    ----------
    out : str or path-like
        Output folder, created if needed: ``demo_synth.npz``, ``report/`` (see
        :func:`matfit.report.write_report`) and ``compare.json``.
    scene : str, default "demo"
        A shipped data_synth scene.
    family : str, default "conductor"
        The family fitted.
    mcmc_steps : int, default 30000
        Cap on the posterior's MCMC steps (0: no posterior).
    compare : sequence of str
        Families compared on a hold-out split.

    Returns
    -------
    dict
        The report's numbers.

    Examples
    --------
    >>> import contextlib, io, tempfile
    >>> from matfit.demo import run_fit_demo
    >>> with tempfile.TemporaryDirectory() as d:  # doctest: +SKIP
    ...     with contextlib.redirect_stdout(io.StringIO()):
    ...         numbers = run_fit_demo(d)
    >>> numbers["metrics"]["relative_rmse"] < 0.05  # doctest: +SKIP
    True
    """
    import time

    from data_synth import load_scene, synthesize, truth_from_table

    from .io import save
    from .pipeline import run_pipeline

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    table = synthesize(load_scene(scene))
    save(out / "demo_synth.npz", table)
    print(f"\n== fitting the built-in scene '{scene}': {table.provenance.get('description', '')}")
    print(f"wrote {out / 'demo_synth.npz'}: {len(table)} rows, channels {table.channels}")
    res = run_pipeline(table, family, posterior_steps=mcmc_steps, truth=truth_from_table(table, family),
                       report=out / "report", title=f"{family} fit of the built-in scene '{scene}'",
                       compare=compare, compare_json=out / "compare.json")
    print(f"fitting job: {time.perf_counter() - t0:.1f} s")
    return res.report
