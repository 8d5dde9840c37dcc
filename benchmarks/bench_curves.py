"""Side-by-side curve registration benchmark: torch4dtree vs fdasrsf (same pairs, same energy).

Run from the benchmark venv (fdasrsf is GPL and not a dependency of the package):

    PYTHONPATH=/work/main /work/main/.venv-bench/bin/python benchmarks/bench_curves.py [--pairs 1000] [--json]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import subprocess
import sys

from torch4dtree.bench.curves import benchmark_curves


def fmt(x, unit: str = "") -> str:
    if x is None:
        return "n/a"
    if unit == "ms":
        return f"{1e3 * x:.3f} ms"
    return f"{x:.4g}"


@contextlib.contextmanager
def busy_core(on: bool):
    """With ``on``, a CPU-bound process spins beside the measurement (a machine whose other core is busy)."""
    proc = subprocess.Popen([sys.executable, "-c", "while True: pass"]) if on else None
    try:
        yield
    finally:
        if proc is not None:
            proc.kill()
            proc.wait()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--pairs", type=int, default=1000)
    p.add_argument("--T", type=int, default=100)
    p.add_argument("--fdasrsf-pairs", type=int, default=40)
    p.add_argument("--single-reps", type=int, default=30)
    p.add_argument("--json", action="store_true")
    p.add_argument("--busy", action="store_true", help="run a CPU-bound process on another core meanwhile")
    a = p.parse_args()
    with busy_core(a.busy):
        r = benchmark_curves(pairs=a.pairs, T=a.T, fdasrsf_pairs=a.fdasrsf_pairs, single_reps=a.single_reps)
    r["busy_core"] = a.busy
    if a.json:
        print(json.dumps(r, indent=2))
        return
    print(f"curve registration, so3 + DP, T={r['T']}, batch {r['pairs']} pairs; numba threads "
          f"{r['numba_threads']}; numba first call (compile or cache load) {r['numba_first_call_s']:.1f} s"
          + ("; a CPU-bound process on another core" if a.busy else ""))
    head = f"{'pairs':10s} {'ours 1 pair':>12s} {'ours batched':>13s} {'fdasrsf':>11s} {'speedup':>8s} " \
           f"{'batched x':>9s} {'E ours/E fda':>12s} {'ours<=fda':>9s} {'dist ours':>9s} {'dist fda':>9s}"
    print(head)
    print("-" * len(head))
    for kind, k in r["kinds"].items():
        f = k.get("fdasrsf_s_per_pair")
        sp = f / k["ours_s_per_pair"] if f else None
        spb = f / k["ours_batched_s_per_pair"] if f else None
        print(f"{kind:10s} {fmt(k['ours_s_per_pair'], 'ms'):>12s} {fmt(k['ours_batched_s_per_pair'], 'ms'):>13s} "
              f"{fmt(f, 'ms'):>11s} {fmt(sp):>8s} {fmt(spb):>9s} "
              f"{fmt(k.get('energy_ratio_ours_over_fdasrsf')):>12s} {fmt(k.get('ours_not_worse_fraction')):>9s} "
              f"{fmt(k.get('ours_mean_distance_same_pairs')):>9s} {fmt(k.get('fdasrsf_mean_distance')):>9s}")
    print("-" * len(head))
    print(f"{'all':10s} {fmt(r['ours_s_per_pair'], 'ms'):>12s} {fmt(r['ours_batched_s_per_pair'], 'ms'):>13s} "
          f"{fmt(r['fdasrsf_s_per_pair'], 'ms'):>11s} {fmt(r['speedup']):>8s} {fmt(r['speedup_batched']):>9s} "
          f"{fmt(r['energy_ratio_ours_over_fdasrsf']):>12s} {fmt(r['ours_not_worse_fraction']):>9s}")
    print(f"DP only, one pair, 50 points: ours {fmt(r['dp50_ours_s'], 'ms')}, fdasrsf {fmt(r['dp50_fdasrsf_s'], 'ms')}")


if __name__ == "__main__":
    main()
