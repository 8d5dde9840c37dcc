"""Cross-plant branch identities on simulator plants, wrong pairs by their botanical relation, and oracles.

Data: ``ROOT/KIND/PLANT/*.swc`` whose type column names every node's organ by botanical position (``1`` then per
level two digits for the node on the parent in growth order and one for the slot there, leaves 1-4, stems 5-9;
``benchmarks/simulate_population.py``). Every pair of the first ``--plants`` plants at each of ``--frames`` is
registered with :func:`torch4dtree.bench.hierarchy.registration_settings` (``--positions``, ``--lp``,
``--order-tol``) and a rotation about the vertical; precision / recall as ``bench_identities.py --modes cross``.

Wrong pairs by relation of their labels: ``main`` (a main branch), ``inherited`` (the parents are a wrong pair),
``slotXY`` (same parent and node, another slot: ``LL`` two leaves, ``LS`` a leaf and a shoot, ``SS``),
``nodeXY`` (same parent, another node), ``parent`` / ``level`` (other parents / depths). The reported ``P`` / ``R``
take the organs of one kind at one node as interchangeable (:func:`merged_scores`): the simulators number the leaves
of a node in an order that geometry does not show (leaf 2's azimuth from leaf 1 is random per plant), so no
registration can tell them apart across plants; ``by slot`` beside them scores the simulator's slot labels as
they are. ``--oracle``: the best matchings a registration could return
on these hierarchies: children of matched branches paired by ``label`` (the ceiling), by ``node`` index, or by
``rank`` of occupied nodes (what node ranks can see).

    PYTHONPATH=. python benchmarks/bench_cross_simulator.py sunflower lupin wheat --positions rank --lp 12
"""

from __future__ import annotations

import argparse
import collections
import itertools
import multiprocessing as mp
import time
from pathlib import Path

import torch

from torch4dtree.bench.hierarchy import registration_settings
from torch4dtree.bench.identities import score_pair
from torch4dtree.data.truth import DEFAULT_IGNORE, IdentityScores, identity_scores
from torch4dtree.io import LoadOptions, read_swc_skeleton, read_tree
from torch4dtree.io.dataset import frame_times, sequence_folders
from torch4dtree.trees import Trees
from torch4dtree.trees.registration import register_trees

_DATA: dict = {}


def load(root: Path, kind: str, plants: list[int], frames: list[int], hierarchy: str) -> dict:
    """``{(k, frame): (tree, (xyz, parent, organ))}`` of the plants numbered ``plants`` (in name order) of
    ``root/kind``, ``k`` their place in ``plants``."""
    opts = LoadOptions(labels_from_type=True, hierarchy=hierarchy)
    out = {}
    folders = sequence_folders(root / kind)
    for p, plant in enumerate(folders[i] for i in plants):
        files = [f for f, _ in frame_times(plant)]
        for j in frames:
            sk = read_swc_skeleton(files[j])
            out[p, j] = (read_tree(files[j], opts), (sk.xyz, sk.parent, sk.types))
    return out


def _init(root: Path, kind: str, n: list[int], frames: list[int], hierarchy: str, kw: dict) -> None:
    torch.set_num_threads(1)
    _DATA.update(data=load(root, kind, n, frames, hierarchy), kw=kw)


def _job(task: tuple[int, int, int]) -> tuple:
    a, b, j = task
    (ta, ska), (tb, skb) = _DATA["data"][a, j], _DATA["data"][b, j]
    r = register_trees(ta, tb, rotation="vertical", **_DATA["kw"])
    return task, r.matches, *score_pair(r.matches, ta, tb, ska, skb)


def _kind(label: str) -> str:
    return "L" if label[-1] < "5" else "S"


def relation(la: list[int], lb: list[int], pa: list[int], pb: list[int], i: int, j: int, partner: dict) -> str:
    """The botanical relation of a wrong pair (module doc)."""
    if i == 0 or j == 0:
        return "main"
    if partner.get(pa[i]) == pb[j] and la[pa[i]] != lb[pb[j]]:
        return "inherited"
    a, b = str(la[i]), str(lb[j])
    if len(a) != len(b):
        return "level"
    if a[:-3] != b[:-3]:
        return "parent"
    pair = "".join(sorted(_kind(a) + _kind(b)))
    return ("slot" if a[-3:-1] == b[-3:-1] else "node") + pair


def merge_slots(label: int) -> int:
    """The label with every slot digit replaced by its kind (1 leaf, 5 stem)."""
    d = list(str(label))
    for k in range(3, len(d), 3):
        d[k] = "1" if d[k] < "5" else "5"
    return int("".join(d))


def merged_scores(matches: list[tuple[int, int]], la: list[int], lb: list[int]) -> IdentityScores:
    """Precision and recall with every label through :func:`merge_slots`, counted as multisets: the two leaves of a
    node are two organs of one kind, each found when a leaf of that node is matched to a leaf of that node (recall:
    per merged label, the right pairs up to the smaller of its two counts, over the sum of those counts)."""
    ma, mb = [merge_slots(v) for v in la], [merge_slots(v) for v in lb]
    skip = set(DEFAULT_IGNORE)
    valid = [(ma[i], mb[j]) for i, j in matches if la[i] not in skip and lb[j] not in skip]
    ca = collections.Counter(v for v, raw in zip(ma, la) if raw not in skip)
    cb = collections.Counter(v for v, raw in zip(mb, lb) if raw not in skip)
    right = collections.Counter(a for a, b in valid if a == b)
    common = {v: min(ca[v], cb[v]) for v in ca.keys() & cb.keys()}
    n_common = sum(common.values())
    found = sum(min(right[v], n) for v, n in common.items())
    return IdentityScores(sum(a == b for a, b in valid) / len(valid) if valid else float("nan"),
                          found / n_common if n_common else float("nan"), len(valid), n_common)


