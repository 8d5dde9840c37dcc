"""``torch4dtree benchmark WHAT``: time the engine against its references (fdasrsf, the paper's figures)."""

from __future__ import annotations

import argparse
import json


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("what", choices=["curves", "trees", "4d"],
                   help="curves: the DP engine vs fdasrsf; trees: Pheno4D tree registration vs the paper; "
                        "4d: spatiotemporal registration of Pheno4D plants, temporal registration, 4D geodesics")
    p.add_argument("--json", action="store_true")
    p.add_argument("--pairs", type=int, default=1000, help="curve pairs in the batched measurement")
    p.add_argument("--points", type=int, default=100, help="points per curve")


def run(args: argparse.Namespace) -> int:
    if args.what == "curves":
        from ..bench.curves import benchmark_curves

        result = benchmark_curves(pairs=args.pairs, T=args.points)
    elif args.what == "4d":
        from ..bench.fourd import benchmark_4d

        result = benchmark_4d()
    else:
        from ..bench.trees import benchmark_trees

        result = benchmark_trees()
    if args.json:
        print(json.dumps(result))
    else:
        for k, v in result.items():
            print(f"{k:>36}: {v}")
    return 0
