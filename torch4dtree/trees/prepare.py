"""A tree in the form the registration solver uses, and how its children's positions are compared.

``positions`` (docs/method.md §3) says what a child's place on its parent is: ``"warped"`` its bifurcation
parameter moved by the parent's warp, ``"arclength"`` its arc length from the parent's base, ``"rank"`` (main
branch's children) its node rank, the weighted count of nodes below it, ``"nodes"`` its node
rank on the main branch and on every axis (a branch that carries organs), an axillary shoot half a node above the leaf
of its node, a compound leaf's leaflets their arc-length fractions (two plants of a kind: the leaf or shoot at node n).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from ..curves.srvf import srvf, srvf_sq_norm
from .aligned import Lambdas, subtree_sq_norms
from .matching import order_groups
from .structures import Trees

__all__ = ["AXIL_OFFSET", "AXIS_CARRIES", "AXIS_MIN_WEIGHT", "MIN_LENGTH", "NODE_POWER", "NODE_SIGNIFICANT",
           "PreparedTree", "RANK_NODE_TOL", "RANK_SIGNIFICANT", "RankedTree", "arc_fractions", "child_positions",
           "prepare_tree"]

# floor of a length used as a divisor: a zero-length branch gives finite positions instead of nan
MIN_LENGTH = 1e-12
# "rank": siblings closer than this share of the main branch's length are one node
RANK_NODE_TOL = 0.02
# "rank": a node counts 1 - exp(-(l / (RANK_SIGNIFICANT x main branch length))^2) towards the ranks above it, l its
# largest subtree's total length: a skeleton spur a few % of the stem long barely counts, an organ counts ~1
RANK_SIGNIFICANT = 0.1
# "nodes": a node counts 1 - exp(-(l / (NODE_SIGNIFICANT x L))^NODE_POWER), L the larger of its parent's length and
# the median size l of the parent's nodes: an organ 9 % of L long counts ~1, a spur 3 % long ~0.06; on a stem
# carrying organs longer than itself (a tomato) a spur is measured against those organs, not the stem's length
NODE_SIGNIFICANT = 0.06
NODE_POWER = 4.0
# "nodes": an axis weighs 1 - exp(-(c / (AXIS_CARRIES x its length))^4), c what it carries (a shoot with its leaves,
# not a compound leaf with its leaflets); it sits AXIL_OFFSET x that weight of a node above the other organs of its
# node, and only branches weighing at least AXIS_MIN_WEIGHT (and the main branch) have their children ranked
AXIS_CARRIES = 1.5
AXIL_OFFSET = 0.5
AXIS_MIN_WEIGHT = 0.5


@dataclass(frozen=True, eq=False)
class RankedTree(Trees):
    """A one-tree :class:`Trees` whose children's node ranks are given: ``ranks (N,)`` for ``positions``
    ``ranks_of`` (``"rank"`` or ``"nodes"``), used by :func:`prepare_tree` instead of the ranks of its own branches.

    Why: a union representative (docs/method.md §5) carries the organs of several plants at each node, so ranks
    counted on it shift every organ above an extra one; the ranks its branches had on the plants they came from are
    those a plant registered onto it has on its own tree. A tree derived from it (``resample``, ``to``) is a plain
    :class:`Trees` again.

    Example (a stem with two leaves; the upper one given rank 2, a node being missing on this tree):
        >>> z = torch.linspace(0, 1, 4, dtype=torch.float64)[:, None]
        >>> stem, leaf = torch.cat([0 * z, 0 * z, 9 * z], 1), torch.cat([2 * z, 0 * z, 3 + 0 * z], 1)
        >>> t = Trees.from_branches([[stem, leaf, leaf + torch.tensor([0.0, 0.0, 3.0])]], [[-1, 0, 0]], T=8,
        ...                         dtype=torch.float64)
        >>> ranks = torch.tensor([0.0, 0.0, 2.0], dtype=torch.float64)
        >>> given = RankedTree(t.points, t.parent, t.s, t.num_branches, t.label, ranks, "nodes")
        >>> prepare_tree(t, (1, 1, 1), "nodes").s.round(1).tolist(), prepare_tree(given, (1, 1, 1), "nodes").s.tolist()
        ([0.0, 0.0, 1.0], [0.0, 0.0, 2.0])
    """

    ranks: Tensor
    ranks_of: str

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.num_trees != 1 or tuple(self.ranks.shape) != (self.points.shape[0],):
            raise ValueError(f"a RankedTree is one tree with one rank a branch, got {self.num_trees} tree(s), "
                             f"{self.points.shape[0]} branches and ranks of shape {tuple(self.ranks.shape)}")
        if self.ranks_of not in ("rank", "nodes"):
            raise ValueError(f"ranks_of must be 'rank' or 'nodes', got {self.ranks_of!r}")


@dataclass
class PreparedTree:
    """One tree in the form the solver uses (float64; branch lists per node)."""

    points: Tensor  # (N, T, d), as given (keeps autograd)
    q: Tensor  # (N, M, d) float64, detached
    s: np.ndarray  # (N,) the compared positions (see prepare_tree)
    frac: np.ndarray  # (N,) the tree's own bifurcation parameters (what a layout is decoded with)
    parent: list[int]
    children: list[list[int]]  # sorted by s
    depth: list[int]
    sqrt_len: np.ndarray  # (N,) sqrt(||q||^2)
    norm: np.ndarray  # (N,) recursive subtree squared norms


def arc_fractions(q: Tensor, frac: np.ndarray, parent: Sequence[int]) -> np.ndarray:
    """``(N,)``: each branch's arc length from its parent's base as a fraction of the parent's length, whatever the
    tree's parameterisation (``|q|^2`` is the speed: cumulative segment lengths give the arc length at each
    parameter); ``q (N, T - 1, d)`` the branches' SRVFs, ``frac (N,)`` their places as parameters of the parent
    (a root keeps its own).

    Example (a stem 6 long with a child at height 1.5):
        >>> z = np.linspace(0, 1, 8)[:, None]
        >>> tree = Trees.from_branches([[np.hstack([0 * z, 0 * z, 6 * z]), np.hstack([z, 0 * z, 1.5 + 0 * z])]],
        ...                            [[-1, 0]], T=8)
        >>> prepared = prepare_tree(tree, (1, 1, 1))
        >>> arc_fractions(prepared.q, prepared.frac, prepared.parent).round(3).tolist()
        [0.0, 0.25]
    """
    seg = q.square().sum(-1).numpy() / q.shape[1]
    arc = np.concatenate([np.zeros((len(parent), 1)), np.cumsum(seg, axis=1)], axis=1)
    grid = np.linspace(0.0, 1.0, arc.shape[1])
    out = np.array(frac, dtype=np.float64, copy=True)
    for i, p in enumerate(parent):
        if p >= 0:
            out[i] = np.interp(frac[i], grid, arc[p]) / max(float(arc[p, -1]), MIN_LENGTH)
    return out


def prepare_tree(tree: Trees, lambdas: Lambdas, positions: str = "warped") -> PreparedTree:
    """The solver's form of a single tree (``tree.num_trees == 1``), on the CPU in float64.

    ``positions`` (see :func:`child_positions`): ``"warped"``: ``s`` as given; ``"arclength"``: ``s`` as arc-length
    fractions of the parents (the parameters themselves for uniformly resampled trees); ``"rank"``: the main
    branch's children's ``s`` as node ranks (:func:`_node_ranks`), deeper ones as arc-length fractions;
    ``"nodes"``: the children of the main branch and of every axis as node ranks, axes :data:`AXIL_OFFSET` above
    their node, the others' as arc-length fractions.
    ``lambdas`` weigh the recursive subtree norms (``norm``, the cost of leaving a subtree unmatched).

    Example (a stem with a leaf at 1/3 and a shoot at 2/3 carrying two leaves):
        >>> import numpy as np
        >>> z = np.linspace(0, 1, 4)[:, None]
        >>> stem, leaf = np.hstack([0 * z, 0 * z, 9 * z]), np.hstack([2 * z, 0 * z, 3 + 0 * z])
        >>> shoot = np.hstack([0 * z, 3 * z, 6 + 3 * z])
        >>> kids = [np.hstack([-5 * z, 1 + 0 * z, 7 + 0 * z]), np.hstack([5 * z, 2 + 0 * z, 8 + 0 * z])]
        >>> tree = Trees.from_branches([[stem, leaf, shoot, *kids]], [[-1, 0, 0, 2, 2]], T=8)
        >>> prepare_tree(tree, (1, 1, 1), "nodes").s.round(1).tolist()
        [0.0, 0.0, 1.5, 0.0, 1.0]
    """
    if tree.num_trees != 1:
        raise ValueError(f"expected a single tree, got a batch of {tree.num_trees}")
    # the discrete solve (DP warps, assignments) runs on the CPU; results go back to the input's device
    q = srvf(tree.points.detach().cpu().to(torch.float64))
    parent = tree.parent.tolist()
    frac = tree.s.detach().cpu().to(torch.float64).numpy()
    s = frac.copy()
    children: list[list[int]] = [[] for _ in parent]
    for i, p in enumerate(parent):
        if p >= 0:
            children[p].append(i)
    for ch in children:
        ch.sort(key=lambda c: s[c])
    lengths = srvf_sq_norm(q).numpy()
    if positions != "warped":  # |q|^2 is the speed: cumulative segment lengths give the arc length at each parameter
        s = arc_fractions(q, frac, parent)
        if isinstance(tree, RankedTree) and tree.ranks_of == positions:
            s = tree.ranks.detach().cpu().to(torch.float64).numpy().copy()
        elif positions in ("rank", "nodes", "closest"):
            s = _node_ranks(s, parent, children, lengths, every_branch=positions == "nodes")
    return PreparedTree(tree.points, q, s, frac, parent, children, tree.depth.tolist(), np.sqrt(lengths),
                        np.asarray(subtree_sq_norms(lengths.tolist(), parent, lambdas)))


def _node_ranks(s_arc: np.ndarray, parent: list[int], children: list[list[int]], lengths: np.ndarray,
                every_branch: bool = False) -> np.ndarray:
    """``(N,)`` positions: a branch's children as the weighted count of nodes below them on it (siblings of one node
    share a rank); only the main branch's children unless ``every_branch``, the others keep their arc-length
    fractions ``s_arc (N,)``. With ``every_branch`` the children of every axis too (:func:`_axis_weights` at least
    :data:`AXIS_MIN_WEIGHT`), and an axis sits :data:`AXIL_OFFSET` of a node above the other organs of its node.

    Why: plants of one kind at different stages share their basal nodes (node k of one is node k of the other),
    while the arc length of node k grows with the internodes below it. ``every_branch`` (plants compared with each
    other): the same holds on side shoots of different lengths, and a leaf is not the shoot in its axil, which the
    shape terms alone would pair (in SRVF a longer curve is closer than none). A compound leaf's leaflets keep their
    fractions: paired leaflets a few % apart come in either order and a rachis's spurs are long beside its length.
    Only the main branch between frames of one plant: leaflets and their spurs count differently from day to day
    (docs/experiments.md).
    """
    total = lengths.astype(np.float64).copy()  # subtree total lengths, children after parents in packed order
    for i in range(len(parent) - 1, 0, -1):
        if parent[i] >= 0:
            total[parent[i]] += total[i]
    out = s_arc.copy()
    axis = _axis_weights(total, lengths) if every_branch else np.zeros(len(parent))
    for p in (range(len(parent)) if every_branch else range(min(len(parent), 1))):
        if not children[p] or (parent[p] >= 0 and axis[p] < AXIS_MIN_WEIGHT):
            continue  # a leaf's leaflets keep their arc-length fractions
        kids = np.asarray(children[p])
        groups = [kids[grp] for grp in order_groups(s_arc[kids], RANK_NODE_TOL)]
        share, power = (NODE_SIGNIFICANT, NODE_POWER) if every_branch else (RANK_SIGNIFICANT, 2.0)
        sizes = [float(total[members].max()) for members in groups]  # a node's size: its largest subtree
        ref = max(float(lengths[p]), float(np.median(sizes))) if every_branch else float(lengths[p])
        scale = max(share * ref, MIN_LENGTH)
        below = 0.0
        for members, size in zip(groups, sizes):
            out[members] = below + AXIL_OFFSET * axis[members]
            below += 1.0 - math.exp(-((size / scale) ** power))
    return out


def _axis_weights(total: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """``(N,)`` in ``[0, 1)``: how much each branch is an axis, from what it carries (its subtree's total length
    ``total (N,)`` less its own ``lengths (N,)``) in units of :data:`AXIS_CARRIES` times its own length."""
    carried = (total - lengths) / np.maximum(AXIS_CARRIES * lengths, MIN_LENGTH)
    return 1.0 - np.exp(-(carried ** 4))


def child_positions(mov: PreparedTree, ref: PreparedTree, a: int, b: int, children: Sequence[int],
                    gamma_ab: np.ndarray, grid: np.ndarray, positions: str) -> np.ndarray:
    """``(len(children),)``: where moving branch ``a``'s ``children`` sit on reference branch ``b``, to be compared
    with the reference children's ``s`` (both trees prepared with the same ``positions``, :func:`prepare_tree`).

    ``"warped"``: ``gamma_ab^{-1}(s_c)`` (``gamma_ab (T,)`` the parent's warp sampled on ``grid (T,)``,
    docs/method.md §3); ``"arclength"``: their arc length from the parent's base whatever the warp, in units of the
    reference parent's length (may exceed 1); ``"rank"``, ``"nodes"``: their node ranks as they are.
    """
    if not len(children):
        return np.zeros(0)
    s_c = mov.s[list(children)]
    if positions == "arclength":
        return s_c * mov.sqrt_len[a] ** 2 / max(float(ref.sqrt_len[b]) ** 2, MIN_LENGTH)
    if positions in ("rank", "nodes", "closest"):
        return s_c.copy()
    return np.interp(s_c, gamma_ab, grid)

