"""Branch identities of growing plants against their organ truth, with the wrong matches counted by cause.

Reads dataset folders whose SWC type column names every node's organ (``benchmarks/simulate_population.py``, or
``torch4dtree synth``) and scores branch correspondences the way :mod:`torch4dtree.bench.hierarchy` does
(majority organ per branch; precision = matched pairs holding the same organ, recall = organs present in both trees
matched to themselves, counts pooled over pairs; :func:`torch4dtree.data.identity_scores`), three ways:

* ``pairs``: the library's defaults as a user calls them: ``read_tree`` on each snapshot, then
  ``register_trees(later, earlier)``;
* ``sequence``: ``read_sequence`` (main branches chosen jointly over time) + ``register_sequence`` (its defaults),
  the consecutive matches read from the identity table;
* ``cross``: the same frame (indices ``--cross-frames``) of two plants of a kind (``--cross-root/KIND``, plants
  observed on the same days), every pair of the first ``--cross-plants`` plants, with the cross-sequence settings
  of the population fit (``torch4dtree.settings`` ``CROSS_*``; :func:`torch4dtree.bench.hierarchy.
  registration_settings`) and a rotation about the vertical. Organs by botanical position make "the same organ"
  mean the k-th organ on its parent in both plants.

Every wrong pair is named by cause: spur, apex chain, split, swap, other (definitions:
:mod:`torch4dtree.bench.identities`); organs missed by recall are ``mismatched`` or ``unmatched``.
``--hierarchy`` passes rules through to ``LoadOptions`` (several: one table each). ``--describe`` prints, instead,
a morphology table per kind and frame (nodes, tips, total length, height, branches, hierarchy depth, median branch
length), for comparing generators.

usage: PYTHONPATH=. python benchmarks/bench_identities.py --root /work/simdata29 --kinds maize tree
       [--hierarchy straightest heaviest] [--modes pairs sequence cross] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from torch4dtree.bench.hierarchy import registration_settings
from torch4dtree.bench.identities import CAUSES, ErrorCauses, branch_lengths, score_pair, sequence_matches, sum_causes
from torch4dtree.data.truth import IdentityScores
from torch4dtree.evaluate.truth import pooled
from torch4dtree.io import LoadOptions, read_sequence, read_swc_skeleton, read_tree
from torch4dtree.io.dataset import frame_times, sequence_folders
from torch4dtree.settings import HIERARCHIES
from torch4dtree.temporal import register_sequence
from torch4dtree.trees.registration import register_trees

MODES = ("pairs", "sequence", "cross")
Skeleton = tuple[np.ndarray, np.ndarray, np.ndarray]


def skeleton(path: Path) -> Skeleton:
    """``(xyz, parent, node organ)`` of an SWC file."""
    sk = read_swc_skeleton(path)
    return sk.xyz, sk.parent, sk.types


def kind_folders(root: Path, kinds: list[str] | None) -> dict[str, Path]:
    """``{kind: dataset folder}``: the sub-folders of ``root`` holding sequence folders (or those named)."""
    if kinds:
        return {k: root / k for k in kinds}
    out = {}
    for p in sorted(root.iterdir()):
        try:
            sequence_folders(p) if p.is_dir() else None
        except Exception:  # noqa: BLE001 - not a dataset folder
            continue
        if p.is_dir():
            out[p.name] = p
    return out


def run_pairs(plants: list[Path], rule: str) -> list[tuple[IdentityScores, ErrorCauses]]:
    """``read_tree`` per snapshot, ``register_trees(later, earlier)`` with the library's defaults."""
    opts = LoadOptions(labels_from_type=True, hierarchy=rule)
    out = []
    for plant in plants:
        files = [p for p, _ in frame_times(plant)]
        trees = [read_tree(f, opts) for f in files]
        sks = [skeleton(f) for f in files]
        for j in range(len(files) - 1):
            reg = register_trees(trees[j + 1], trees[j])
            out.append(score_pair(reg.matches, trees[j + 1], trees[j], sks[j + 1], sks[j]))
    return out


