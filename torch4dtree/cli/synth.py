"""``torch4dtree synth``: write a dataset folder of synthetic growing plants (with ground truth)."""

from __future__ import annotations

import argparse


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--kind", choices=["tomato", "maize", "bean"], default="tomato")
    p.add_argument("--plants", type=int, default=4)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--frames", type=int, default=10, help="frames per plant")
    p.add_argument("--out", required=True, help="output dataset folder (must not exist or be empty)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing non-empty folder's files")


def run(args: argparse.Namespace) -> int:
    from ..data import run_synth

    out = run_synth(kind=args.kind, plants=args.plants, seed=args.seed, out=args.out, frames=args.frames,
                    overwrite=args.overwrite)
    print(f"wrote {args.plants} synthetic {args.kind} plants to {out}")
    return 0