def _keyed(tree: Trees, i: int, mode: str) -> dict:
    lab, par, s = tree.label.tolist(), tree.parent.tolist(), tree.s.tolist()
    kids = [c for c in range(len(par)) if par[c] == i]
    if mode == "label":
        return {lab[c]: c for c in kids}
    nodes: dict[int, list[int]] = collections.defaultdict(list)
    for c in sorted(kids, key=lambda c: (s[c], lab[c])):
        nodes[int(str(lab[c])[-3:-1])].append(c)
    return {(n if mode == "node" else r, k): c for r, n in enumerate(sorted(nodes))
            for k, c in enumerate(sorted(nodes[n], key=lambda c: lab[c]))}


def oracle(ta: Trees, tb: Trees, mode: str) -> list[tuple[int, int]]:
    """Main branches matched, then children of matched branches paired by ``mode`` (module doc)."""
    out, todo = [(0, 0)], [(0, 0)]
    while todo:
        i, j = todo.pop()
        ka, kb = _keyed(ta, i, mode), _keyed(tb, j, mode)
        for k in set(ka) & set(kb):
            out.append((ka[k], kb[k]))
            todo.append((ka[k], kb[k]))
    return out


def pooled(items: list) -> tuple[float, float]:
    """Micro-averaged precision and recall of :class:`IdentityScores`."""
    m, c = sum(s.n_matched for s in items), sum(s.n_common for s in items)
    return (sum(s.precision * s.n_matched for s in items) / max(m, 1),
            sum(s.recall * s.n_common for s in items) / max(c, 1))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("kinds", nargs="+")
    ap.add_argument("--root", default="/work/simdata29/cross")
    default = registration_settings()
    ap.add_argument("--positions", default=default["positions"])
    ap.add_argument("--lp", type=float, default=default["lambdas"][2])
    ap.add_argument("--order-tol", type=float, default=default["order_tol"], help="-1: any order")
    ap.add_argument("--plants", type=int, default=5)
    ap.add_argument("--select", default="", help="plant numbers instead of the first --plants, e.g. 0,2,3,8,9")
    ap.add_argument("--frames", default="3,6,9")
    ap.add_argument("--hierarchy", default="straightest")
    ap.add_argument("--processes", type=int, default=2)
    ap.add_argument("--oracle", action="store_true", help="print the oracles' scores only")
    ap.add_argument("--show", type=int, default=0, help="print this many wrong pairs (not inherited)")
    a = ap.parse_args()
    root, frames = Path(a.root), [int(x) for x in a.frames.split(",")]
    kw = registration_settings(a.lp, a.positions, None if a.order_tol < 0 else a.order_tol)
    chosen = [int(x) for x in a.select.split(",")] if a.select else list(range(a.plants))
    tasks = [(x, y, j) for j in frames for x, y in itertools.combinations(range(len(chosen)), 2)]
    for kind in a.kinds:
        data = load(root, kind, chosen, frames, a.hierarchy)
        if a.oracle:
            for mode in ("label", "node", "rank"):
                sc = [identity_scores(oracle(data[x, j][0], data[y, j][0], mode), data[x, j][0].label.tolist(),
                                      data[y, j][0].label.tolist()) for x, y, j in tasks]
                print(f"{kind} oracle by {mode}: P {pooled(sc)[0]:.3f} R {pooled(sc)[1]:.3f}")
            continue
        t0 = time.time()
        with mp.get_context("spawn").Pool(a.processes, initializer=_init,
                                          initargs=(root, kind, chosen, frames, a.hierarchy, kw)) as pool:
            res = pool.map(_job, tasks, chunksize=1)
        rel: collections.Counter = collections.Counter()
        causes: collections.Counter = collections.Counter()
        merged, shown = [], 0
        for (x, y, j), matches, _, c in res:
            ta, tb = data[x, j][0], data[y, j][0]
            la, lb, pa, pb = ta.label.tolist(), tb.label.tolist(), ta.parent.tolist(), tb.parent.tolist()
            partner = dict(matches)
            causes.update(c.to_dict())
            merged.append(merged_scores(matches, la, lb))
            for i, k in matches:
                if la[i] != lb[k]:
                    r = relation(la, lb, pa, pb, i, k, partner)
                    rel[r] += 1
                    if shown < a.show and r != "inherited":
                        print(f"  {x}-{y} frame {j}: {la[i]} -> {lb[k]} {r}")
                        shown += 1
        p, r = pooled([s for *_, s, _ in res])
        mp_, mr = pooled(merged)
        print(f"{kind} {a.positions} lp {a.lp} order_tol {a.order_tol}: P {mp_:.3f} R {mr:.3f} (by slot "
              f"{p:.3f} / {r:.3f}), {len(res)} registrations, {time.time() - t0:.0f} s; relations "
              f"{dict(rel)}; causes {dict(causes)}", flush=True)


if __name__ == "__main__":
    main()
