"""Registration of 3D trees on Pheno4D (consecutive days) vs the paper: time, distances, cycle consistency,
and branch-correspondence accuracy on synthetic plants with ground truth.

    python benchmarks/bench_trees.py [--T 64] [--rotation none] [--source swc|mat] [--repeats 1] [--refine 0]
                                     [--skip-timing] [--skip-cycle] [--skip-synthetic] [--skip-all-pairs] [--rows]
"""

from __future__ import annotations

import argparse

import numba
import torch

from torch4dtree.bench.trees import (
    PAPER_SECONDS,
    benchmark_all_pairs,
    benchmark_cross_plant_accuracy,
    benchmark_cycle_consistency,
    benchmark_synthetic_accuracy,
    benchmark_trees,
)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--T", type=int, default=64)
    p.add_argument("--rotation", default="none", choices=("none", "vertical", "so3"))
    p.add_argument("--repeats", type=int, default=1)
    p.add_argument("--source", default="swc", choices=("swc", "mat"),
                   help="raw SWC skeletons or the paper's hand-corrected .mat trees")
    p.add_argument("--refine", type=int, default=0, help="Gauss-Newton warp refinement (register_trees refine)")
    p.add_argument("--skip-timing", action="store_true")
    p.add_argument("--skip-cycle", action="store_true")
    p.add_argument("--skip-synthetic", action="store_true")
    p.add_argument("--skip-all-pairs", action="store_true")
    p.add_argument("--skip-hierarchy-speed", action="store_true")
    p.add_argument("--rows", action="store_true", help="print every pair")
    p.add_argument("--threads", type=int, default=1, help="torch and numba threads (1: CPU time = alone time)")
    a = p.parse_args()
    torch.set_num_threads(a.threads)
    numba.set_num_threads(a.threads)

    kw = {"refine": a.refine} if a.refine else {}
    if not a.skip_timing:
        timing(a, kw)
    if not a.skip_cycle:
        cycle(a, kw)
    if not a.skip_all_pairs:
        x = benchmark_all_pairs(T=a.T, source=a.source, rotation=a.rotation, **kw)
        print(f"\nall-pairs distance matrix of every Pheno4D tomato frame (within and across plants): "
              f"{x['trees']} trees, {x['pairs']} pairs in {x['seconds']:.1f} s on {x['processes']} processes "
              f"({x['s_per_pair'] * 1e3:.1f} ms a pair); the authors' scripts: 4-5 min for the tomato "
              f"spatial registrations ({x['speedup_vs_paper']:.0f}x)")
    if not a.skip_synthetic:
        synthetic(a)
    if not a.skip_hierarchy_speed:
        hierarchy_speed(a)


def timing(a: argparse.Namespace, kw: dict) -> None:
    r = benchmark_trees(T=a.T, rotation=a.rotation, repeats=a.repeats, source=a.source, **kw)
    if a.rows:
        for kind, name, sec, before, after, na, nb in r["rows"]:
            print(f"{kind:7s} {name:45s} {na:3d}->{nb:3d} branches {sec * 1e3:8.1f} ms "
                  f"d {before:7.2f} -> {after:7.2f}")
    print(f"\nPheno4D ({a.source}) consecutive-day pairs, T={a.T}, rotation={a.rotation}, register_trees defaults; "
          f"time of a pair = best of {a.repeats}; paper: {PAPER_SECONDS} s per pair (a mean), so 'x paper' = "
          f"paper mean / our mean")
    print(f"{a.threads} thread(s); wall = elapsed time (inflated when other jobs share the cores), cpu = CPU time "
          f"of this process; 'x paper' = 2.3 s / our mean")
    print(f"{'kind':8s} {'pairs':>5s} {'wall mean/median/max ms':>24s} {'x paper':>8s} {'cpu mean/median/max ms':>24s} "
          f"{'x paper':>8s} {'d before':>9s} {'d after':>8s} {'improved':>9s}")
    for kind, s in list(r["per_kind"].items()) + [("all", r)]:
        wall = f"{s['mean_s'] * 1e3:.1f}/{s['median_s'] * 1e3:.1f}/{s['max_s'] * 1e3:.0f}"
        cpu = f"{s['cpu_mean_s'] * 1e3:.1f}/{s['cpu_median_s'] * 1e3:.1f}/{s['cpu_max_s'] * 1e3:.0f}"
        print(f"{kind:8s} {s['pairs']:5d} {wall:>24s} {s['speedup_vs_paper']:8.0f} {cpu:>24s} "
              f"{s['speedup_vs_paper_cpu']:8.0f} {s['distance_before_mean']:9.2f} {s['distance_after_mean']:8.2f} "
              f"{s['improved_pairs']:5d}/{s['pairs']}")
    print("(distances: means over pairs, before = index order)")


