"""``torch4dtree synth``: write a dataset folder of synthetic growing plants (with ground truth)."""

from __future__ import annotations

import argparse

from .options import int_at_least, non_negative_int, positive_int


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--kind", choices=["tomato", "maize", "bean", "almond"], default="tomato",
                   help="tomato (3-4 branch layers, basal side shoots), maize (2 layers, two-ranked leaves), bean "
                        "(trifoliate leaves and side shoots, 4 layers) or almond (a young tree's wood: trunk, "
                        "scaffolds, shoots, spurs; 4 layers) (default: %(default)s)")
    p.add_argument("--plants", type=positive_int, default=4, metavar="N",
                   help="number of plants, each a sequence folder (default: %(default)s)")
    p.add_argument("--seed", type=non_negative_int, default=0,
                   help="random seed; the same seed gives the same plants (default: %(default)s)")
    p.add_argument("--frames", type=int_at_least(2), default=10, metavar="N",
                   help="frames (scans) per plant, on irregular days (default: %(default)s)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="output dataset folder; created if missing, must be empty unless --overwrite")
    p.add_argument("--overwrite", action="store_true", help="write into a non-empty folder, replacing its files")
    p.add_argument("--vary", action="store_true",
                   help="herbaceous plants vary in vigour as crops in one field do: leaf count, side shoots and their "
                        "leaves (tomato, maize, bean)")


def run(args: argparse.Namespace) -> int:
    from ..data import run_synth

    out = run_synth(kind=args.kind, plants=args.plants, seed=args.seed, out=args.out, frames=args.frames,
                    overwrite=args.overwrite, variation=args.vary)
    print(f"wrote {args.plants} synthetic {args.kind} plants ({args.frames} frames each) to {out}/")
    return 0
