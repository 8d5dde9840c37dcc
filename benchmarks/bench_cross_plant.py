"""Cross-plant identity precision / recall on four plant sets per kind (target: >= 85 % across plants).

Sets: ``synthetic_plant(kind, seed)`` for seeds 0-5 (``p0``, = ``identity_accuracy``'s cross rows) and 6-11 (``p6``),
``synthetic_dataset(kind, 6, 0)`` (``d0``) and ``(kind, 6, 1)`` (``d1``); every pair of the 6 plants at each frame
(3, 6, 9 of 10), T = 32, vertical rotation: 45 pairs per set and frame list.

    PYTHONPATH=. python benchmarks/bench_cross_plant.py KIND [--positions nodes] [--lp 100] [--order-tol 0.02]
        [--frames 3,6,9] [--sets p0,p6,d0,d1] [--processes 2]

Defaults: :func:`torch4dtree.bench.hierarchy.registration_settings` (the cross-plant setting: node ranks on every
axis, lp 100, as on the simulator plants of ``benchmarks/bench_cross_simulator.py``). ``--order-tol -1``: any-order
children's matching; ``--positions rank --lp 12``: node ranks on the main branch only. Prints pooled precision /
recall % per set, overall and per set and frame.
"""

from __future__ import annotations

import argparse
import itertools
import time
from multiprocessing import Pool

import torch

from torch4dtree.bench.hierarchy import registration_settings

_plants: dict[str, list] = {}
_args: argparse.Namespace


def plants(kind: str, name: str) -> list:
    """The 6 plants' frames of set ``name`` (cached per process)."""
    from torch4dtree.data import synthetic_dataset, synthetic_plant

    if name not in _plants:
        if name.startswith("p"):
            first = int(name[1:])
            _plants[name] = [synthetic_plant(kind, s, n_frames=10, T=32, dtype=torch.float64).sequence.frames
                             for s in range(first, first + 6)]
        else:
            _plants[name] = [p.sequence.frames for p in
                             synthetic_dataset(kind, 6, int(name[1:]), n_frames=10, T=32, dtype=torch.float64)]
    return _plants[name]


def job(task: tuple[str, int, int, int]) -> tuple[str, int, float, int, float, int]:
    from torch4dtree.data import score_registration
    from torch4dtree.trees.registration import register_trees

    name, a, b, j = task
    frames = plants(_args.kind, name)
    order_tol = None if _args.order_tol < 0 else _args.order_tol
    kw = registration_settings(_args.lp, _args.positions, order_tol)
    r = register_trees(frames[a][j], frames[b][j], rotation="vertical", **kw)
    sc = score_registration(r, frames[a][j], frames[b][j])
    return name, j, sc.precision * sc.n_matched, sc.n_matched, sc.recall * sc.n_common, sc.n_common


def _init(args: argparse.Namespace) -> None:
    global _args
    _args = args
    torch.set_num_threads(1)


def main() -> None:
    default = registration_settings()
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("kind")
    p.add_argument("--positions", default=default["positions"])
    p.add_argument("--lp", type=float, default=default["lambdas"][2])
    p.add_argument("--order-tol", type=float, default=default["order_tol"])
    p.add_argument("--frames", default="3,6,9")
    p.add_argument("--sets", default="p0,p6,d0,d1")
    p.add_argument("--processes", type=int, default=2)
    args = p.parse_args()
    frames = [int(x) for x in args.frames.split(",")]
    sets = args.sets.split(",")
    t0 = time.time()
    tasks = [(n, a, b, j) for n in sets for j in frames for a, b in itertools.combinations(range(6), 2)]
    with Pool(args.processes, initializer=_init, initargs=(args,)) as pool:
        res = pool.map(job, tasks, chunksize=5)

    def pooled(rows: list) -> str:
        prec = sum(r[2] for r in rows) / max(sum(r[3] for r in rows), 1)
        rec = sum(r[4] for r in rows) / max(sum(r[5] for r in rows), 1)
        return f"{100 * prec:.1f}/{100 * rec:.1f}"

    print(args.kind, args.positions, f"lp {args.lp}", f"order_tol {args.order_tol}", "sets:",
          " ".join(f"{n} {pooled([r for r in res if r[0] == n])}" for n in sets), "all", pooled(res),
          f"({time.time() - t0:.0f} s)")
    print("  per frame:", " ".join(f"{n}/f{j} {pooled([r for r in res if r[:2] == (n, j)])}"
                                   for n in sets for j in frames))


if __name__ == "__main__":
    main()
