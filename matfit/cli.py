"""Command-line interface: ``matfit demo``, ``matfit synth``, ``matfit info``.

Examples
--------
``python -m matfit demo --out demo_out`` evaluates and samples the built-in materials, writes a
polar lobe plot (``lobes.png``) and a table of directional albedos (``albedo.csv``).

``matfit synth SCENE.toml -o TABLE.npz`` renders a synthetic measurement (data_synth); a shipped scene
may be named without its folder (``matfit synth demo -o demo.npz``). ``matfit info TABLE`` prints the
summary of any table or measured file that ``matfit.io.load`` reads. Errors (scene-file errors, malformed
data) are printed as one line and the exit status is 2.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


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


def build_parser():
    p = argparse.ArgumentParser(prog="matfit", description="Differentiable physically based material fitting.")
    sub = p.add_subparsers(dest="command", required=True)
    d = sub.add_parser("demo", help="run the main job on a built-in scene")
    d.add_argument("--out", default="demo_out", help="output folder (default: demo_out)")
    d.set_defaults(func=_cmd_demo)
    sy = sub.add_parser("synth", help="render a synthetic measurement from a scene TOML file")
    sy.add_argument("scene", help="scene file (or the name of a shipped scene, e.g. demo)")
    sy.add_argument("-o", "--output", required=True, help="output table (.npz or .csv)")
    sy.add_argument("--seed", type=int, default=None, help="override the scene's seed")
    sy.set_defaults(func=_cmd_synth)
    inf = sub.add_parser("info", help="summarize a table or measured file (.npz .csv .binary .bsdf .alta)")
    inf.add_argument("table", help="file to summarize")
    inf.set_defaults(func=_cmd_info)
    return p


def main(argv=None):
    """Entry point of the ``matfit`` command."""
    parser = build_parser()
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    try:
        return args.func(args)
    except (ValueError, OSError) as exc:  # clear one-line errors for the user
        print(f"matfit {args.command}: error: {exc}", file=sys.stderr)
        return 2
