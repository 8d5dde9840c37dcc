"""Robustness of the registration to noise and topological variation (docs/method.md §7).

The authors' journal extension (arXiv 2509.19048) claims robustness to noise and topological variation; this
section measures ours. A frame is perturbed in a known way and registered onto the unperturbed frame (no
rotation: the perturbations do not turn the plant). Every node of the perturbed frame remembers the branch of the
original it came from, so each perturbed branch has a known identity and the matches can be scored with
:func:`torch4dtree.data.identity_scores` (precision: share of matched pairs that are the same branch; recall: share
of the original branches still present that were matched to themselves).

**Where perturbations act**: on the data's own nodes (about 1.2 mm apart in every source), in two modes.

* ``rule`` (raw skeletons: ``.swc`` frames of the Pheno4D ``swc`` and the ``synthetic`` sources): the skeleton
  graph. The original and every perturbed skeleton go through the reader's hierarchy rule
  (:func:`~torch4dtree.trees.skeleton.skeleton_to_trees`), as a noisier scan would; the hierarchy may change, so
  a perturbed branch's identity is the original branch most of its own nodes come from. This is the whole
  pipeline from a raw skeleton.
* ``fixed`` (the same skeletons, and the hand-corrected ``.mat`` trees): the branch polylines (for a skeleton,
  those the rule gave the original); the hierarchy is kept, so every branch keeps its identity. This is the
  registration alone. Where ``rule`` fails and ``fixed`` does not, the hierarchy rule is the weak link.

**Perturbations** (:data:`LEVELS`), one kind at a time:

* ``noise``: independent Gaussian noise on every node, sigma a share of the plant's height (z extent above the
  root, :meth:`~torch4dtree.trees.Trees.height`). Per-node noise is harsh: at 1 % of a 130 mm tomato every
  coordinate moves by 1.3 mm, about the node spacing, so curves turn rough and their lengths (the SRVF norms)
  grow; a scanner's errors would be smoother.
* ``drop``: a share of the side branches removed, *leaf-most first*: one at a time, a branch without side
  branches of its own is picked at random (its parent may become one), as organs missed by a scan rather than
  whole shoots cut off.
* ``split``: a share of the edges gets a midpoint node. The geometry is unchanged, so the distance must stay
  ~0 and every identity be kept: a check of the reader's invariance to node density. (The index-order baseline
  pairs siblings at the same ``s`` in packed order, which new nodes can change, so its scores may drop though
  nothing moved.)

**Scores** per level, pooled over the sampled frames: precision / recall of the registration (counts pooled)
and of the index-order correspondence (children matched by order of ``s``; the baseline), the registered
distance relative to the plant's scan-to-scan distance (the next frame, or the previous one for a last frame,
registered onto the frame; so ``distance / day`` = 1 means the perturbation moved the tree as far as the growth
between two scans), and the share of frames where the registered distance is strictly below the index-order
one (among frames the perturbation moved by more than 1e-6 of that; the registration is never above it, and
equal where index order already gives the best correspondence, e.g. when the dropped branch was a last
sibling). Level 0 is the original registered onto itself (once per mode).

**Sampling**: ``FRAMES_PER_KIND`` frames of every kind of every source (plants in random order by
``settings.seed``, frames at normalised times ``1/n, 2/n, ..., 1``: later frames have more branches); one random
draw per frame and level, from a stream per source and kind. ``quick``: one frame, two levels.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..data.synthetic import KINDS
from ..data.truth import identity_scores
from ..io.dataset import DatasetError
from ..trees.structures import Trees
from .data import SOURCES, EvalData, EvalSettings, Plant4D
from .stats import fmt, md_table, summary
from .truth import pooled

__all__ = ["FRAMES_PER_KIND", "LEVELS", "LabelledNodes", "add_noise", "drop_branches", "frame_nodes", "from_polylines",
           "from_skeleton", "markdown", "perturb", "run", "sample_frames", "split_edges", "to_trees"]

LEVELS: dict[str, tuple[float, ...]] = {
    "noise": (0.0, 0.005, 0.01, 0.02, 0.05),  # sigma / plant height
    "drop": (0.0, 0.05, 0.1, 0.2),  # share of the side branches
    "split": (0.0, 0.25, 0.5, 1.0),  # share of the edges
}
QUICK_LEVELS: dict[str, tuple[float, ...]] = {"noise": (0.0, 0.02), "drop": (0.0, 0.2), "split": (0.0, 1.0)}
LEVEL_UNITS = {"noise": "sigma, % of height", "drop": "% of side branches", "split": "% of edges"}
FRAMES_PER_KIND = 4  # at normalised times 1/4, 1/2, 3/4, 1: ~30-60 s for all of Pheno4D (swc + mat)
QUICK_FRAMES_PER_KIND = 1
SEED_OFFSET = 500  # keeps this section's random stream apart from the others' (EvalSettings.generator)
MOVED_SHARE = 1e-6  # a perturbation moved a frame when its distance exceeds this share of the scan-to-scan one


@dataclass(frozen=True)
class LabelledNodes:
    """Nodes with parent links, each remembering the original branch it belongs to.

    Attributes:
        xyz: ``(n, 3)`` coordinates. parent: ``(n,)`` parent node (``-1``: the root, or in a ``forest`` the
            first point of every branch). label: ``(n,)`` the original branch of each node.
        branch_parent: the original hierarchy (parent branch of every branch, ``-1`` for the main one).
        forest: each branch is its own chain of nodes (its first point = its attachment point) and trees are
            rebuilt with the hierarchy ``branch_parent`` (mode ``fixed``); otherwise one skeleton, rebuilt by the
            reader's hierarchy rule (mode ``rule``).
    """

    xyz: np.ndarray
    parent: np.ndarray
    label: np.ndarray
    branch_parent: tuple[int, ...]
    forest: bool

    @property
    def mode(self) -> str:
        return "fixed" if self.forest else "rule"


def from_skeleton(xyz: np.ndarray, parent: np.ndarray, where: str = "skeleton") -> LabelledNodes:
    """A skeleton's nodes labelled by the branch the reader's hierarchy rule puts them in (a side branch's
    own nodes; its branch point belongs to the parent), so :func:`to_trees` gives branch ``b`` label ``b``."""
    from ..trees.skeleton import skeleton_to_branches

    xyz, parent = np.asarray(xyz, dtype=np.float64), np.asarray(parent, dtype=np.int64)
    _, parents, paths = skeleton_to_branches(xyz, parent, where=where)
    label = np.full(len(xyz), -1, dtype=np.int64)
    for b, path in enumerate(paths):
        label[path if b == 0 else path[1:]] = b
    if (label < 0).any():
        raise DatasetError(f"{where}: {int((label < 0).sum())} nodes lie on no branch")
    return LabelledNodes(xyz, parent, label, tuple(parents), forest=False)


def from_polylines(polylines: Sequence[np.ndarray], parents: Sequence[int]) -> LabelledNodes:
    """A tree's branch polylines as a forest of chains (one per branch, labelled by its index)."""
    sizes = [len(p) for p in polylines]
    xyz = np.concatenate([np.asarray(p, dtype=np.float64) for p in polylines])
    parent = np.arange(len(xyz), dtype=np.int64) - 1
    parent[np.cumsum([0, *sizes[:-1]])] = -1
    label = np.repeat(np.arange(len(polylines), dtype=np.int64), sizes)
    return LabelledNodes(xyz, parent, label, tuple(int(p) for p in parents), forest=True)


