"""Skeleton graphs (nodes + parent links) to branch hierarchies and back.

The rule (SPEC §2, the one used for the published Pheno4D trees): the main branch is the
longest root-to-leaf path; then, recursively, every child of a node of a branch that is not
the branch's own continuation starts a side branch that follows the longest path down its
subtree. Path length is Euclidean length along the skeleton.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence

import numpy as np
import torch

from .structures import DEFAULT_T, TreeError, Trees


def validate_skeleton(xyz: np.ndarray, parent: np.ndarray, where: str, ids: np.ndarray | None = None) -> np.ndarray:
    """Check a skeleton and return its nodes in breadth-first order from the root.

    Args:
        xyz: ``(n, d)`` node coordinates.
        parent: ``(n,)`` parent node index (``-1`` for the root).
        where: a name for error messages (a file name).
        ids: ``(n,)`` node ids to name in errors (defaults to the indices).
    """
    ids = np.arange(len(xyz)) if ids is None else ids
    n = len(xyz)
    if n == 0:
        raise TreeError(f"{where}: the skeleton has no nodes")
    if n < 2:
        raise TreeError(f"{where}: the skeleton has a single node, a tree needs at least one branch")
    bad = np.nonzero(~np.isfinite(xyz).all(1))[0]
    if len(bad):
        raise TreeError(f"{where}: node {ids[bad[0]]} has NaN or infinite coordinates")
    roots = np.nonzero(parent == -1)[0]
    if len(roots) != 1:
        named = ", ".join(str(ids[r]) for r in roots[:5])
        raise TreeError(f"{where}: expected exactly one root (parent -1), found {len(roots)}: {named}")
    out_of_range = np.nonzero((parent < -1) | (parent >= n))[0]
    if len(out_of_range):
        raise TreeError(f"{where}: node {ids[out_of_range[0]]} has an invalid parent")
    children = _children(parent)
    order = [int(roots[0])]
    for v in order:  # grows while iterating: breadth-first
        order.extend(children[v])
    if len(order) != n:
        seen = np.zeros(n, bool)
        seen[order] = True
        stray = np.nonzero(~seen)[0]
        raise TreeError(f"{where}: nodes not connected to the root (a cycle through node {ids[stray[0]]})")
    return np.asarray(order)


def repair_skeleton(xyz: np.ndarray, parent: np.ndarray, ids: np.ndarray | None = None) -> tuple[np.ndarray, list[str]]:
    """Make a broken skeleton a tree: break cycles, join stray parts at their nearest node.

    The links are taken as undirected edges; parts that do not reach the root are joined by the
    shortest gap between a reached and an unreached node; a breadth-first spanning tree from the
    root then gives the new parents (a cycle loses the edge that closes it). Returns the new
    ``parent (n,)`` and one message per repair, naming the nodes.
    """
    ids = np.arange(len(xyz)) if ids is None else ids
    n = len(xyz)
    roots = np.nonzero(parent == -1)[0]
    if len(roots) == 0:
        raise TreeError("cannot repair a skeleton without a root (parent -1)")
    adjacency: list[list[int]] = [[] for _ in range(n)]
    for v, p in enumerate(parent.tolist()):
        if p >= 0:
            adjacency[v].append(p)
            adjacency[p].append(v)
    messages: list[str] = []
    new_parent = np.full(n, -2, dtype=np.int64)
    new_parent[roots[0]] = -1
    frontier = [int(roots[0])]
    while True:
        for v in frontier:  # breadth-first, grows while iterating
            for w in adjacency[v]:
                if new_parent[w] == -2:
                    new_parent[w] = v
                    frontier.append(w)
        unreached = np.nonzero(new_parent == -2)[0]
        if len(unreached) == 0:
            break
        reached = np.nonzero(new_parent != -2)[0]
        gaps = np.linalg.norm(xyz[reached][:, None] - xyz[unreached][None], axis=-1)
        a, b = np.unravel_index(gaps.argmin(), gaps.shape)
        messages.append(
            f"{len(unreached)} nodes did not reach the root (a cycle or a stray part); joined node "
            f"{ids[unreached[b]]} to node {ids[reached[a]]} across a gap of {gaps[a, b]:.3g}"
        )
        new_parent[unreached[b]] = reached[a]
        frontier = [int(unreached[b])]
    changed = np.nonzero(new_parent != parent)[0]
    if len(changed) and not messages:
        messages.append(f"re-linked {len(changed)} nodes")
    return new_parent, messages


def _children(parent: np.ndarray) -> list[list[int]]:
    children: list[list[int]] = [[] for _ in range(len(parent))]
    for v, p in enumerate(parent.tolist()):
        if p >= 0:
            children[p].append(v)
    return children


def skeleton_to_branches(
    xyz: np.ndarray,
    parent: np.ndarray,
    max_layers: int | None = None,
    min_branch_length: float = 0.0,
    main_path: Sequence[int] | None = None,
    where: str = "skeleton",
    ids: np.ndarray | None = None,
) -> tuple[list[np.ndarray], list[int], list[list[int]]]:
    """Decompose a skeleton into branches by the longest-path rule.

    Args:
        xyz: ``(n, d)`` node coordinates.
        parent: ``(n,)`` parent node index, ``-1`` for the root.
        max_layers: keep at most this many layers (1 = main branch only); ``None`` keeps all.
        min_branch_length: drop side branches (and their subtrees) shorter than this.
        main_path: node indices of the main branch, starting at the root (default: longest path).
        where: a name for error messages.
        ids: node ids for error messages.

    Returns:
        ``(polylines, parents, node_paths)``: per branch its points ``(n_i, d)``, the index of
        its parent branch (``-1`` for the main one) and the skeleton nodes it runs through (a side
        branch starts at its branch point on the parent).
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    parent = np.asarray(parent, dtype=np.int64)
    order = validate_skeleton(xyz, parent, where, ids)
    children = _children(parent)
    edge = np.zeros(len(xyz))
    has_parent = parent >= 0
    edge[has_parent] = np.linalg.norm(xyz[has_parent] - xyz[parent[has_parent]], axis=1)
    reach = np.zeros(len(xyz))  # longest path length from a node down to a leaf
    best = np.full(len(xyz), -1)
    for v in order[::-1]:
        for c in children[v]:
            if edge[c] + reach[c] > reach[v] or best[v] < 0:
                reach[v], best[v] = edge[c] + reach[c], c

    def follow(start: int) -> list[int]:
        path = [start]
        while best[path[-1]] >= 0:
            path.append(int(best[path[-1]]))
        return path

    root = int(order[0])
    if main_path is not None:
        main = [int(v) for v in main_path]
        if not main or main[0] != root:
            raise TreeError(f"{where}: the given main path must start at the root node")
        for a, b in zip(main[:-1], main[1:]):
            if parent[b] != a:
                raise TreeError(f"{where}: the given main path is not a chain of parent links at node {b}")
    else:
        main = follow(root)
    if len(main) < 2:
        raise TreeError(f"{where}: the main branch has a single node")
    paths: list[list[int]] = [main]
    parents: list[int] = [-1]
    layer: list[int] = [1]
    k = 0
    while k < len(paths):  # paths grows while we walk it: breadth-first over branches
        path, on_path = paths[k], set(paths[k])
        if max_layers is None or layer[k] < max_layers:
            for v in path if k == 0 else path[1:]:  # a side branch's first node is its parent's
                for c in children[v]:
                    if c in on_path:
                        continue
                    side = [v, *follow(c)]
                    if edge[c] + reach[c] < min_branch_length:
                        continue
                    paths.append(side)
                    parents.append(k)
                    layer.append(layer[k] + 1)
        k += 1
    return [xyz[p] for p in paths], parents, paths