def run_sequence(plants: list[Path], rule: str, positions: str | None = None
                 ) -> list[tuple[IdentityScores, ErrorCauses]]:
    """``read_sequence`` + ``register_sequence`` (defaults; ``positions`` if given); frame ``j + 1`` is the moving
    tree of each pair."""
    opts = LoadOptions(labels_from_type=True, hierarchy=rule)
    out = []
    for plant in plants:
        loaded = read_sequence(plant, opts)
        frames = loaded.sequence.frames
        sks = [skeleton(plant / name) for name in loaded.files]
        aligned = register_sequence(loaded.sequence, **({"positions": positions} if positions else {}))
        ident = aligned.identity.cpu()
        for j in range(len(loaded.files) - 1):
            matches = [(b, a) for a, b in sequence_matches(ident, j)]
            out.append(score_pair(matches, frames[j + 1], frames[j], sks[j + 1], sks[j]))
    return out


def run_cross(plants: list[Path], rule: str, at: list[int]) -> list[tuple[IdentityScores, ErrorCauses]]:
    """The same frame of every pair of plants, cross-sequence settings, rotation about the vertical."""
    opts = LoadOptions(labels_from_type=True, hierarchy=rule)
    kw = registration_settings()
    files = [[p for p, _ in frame_times(plant)] for plant in plants]
    out = []
    for j in at:
        trees = [read_tree(f[j], opts) for f in files]
        sks = [skeleton(f[j]) for f in files]
        for a in range(len(plants)):
            for b in range(a + 1, len(plants)):
                reg = register_trees(trees[a], trees[b], rotation="vertical", **kw)
                out.append(score_pair(reg.matches, trees[a], trees[b], sks[a], sks[b]))
    return out


def summarise(results: list[tuple[IdentityScores, ErrorCauses]], seconds: float) -> dict:
    """Pooled precision / recall and summed causes of a list of scored registrations."""
    return {**pooled(s for s, _ in results), "n_matched": sum(s.n_matched for s, _ in results),
            "n_common": sum(s.n_common for s, _ in results), "causes": sum_causes(c for _, c in results),
            "seconds": seconds}


def fmt_row(kind: str, mode: str, rule: str, r: dict) -> str:
    c = r["causes"]
    wrong = sum(c[k] for k in CAUSES)
    causes = " | ".join(str(c[k]) for k in CAUSES)
    return (f"| {kind} | {mode} | {rule} | {r['precision']:.3f} / {r['recall']:.3f} | {r['pairs']} | "
            f"{r['n_matched']} | {wrong} | {causes} | {c['mismatched']} / {c['unmatched']} | {r['seconds']:.0f} |")


HEADER = ("| kind | mode | rule | P / R | pairs | matched | wrong | " + " | ".join(CAUSES)
          + " | missed: mismatched / unmatched | s |\n|" + "---|" * (8 + len(CAUSES)))