def add_noise(nodes: LabelledNodes, sigma: float, generator: torch.Generator) -> LabelledNodes:
    """Independent Gaussian noise of standard deviation ``sigma`` on every coordinate of every node."""
    if sigma == 0:
        return nodes
    noise = torch.randn(nodes.xyz.shape, generator=generator, dtype=torch.float64).numpy()
    return replace(nodes, xyz=nodes.xyz + sigma * noise)


def _count(share: float, n: int, generator: torch.Generator) -> int:
    """``share * n`` rounded up or down at random (by its fraction), so every level means its share on average:
    5 % of a maize plant's 5 side branches drops one a quarter of the time rather than never."""
    x = share * n
    return min(int(x) + int(float(torch.rand((), generator=generator, dtype=torch.float64)) < x - int(x)), n)


def split_edges(nodes: LabelledNodes, share: float, generator: torch.Generator) -> LabelledNodes:
    """Insert a midpoint node into a random ``share`` of the edges (randomly rounded; new nodes go last; a midpoint
    belongs to the branch of the edge's lower node, which the edge leads into)."""
    edges = np.nonzero(nodes.parent >= 0)[0]
    k = _count(share, len(edges), generator)
    if k == 0:
        return nodes
    chosen = edges[torch.randperm(len(edges), generator=generator)[:k].numpy()]
    parent = nodes.parent.copy()
    new = np.arange(len(parent), len(parent) + k)
    mid = 0.5 * (nodes.xyz[chosen] + nodes.xyz[parent[chosen]])
    new_parent = parent[chosen]
    parent[chosen] = new
    return replace(nodes, xyz=np.concatenate([nodes.xyz, mid]), parent=np.concatenate([parent, new_parent]),
                   label=np.concatenate([nodes.label, nodes.label[chosen]]))


