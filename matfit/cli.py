"""Command-line interface: ``matfit demo``.

Examples
--------
``python -m matfit demo --out demo_out`` evaluates and samples the built-in materials, writes a
polar lobe plot (``lobes.png``) and a table of directional albedos (``albedo.csv``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def _cmd_demo(args):
    from .demo import run_demo

    run_demo(Path(args.out))
    return 0


def build_parser():
    p = argparse.ArgumentParser(prog="matfit", description="Differentiable physically based material fitting.")
    sub = p.add_subparsers(dest="command", required=True)
    d = sub.add_parser("demo", help="run the main job on a built-in scene")
    d.add_argument("--out", default="demo_out", help="output folder (default: demo_out)")
    d.set_defaults(func=_cmd_demo)
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
