"""``torch4dtree info PATH``: frames, times, branches per layer, height and length of trees on disk."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from .options import add_config_arguments, config_from_args

# columns of the per-frame table: header, alignment (">" numbers, "<" text)
COLUMNS = (("time", ">"), ("branches", ">"), ("height", ">"), ("length", ">"), ("per layer", "<"))


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("path", help="an SWC or .mat tree file, a sequence folder (one file per frame) or a dataset folder "
                                "(one sequence folder per plant)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of tables")
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
        raise FileNotFoundError(f"{path}: no such file or folder")

    def sequence(folder: Path) -> dict:
        loaded = read_sequence(folder, options)
        seq = loaded.sequence
        return {"name": seq.name, "frames": len(seq), "times": [float(t) for t in seq.times],
                "files": loaded.files, "skipped": loaded.skipped, **_tree_summary(seq.frames)}

    if is_sequence_folder(path):
        return sequence(path)
    return {"sequences": [sequence(p) for p in sequence_folders(path)]}


def _rows(s: dict) -> list[tuple[str, ...]]:
    """The cells of a sequence's table, one tuple of strings per frame (in COLUMNS order)."""
    return [(f"{t:g}", str(n), f"{h:.1f}", f"{ln:.1f}", " ".join(map(str, layers)))
            for t, n, layers, h, ln in zip(s["times"], s["branches"], s["branches_per_layer"], s["height"],
                                            s["total_length"])]


def format_tables(sequences: list[dict]) -> list[str]:
    """Lines of one table per sequence, with the same column widths in all of them (wide enough for every
    cell, so that no long row shifts the columns after it)."""
    rows = [_rows(s) for s in sequences]
    header = tuple(name for name, _ in COLUMNS)
    widths = [max(len(r[c]) for r in [header, *(row for rs in rows for row in rs)]) for c in range(len(COLUMNS))]

    def line(cells: tuple[str, ...]) -> str:
        return ("  " + "  ".join(f"{x:{a}{w}}" for x, (_, a), w in zip(cells, COLUMNS, widths))).rstrip()

    lines = []
    for s, rs in zip(sequences, rows):
        skipped = f" ({len(s['skipped'])} empty skipped)" if s["skipped"] else ""
        lines += [f"{s['name']}: {s['frames']} frames{skipped}", line(header)] + [line(r) for r in rs]
    return lines


def run(args: argparse.Namespace) -> int:
    summary = info(args.path, config_from_args(args).load_options())
    if args.json:
        print(json.dumps(summary))
    elif "sequences" in summary or "frames" in summary:
        print("\n".join(format_tables(summary.get("sequences", [summary]))))
    elif summary.get("empty"):
        print(f"{summary['file']}: empty frame")
    else:
        layers = " ".join(map(str, summary["branches_per_layer"]))
        print(f"{summary['file']}: {summary['branches']} branches (per layer {layers}), "
              f"height {summary['height']:.1f}, total length {summary['total_length']:.1f}")
    return 0
