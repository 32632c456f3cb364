"""Command-line interface: ``matfit demo``, ``synth``, ``info``, ``fit``, ``compare``, ``export``, ``render``,
``fit-map``.

Examples
--------
``python -m matfit demo --out demo_out`` evaluates and samples the built-in materials, writes a
polar lobe plot (``lobes.png``) and a table of directional albedos (``albedo.csv``).

``matfit synth SCENE.toml -o TABLE.npz`` renders a synthetic measurement (data_synth); a shipped scene
may be named without its folder (``matfit synth demo -o demo.npz``). ``matfit info TABLE`` prints the
summary of any table or measured file that ``matfit.io.load`` reads.

``matfit fit TABLE --model conductor --method lm --report DIR`` fits a model family to any file that
``matfit.io.load`` reads (.npz, .csv, MERL .binary, RGL .bsdf, .alta), prints the parameter table (with the
truth when the table is synthetic) and, with ``--report``, writes a report (``matfit.report``).
``--method mcmc`` runs a least-squares fit and then samples the posterior (``matfit.fitting.mcmc``).
``matfit compare TABLE --models lambert,conductor,plastic`` compares families on a hold-out split
(``matfit.fitting.select``).

``matfit fit TABLE --model plastic --export gltf paint.gltf`` also writes the material for a renderer
(``mitsuba``, ``mitsuba-xml``, ``pbrt``, ``gltf``, ``mtlx``, ``openpbr``, ``usd``; ``matfit.export``) and prints how exactly each
parameter maps; ``--save-model FIT.json`` keeps the model, and ``matfit export FIT.json --to pbrt -o m.pbrt``
or ``matfit render FIT.json --env sky -o sphere.png`` use it later (a report's ``model.json`` too).

``matfit fit-map CAPTURE -o MAPS/`` fits a family (default ``diffuse_specular``) to every texel of a
capture folder (``matfit.maps``: images and ``capture.json``) and writes PNG/EXR maps and a textured glTF;
``--coordinator HOST:PORT --num-processes N --process-id I`` splits the map over processes.

Errors (bad arguments, scene-file errors, malformed data, impossible fits) are printed as one line and
the exit status is 2.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def _cmd_demo(args):
    from .demo import run_demo

    run_demo(Path(args.out))
    return 0


def _cmd_synth(args):
    from data_synth import load_scene, synthesize
    from .io import save

    scene = load_scene(args.scene)
    if args.seed is not None:
        scene.seed = args.seed
    table = synthesize(scene)
    out = Path(args.output)
    if out.parent and not out.parent.exists():
        out.parent.mkdir(parents=True, exist_ok=True)
    save(out, table)
    print(f"wrote {out}: {len(table)} samples ({table.n_valid} valid), channels {table.channels}, "
          f"scene '{scene.name}'")
    return 0


def _cmd_info(args):
    from .io import load

    table = load(args.table)
    print(table.summary())
    gt = table.provenance.get("ground_truth")
    if gt:
        print(f"  ground truth: {gt.get('model')} {_short_params(gt.get('params', {}))}, seed {gt.get('seed')}")
    return 0


def _short_params(p):
    return "{" + ", ".join(f"{k}={_short_params(v) if isinstance(v, dict) else v}" for k, v in p.items()
                           if k != "model") + "}"


def _parse_fixed(items):
    """``["eta=1.5", "albedo=0.2,0.3,0.4"]`` -> ``{"eta": 1.5, "albedo": [0.2, 0.3, 0.4]}``."""
    out = {}
    for it in items or ():
        name, sep, val = it.partition("=")
        name = name.strip()
        if not sep or not name or not val.strip():
            raise ValueError(f"--fixed expects name=value (or name=v1,v2,v3), got {it!r}")
        try:
            nums = [float(v) for v in val.split(",")]
        except ValueError:
            raise ValueError(f"--fixed {name}: expected numbers, got {val!r}") from None
        out[name] = nums[0] if len(nums) == 1 else nums
    return out


def _load_table(path, subsample=None, seed=0, with_full=False):
    """The table at ``path``, subsampled to ``subsample`` valid rows (``(subsampled, full)`` with ``with_full``)."""
    from .io import load

    p = Path(path)
    if not p.exists():
        raise ValueError(f"{path}: no such file")
    full = table = load(p)
    if table.n_valid == 0:
        raise ValueError(f"{path}: the table has no valid rows")
    if subsample is not None:
        if subsample < 1:
            raise ValueError(f"--subsample must be a positive number of rows, got {subsample}")
        if subsample < table.n_valid:
            table = table.subsample(subsample, seed=seed)
    return (table, full) if with_full else table


def _cmd_fit(args):
    from .pipeline import run_pipeline

    table, full = _load_table(args.table, args.subsample, args.seed, with_full=True)
    truth = None
    if (table.provenance or {}).get("ground_truth"):  # a synthetic table: data_synth reads its truth back
        from data_synth import truth_from_table

        truth = truth_from_table(table, args.model)
    cands = None
    if args.candidates:
        if args.model:
            raise ValueError("--candidates chooses among families: leave out --model")
        cands = [c.strip() for c in args.candidates.split(",") if c.strip()]
    run_pipeline(table, args.model, candidates=cands, method=None if args.method == "mcmc" else args.method, loss=args.loss,
                 fixed=_parse_fixed(args.fixed), starts=args.starts, max_steps=args.max_steps, seed=args.seed,
                 posterior_steps=args.mcmc_steps if args.method == "mcmc" else 0,
                 truth=truth, report=args.report, report_table=full,
                 title=f"{args.model or 'chosen'} fit of {Path(args.table).name}", save_model=args.save_model,
                 source=args.table,
                 export=[tuple(args.export)] if args.export else ())
    return 0


def _cmd_export(args):
    from .export import export, load_model

    r = export(load_model(args.fit), args.to)
    r.write(args.output)
    print(r.summary())
    print(f"wrote {args.output}")
    return 0


def _cmd_render(args):
    from .export import load_model
    from .render import render_sphere, save_png

    model = load_model(args.model)
    img = render_sphere(model, args.env, size=args.size, spp=args.spp, seed=args.seed, strategy=args.strategy,
                        progress=True)
    out = Path(args.output)
    if out.suffix.lower() == ".npy":
        out.parent.mkdir(parents=True, exist_ok=True)
        np.save(out, img)
    else:
        save_png(out, img, exposure=args.exposure)
    print(f"wrote {out}: {args.size}x{args.size}, {args.spp} spp, environment {args.env}")
    return 0


def _cmd_fit_map(args):
    import time

    if args.num_processes > 1 or args.coordinator:
        from .maps import initialize_processes

        if not args.coordinator:
            raise ValueError("--num-processes > 1 needs --coordinator HOST:PORT (the address of process 0)")
        initialize_processes(args.coordinator, args.num_processes, args.process_id)
    from .maps import load_capture

    import tempfile

    # the measurements go to a scratch file beside the output folder (a 4096 x 4096 capture's
    # values do not fit in memory); fit_map reads them a chunk at a time. The output folder is
    # made only once the maps are written: a capture that fails leaves nothing behind.
    parent = Path(args.output).resolve().parent
    parent.mkdir(parents=True, exist_ok=True)
    scratch = tempfile.TemporaryDirectory(prefix=".matfit-capture-", dir=parent)
    try:
        return _fit_map_from(args, load_capture(args.capture, out=scratch.name), t0=time.perf_counter())
    finally:
        scratch.cleanup()


def _fit_map_from(args, cap, t0):
    import time

    import jax

    from .maps import fit_map, write_maps

    H, W = cap.shape
    print(f"{args.capture}: {H}x{W} texels, {cap.n_images} images, {cap.n_channels} channels, directions "
          f"{'shared' if cap.shared_directions else 'per texel'}; {int((~cap.valid).sum())} measurements unusable")
    res = fit_map(cap.wo, cap.wi, cap.values, model=args.model, valid=cap.valid, chunk=args.chunk,
                  max_steps=args.max_steps, smooth=args.smooth, progress=not args.quiet)
    if jax.process_index() == 0:  # every process holds the merged map; one writes it
        index = write_maps(res, args.output, formats=tuple(args.formats.split(",")))
        print(res.summary())
        print(f"wrote {args.output}/ ({', '.join(sorted(index['params']))} maps, maps.json"
              f"{', material.gltf' if 'gltf' in index else ''}) in {time.perf_counter() - t0:.1f} s")
        for note in index.get("gltf_notes", []):
            print(f"  glTF: {note}")
    return 0


def _cmd_compare(args):
    import json

    from .fitting import compare_models

    table = _load_table(args.table, args.subsample, args.seed)
    models = [m.strip() for m in args.models.split(",") if m.strip()]
    cmp = compare_models(table, models=models, holdout=args.holdout, seed=args.seed, tol=args.tol,
                         method=args.method, loss=args.loss, fixed=_parse_fixed(args.fixed), starts=args.starts)
    print(cmp.summary())
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        with open(args.json, "w") as fh:
            json.dump(cmp.to_dict(), fh, indent=2)
        print(f"wrote {args.json}")
    return 0


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (exit status 2)."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message}\n")


def _checked(convert, ok, expected):
    """An argparse type: ``convert(s)`` when it succeeds and ``ok`` holds, else one error naming
    what was expected."""

    def parse(s):
        try:
            v = convert(s)
        except ValueError:
            v = None
        if v is None or not ok(v):
            raise argparse.ArgumentTypeError(f"expected {expected}, got {s!r}")
        return v

    return parse


_positive_int = _checked(int, lambda v: v >= 1, "a positive integer")
_seed = _checked(int, lambda v: v >= 0, "a non-negative integer seed")
_fraction = _checked(float, lambda v: 0 < v < 1, "a fraction in (0, 1)")


def build_parser():
    """The ``matfit`` command's argument parser (one subcommand per command of the module docstring).

    Returns
    -------
    argparse.ArgumentParser
        A parser whose errors are one line with exit status 2; each subcommand sets ``func``,
        the function that runs it on the parsed arguments.

    Examples
    --------
    >>> from matfit.cli import build_parser
    >>> args = build_parser().parse_args(["fit", "table.npz", "--model", "lambert", "--starts", "2"])
    >>> args.command, args.model, args.starts, args.method == "mcmc"
    ('fit', 'lambert', 2, False)
    """
    from .fitting import COMPARE_FAMILIES, DEFAULT_LOSS, FAMILIES, LOSSES
    from .fitting.methods import DEFAULT_METHOD, METHODS

    p = _Parser(prog="matfit", description="Differentiable physically based material fitting.")
    sub = p.add_subparsers(dest="command", required=True)
    d = sub.add_parser("demo", help="run the main job on a built-in scene")
    d.add_argument("--out", default="demo_out", help="output folder (default: demo_out)")
    d.set_defaults(func=_cmd_demo)
    sy = sub.add_parser("synth", help="render a synthetic measurement from a scene TOML file")
    sy.add_argument("scene", help="scene file (or the name of a shipped scene, e.g. demo)")
    sy.add_argument("-o", "--output", required=True, help="output table (.npz or .csv)")
    sy.add_argument("--seed", type=_seed, default=None, help="override the scene's seed")
    sy.set_defaults(func=_cmd_synth)
    inf = sub.add_parser("info", help="summarize a table or measured file (.npz .csv .binary .bsdf .alta)")
    inf.add_argument("table", help="file to summarize")
    inf.set_defaults(func=_cmd_info)

    from .export import EXPORTERS

    targets = sorted(EXPORTERS)
    families = sorted(FAMILIES)
    fi = sub.add_parser("fit", help="fit a model family to a table or measured file")
    fi.add_argument("table", help="table or measured file (.npz .csv .binary .bsdf .alta)")
    fi.add_argument("--model", default=None, choices=families, metavar="NAME",
                    help=f"model family: {', '.join(families)} (default: the candidate family whose render looks "
                         "most like the measurement, matfit.fitting.choose_family)")
    fi.add_argument("--method", default=DEFAULT_METHOD, choices=list(METHODS) + ["mcmc"],
                    help=f"solver (default {DEFAULT_METHOD}; see matfit.fitting.methods); "
                         f"mcmc: {DEFAULT_METHOD}, then posterior sampling")
    fi.add_argument("--candidates", default=None, metavar="A,B",
                    help="without --model: the families to choose from (default: those the data call for)")
    fi.add_argument("--loss", default=None, choices=list(LOSSES),
                    help="loss (default l2 for a named family, e2 when the family is chosen)")
    fi.add_argument("--fixed", nargs="+", action="extend", default=[], metavar="NAME=VALUE",
                    help="hold parameters fixed, e.g. --fixed eta=1.5 albedo=0.2,0.3,0.4")
    fi.add_argument("--subsample", type=_positive_int, default=None, metavar="N",
                    help="fit N random valid rows (the report still uses the whole table)")
    fi.add_argument("--report", default=None, metavar="DIR", help="write a report (Markdown, PNG, JSON) into DIR")
    fi.add_argument("--starts", type=_positive_int, default=4, help="number of starts (default 4)")
    fi.add_argument("--max-steps", type=_positive_int, default=256, help="solver steps per start (default 256)")
    fi.add_argument("--mcmc-steps", type=_positive_int, default=4000,
                    help="cap on MCMC steps, burn-in included (default 4000; min 100)")
    fi.add_argument("--seed", type=_seed, default=0, help="seed of starts, subsample and sampler (default 0)")
    fi.add_argument("--save-model", default=None, metavar="FILE",
                    help="write the fitted model as JSON (read by matfit export and matfit render)")
    fi.add_argument("--export", nargs=2, default=None, metavar=("FORMAT", "FILE"),
                    help=f"export the fitted material: FORMAT one of {', '.join(targets)}")
    fi.set_defaults(func=_cmd_fit)

    ex = sub.add_parser("export", help="export a fitted model (model.json or report.json) to a renderer's format")
    ex.add_argument("fit", help="model document: --save-model output, or a report's model.json / report.json")
    ex.add_argument("--to", required=True, choices=targets, help="target format")
    ex.add_argument("-o", "--output", required=True, help="output file")
    ex.set_defaults(func=_cmd_export)

    re_ = sub.add_parser("render", help="render a sphere of a fitted model (model.json or report.json)")
    re_.add_argument("model", help="model document (as for export)")
    re_.add_argument("--env", default="sky", help="furnace, sky, or an environment map (.npy, .hdr, .exr)")
    re_.add_argument("-o", "--output", required=True, help="output image (.png tone-mapped sRGB, .npy linear)")
    re_.add_argument("--size", type=_positive_int, default=256, help="image size in pixels (default 256)")
    re_.add_argument("--spp", type=_positive_int, default=64, help="samples per pixel (default 64)")
    re_.add_argument("--strategy", default="mis", choices=["mis", "bsdf", "env"], help="sampling (default mis)")
    re_.add_argument("--exposure", type=float, default=1.0, help="exposure of the PNG (default 1)")
    re_.add_argument("--seed", type=_seed, default=0, help="seed (default 0)")
    re_.set_defaults(func=_cmd_render)

    fm = sub.add_parser("fit-map", help="fit a model family to every texel of a capture (a folder with capture.json)")
    fm.add_argument("capture", help="capture folder (images + capture.json or capture.toml)")
    fm.add_argument("--model", default="diffuse_specular", choices=sorted(FAMILIES))
    fm.add_argument("-o", "--output", required=True, help="output folder for the maps")
    fm.add_argument("--formats", default="png,exr,gltf", help="comma-separated: png, exr, gltf (default: all)")
    fm.add_argument("--chunk", type=_positive_int, default=16384, help="texels per solver call (default 16384)")
    fm.add_argument("--max-steps", type=_positive_int, default=64)
    fm.add_argument("--smooth", type=float, default=0.0, help="strength of the neighbour prior (default 0: off)")
    fm.add_argument("--quiet", action="store_true", help="no progress bar")
    fm.add_argument("--coordinator", default=None, help="HOST:PORT of process 0 for a multi-process run")
    fm.add_argument("--num-processes", type=_positive_int, default=1)
    fm.add_argument("--process-id", type=int, default=0)
    fm.set_defaults(func=_cmd_fit_map)
    co = sub.add_parser("compare", help="compare model families on a hold-out split")
    co.add_argument("table", help="table or measured file (.npz .csv .binary .bsdf .alta)")
    co.add_argument("--models", default=",".join(COMPARE_FAMILIES),
                    help=f"comma-separated families (default {','.join(COMPARE_FAMILIES)})")
    co.add_argument("--holdout", type=_fraction, default=0.2, help="hold-out fraction (default 0.2)")
    co.add_argument("--tol", type=float, default=0.02,
                    help="relative hold-out tolerance for preferring a simpler family (default 0.02)")
    co.add_argument("--method", default=DEFAULT_METHOD, choices=list(METHODS),
                    help=f"solver (default {DEFAULT_METHOD})")
    co.add_argument("--loss", default=DEFAULT_LOSS, choices=list(LOSSES), help=f"loss (default {DEFAULT_LOSS})")
    co.add_argument("--fixed", nargs="+", action="extend", default=[], metavar="NAME=VALUE", help="as for fit (families that have it)")
    co.add_argument("--subsample", type=_positive_int, default=None, metavar="N", help="use N random valid rows")
    co.add_argument("--starts", type=_positive_int, default=4, help="number of starts (default 4)")
    co.add_argument("--seed", type=_seed, default=0, help="seed of the split (default 0)")
    co.add_argument("--json", default=None, metavar="FILE", help="also write the comparison as JSON")
    co.set_defaults(func=_cmd_compare)
    return p


def main(argv=None):
    """Entry point of the ``matfit`` command.

    Switches on the persistent compilation cache (:func:`matfit.cache.enable_compilation_cache`)
    and runs the subcommand. A ``ValueError`` or ``OSError`` (matfit's errors included) is
    printed to stderr as one line ``matfit <command>: error: <message>``.

    Parameters
    ----------
    argv : sequence of str, optional
        The arguments (default: ``sys.argv[1:]``).

    Returns
    -------
    int
        The exit status: 0 on success, 2 on an error (argparse exits with 2 itself on bad
        arguments).

    Examples
    --------
    >>> import contextlib, io, os, tempfile, unittest.mock
    >>> import numpy as np
    >>> from matfit import Table
    >>> from matfit.io import save
    >>> from matfit.cli import main
    >>> wo = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, 0.6, 0.8]]); wi = wo[[1, 2, 0]]
    >>> with tempfile.TemporaryDirectory() as d, unittest.mock.patch.dict(os.environ, {"MATFIT_NO_CACHE": "1"}):
    ...     save(f"{d}/t.npz", Table(wo=wo, wi=wi, values=np.full((3, 3), 0.1)))
    ...     with contextlib.redirect_stdout(io.StringIO()) as out:
    ...         status = main(["info", f"{d}/t.npz"])
    ...     with contextlib.redirect_stderr(io.StringIO()) as err:
    ...         missing = main(["info", f"{d}/missing.npz"])
    >>> status, out.getvalue().splitlines()[0]
    (0, 'Table: 3 samples (3 valid), channels rgb')
    >>> missing, err.getvalue().startswith("matfit info: error:")
    (2, True)
    """
    parser = build_parser()
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    from .cache import enable_compilation_cache

    enable_compilation_cache()  # compile once per machine (MATFIT_NO_CACHE=1 turns it off)
    try:
        return args.func(args)
    except (ValueError, OSError) as exc:  # clear one-line errors for the user
        msg = " ".join(str(exc).split()) or type(exc).__name__
        print(f"matfit {args.command}: error: {msg}", file=sys.stderr)
        return 2
