"""All-pairs tree distances of N small synthetic plants inline, on local worker processes and on a Dask LocalCluster
(one run each; the same matrix everywhere is checked).

    python benchmarks/bench_executors.py [--plants 30] [--T 32] [--workers 2] [--no-dask]
"""

from __future__ import annotations

import argparse
import time

import torch

from torch4dtree.data import synthetic_plant
from torch4dtree.parallel import local_executor, make_executor
from torch4dtree.trees import Trees, pairwise_distances


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--plants", type=int, default=30)
    p.add_argument("--T", type=int, default=32)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--no-dask", action="store_true")
    args = p.parse_args()
    trees = Trees.cat([synthetic_plant("tomato", seed=i, n_frames=4, T=args.T, dtype=torch.float64).sequence.frames[3]
                       for i in range(args.plants)])
    pairs = args.plants * (args.plants - 1) // 2
    warm = Trees.cat(trees.split()[:2])
    torch.set_num_threads(1)  # as a worker: one thread
    t = time.perf_counter()
    ref = pairwise_distances(trees, processes=1, progress=False)
    rows = [("inline (1 thread)", time.perf_counter() - t, 0.0)]

    def timed(name: str, opened: float, ex) -> None:
        pairwise_distances(warm, executor=ex, progress=False)  # start the workers
        start = time.perf_counter() - opened
        t = time.perf_counter()
        D = pairwise_distances(trees, executor=ex, progress=False)
        rows.append((name, time.perf_counter() - t, start))
        if not torch.equal(D, ref):
            raise SystemExit(f"{name} gave another matrix")

    opened = time.perf_counter()
    with local_executor(args.workers) as ex:
        timed(f"{args.workers} local processes", opened, ex)
    if not args.no_dask:
        from distributed import LocalCluster

        opened = time.perf_counter()
        with LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True, dashboard_address=None,
                          silence_logs=40) as cluster, make_executor(scheduler=cluster.scheduler_address) as ex:
            timed(f"Dask LocalCluster, {args.workers} workers", opened, ex)
    print(f"{args.plants} plants, {pairs} pairs, T = {args.T}, default tiles (identical matrices)")
    print("| where | seconds | s / pair | speed-up | start-up s |")
    print("|---|---|---|---|---|")
    for name, sec, start in rows:
        print(f"| {name} | {sec:.1f} | {sec / pairs * 1e3:.1f} ms | {rows[0][1] / sec:.2f} | {start:.1f} |")


if __name__ == "__main__":
    main()
