"""Side-by-side curve registration benchmark: torch4dtree vs fdasrsf (same pairs, same energy).

Run from the benchmark venv (fdasrsf is GPL and not a dependency of the package):

    PYTHONPATH=. .venv-bench/bin/python benchmarks/bench_curves.py [--pairs 1000] [--fdasrsf-pairs 50] [--json]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import subprocess
import sys

from torch4dtree.bench.curves import benchmark_curves


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
    p.add_argument("--fdasrsf-rounds", type=int, default=5)
    p.add_argument("--json", action="store_true")
    p.add_argument("--busy", action="store_true", help="run a CPU-bound process on another core meanwhile")
    a = p.parse_args()
    with busy_core(a.busy):
        r = benchmark_curves(pairs=a.pairs, T=a.T, fdasrsf_pairs=a.fdasrsf_pairs, single_reps=a.single_reps,
                             fdasrsf_rounds=a.fdasrsf_rounds)
    r["busy_core"] = a.busy
    if a.json:
        print(json.dumps(r, indent=2))
        return
    nt = r["numba_threads"]
    print(f"curve registration, so3 + DP, T={r['T']}, register_curves defaults; batch of {r['pairs']} pairs per kind "
          f"(median of 3 runs per thread setting, alternating); one pair per call: ours and fdasrsf 2.7.3 "
          f"interleaved on the same {r['fdasrsf_pairs']} pairs per kind; fdasrsf iterated = {r['fdasrsf_rounds']} "
          f"rounds of (rotation, DP); numba first call (compile or cache load) {r['numba_first_call_s']:.1f} s")
    print("\ntimes per pair (ms): mean / median")
    head = f"{'pairs':8s} {'ours 1 pair':>15s} {'ours batch 1 thr':>16s} {'ours batch ' + str(nt) + ' thr':>16s} " \
           f"{'fdasrsf':>15s} {'fdasrsf iter.':>15s}"
    print(head)
    for kind, k in list(r["kinds"].items()) + [("all", r["all"])]:
        f, fi = k.get("fdasrsf_s_per_pair"), k.get("fdasrsf_iterated_s_per_pair")
        print(f"{kind:8s} {ms2(k['ours_s_per_pair']):>15s} {1e3 * k['batched_1_thread_s_per_pair']:16.3f} "
              f"{1e3 * k[f'batched_{nt}_threads_s_per_pair']:16.3f} {ms2(f):>15s} {ms2(fi):>15s}")
    al = r["all"]
    print("CPU time of one pair per call (ms, mean / median; single-threaded, so what a call costs alone):")
    for kind, k in list(r["kinds"].items()) + [("all", al)]:
        print(f"{kind:8s} ours {ms2(k['ours_cpu_s_per_pair'])}   fdasrsf {ms2(k.get('fdasrsf_cpu_s_per_pair'))}")
    if "speedup_one_pair_by_means" in al:
        print(f"speed-up vs fdasrsf, mean / mean: one pair {al['speedup_one_pair_by_means']:.0f}x (CPU time: "
              f"{al['speedup_one_pair_cpu_by_means']:.0f}x), batched on 1 thread "
              f"{al['speedup_batched_1_thread_by_means']:.0f}x, batched on {nt} threads "
              f"{al[f'speedup_batched_{nt}_threads_by_means']:.0f}x (fdasrsf runs on 1 thread)")
        print("\nenergies: mean(ours) / mean(theirs) over the same pairs (share of pairs where ours is not "
              "worse)")
        print(f"{'pairs':8s} {'grid vs fda':>16s} {'fine vs fda':>16s} {'grid vs fda it.':>16s} "
              f"{'fine vs fda it.':>16s} {'fine/grid: ours, fda, fda it.':>30s}")
        for kind, k in list(r["kinds"].items()) + [("all", al)]:
            cols = ("grid_vs_fdasrsf", "fine_vs_fdasrsf", "grid_vs_fdasrsf_iterated", "fine_vs_fdasrsf_iterated")
            row = " ".join(f"{k[x]['ratio_of_means']:8.3f} ({100 * k[x]['not_worse']:3.0f}%)" for x in cols)
            fg = k.get("fine_over_grid")
            fgs = " ".join(f"{fg[x]:.3f}" for x in ("ours", "fdasrsf", "fdasrsf_iterated")) if fg else ""
            print(f"{kind:8s} {row} {fgs:>30s}")
    d = r["dp_only"]
    print(f"\nDP warp alone (no rotation), {d['pairs']} random pairs of {d['T']} points, one pair per call, "
          "interleaved:")
    for name in ("banded_default", "full_lattice", "fdasrsf"):
        x = d.get(name)
        if x:
            print(f"  {name:15s} {ms2(x['s_per_pair'])} ms (mean / median); mean energy on our grid "
                  f"{x['energy_grid_mean']:.4f}, on the fine grid {x['energy_fine_mean']:.4f}")


def ms2(x: dict | None) -> str:
    return "n/a" if x is None else f"{1e3 * x['mean']:.3f} / {1e3 * x['median']:.3f}"


if __name__ == "__main__":
    main()
