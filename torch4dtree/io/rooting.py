"""Where a plant skeleton is rooted: at its stem base (docs/method.md §6).

A skeletoniser roots a plant scan at its lowest node. When a leaf hangs below the stem base, that node is the
leaf's tip: the main branch then runs up the leaf and the stem becomes a side branch of it. A neuron's SWC, by
contrast, is rooted at its soma on purpose. The readers therefore take a ``root`` choice (:data:`ROOTS`):

* ``"file"``: the root the file names (parent ``-1``), as written.
* ``"base"``: the stem base by the rule below, whatever the file's root is.
* ``"auto"`` (default): the rule, for files whose root is a single-child node that is not a soma (SWC type 1);
  a file rooted at a soma or at a branching node keeps its root. A change is reported with a warning naming the
  file and both node ids.

**The rule.** The main branch of a plant rooted at its stem base rises (it is the stem); rooted at a hanging leaf
tip it runs up the leaf and then along or down the stem, sideways. Among the tips (single-neighbour nodes) within
:data:`BASE_BAND` of the plant's height above its lowest node, the one whose main branch (``"straightest"``
hierarchy, rooted there) rises most replaces the file's root only if that rise is at least :data:`BASE_RISE` and
beats the file root's rise by :data:`RISE_MARGIN`; otherwise the file's root stays. The rise of a main branch is
its chord's vertical share, ``dz / |chord|`` (``z`` up). Re-rooting reverses the parent links on the path between
the two roots and keeps every edge, node and attribute.
"""

from __future__ import annotations

import math

import numpy as np

from ..settings import DEFAULT_ROOT, ROOTS, check_choice
from ..trees.skeleton import follow_continuations, resolve_branch_points, validate_skeleton
from ..trees.structures import TreeError

# the vertical axis of a plant scan (Pheno4D and the simulators: millimetres, z up)
UP_AXIS = 2
# candidate stem bases: tips at most this share of the plant's height above its lowest node (the stem bases of the
# misrooted Pheno4D frames sit 0.6-5.5 % above the hanging leaf tip; docs/experiments.md)
BASE_BAND = 0.1
# at most this many candidates, the lowest (a scan's web on the pot surface gives 19 on Pheno4D): each costs one
# hierarchy resolution, and a skeleton drawn flat must not cost one per tip
MAX_CANDIDATES = 32
# a stem base's main branch climbs at least this steeply (chord about 44 degrees above the horizontal); the stem
# bases found on Pheno4D rise 0.88-0.99
BASE_RISE = 0.7
# and at least this much more steeply than the file root's: on Pheno4D a misrooted frame's stem base gains 0.56-0.99,
# while the other low tips of well-rooted frames gain at most 0.10 (spurs beside the base)
RISE_MARGIN = 0.4
# the hierarchy whose main branch the rule measures: fixed, so that every hierarchy sees the same root
ROOT_HIERARCHY = "straightest"
SOMA_TYPE = 1  # the SWC type of a neuron's soma
# divisor floor of a chord length: a zero-length chord gives a rise of 0 instead of nan
MIN_CHORD = 1e-300


def reroot(parent: np.ndarray, root: int) -> np.ndarray:
    """The parent links ``(n,)`` of the same tree rooted at node index ``root``.

    Only the links on the path from ``root`` to the old root are reversed: the edge set, the node order and
    every other link stay as they are. ``parent`` must be a valid tree (one ``-1``, no cycles).

    Example:
        >>> reroot(np.array([-1, 0, 1, 1]), 3).tolist()  # a chain 0-1-2 with a side node 3 on node 1
        [1, 3, 1, -1]
    """
    parent = np.asarray(parent, dtype=np.int64)
    if not 0 <= root < len(parent):
        raise TreeError(f"cannot root at node index {root}: the skeleton has {len(parent)} nodes")
    out = parent.copy()
    prev, v = -1, int(root)
    for _ in range(len(parent)):
        up = int(parent[v])
        out[v] = prev
        if up < 0:
            return out
        prev, v = v, up
    raise TreeError("cannot re-root: the parent links hold a cycle")


def main_branch_rise(xyz: np.ndarray, parent: np.ndarray, where: str = "skeleton") -> float:
    """The rise of a skeleton's main branch (``"straightest"`` hierarchy): its chord's vertical share in
    ``[-1, 1]`` (``1`` straight up). ``xyz (n, 3)`` with ``z`` up, ``parent (n,)`` a valid tree."""
    order, _, _, best = resolve_branch_points(xyz, parent, ROOT_HIERARCHY, where)
    path = follow_continuations(best, int(order[0]))
    chord = xyz[path[-1]] - xyz[path[0]]
    return float(chord[UP_AXIS] / max(float(np.linalg.norm(chord)), MIN_CHORD))


