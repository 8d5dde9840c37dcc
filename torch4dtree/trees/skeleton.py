"""Skeleton graphs (nodes + parent links) to branch hierarchies and back.

A skeleton does not say which child continues a branch at a branch point; a **hierarchy rule**
decides it (docs/method.md §2). The main branch starts at the root and, at every branch point, continues
into the child the rule picks; every other child starts a side branch, decomposed the same way.

* ``"longest"``: the child with the longest path down to a leaf (the paper's rule). Unstable under
  growth: the main branch runs up the stem and into whichever organ is longest at the top.
* ``"heaviest"``: the child whose subtree has the largest total length.
* ``"continuation"``: ``"straightest"``'s turn, less :data:`CARRY_RADIANS` times the log of what the
  child carries (its subtree's length off its own longest path, plus one window) relative to the candidate that
  carries most. A shoot that carries laterals goes on through a fork where a bare leader or twig turns a little
  less (a woody tree's overtaken leader, a sympodial shoot's zig-zag); a leaf or a young maize leaf, carrying
  little, never outweighs the stem's straightness.
* ``"straightest"`` (default): the child whose first stretch (a window of arc length) turns least from the
  branch's incoming direction (measured back along the branch itself, at most to where it starts: at a shoot's
  first node its first internode, not the stem it leaves, so an upright lateral there does not take the shoot
  over as it grows), among children whose subtree is not negligible (spurs); the heaviest
  where there is no incoming direction (at the root). Stems, rachises and shoots run straight through
  their nodes while leaves and leaflets leave at an angle, whichever is longer on that day. The window at a
  branch point is half the length of the side organ leaving there, at least 2 % of the plant's extent
  (:func:`organ_window`).

Lengths are Euclidean along the skeleton, directions are measured over arc-length windows and the
windows are lengths of the geometry, so the hierarchy does not depend on how densely the nodes sample
the branches (splitting edges anywhere or merging collinear ones leaves it as is).
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence

import numpy as np
import torch

from ..settings import DEFAULT_HIERARCHY, DEFAULT_T, HIERARCHIES, check_choice
from .structures import TreeError, Trees


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


# straightest rule: shares of lengths of the geometry, never of the node spacing (the measurements that chose them
# are in docs/experiments.md)
WINDOW_EXTENT_SHARE = 0.02  # the plant-wide floor of the window: a share of the plant's extent
WINDOW_ORGAN_SHARE = 0.5  # the window at a branch point: a share of the side organ's length there
# children whose subtree is shorter than this many windows are spurs, not candidates; a longer threshold would drop
# the short stem tip above the youngest leaf (a true continuation) where the window is long
SPUR_WINDOWS = 0.1
# "continuation": the turn (rad) a child adds for carrying e times less than the candidate that carries most (what a
# child carries: its subtree's length off its own longest path, plus one window); 0.1-0.25 keep the herbaceous
# identities of "straightest" and fix the woody ones, 0.5 loses tomato and bean leaves (docs/experiments.md)
CARRY_RADIANS = 0.15
DIRECTED = ("straightest", "continuation")  # the rules that measure directions
# divisor floor of a product of vector norms: a zero-length direction gives an angle instead of nan
MIN_NORM = 1e-300


def default_window(xyz: np.ndarray, parent: np.ndarray, edge: np.ndarray,
                   children: list[list[int]] | None = None) -> float:
    """Floor of the ``"straightest"`` rule's direction window: ``WINDOW_EXTENT_SHARE`` of the farthest node's path
    distance from the root. Each branch point widens it to :func:`organ_window` (``continuation_children``)."""
    return WINDOW_EXTENT_SHARE * float(_root_distances(parent, edge, children).max())


def organ_window(child_reach: np.ndarray, floor: float) -> float:
    """Direction window at one branch point: ``WINDOW_ORGAN_SHARE`` of the second-longest child path ``(k,)``
    (the side organ that leaves there), at least ``floor``.

    Why the organ and not the plant: a maize leaf's sheath hugs the stem for a good part of the leaf's length,
    so the window must reach past it, while a short spur or a young leaflet must not widen the window beyond
    its own scale. Both are lengths of the geometry, so splitting or merging collinear edges leaves them as is
    (a floor in median edges would halve when every edge is split)."""
    if len(child_reach) < 2:
        return floor
    return max(floor, WINDOW_ORGAN_SHARE * float(np.partition(child_reach, -2)[-2]))


def _root_distances(parent: np.ndarray, edge: np.ndarray, children: list[list[int]] | None = None) -> np.ndarray:
    """``(n,)`` path length from the root to every node (``children``: :func:`_children`, if at hand)."""
    children = _children(parent) if children is None else children
    dist = [0.0] * len(parent)
    length = edge.tolist()  # Python floats: the same sums, without numpy's per-element overhead
    stack = [int(np.nonzero(parent == -1)[0][0])]
    while stack:
        v = stack.pop()
        for c in children[v]:
            dist[c] = dist[v] + length[c]
            stack.append(c)
    return np.asarray(dist)


def _subtree_lengths(order: np.ndarray, children: list[list[int]], edge: np.ndarray) -> tuple[list[float], list[float]]:
    """Per node, the longest path down to a leaf (``reach``) and the total length below it (``weight``)."""
    n = len(edge)
    length = edge.tolist()
    reach, weight = [0.0] * n, [0.0] * n
    for v in order[::-1].tolist():
        for c in children[v]:
            through = length[c] + reach[c]
            if through > reach[v]:
                reach[v] = through
            weight[v] += length[c] + weight[c]
    return reach, weight


def _point_up(xyz: np.ndarray, parent: np.ndarray, edge: np.ndarray, v: int, length: float) -> np.ndarray | None:
    """The point ``length`` back along the path from node ``v`` towards the root (None at the root)."""
    if parent[v] < 0:
        return None
    left = length
    while parent[v] >= 0:
        if edge[v] >= left:
            return xyz[v] + (xyz[parent[v]] - xyz[v]) * (left / edge[v])
        left -= edge[v]
        v = int(parent[v])
    return xyz[v]


def _point_down(xyz: np.ndarray, parent: np.ndarray, children: list[list[int]], edge: np.ndarray, c: int,
                length: float, axis: np.ndarray) -> np.ndarray:
    """The point ``length`` along the skeleton from the parent of ``c`` through ``c``, continuing at every branch
    point on the way into the child that keeps the walk closest to ``axis`` (the way a stem or rachis goes on)."""
    left = length
    while edge[c] < left:
        left -= edge[c]
        if not children[c]:
            return xyz[c]
        if len(children[c]) == 1:
            c = children[c][0]
            continue
        # each child's walk is the walk on through it: return the chosen one's end, never walk it twice
        ends = {k: _point_down(xyz, parent, children, edge, k, left, axis) for k in children[c]}
        return ends[min(ends, key=lambda k: _angle(axis, ends[k] - xyz[c]))]
    p = parent[c]
    return xyz[p] + (xyz[c] - xyz[p]) * (left / edge[c])


def _angle(u: np.ndarray, v: np.ndarray) -> float:
    # np.linalg.norm of a vector is sqrt(x.dot(x)): the same numbers, without its overhead (a hot path)
    norms = math.sqrt(float(u.dot(u))) * math.sqrt(float(v.dot(v)))
    return math.acos(min(max(float(u @ v) / max(norms, MIN_NORM), -1.0), 1.0))


def continuation_children(xyz: np.ndarray, parent: np.ndarray, order: np.ndarray, children: list[list[int]],
                          edge: np.ndarray, hierarchy: str = DEFAULT_HIERARCHY, where: str = "skeleton",
                          window: float | None = None) -> np.ndarray:
    """``best (n,)``: the child that continues the branch through each node (``-1`` at leaves)."""
    check_choice(f"{where}: hierarchy", hierarchy, HIERARCHIES)
    n = len(xyz)
    reach, weight = _subtree_lengths(order, children, edge)
    length = edge.tolist()
    path = [length[c] + reach[c] for c in range(n)]  # longest path from a node's parent through it
    down = [length[c] + weight[c] for c in range(n)]  # what hangs from a node's parent through that node
    best = np.full(n, -1)
    own = [0.0] * n  # arc length from the start of the branch a node lies on (as decided above it) to the node
    floor = 0.0
    if hierarchy in DIRECTED:
        if window is not None and not window > 0:
            raise TreeError(f"{where}: the direction window must be positive, got {window}")
        floor = default_window(xyz, parent, edge, children) if window is None else float(window)
    for v in order.tolist():
        p = int(parent[v])
        if p >= 0:
            own[v] = (own[p] if best[p] == v else 0.0) + length[v]
        kids = children[v]
        if len(kids) < 2:  # a leaf, or a node inside a branch: every rule continues into its only child
            if kids:
                best[v] = kids[0]
            continue
        if hierarchy == "longest":
            best[v] = max(kids, key=lambda c: (path[c], -c))
            continue
        heaviest = max(kids, key=lambda c: (down[c], -c))
        if hierarchy not in DIRECTED or window is not None:
            w = floor
        else:
            w = organ_window(np.array([path[c] for c in kids]), floor)
        # the incoming direction is the branch's own: a shoot's first internode, never the stem it leaves
        back = _point_up(xyz, parent, edge, v, min(w, own[v]) if own[v] > 0 else w) if w > 0 else None
        if back is None:
            best[v] = heaviest
            continue
        incoming = xyz[v] - back
        candidates = [c for c in kids if down[c] >= SPUR_WINDOWS * w] or [heaviest]
        turn = {c: _angle(incoming, _point_down(xyz, parent, children, edge, c, w, incoming) - xyz[v])
                for c in candidates}
        if hierarchy == "continuation":
            # what each child carries besides its own longest path (side organs), a window counting as nothing
            carried = {c: down[c] - path[c] + w for c in candidates}
            top = max(carried.values())
            score = {c: turn[c] - CARRY_RADIANS * math.log(carried[c] / top) for c in candidates}
            best[v] = min(candidates, key=lambda c: (score[c], -down[c], c))
        else:
            best[v] = min(candidates, key=lambda c: (turn[c], -down[c], c))
    return best


def resolve_branch_points(xyz: np.ndarray, parent: np.ndarray, hierarchy: str = DEFAULT_HIERARCHY,
                          where: str = "skeleton", ids: np.ndarray | None = None, window: float | None = None
                          ) -> tuple[np.ndarray, list[list[int]], np.ndarray, np.ndarray]:
    """A validated skeleton's ``(order, children, edge, best)``: breadth-first node order, children lists, the
    length ``(n,)`` of each node's edge to its parent and the child ``best (n,)`` the rule continues into (``-1`` at
    leaves)."""
    order = validate_skeleton(xyz, parent, where, ids)
    children = _children(parent)
    edge = np.zeros(len(xyz))
    has_parent = parent >= 0
    edge[has_parent] = np.linalg.norm(xyz[has_parent] - xyz[parent[has_parent]], axis=1)
    return order, children, edge, continuation_children(xyz, parent, order, children, edge, hierarchy, where, window)


def follow_continuations(best: np.ndarray, start: int) -> list[int]:
    """The path from node ``start`` down through the continuation children ``best`` to a leaf."""
    path = [start]
    while best[path[-1]] >= 0:
        path.append(int(best[path[-1]]))
    return path


def skeleton_to_branches(
    xyz: np.ndarray,
    parent: np.ndarray,
    max_layers: int | None = None,
    min_branch_length: float = 0.0,
    main_path: Sequence[int] | None = None,
    where: str = "skeleton",
    ids: np.ndarray | None = None,
    hierarchy: str = DEFAULT_HIERARCHY,
    window: float | None = None,
) -> tuple[list[np.ndarray], list[int], list[list[int]]]:
    """Decompose a skeleton into branches by a hierarchy rule (module docstring).

    Args:
        xyz: ``(n, d)`` node coordinates.
        parent: ``(n,)`` parent node index, ``-1`` for the root.
        max_layers: keep at most this many layers (1 = main branch only); ``None`` keeps all.
        min_branch_length: drop side branches (and their subtrees) shorter than this.
        main_path: node indices of the main branch, starting at the root (default: by the rule).
        where: a name for error messages.
        ids: node ids for error messages.
        hierarchy: ``"straightest"`` (default), ``"continuation"``, ``"heaviest"`` or ``"longest"`` (module
            docstring).
        window: arc length over which ``"straightest"`` and ``"continuation"`` measure directions at every branch point
            (default: per branch point, :func:`organ_window` with the floor :func:`default_window`).

    Returns:
        ``(polylines, parents, node_paths)``: per branch its points ``(n_i, d)``, the index of
        its parent branch (``-1`` for the main one) and the skeleton nodes it runs through (a side
        branch starts at its branch point on the parent).
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    parent = np.asarray(parent, dtype=np.int64)
    order, children, edge, best = resolve_branch_points(xyz, parent, hierarchy, where, ids, window)
    reach = _subtree_lengths(order, children, edge)[0]  # longest path length from a node down to a leaf

    def follow(start: int) -> list[int]:
        return follow_continuations(best, start)

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
    hierarchy: str = DEFAULT_HIERARCHY,
    window: float | None = None,
) -> Trees:
    """One skeleton as a single-tree :class:`Trees` (see :func:`skeleton_to_branches`).

    ``node_labels (n,)``, if given, labels each branch by the most common label of its own nodes
    (the branch point it starts from belongs to the parent and is not counted).

    Example:
        >>> import numpy as np
        >>> xyz = np.array([[0, 0, 0], [0, 0, 1], [0, 0, 2], [1, 0, 1.5]], dtype=float)  # a stem and one side node
        >>> tree = skeleton_to_trees(xyz, np.array([-1, 0, 1, 1]), T=8)
        >>> tree.num_branches.tolist(), tree.parent.tolist(), tree.s.tolist()
        ([2], [-1, 0], [0.0, 0.5])
    """
    polylines, parents, paths = skeleton_to_branches(
        xyz, parent, max_layers, min_branch_length, main_path, where, ids, hierarchy, window
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
