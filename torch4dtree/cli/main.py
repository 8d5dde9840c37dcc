"""The ``torch4dtree`` console script: one entry point, one small module per subcommand.

Each subcommand module has ``add_arguments(parser)`` and ``run(args) -> exit code``; modules are
imported when the parser is built, and heavy imports (OpenGL, the registration engine) happen
inside ``run``.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from ..trees.structures import TreeError

# (name, module, help), in the order of the pipeline
COMMANDS = (
    ("synth", "synth", "generate a dataset folder of synthetic growing plants"),
    ("info", "info", "summarise a tree file, a sequence folder or a dataset folder"),
    ("register", "register", "register two trees (SWC or .mat): distances, correspondence, geodesic"),
    ("register4d", "register4d", "register two 4D trees (sequence folders) in space and time"),
    ("fit", "fit", "fit the generative model of 4D trees on a dataset folder (writes a run directory)"),
    ("sample", "sample", "generate 4D trees from a fitted model: sequence folders and videos"),
    ("forecast", "forecast", "complete a partly observed 4D tree with a fitted model"),
    ("render", "render", "render a tree file, sequence or dataset folder to PNG / GIF / MP4"),
    ("benchmark", "benchmark", "time the registration engine"),
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="torch4dtree", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    for name, module, help_ in COMMANDS:
        mod = importlib.import_module(f".{module}", __package__)
        p = sub.add_parser(name, help=help_)
        mod.add_arguments(p)
        p.set_defaults(func=mod.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (TreeError, FileExistsError, FileNotFoundError) as e:
        print(f"torch4dtree {args.command}: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