def base_candidates(xyz: np.ndarray, parent: np.ndarray) -> np.ndarray:
    """Node indices of the tips (one neighbour) at most :data:`BASE_BAND` of the height above the lowest node,
    lowest first, at most :data:`MAX_CANDIDATES`; none in a skeleton without height (nothing rises there)."""
    n = len(parent)
    linked = parent >= 0
    degree = np.bincount(parent[linked], minlength=n) + linked
    z = xyz[:, UP_AXIS]
    height = float(z.max() - z.min())
    if not height > 0:
        return np.zeros(0, dtype=np.int64)
    tips = np.nonzero((degree == 1) & (z <= z.min() + BASE_BAND * height))[0]
    return tips[np.argsort(z[tips], kind="stable")][:MAX_CANDIDATES]


def stem_base(xyz: np.ndarray, parent: np.ndarray, where: str = "skeleton") -> tuple[int, float, float]:
    """The stem base by the module's rule: ``(node index, its main branch's rise, the current root's rise)``; the
    index is the current root's when no candidate qualifies (the rises are then ``nan`` when no other tip lies
    in the band: nothing was measured).

    Example:
        >>> xyz = np.array([[0, 0, 0], [0, 0, 5], [0, 0, 10], [1, 0, 6], [4, 0, -1]], dtype=float)
        >>> parent = np.array([-1, 0, 1, 1, 3])  # node 0 is the stem base, node 4 a leaf tip hanging below it
        >>> stem_base(xyz, reroot(parent, 4))[0]
        0
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    parent = np.asarray(parent, dtype=np.int64)
    if xyz.ndim != 2 or xyz.shape[1] <= UP_AXIS:
        raise TreeError(f"{where}: rooting at the stem base needs 3D points (z up), got shape {tuple(xyz.shape)}")
    order = validate_skeleton(xyz, parent, where)
    root = int(order[0])
    candidates = [c for c in base_candidates(xyz, parent).tolist() if c != root]
    if not candidates:  # the usual case, decided without resolving a hierarchy
        return root, math.nan, math.nan
    rise = main_branch_rise(xyz, parent, where)
    best, best_rise = root, rise
    if rise + RISE_MARGIN > 1.0:  # no rise exceeds 1: nothing can beat this root by the margin
        return best, best_rise, rise
    for c in candidates:
        r = main_branch_rise(xyz, reroot(parent, c), where)
        if r > best_rise:
            best, best_rise = c, r
    if best_rise >= BASE_RISE and best_rise - rise >= RISE_MARGIN:
        return best, best_rise, rise
    return root, rise, rise


def choose_root(xyz: np.ndarray, parent: np.ndarray, types: np.ndarray, root: str = DEFAULT_ROOT,
                where: str = "skeleton", ids: np.ndarray | None = None) -> tuple[int, str]:
    """The node index a skeleton is rooted at by the ``root`` choice (module doc), and a sentence saying why
    it differs from the file's root (``""`` when it does not).

    Args:
        xyz: ``(n, 3)`` node coordinates, ``z`` up. parent: ``(n,)`` a valid tree (``-1`` at the file's root).
        types: ``(n,)`` the SWC type column (``"auto"`` keeps a soma root, type 1).
        root: one of :data:`ROOTS`.
        where: a name for messages (the file). ids: ``(n,)`` node ids named in messages (default: the indices).

    Example:
        >>> xyz = np.array([[4, 0, -1], [1, 0, 6], [0, 0, 5], [0, 0, 0], [0, 0, 10]], dtype=float)
        >>> parent = np.array([-1, 0, 1, 2, 2])  # rooted at a leaf tip (node 0) below the stem base (node 3)
        >>> choose_root(xyz, parent, np.zeros(5))[0], choose_root(xyz, parent, np.zeros(5), "file")[0]
        (3, 0)
    """
    check_choice("root", root, ROOTS)
    parent = np.asarray(parent, dtype=np.int64)
    file_root = int(np.nonzero(parent == -1)[0][0])
    if root == "file":
        return file_root, ""
    if root == "auto" and (int(np.count_nonzero(parent == file_root)) != 1 or int(types[file_root]) == SOMA_TYPE):
        return file_root, ""
    node, rise, file_rise = stem_base(xyz, parent, where)
    if node == file_root:
        return file_root, ""
    ids = np.arange(len(parent)) if ids is None else ids
    height = float(xyz[node, UP_AXIS] - xyz[:, UP_AXIS].min())
    return node, (f"{where}: rooted at the stem base, node {ids[node]} ({height:.3g} above the lowest node; its main "
                  f"branch rises {rise:.2f}), instead of the file's root, node {ids[file_root]} (whose main branch "
                  f"rises {file_rise:.2f}); pass root='file' to keep the file's root")
