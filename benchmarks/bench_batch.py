"""Per-pair time of batched curve registration against a loop of single calls (T = 100, SO(3) + DP), and of the
tree registration's batched DP warps (no rotation, the solver's settings), with numba / torch on 1 and 2 threads,
with the machine's other core idle and loaded by a busy-loop process.

    python benchmarks/bench_batch.py [--T 100] [--pairs 400] [--sizes 1 2 4 8 16 32 64 128 200 400] [--reps 3]
                                     [--threads 1 2] [--loads idle busy] [--chunk N] [--min-pairs N]
                                     [--json]

Every number is a median over ``--reps`` interleaved runs of about ``--pairs`` pairs; ratios divide the batch's
per-pair time by the single calls' (below 1: the batch is faster). "idle" means no process of this benchmark
loads the machine (other users may); "busy" starts one pure-Python busy loop per spare core.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from collections.abc import Callable

import numba
import torch

from torch4dtree.bench.curves import curve_pairs
from torch4dtree.curves import dp_numba, dp_warp, register_curves, srvf


def per_pair(fn: Callable[[], object], pairs: int) -> float:
    """Seconds per pair of one run of ``fn`` (which registers ``pairs`` pairs)."""
    t0 = time.perf_counter()
    fn()
    return (time.perf_counter() - t0) / pairs


def loop_single(call: Callable[[int], object], n: int) -> Callable[[], object]:
    return lambda: [call(i) for i in range(n)]


def loop_batches(call: Callable[[int, int], object], n: int, b: int) -> Callable[[], object]:
    return lambda: [call(i, i + b) for i in range(0, n - b + 1, b)]


def measure(one: Callable[[int], object], call: Callable[[int, int], object], n: int, sizes: list[int],
            reps: int) -> dict[str, float]:
    """Median seconds per pair of unbatched single calls (``"single"``) and of batches of each size, interleaved."""
    runs: dict[str, list[float]] = {"single": [], **{str(b): [] for b in sizes}}
    for _ in range(reps):
        runs["single"].append(per_pair(loop_single(one, n), n))
        for b in sizes:
            done = (n // b) * b
            runs[str(b)].append(per_pair(loop_batches(call, n, b), done))
    return {k: statistics.median(v) for k, v in runs.items()}


def busy_loops(count: int) -> list[subprocess.Popen]:
    """``count`` pure-Python busy-loop processes (the caller terminates them)."""
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(count)]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--T", type=int, default=100)
    p.add_argument("--pairs", type=int, default=400)
    p.add_argument("--sizes", type=int, nargs="+", default=[1, 2, 4, 8, 16, 32, 64, 128, 200, 400])
    p.add_argument("--reps", type=int, default=3)
    p.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    p.add_argument("--loads", nargs="+", default=["idle", "busy"], choices=("idle", "busy"))
    p.add_argument("--chunk", type=int, default=None, help="pairs a thread takes at a time (default: THREAD_CHUNK)")
    p.add_argument("--min-pairs", type=int, default=None,
                   help="pairs a thread at least (default: PARALLEL_MIN_PAIRS)")
    p.add_argument("--json", action="store_true")
    a = p.parse_args()
    sizes = [b for b in a.sizes if b <= a.pairs]
    g = torch.Generator().manual_seed(0)
    mov, ref = curve_pairs("random", a.pairs, a.T, g)
    q1, q2 = srvf(ref), srvf(mov)
    tree_dp = {"neighbourhood": 4, "band": 4, "coarse": 16, "refine": 0}  # the tree registration's DP settings
    paths: dict[str, tuple[Callable[[int], object], Callable[[int, int], object]]] = {
        "curves so3": (lambda i: register_curves(mov[i], ref[i], rotation="so3"),
                       lambda i, j: register_curves(mov[i:j], ref[i:j], rotation="so3")),
        "tree DP": (lambda i: dp_warp(q1[i], q2[i], **tree_dp), lambda i, j: dp_warp(q1[i:j], q2[i:j], **tree_dp)),
    }
    if a.chunk is not None:
        dp_numba.THREAD_CHUNK = a.chunk
    if a.min_pairs is not None:
        dp_numba.PARALLEL_MIN_PAIRS = a.min_pairs
    for _, call in paths.values():  # compile / load the kernels, start the pools
        call(0, 64)
    spare = max((os.cpu_count() or 1) - 1, 1)
    results = []
    for load in a.loads:
        procs = busy_loops(spare) if load == "busy" else []
        try:
            time.sleep(0.5 if procs else 0.0)
            for th in a.threads:
                numba.set_num_threads(min(th, numba.config.NUMBA_NUM_THREADS))
                torch.set_num_threads(th)
                for name, (one, call) in paths.items():
                    r = measure(one, call, a.pairs, sizes, a.reps)
                    results.append({"load": load, "threads": th, "path": name, "load_avg": os.getloadavg()[0],
                                    "single_ms": r["single"] * 1e3,
                                    "batch_ms": {b: r[str(b)] * 1e3 for b in sizes},
                                    "ratio": {b: r[str(b)] / r["single"] for b in sizes}})
        finally:
            for proc in procs:
                proc.terminate()
                proc.wait()
    chunk = getattr(dp_numba, "THREAD_CHUNK", None)  # None: a version that splits batches in fixed shares
    if a.json:
        print(json.dumps({"T": a.T, "pairs": a.pairs, "cpus": os.cpu_count(), "chunk": chunk,
                          "min_pairs": dp_numba.PARALLEL_MIN_PAIRS, "results": results}))
        return
    print(f"T = {a.T}, {a.pairs} pairs a run, median of {a.reps}, chunk {chunk}, min pairs "
          f"{dp_numba.PARALLEL_MIN_PAIRS}; ratio = batch ms a pair / single-call ms a pair")
    print(f"{'path':>11} {'load':>5} {'thr':>3} {'single ms':>9} " + " ".join(f"{b:>6}" for b in sizes))
    for r in results:
        print(f"{r['path']:>11} {r['load']:>5} {r['threads']:>3} {r['single_ms']:>9.3f} "
              + " ".join(f"{r['ratio'][b]:>6.2f}" for b in sizes))


if __name__ == "__main__":
    main()