def cycle(a: argparse.Namespace, kw: dict) -> None:
    c = benchmark_cycle_consistency(T=a.T, rotation=a.rotation, source=a.source, **kw)
    print(f"\ncycle consistency over {c['pairs']} pairs (share of points returning farther than eps * height, "
          f"A -> B -> A for day k -> k+1 -> k; 'mapped' leaves out points on branches matched to null, "
          f"'all' counts them as failures)")
    print(f"{'':20s}" + "".join(f"{'eps=' + str(e):>11s}" for e in c["eps"]))
    print(f"{'paper (mean)':20s}" + "".join(f"{100 * v:10.2f}%" for v in c["paper_mean"]))
    for kind, s in list(c["per_kind"].items()) + [("all", c)]:
        for stat, key in (("mapped mean", "mean"), ("mapped median", "median"), ("all mean", "all_mean"),
                          ("all median", "all_median")):
            print(f"{kind + ' ' + stat:20s}" + "".join(f"{100 * v:10.2f}%" for v in s[key]))
    print(f"points on branches matched to null: {100 * c['unmatched_mean']:.2f}% of the length on average, "
          f"up to {100 * c['unmatched_max']:.1f}% on one pair; lost on the way back (failures in both counts): "
          f"{100 * c['lost_mean']:.2f}%")


def synthetic(a: argparse.Namespace) -> None:
    s = benchmark_synthetic_accuracy(rotation=a.rotation)
    print("\nsynthetic plants, consecutive frames (ground-truth branch identities)")
    for kind, v in s.items():
        print(f"{kind:8s} pairs {v['pairs']:3d}  accuracy mean {100 * v['accuracy_mean']:.1f}% "
              f"min {100 * v['accuracy_min']:.1f}%  median {v['median_s'] * 1e3:.1f} ms  cycle error "
              + " ".join(f"{100 * e:.2f}%" for e in v["cycle_error_mean"]))
    x = benchmark_cross_plant_accuracy()
    print("\nsynthetic plants, different plants of one kind at the same frame (vertical rotation; "
          "3 dataset seeds x 6 pairs of 4 plants)")
    for kind, v in x.items():
        frames = "  ".join(f"frame {f}: {100 * m:.0f}%" for f, m in v["per_frame"].items())
        print(f"{kind:8s} pairs {v['pairs']:3d}  accuracy mean {100 * v['accuracy_mean']:.1f}% "
              f"min {100 * v['accuracy_min']:.1f}%  median {v['median_s'] * 1e3:.0f} ms  ({frames})")


def hierarchy_speed(a: argparse.Namespace, repeats: int = 5) -> None:
    """CPU time of reading a ~1,000-node skeleton (two frames of a synthetic almond tree) by each hierarchy rule and
    of registering the two trees with the defaults (best of ``repeats``)."""
    import time

    from torch4dtree.data import synthetic_plant
    from torch4dtree.settings import HIERARCHIES
    from torch4dtree.trees.registration import register_trees
    from torch4dtree.trees.skeleton import skeleton_to_trees

    plant = synthetic_plant("almond", 1, n_frames=10, T=8)
    frames = [plant.skeletons[j] for j in (3, 4)]  # 815 and 1165 nodes
    print(f"\nreading a {len(frames[0][0])}- and a {len(frames[1][0])}-node skeleton (T={a.T}) and registering "
          f"them (register_trees defaults), CPU ms, best of {repeats}")
    for rule in HIERARCHIES:
        read, reg = [], []
        for _ in range(repeats):
            t0 = time.process_time()
            trees = [skeleton_to_trees(xyz, parent, T=a.T, hierarchy=rule) for xyz, parent, _ in frames]
            t1 = time.process_time()
            register_trees(trees[1], trees[0])
            read.append(t1 - t0)
            reg.append(time.process_time() - t1)
        print(f"{rule:13s} read {1e3 * min(read):7.1f}  register {1e3 * min(reg):7.1f}  "
              f"branches {trees[0].num_branches.item()} / {trees[1].num_branches.item()}")


if __name__ == "__main__":
    main()