def drop_branches(nodes: LabelledNodes, share: float, generator: torch.Generator) -> LabelledNodes:
    """Remove ``share`` of the side branches (randomly rounded), leaf-most first (module doc)."""
    bp = nodes.branch_parent
    side = [b for b in range(len(bp)) if bp[b] >= 0]
    k = _count(share, len(side), generator)
    if k == 0:
        return nodes
    kids = np.zeros(len(bp), dtype=np.int64)
    for b in side:
        kids[bp[b]] += 1
    dropped: set[int] = set()
    for _ in range(k):
        free = [b for b in side if b not in dropped and kids[b] == 0]
        b = free[int(torch.randint(len(free), (1,), generator=generator))]
        dropped.add(b)
        kids[bp[b]] -= 1
    keep = ~np.isin(nodes.label, sorted(dropped))
    new_index = np.cumsum(keep) - 1
    parent = nodes.parent[keep]
    if (parent >= 0).any() and not keep[parent[parent >= 0]].all():
        raise RuntimeError("internal error: a kept node hangs from a dropped one")
    parent = np.where(parent >= 0, new_index[np.maximum(parent, 0)], -1)
    return replace(nodes, xyz=nodes.xyz[keep], parent=parent, label=nodes.label[keep])


def perturb(nodes: LabelledNodes, kind: str, level: float, height: float, generator: torch.Generator
            ) -> LabelledNodes:
    """One perturbation of :data:`LEVELS` (``noise`` sigma is ``level * height``)."""
    if kind == "noise":
        return add_noise(nodes, level * height, generator)
    if kind == "drop":
        return drop_branches(nodes, level, generator)
    if kind == "split":
        return split_edges(nodes, level, generator)
    raise ValueError(f"unknown perturbation {kind!r}; expected one of {', '.join(LEVELS)}")


def _chains(nodes: LabelledNodes) -> dict[int, list[int]]:
    """Per branch label, its chain of nodes in a forest (from the chain's start, following the only child)."""
    child = np.full(len(nodes.parent), -1, dtype=np.int64)
    has = nodes.parent >= 0
    child[nodes.parent[has]] = np.nonzero(has)[0]
    out: dict[int, list[int]] = {}
    for v in np.nonzero(~has)[0].tolist():
        chain = [v]
        while child[chain[-1]] >= 0:
            chain.append(int(child[chain[-1]]))
        out[int(nodes.label[v])] = chain
    return out


def to_trees(nodes: LabelledNodes, T: int, where: str = "perturbed") -> Trees:
    """The tree of ``nodes`` (float64, ``label`` = original branch): the reader's rule for a skeleton, the kept
    hierarchy for a forest."""
    from ..trees.skeleton import skeleton_to_trees

    if not nodes.forest:
        return skeleton_to_trees(nodes.xyz, nodes.parent, T=T, node_labels=nodes.label, dtype=torch.float64,
                                 where=where)
    chains = _chains(nodes)
    present = sorted(chains)
    index = {b: i for i, b in enumerate(present)}
    parents = [index[nodes.branch_parent[b]] if nodes.branch_parent[b] >= 0 else -1 for b in present]
    return Trees.from_branches([[nodes.xyz[chains[b]] for b in present]], [parents], T=T, labels=[present],
                               dtype=torch.float64, names=[where])


def frame_nodes(path: Path) -> list[LabelledNodes]:
    """The labelled nodes of one frame file in every mode it offers: a ``.swc`` skeleton as it is (mode ``rule``)
    and as its branches (``fixed``: the hierarchy the rule gave the original, kept), a ``.mat`` tree as its
    branches (``fixed``). All modes of a file rebuild the same unperturbed tree."""
    from ..trees.skeleton import skeleton_to_branches

    if path.suffix.lower() == ".mat":
        from ..io.mat import load_mat_struct, mat_to_branches

        struct = load_mat_struct(path)
        if struct is None:
            raise DatasetError(f"{path}: an empty frame")
        return [from_polylines(*mat_to_branches(struct, str(path)))]
    from ..io.swc import read_swc_skeleton

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # repaired Pheno4D skeletons are reported by the reader; known here
        sk = read_swc_skeleton(path, repair=True)
    polylines, parents, _ = skeleton_to_branches(sk.xyz, sk.parent, where=str(path))
    return [from_skeleton(sk.xyz, sk.parent, str(path)), from_polylines(polylines, parents)]


