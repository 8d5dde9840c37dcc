"""``torch4dtree benchmark WHAT``: time the engine against its references (fdasrsf, the paper's figures)."""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from .options import UsageError, int_at_least, positive_int

# where the real data comes from, for the message when it is missing
PHENO4D_HELP = ("The Pheno4D skeletons are not part of this repository: they are published in the dataset/ "
                "folder of the paper's reference code (https://github.com/Tahmina979/4Dtreeshape_project). Put "
                "the plant folders of SWC files under DIR/swc/ (e.g. DIR/swc/Tomato_3/T03_0305_a_seg.swc) and "
                "point --data or $TORCH4DTREE_PHENO4D at DIR (default: ../shared/data/pheno4d beside the "
                "repository).")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("what", choices=["curves", "trees", "4d", "all", "scale"],
                   help="curves: curve registration vs fdasrsf (random, helix and, if present, Pheno4D curves); "
                        "trees: all consecutive-day Pheno4D pairs vs the paper (needs the Pheno4D skeletons); "
                        "4d: spatiotemporal registration of Pheno4D plants, temporal registration, 4D geodesics; "
                        "all: curves, trees, 4d and the generative model (fit, 4D mean, sampling, decoding) at "
                        "moderate sizes (a few minutes), with ratios against the paper and fdasrsf (the Pheno4D "
                        "parts are skipped, with a note, when the data is missing); "
                        "scale: time and peak memory of reading, fitting (both models) and all-pairs distances of "
                        "synthetic tomatoes at --sizes plants, each stage in a fresh process, with growth exponents "
                        "and the all-pairs speed-up of 2 workers over 1 (docs/scaling.md; 25-100 plants about "
                        "18 minutes)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--quick", action="store_true", help="all: tiny sizes (about a minute), for a first look")
    p.add_argument("--pairs", type=positive_int, default=1000, metavar="N",
                   help="curves: pairs in the batched measurement (default: %(default)s; all uses its own sizes)")
    p.add_argument("--points", type=int_at_least(4), default=100, metavar="T",
                   help="curves: points per curve (default: %(default)s; all uses its own sizes)")
    p.add_argument("--sizes", type=positive_int, nargs="+", default=None, metavar="N",
                   help="scale: plants per run (default: 25 50 100 200)")
    p.add_argument("--data", type=Path, default=None, metavar="DIR",
                   help="the Pheno4D folder holding swc/ (default: $TORCH4DTREE_PHENO4D, else "
                        "../shared/data/pheno4d beside the repository)")


def _data_root(args: argparse.Namespace) -> Path:
    from ..bench.trees import default_data_root

    return args.data if args.data is not None else default_data_root()


def _print_all(result: dict) -> None:
    """``benchmark all`` as text: the seconds per section, the notes and the ratio table."""
    def num(x: float | None) -> str:
        return "-" if x is None else f"{x:.3g}"

    print("seconds: " + ", ".join(f"{k} {v:.1f}" for k, v in result["seconds"].items()))
    for note in result["notes"]:
        print(f"note: {note}")
    print(f"{'ratio (reference / ours)':>40}  {'ours s':>9}  {'ref. s':>9}  {'ratio':>7}  reference")
    for name, r in result["ratios"].items():
        print(f"{name:>40}  {num(r['ours_s']):>9}  {num(r['reference_s']):>9}  {num(r['ratio']):>7}  {r['reference']}")


def run(args: argparse.Namespace) -> int:
    root = _data_root(args)
    if args.quick and args.what != "all":
        raise UsageError("--quick applies to 'benchmark all' only")
    if args.sizes is not None and args.what != "scale":
        raise UsageError("--sizes applies to 'benchmark scale' only")
    if args.what == "scale":
        import sys

        from ..bench.scale import DEFAULT_SIZES, benchmark_scale, format_table

        result = benchmark_scale(args.sizes or DEFAULT_SIZES,
                                 log=lambda line: print(f"torch4dtree benchmark scale: {line}", file=sys.stderr))
        print(json.dumps(result) if args.json else format_table(result))
        return 0
    if args.what == "all":
        import sys

        from ..bench.all import benchmark_all

        result = benchmark_all(root, quick=args.quick,
                               log=lambda line: print(f"torch4dtree benchmark all: {line}", file=sys.stderr))
        if args.json:
            print(json.dumps(result))
        else:
            _print_all(result)
        return 0
    if args.what in ("trees", "4d") and not (root / "swc").is_dir():
        source = "--data" if args.data is not None else (
            "$TORCH4DTREE_PHENO4D" if os.environ.get("TORCH4DTREE_PHENO4D") else "the default location")
        raise UsageError(f"no Pheno4D skeletons at {root / 'swc'} ({source}). {PHENO4D_HELP}")
    if args.what == "curves":
        from ..bench.curves import benchmark_curves

        result = benchmark_curves(pairs=args.pairs, T=args.points, pheno4d=root / "swc")
    elif args.what == "4d":
        from ..bench.fourd import benchmark_4d

        result = benchmark_4d(root)
    else:
        from ..bench.trees import benchmark_trees

        result = benchmark_trees(root)
    if args.json:
        print(json.dumps(result))
    else:
        for k, v in result.items():
            print(f"{k:>36}: {v}")
    return 0
