"""The registration's targets on Pheno4D (set PYTHONPATH to the tree to measure):

* ``cycle``: evaluate's Table 2 on the ``.mat`` trees at T = 256 (64 consecutive pairs, kinds pooled): share of
  mapped points / of all points whose A -> B -> A round trip misses by more than eps x the height;
* ``speed``: mean time of ``register_trees(day k + 1, day k)`` over the ``.mat`` consecutive pairs at T = 64 and
  ``register4d`` of the first two tomato plants, one thread, minimum over ``--repeats``.

    PYTHONPATH=. python benchmarks/bench_symmetric.py [cycle] [speed] [--repeats 3] [--data DIR]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import torch

from torch4dtree.evaluate.data import EvalSettings, load_eval_data
from torch4dtree.evaluate.spatial import consecutive_pairs, cycle_table
from torch4dtree.temporal import register4d
from torch4dtree.trees.correspondence import DEFAULT_EPS
from torch4dtree.trees.registration import register_trees


def cycle(data_dir: str) -> None:
    data = load_eval_data(data_dir, "mat", T=64)
    settings = EvalSettings()
    tables = [cycle_table(data, kind, settings, settings.T_cycle, False) for kind in data.kinds]
    for name in ("mapped", "all"):
        rows = [r for t in tables for r in t["per_pair"][name]]
        print(f"cycle consistency ({name}, {len(rows)} pairs, T = {settings.T_cycle}), eps {DEFAULT_EPS}: "
              + " / ".join(f"{100 * x:.2f} %" for x in np.mean(rows, 0)))


def speed(data_dir: str, repeats: int) -> None:
    torch.set_num_threads(1)
    data = load_eval_data(data_dir, "mat", T=64)
    settings = EvalSettings()
    pairs = [(p, k) for kind in data.kinds for p, k in consecutive_pairs(data, kind, settings)]
    tomatoes = [p for p in data.plants if p.kind == "tomato"]
    f = pairs[0][0].sequence.frames
    register_trees(f[1], f[0], settings.lambdas, "none")  # kernels loaded
    best3, best4 = float("inf"), float("inf")
    for _ in range(repeats):
        secs = []
        for p, k in pairs:
            f = p.sequence.frames
            t0 = time.perf_counter()
            register_trees(f[k + 1], f[k], settings.lambdas, "none")
            secs.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        register4d(tomatoes[0].sequence, tomatoes[1].sequence)
        best4 = min(best4, time.perf_counter() - t0)
        best3 = min(best3, statistics.fmean(secs))
    print(f"3D pair mean {1000 * best3:.1f} ms ({len(pairs)} .mat pairs, T = 64); register4d {tomatoes[0].name}, "
          f"{tomatoes[1].name} {best4:.3f} s (min of {repeats})")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("what", nargs="*", help="cycle and / or speed (default: both)")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--data", default="../shared/data/pheno4d")
    a = p.parse_args()
    a.what = a.what or ["cycle", "speed"]
    if set(a.what) - {"cycle", "speed"}:
        p.error(f"unknown: {sorted(set(a.what) - {'cycle', 'speed'})}")
    if "speed" in a.what:
        speed(a.data, a.repeats)
    if "cycle" in a.what:
        cycle(a.data)


if __name__ == "__main__":
    main()
