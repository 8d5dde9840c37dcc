"""Within-sequence identities against the synthetic organ truth (target: >= 95 % per pair and over
whole sequences), on 14 plants per kind: ``synthetic_dataset(kind, 8, 0)`` and ``synthetic_plant(kind, seed)`` for
seeds 0-5 (10 frames, T = 32, ``register_sequence``'s defaults).

    PYTHONPATH=. python benchmarks/bench_within.py [--kinds maize,tomato,bean] [--worst 5] [--json]

Per kind: how many consecutive pairs reach 95 %, the worst pair, the mean pair, the whole-sequence mean and minimum
(:func:`torch4dtree.temporal.within.identity_accuracy`), and the worst pairs with the organs whose slots disagree.
"""

from __future__ import annotations

import argparse
import json
import time
from collections import Counter

import torch

from torch4dtree.data import synthetic_dataset, synthetic_plant
from torch4dtree.temporal.within import identity_accuracy, register_sequence


def plants(kind: str, T: int = 32, hierarchy_kwargs: dict | None = None) -> list:
    """The 14 plants of the measurement (dataset plants first); ``hierarchy_kwargs`` go to the joint hierarchy
    (:func:`torch4dtree.trees.growth.consistent_frames`)."""
    out = synthetic_dataset(kind, 8, 0, T=T, dtype=torch.float64, hierarchy_kwargs=hierarchy_kwargs)
    return out + [synthetic_plant(kind, seed, n_frames=10, T=T, dtype=torch.float64, hierarchy_kwargs=hierarchy_kwargs)
                  for seed in range(6)]


def _slot_labels(aligned, labels: torch.Tensor) -> list[list[int | None]]:
    ident = aligned.identity.cpu()
    counts = (ident >= 0).sum(1)
    ptr = torch.cat([counts.new_zeros(1), counts.cumsum(0)]).tolist()
    lab = labels.tolist()
    return [[None if i < 0 else lab[ptr[j] + i] for i in ident[j].tolist()] for j in range(len(ident))]


def swaps(slots: list[list[int | None]], j: int, skip: tuple[int, ...] = (99,)) -> list[tuple[str, int, int | None]]:
    """The errors :func:`identity_accuracy` counts in pair ``j``: organs of one frame whose slot holds another organ
    (or nothing, or something where the organ is absent) in the other: ``(">" or "<", organ, other)``."""
    out = []
    for arrow, x, y in ((">", j, j + 1), ("<", j + 1, j)):
        there = {v for v in slots[y] if v is not None}
        for k, v in enumerate(slots[x]):
            if v is None or v in skip:
                continue
            w = slots[y][k]
            if (v in there and w != v) or (v not in there and w is not None):
                out.append((arrow, v, w))
    return out


def kind_of_error(slots: list[list[int | None]], x: int, organ: int, other: int | None) -> str:
    """Why an organ of frame ``x`` is counted wrong: ``split`` (the hierarchy cut it in two: its label names two
    branches of its frame), ``spur`` (absent from the other frame, a skeletonisation spur holds its slot there),
    ``swap`` (another organ holds its slot) or ``lost`` (present in the other frame, its slot empty there)."""
    if sum(v == organ for v in slots[x]) > 1:
        return "split"
    if other == 99:
        return "spur"
    return "lost" if other is None else "swap"


def measure(kind: str, worst: int = 5, hierarchy_kwargs: dict | None = None, **kwargs: object) -> dict:
    rows, t0 = [], time.perf_counter()
    for p in plants(kind, hierarchy_kwargs=hierarchy_kwargs):
        al = register_sequence(p.sequence, **kwargs)  # type: ignore[arg-type]
        acc = identity_accuracy(al, p.sequence.frames.label)
        slots = _slot_labels(al, p.sequence.frames.label)
        rows.append({"plant": p.name, "per_pair": acc.per_pair.tolist(), "sequence": acc.sequence,
                     "swaps": {j: [(d, a, b, kind_of_error(slots, j if d == ">" else j + 1, a, b))
                                   for d, a, b in swaps(slots, j)]
                               for j in range(len(acc.per_pair)) if float(acc.per_pair[j]) < 0.95}})
    pairs = [(x, r["plant"], j) for r in rows for j, x in enumerate(r["per_pair"])]
    seqs = [r["sequence"] for r in rows]
    bad = sorted(pairs)[:worst]
    return {"kind": kind, "pairs_ok": sum(x >= 0.95 for x, *_ in pairs), "pairs": len(pairs),
            "worst_pair": min(x for x, *_ in pairs), "mean_pair": sum(x for x, *_ in pairs) / len(pairs),
            "sequence_mean": sum(seqs) / len(seqs), "sequence_min": min(seqs),
            "sequences_ok": sum(s >= 0.95 for s in seqs), "plants": len(seqs),
            "errors_in_bad_pairs": dict(Counter(e[3] for r in rows for v in r["swaps"].values() for e in v)),
            "worst": [{"plant": p, "pair": j, "accuracy": x,
                       "swaps": next(r for r in rows if r["plant"] == p)["swaps"][j]} for x, p, j in bad
                      if x < 0.95],
            "seconds": time.perf_counter() - t0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kinds", default="maize,tomato,bean")
    ap.add_argument("--worst", type=int, default=5)
    ap.add_argument("--order-tol", type=float, default=None, help="register_sequence's order_tol (when it has one)")
    ap.add_argument("--top", type=int, default=None, help="the joint hierarchy's top branch points (consistent_frames)")
    ap.add_argument("--positions", default=None, help="register_sequence's positions (warped / arclength / rank)")
    ap.add_argument("--lp", type=float, default=None, help="register_sequence's relative lp")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    kw: dict = {} if a.order_tol is None else {"order_tol": a.order_tol}
    if a.positions is not None:
        kw["positions"] = a.positions
    if a.lp is not None:
        kw["lambdas"] = (1.0, 1.0, a.lp)
    hk = None if a.top is None else {"top": a.top}
    out = [measure(k, a.worst, hk, **kw) for k in a.kinds.split(",")]
    if a.json:
        print(json.dumps(out))
        return
    for r in out:
        print(f"{r['kind']:7s} pairs >= 95 %: {r['pairs_ok']} / {r['pairs']}, worst pair {r['worst_pair']:.3f}, "
              f"mean pair {r['mean_pair']:.3f}; whole sequence mean {r['sequence_mean']:.3f}, "
              f"min {r['sequence_min']:.3f}, {r['sequences_ok']} / {r['plants']} >= 95 % "
              f"({r['seconds']:.0f} s)")
        for w in r["worst"]:
            c = Counter(w["swaps"])
            print(f"    {w['plant']} pair {w['pair']}: {w['accuracy']:.3f}  organ, its slot in frame j+1 (>) / j (<): "
                  + ", ".join(f"{a}{d}{b} ({e})" for (d, a, b, e), _ in c.most_common()))
        print(f"    errors in the pairs below 95 %: {r['errors_in_bad_pairs']}")


if __name__ == "__main__":
    main()
