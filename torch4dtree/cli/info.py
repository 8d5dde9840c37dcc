"""``torch4dtree info PATH``: frames, times, branches per layer, height and length of trees on disk."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ..config import add_config_arguments, config_from_args
from ..trees.structures import TreeError


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("path")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    add_config_arguments(p)


def _tree_summary(trees) -> dict:  # noqa: ANN001 - Trees
    return {
        "branches": [sum(layers) for layers in trees.branches_per_layer()],
        "branches_per_layer": trees.branches_per_layer(),
        "total_length": [round(float(x), 3) for x in trees.total_length()],
        "height": [round(float(x), 3) for x in trees.height()],
    }


def info(path: str | Path, options: object = None) -> dict:
    """A JSON-ready summary of a tree file, a sequence folder or a dataset folder."""
    from ..io import read_sequence, read_tree, sequence_folders
    from ..io.dataset import is_sequence_folder

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


def run(args: argparse.Namespace) -> int:
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
