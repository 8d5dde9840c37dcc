"""register_trees' default ``positions``: the paper's warped parameters against node ranks, side by side.

    PYTHONPATH=. python benchmarks/bench_default_positions.py [identities] [cycle] [speed] [--seeds 6]

* ``identities``: branch identity precision / recall on realistic synthetic plants at the library's settings (lp 1
  relative, any-order matching): consecutive frames (``--seeds`` plants x 9 pairs per kind) and the same frame of
  two plants (frames 3 / 6 / 9, vertical rotation), with main branches chosen jointly over time or frame by frame
  (:func:`torch4dtree.bench.hierarchy.identity_accuracy`).
* ``cycle``: Table 2 on the paper's ``.mat`` trees (64 consecutive pairs, T = 256): the share of the length on
  null-matched branches (every other point comes back: symmetric registration) and the paper's null-at-base count,
  plus Table 1's after / before ratio at T = 64 (``evaluate``'s spatial section).
* ``speed``: Pheno4D consecutive pairs (SWC and ``.mat``, T = 64, 1 thread), best of 2 per pair, both settings
  interleaved twice.
"""

from __future__ import annotations

import argparse
import time

import torch

POSITIONS = ("warped", "rank")
DATA = "../shared/data/pheno4d"


def identities(seeds: int) -> None:
    from torch4dtree.bench.hierarchy import identity_accuracy

    for joint in (True, False):
        for pos in POSITIONS:
            rows = identity_accuracy(kinds=("tomato", "maize", "bean"), seeds=tuple(range(seeds)),
                                     rules=("straightest",), lp_per_length=(1.0,), joint_hierarchy=joint,
                                     positions=pos, cross_lp_per_length=1.0, cross_positions=pos,
                                     cross_order_tol=None)
            for r in rows:
                c, x = r["consecutive"], r["cross"]
                print(f"joint hierarchy {joint!s:5} {pos:6} {r['kind']:6}: consecutive {100 * c['precision']:.1f} / "
                      f"{100 * c['recall']:.1f} %, across plants {100 * x['precision']:.1f} / "
                      f"{100 * x['recall']:.1f} % ({r['seconds']:.0f} s)", flush=True)


def cycle() -> None:
    from torch4dtree.evaluate import spatial
    from torch4dtree.evaluate.data import EvalSettings, load_eval_data
    from torch4dtree.trees import registration

    data = load_eval_data(DATA, "mat", T=64)
    plain = spatial.register_trees
    try:
        for pos in POSITIONS:
            spatial.register_trees = lambda *a, _p=pos, **k: registration.register_trees(*a, positions=_p, **k)
            for kind in data.kinds:
                r = spatial.cycle_table(data, kind, EvalSettings(), 256, False)
                t1 = spatial.registration_3d(data, kind, EvalSettings(), False)
                null = {e: round(100 * r["null_at_base"][e]["mean"], 2) for e in ("0.1", "0.05", "0.02", "0.01")}
                print(f"{pos:6} {kind:6}: {r['pairs']} pairs, null-matched length {100 * r['unmatched']['mean']:.2f} %"
                      f", mapped {100 * r['mapped']['0.1']['mean']:.2f} % at eps 0.1, null at base {null}; Table 1 "
                      f"after / before {t1['ratio']:.3f}, lowered {t1['lowered']} / {t1['pairs']}", flush=True)
    finally:
        spatial.register_trees = plain


def speed() -> None:
    from torch4dtree.bench.trees import benchmark_trees

    torch.set_num_threads(1)
    for rnd in range(2):
        for pos in POSITIONS:
            for src in ("swc", "mat"):
                t0 = time.perf_counter()
                r = benchmark_trees(DATA, positions=pos, source=src, repeats=2)
                print(f"round {rnd} {pos:6} {src}: {r['pairs']} pairs, median {1e3 * r['median_s']:.1f} ms, mean "
                      f"{1e3 * r['mean_s']:.1f} ms, CPU mean {1e3 * r['cpu_mean_s']:.1f} ms; after / before "
                      f"{r['distance_after_mean'] / r['distance_before_mean']:.3f} ({time.perf_counter() - t0:.0f} s)",
                      flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("parts", nargs="*", default=["identities", "cycle", "speed"])
    ap.add_argument("--seeds", type=int, default=6)
    a = ap.parse_args()
    for part in a.parts:
        {"identities": lambda: identities(a.seeds), "cycle": cycle, "speed": speed}[part]()


if __name__ == "__main__":
    main()