def sample_frames(plants: Sequence[Plant4D], n: int, generator: torch.Generator) -> list[tuple[Plant4D, int]]:
    """``n`` frames of a kind: plants in random order, frame ``i`` at normalised time ``(i + 1) / n``."""
    usable = [p for p in plants if len(p.sequence) >= 2]
    if not usable:
        return []
    order = torch.randperm(len(usable), generator=generator).tolist()
    out = []
    for i in range(n):
        p = usable[order[i % len(usable)]]
        nt = p.sequence.normalized_times().double()
        out.append((p, int((nt - (i + 1) / n).abs().argmin())))
    return out


def _frame_rows(plant: Plant4D, j: int, levels: dict[str, tuple[float, ...]], settings: EvalSettings,
                generator: torch.Generator) -> tuple[dict[str, Any], dict[tuple[str, str, float], dict[str, Any]]]:
    """Register every perturbation of frame ``j`` (in every mode) onto the frame: its description and a row per
    ``(mode, perturbation, level)`` (``("zero", 0.0)`` for the unperturbed frame)."""
    from ..trees.registration import index_order_matches, register_to_reference, register_trees

    where = str(plant.files[j])
    modes = frame_nodes(plant.files[j])
    ref = to_trees(modes[0], settings.T, where)
    height = float(ref.height()[0])
    jobs = [(nodes, k, lv) for nodes in modes
            for k, lv in [("zero", 0.0)] + [(k, lv) for k, lvs in levels.items() for lv in lvs if lv > 0]]
    moved = [perturb(nodes, k, lv, height, generator) if k != "zero" else nodes for nodes, k, lv in jobs]
    trees = [to_trees(m, settings.T, f"{where} ({m.mode} {k} {lv:g})") for m, (_, k, lv) in zip(moved, jobs)]
    regs = register_to_reference(Trees.cat(trees), ref, settings.lambdas, rotation="none")
    frames = plant.sequence.frames.to(torch.float64)
    nb = j + 1 if j + 1 < len(plant.sequence) else j - 1
    day = float(register_trees(frames[nb], frames[j], settings.lambdas).distance)
    ref_labels = ref.label.tolist()
    ref_length = float(ref.total_length()[0])
    rows: dict[tuple[str, str, float], dict[str, Any]] = {}
    for (nodes, k, lv), m, tree, reg in zip(jobs, moved, trees, regs):
        labels = tree.label.tolist()
        rows[(nodes.mode, k, lv)] = {
            "scores": identity_scores(reg.matches, labels, ref_labels, ignore=()),  # labels are branch indices
            "index": identity_scores(index_order_matches(tree, ref), labels, ref_labels, ignore=()),
            "distance": float(reg.distance), "before": float(reg.distance_before), "day": day,
            "ratio": float(reg.distance) / day, "branches": len(labels), "nodes": len(m.xyz),
            "length_ratio": float(tree.total_length()[0]) / ref_length}
    info = {"plant": plant.name, "frame": j, "file": plant.files[j].name, "modes": [m.mode for m in modes],
            "height": height, "branches": len(ref_labels), "nodes": len(modes[0].xyz), "neighbour": nb,
            "day_distance": day}
    return info, rows


def _curve(rows: list[dict[str, Any]], level: float) -> dict[str, Any]:
    """One point of a curve: a level's rows over the sampled frames, pooled."""
    sc, ix = pooled(r["scores"] for r in rows), pooled(r["index"] for r in rows)
    # only where the perturbation moved the tree at all (a split one is the same curve: both distances ~0)
    improved = [r["distance"] < r["before"] for r in rows if r["before"] > MOVED_SHARE * r["day"]]
    return {"level": level, "frames": len(rows), "precision": sc["precision"], "recall": sc["recall"],
            "index_precision": ix["precision"], "index_recall": ix["recall"],
            "distance": summary(r["distance"] for r in rows), "ratio": summary(r["ratio"] for r in rows),
            "improved": sum(improved) / len(improved) if improved else float("nan"),
            "branches_mean": float(np.mean([r["branches"] for r in rows])),
            "nodes_mean": float(np.mean([r["nodes"] for r in rows])),
            "length_ratio_mean": float(np.mean([r["length_ratio"] for r in rows]))}


