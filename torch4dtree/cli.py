"""The ``torch4dtree`` console script: one entry point, one subcommand per job.

Subcommands import their modules lazily, so ``torch4dtree info`` never loads OpenGL.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from .config import add_config_arguments, config_from_args
from .structures import TreeError


# ------------------------------------------------------------------------------------- synth
def _cmd_synth(args: argparse.Namespace) -> int:
    from .data import run_synth

    out = run_synth(kind=args.kind, plants=args.plants, seed=args.seed, out=args.out, frames=args.frames,
                    overwrite=args.overwrite)
    print(f"wrote {args.plants} synthetic {args.kind} plants to {out}")
    return 0


# -------------------------------------------------------------------------------------- info
def _tree_summary(trees) -> dict:  # noqa: ANN001 - Trees
    return {
        "branches": [sum(layers) for layers in trees.branches_per_layer()],
        "branches_per_layer": trees.branches_per_layer(),
        "total_length": [round(float(x), 3) for x in trees.total_length()],
        "height": [round(float(x), 3) for x in trees.height()],
    }


def info(path: str | Path, options: object = None) -> dict:
    """A JSON-ready summary of a tree file, a sequence folder or a dataset folder."""
    from .io import read_sequence, read_tree, sequence_folders
    from .io.dataset import is_sequence_folder

    path = Path(path)
    if path.is_file():
        tree = read_tree(path, options)
        if tree is None:
            return {"file": str(path), "empty": True}
        return {"file": str(path), **{k: v[0] for k, v in _tree_summary(tree).items()}}
    if not path.is_dir():
        raise TreeError(f"{path}: no such file or folder")

    def sequence(folder: Path) -> dict:
        loaded = read_sequence(folder, options)
        seq = loaded.sequence
        return {"name": seq.name, "frames": len(seq), "times": [float(t) for t in seq.times],
                "files": loaded.files, "skipped": loaded.skipped, **_tree_summary(seq.frames)}

    if is_sequence_folder(path):
        return sequence(path)
    return {"sequences": [sequence(p) for p in sequence_folders(path)]}


def _print_sequence(s: dict) -> None:
    print(f"{s['name']}: {s['frames']} frames" + (f" ({len(s['skipped'])} empty skipped)" if s["skipped"] else ""))
    print(f"  {'time':>8} {'branches':>8}  {'per layer':<16} {'height':>8} {'length':>9}")
    for t, n, layers, h, ln in zip(s["times"], s["branches"], s["branches_per_layer"], s["height"], s["total_length"]):
        print(f"  {t:8g} {n:8d}  {str(layers):<16} {h:8.1f} {ln:9.1f}")


def _cmd_info(args: argparse.Namespace) -> int:
    summary = info(args.path, config_from_args(args).load_options())
    if args.json:
        print(json.dumps(summary))
    elif "sequences" in summary:
        for s in summary["sequences"]:
            _print_sequence(s)
    elif "frames" in summary:
        _print_sequence(summary)
    elif summary.get("empty"):
        print(f"{summary['file']}: empty frame")
    else:
        print(f"{summary['file']}: {summary['branches']} branches, per layer {summary['branches_per_layer']}, "
              f"height {summary['height']:.1f}, total length {summary['total_length']:.1f}")
    return 0


# --------------------------------------------------------------------------------- benchmark
def _cmd_benchmark(args: argparse.Namespace) -> int:
    if args.what == "curves":
        from .bench import benchmark_curves

        result = benchmark_curves(pairs=args.pairs, T=args.points)
    else:
        from .bench_trees import benchmark_trees

        result = benchmark_trees()
    if args.json:
        print(json.dumps(result))
    else:
        for k, v in result.items():
            print(f"{k:>36}: {v}")
    return 0


# ------------------------------------------------------------------------------------ parser
def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="torch4dtree", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("synth", help="generate a dataset folder of synthetic growing plants")
    p.add_argument("--kind", choices=["tomato", "maize", "bean"], default="tomato")
    p.add_argument("--plants", type=int, default=4)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--frames", type=int, default=10, help="frames per plant")
    p.add_argument("--out", required=True, help="output dataset folder (must not exist or be empty)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing non-empty folder's files")
    p.set_defaults(func=_cmd_synth)

    p = sub.add_parser("info", help="summarise a tree file, a sequence folder or a dataset folder")
    p.add_argument("path")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    add_config_arguments(p)
    p.set_defaults(func=_cmd_info)

    p = sub.add_parser("benchmark", help="time the registration engine")
    p.add_argument("what", choices=["curves", "trees"])
    p.add_argument("--json", action="store_true")
    p.add_argument("--pairs", type=int, default=1000, help="curve pairs in the batched measurement")
    p.add_argument("--points", type=int, default=100, help="points per curve")
    p.set_defaults(func=_cmd_benchmark)

    _add_optional(sub, "register", "register two trees (SWC or .mat): distances, correspondence, geodesic",
                  "registration", "add_register_arguments", "run_register")
    _add_optional(sub, "render", "render a tree file, sequence or dataset folder to PNG / GIF / MP4",
                  "render", "add_render_arguments", "run_render")
    return parser


def _add_optional(sub: argparse._SubParsersAction, name: str, help_: str, module: str, add: str, run: str) -> None:
    """A subcommand whose arguments and runner live in their module (imported lazily at run time)."""
    import importlib

    try:
        mod = importlib.import_module(f".{module}", __package__)
    except ModuleNotFoundError as e:
        if e.name != f"{__package__}.{module}":
            raise
        return
    add_arguments, runner = getattr(mod, add, None), getattr(mod, run, None)
    if add_arguments is None or runner is None:
        return
    p = sub.add_parser(name, help=help_)
    add_arguments(p)
    p.set_defaults(func=runner)


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (TreeError, FileExistsError, FileNotFoundError) as e:
        print(f"torch4dtree {args.command}: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