def describe(kinds: dict[str, Path], rule: str, plants: int) -> list[str]:
    """Per kind and frame index, medians over plants of: skeleton nodes, tips, total length, height, and under
    ``rule``: branches, hierarchy depth (layers), median branch length."""
    lines = ["| kind | frame | nodes | tips | total length | height | branches | depth | median branch |",
             "|---|---|---|---|---|---|---|---|---|"]
    opts = LoadOptions(hierarchy=rule)
    for kind, folder in kinds.items():
        per_frame: dict[int, list[tuple]] = {}
        for plant in sequence_folders(folder)[:plants]:
            for j, (f, _) in enumerate(frame_times(plant)):
                xyz, parent, _ = skeleton(f)
                edges = np.linalg.norm(xyz[parent >= 0] - xyz[parent[parent >= 0]], axis=1).sum()
                tips = int(len(parent) - len(set(parent[parent >= 0].tolist())))
                tree = read_tree(f, opts)
                lens = branch_lengths(tree)
                depth = int(tree.depth.max()) + 1
                per_frame.setdefault(j, []).append((len(xyz), tips, edges, float(np.ptp(xyz[:, 2])),
                                                    len(lens), depth, float(np.median(lens))))
        for j, rows in sorted(per_frame.items()):
            med = [statistics.median(r[i] for r in rows) for i in range(7)]
            lines.append(f"| {kind} | {j} | {med[0]:.0f} | {med[1]:.0f} | {med[2]:.0f} | {med[3]:.0f} | "
                         f"{med[4]:.0f} | {med[5]:.0f} | {med[6]:.1f} |")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--root", default="/work/simdata29", help="folder of kind folders (dataset folders)")
    ap.add_argument("--kinds", nargs="*", help="kind folders under --root (default: every dataset folder there)")
    ap.add_argument("--hierarchy", nargs="*", default=["straightest"],
                    help=f"rules passed to LoadOptions (known now: {', '.join(HIERARCHIES)})")
    ap.add_argument("--modes", nargs="*", default=list(MODES), choices=MODES)
    ap.add_argument("--plants", type=int, default=5, help="plants per kind for pairs and sequence")
    ap.add_argument("--skip-plants", type=int, default=0, help="leave out the first plants of each kind")
    ap.add_argument("--positions", default=None, help="register_sequence's positions (default: its own)")
    ap.add_argument("--cross-root", default=None, help="folder of kind folders for cross (default: ROOT/cross)")
    ap.add_argument("--cross-plants", type=int, default=6, help="plants per kind for cross (every pair)")
    ap.add_argument("--cross-frames", type=int, nargs="*", default=[3, 6, 9], help="frame indices for cross")
    ap.add_argument("--describe", action="store_true", help="print the morphology table only")
    ap.add_argument("--json", default=None, help="write every row to this JSON file")
    a = ap.parse_args(argv)
    root = Path(a.root)
    kinds = kind_folders(root, a.kinds)
    kinds.pop("cross", None)
    if a.describe:
        print("\n".join(describe(kinds, a.hierarchy[0], a.plants)))
        return 0
    cross_root = Path(a.cross_root) if a.cross_root else root / "cross"
    rows = []
    for rule in a.hierarchy:
        print(f"\n### hierarchy {rule}\n\n{HEADER}", flush=True)
        pooled_by_mode: dict[str, list] = {}
        for kind, folder in kinds.items():
            for mode in a.modes:
                if mode == "cross":
                    if not (cross_root / kind).is_dir():
                        continue
                    plants = sequence_folders(cross_root / kind)[:a.cross_plants]
                else:
                    plants = sequence_folders(folder)[a.skip_plants:a.skip_plants + a.plants]
                t0 = time.perf_counter()
                if mode == "pairs":
                    res = run_pairs(plants, rule)
                elif mode == "sequence":
                    res = run_sequence(plants, rule, a.positions)
                else:
                    res = run_cross(plants, rule, a.cross_frames)
                r = summarise(res, time.perf_counter() - t0)
                pooled_by_mode.setdefault(mode, []).extend(res)
                rows.append({"kind": kind, "mode": mode, "rule": rule, **r})
                print(fmt_row(kind, mode, rule, r), flush=True)
        for mode, res in pooled_by_mode.items():
            r = summarise(res, sum(x["seconds"] for x in rows if x["mode"] == mode and x["rule"] == rule))
            rows.append({"kind": "pooled", "mode": mode, "rule": rule, **r})
            print(fmt_row("pooled", mode, rule, r), flush=True)
    if a.json:
        Path(a.json).write_text(json.dumps({"root": str(root), "cross_root": str(cross_root), "plants": a.plants,
                                            "cross_plants": a.cross_plants, "cross_frames": a.cross_frames,
                                            "rows": rows}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