def _kind(plants: Sequence[Plant4D], levels: dict[str, tuple[float, ...]], n_frames: int, settings: EvalSettings,
          generator: torch.Generator, progress: bool) -> dict[str, Any]:
    from tqdm.auto import tqdm

    frames, rows = [], []
    picked = sample_frames(plants, n_frames, generator)
    for plant, j in tqdm(picked, disable=not progress, desc=f"robustness {plants[0].kind}", unit="frame"):
        info, r = _frame_rows(plant, j, levels, settings, generator)
        frames.append(info)
        rows.append(r)
    modes = frames[0]["modes"] if frames else []
    curves = {mode: {k: [_curve([r[(mode, "zero", 0.0)] if lv == 0 else r[(mode, k, lv)] for r in rows], lv)
                         for lv in lvs] for k, lvs in levels.items()} for mode in modes}
    return {"frames": frames, "curves": curves}


def _stream(source: str, kind: str) -> int:
    """A fixed generator offset per source and kind (a source's draws do not depend on which others are present)."""
    src = SOURCES.index(source) if source in SOURCES else len(SOURCES)
    knd = KINDS.index(kind) if kind in KINDS else len(KINDS)
    return SEED_OFFSET + 10 * src + knd


def run(datas: dict[str, EvalData], settings: EvalSettings, progress: bool = False) -> dict[str, Any]:
    """The robustness section (module doc): ``{"robustness": {"levels", "sources": {source: {kind: {"frames",
    "curves": {perturbation: [point per level]}}}}}}``; the curves are the plot data."""
    levels = QUICK_LEVELS if settings.quick else LEVELS
    n_frames = QUICK_FRAMES_PER_KIND if settings.quick else FRAMES_PER_KIND
    sources: dict[str, Any] = {}
    timings: dict[str, Any] = {}
    for name, data in datas.items():
        t0 = time.perf_counter()
        sources[name] = {kind: _kind(data.by_kind(kind), levels, n_frames, settings,
                                     settings.generator(_stream(name, kind)), progress) for kind in data.kinds}
        timings[f"robustness_{name}"] = {
            "seconds": time.perf_counter() - t0, "paper_seconds": None,
            "what": f"perturb and register {n_frames} frame(s) per kind of {name} at every level"}
    return {"robustness": {"levels": {k: list(v) for k, v in levels.items()}, "units": LEVEL_UNITS,
                           "frames_per_kind": n_frames, "sources": sources}, "timings": timings}


def markdown(report: dict[str, Any]) -> list[str]:
    """A table per perturbation: level -> precision, recall (registered and index order), distance / day."""
    res = report.get("robustness")
    if not res or not res.get("sources"):
        return []
    lines = ["## Robustness to noise and topological variation", "",
             "A frame perturbed in a known way, registered onto itself unperturbed (no rotation); every branch's "
             "true identity is known from the nodes it is made of. Mode *rule*: the perturbed skeleton's hierarchy "
             "derived again by the reader's rule (the pipeline from a raw skeleton); *fixed*: the hierarchy kept "
             "(the registration alone; `.mat` trees only have this one). *P / R*: identity precision / recall of "
             "the registration, pooled over frames; *index P / R*: of the index-order correspondence; "
             "*distance / day*: the registered distance over the distance between that frame and the next scan "
             "of the plant (median over frames, max in brackets); *branches*: the perturbed trees' (mean over frames); "
             "*length*: the perturbed tree's total length over the original's; *beats index*: share of frames "
             "whose registered distance is strictly below the index-order one (never above it) "
             f"(of those the perturbation moved). {res['frames_per_kind']} frame(s) per kind and source.", ""]
    for kind_of, unit in res["units"].items():
        rows = []
        for src, kinds in res["sources"].items():
            for kind, v in kinds.items():
                for mode, curves in v["curves"].items():
                    for pt in curves.get(kind_of, []):
                        rows.append([src, mode, kind, f"{100 * pt['level']:g}", pt["frames"], fmt(pt["branches_mean"]),
                                     f"{fmt(pt['precision'], percent=True)} / {fmt(pt['recall'], percent=True)}",
                                     f"{fmt(pt['index_precision'], percent=True)} / "
                                     f"{fmt(pt['index_recall'], percent=True)}",
                                     f"{fmt(pt['ratio']['median'])} ({fmt(pt['ratio']['max'])})",
                                     fmt(pt["length_ratio_mean"]), fmt(pt["improved"], percent=True)])
        lines += [f"**{kind_of}** (level: {unit})", "",
                  *md_table(["source", "mode", "kind", "level", "frames", "branches", "P / R", "index P / R",
                             "distance / day", "length", "beats index"], rows), ""]
    return lines[:-1]