def skeleton_to_trees(
    xyz: np.ndarray,
    parent: np.ndarray,
    T: int = DEFAULT_T,
    max_layers: int | None = None,
    min_branch_length: float = 0.0,
    main_path: Sequence[int] | None = None,
    node_labels: np.ndarray | None = None,
    where: str = "skeleton",
    ids: np.ndarray | None = None,
    dtype: torch.dtype = torch.float32,
) -> Trees:
    """One skeleton as a single-tree :class:`Trees` (see :func:`skeleton_to_branches`).

    ``node_labels (n,)``, if given, labels each branch by the most common label of its own nodes
    (the branch point it starts from belongs to the parent and is not counted).
    """
    polylines, parents, paths = skeleton_to_branches(
        xyz, parent, max_layers, min_branch_length, main_path, where, ids
    )
    labels = None
    if node_labels is not None:
        own = [p if i == 0 else p[1:] for i, p in enumerate(paths)]
        labels = [[Counter(int(node_labels[v]) for v in nodes).most_common(1)[0][0] for nodes in own]]
    return Trees.from_branches([polylines], [parents], T=T, labels=labels, dtype=dtype, names=[where])


def trees_to_skeleton(tree: Trees) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A single tree as a skeleton graph: ``(xyz (n, d), parent (n,), node_label (n,))``.

    Each side branch hangs off a node inserted into its parent at the exact attachment point
    (parameter ``s``), so reading the skeleton back gives the same branch geometry.
    """
    if tree.num_trees != 1:
        raise TreeError(f"trees_to_skeleton takes one tree, got {tree.num_trees}")
    pts = tree.points.detach().cpu().double().numpy()
    parents, s = tree.parent.tolist(), tree.s.detach().cpu().double().tolist()
    labels = tree.label.tolist()
    T = tree.T
    kids: list[list[int]] = [[] for _ in parents]
    for i, p in enumerate(parents):
        if p >= 0:
            kids[p].append(i)
    xyz: list[np.ndarray] = []
    par: list[int] = []
    lab: list[int] = []
    attach_node: dict[int, int] = {}
    for b in range(len(parents)):
        # the branch's own grid nodes, plus one node per child attachment, sorted by parameter
        stops = [(k / (T - 1), -1, k) for k in range(T)] + [(s[c], c, -1) for c in kids[b]]
        stops.sort(key=lambda st: (st[0], st[1] >= 0))
        prev = attach_node[b] if b in attach_node else -1
        for u, child, grid_k in stops:
            if grid_k == 0 and parents[b] >= 0:
                continue  # a side branch's first point is its attachment node on the parent
            if child >= 0 and xyz and prev >= 0 and np.allclose(_point_at(pts[b], u), xyz[prev]):
                attach_node[child] = prev  # attaches exactly at an existing node
                continue
            point = pts[b][grid_k] if grid_k >= 0 else _point_at(pts[b], u)
            xyz.append(point)
            par.append(prev)
            lab.append(labels[b])
            prev = len(xyz) - 1
            if child >= 0:
                attach_node[child] = prev
    return np.asarray(xyz), np.asarray(par), np.asarray(lab)


def _point_at(curve: np.ndarray, u: float) -> np.ndarray:
    x = u * (len(curve) - 1)
    lo = min(int(np.floor(x)), len(curve) - 2)
    return curve[lo] + (x - lo) * (curve[lo + 1] - curve[lo])
