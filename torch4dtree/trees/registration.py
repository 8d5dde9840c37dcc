"""Elastic registration of 3D trees (SPEC §3): warps, partial branch correspondences, rotation.

For a moving tree ``Q2`` and a reference ``Q1`` we minimise, over a global rotation ``O``, a warp of
every branch and a partial matching of side subtrees at every node,

    D(a, b) = lm ||q_b - O (q_a o gamma_ab)||^2 + min_matching [ sum_matched lp (s'_c - s_e)^2 + ls D(c, e)
                                                               + sum_unmatched ls ||Q||^2 ],

where ``s'_c = gamma_ab^{-1}(s_c)`` is where child ``c`` sits on the warped parent, ``||Q||^2`` the
recursive norm (the squared distance to the null tree, a null partner sitting at the same ``s``).
As in the paper the warp of a branch is chosen on the branch alone (DP), then the children's
parameters move with it and their matching is one linear assignment on the augmented
``(k1 + k2) x (k1 + k2)`` cost matrix.

Children-aware warps (beyond the paper): the metric charges ``lp (s'_c - s_e)^2`` for every matched
child, which the parent's own DP warp ignores (a nearly straight stem leaves its children wherever the
identity puts them). Where those terms are at least ``LANDMARK_MIN_SHARE`` of a node's cost, the parent
warp is composed with a piecewise-linear warp that carries the matched children onto their partners
(best of a few blends, by the exact node cost) and the children's assignment is re-solved; this never
raises the energy (mean distance 8.80 -> 8.15 on synthetic tomato pairs with lp = 300). With lp = 1 on
plants measured in mm the terms are negligible and nothing changes.

Batching: the candidate pairs are generated top-down, depth by depth (children pairs of every
non-pruned parent pair), and each depth is ONE batched :func:`dp_warp` call over every pair of
every registration in flight (all the trees of :func:`register_to_reference`, all rotation starts).
The assignments are then solved bottom-up from those costs. Pruning is exact: a pair whose lower
bound ``lp ds^2 + ls lm E_branch`` already costs as much as leaving both subtrees unmatched can
never be used by an optimal assignment, so its subtrees are not explored.

The rotation alternates with the recursion (weighted Kabsch / rotation about ``up`` on all matched
branch pairs) until the energy stops decreasing; several starting rotations are tried. The result
is never worse than the index-order solution (children matched by order of ``s``, identity warps
and rotation), which is a valid candidate and is kept when it is better.

Symmetry (default ``symmetric=True``): the solver above is not symmetric (the DP warps the moving branch on the
reference's grid, the position term is measured after the moving tree's warp, children refits and rotation starts
act on the moving tree), so ``A -> B`` and ``B -> A`` used to pick different near-tied leaflets and different warps
of weakly determined branches. Each pair is now solved in one canonical direction (smaller tree onto larger) and
the other direction returns its inverse.
"""

from __future__ import annotations

import hashlib
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np
import torch
from scipy.optimize import linear_sum_assignment
from torch import Tensor

from ..curves.register import DPWarp, dp_warp, register_curves, warp_energies
from ..curves.rotation import axis_rotation, check_rotation_mode, kabsch, vertical_rotation
from ..curves.srvf import srvf, srvf_sq_norm, warp_srvf
from ..curves.warps import invert_warp
from .aligned import AlignedTrees, Lambdas, slot_weights, subtree_sq_norms
from .structures import Trees

__all__ = [
    "DEFAULT_POSITIONS",
    "ORDER_TOL",
    "POSITIONS",
    "TreeRegistration",
    "effective_lambdas",
    "index_order_matches",
    "pairwise_distances",
    "register_to_reference",
    "register_trees",
]


class TreeRegistration(NamedTuple):
    """Result of :func:`register_trees` (moving tree with ``Nm`` branches, ``T`` points per branch).

    * ``distance``: scalar, the registered distance ``||f(moving*) - f(reference)||`` (metric of SPEC §3, with the
      children's positions compared as the registration's ``positions`` says); differentiable in the input points
      given the discrete choices.
    * ``distance_before``: scalar, the index-order distance (children matched by order of ``s``, extra
      ones to null, identity warps and rotation).
    * ``rotation``: ``(d, d)`` acting on row vectors of the moving tree as ``x @ O.T`` (about its root).
    * ``gamma``: ``(Nm, T)`` warp of each moving branch (identity for branches matched to null).
    * ``matches``: ``[(moving branch, reference branch), ...]``, indices within each tree's packed
      branches (depth-first order), the main branches first.
    * ``unmatched_moving`` / ``unmatched_reference``: branches matched to a null branch.
    * ``aligned``: :class:`AlignedTrees` with 2 trees in one layout: ``[registered moving, reference]``
      (reference's slots first, in its packed order, then slots for the moving tree's unmatched branches); its
      ``s`` are bifurcation parameters whatever the ``positions`` compared (with ``"warped"``, ``distance`` is its
      features' distance).
    * ``used_index_order``: the index-order solution was better than the optimised one and was kept.
    """

    distance: Tensor
    distance_before: Tensor
    rotation: Tensor
    gamma: Tensor
    matches: list[tuple[int, int]]
    unmatched_moving: list[int]
    unmatched_reference: list[int]
    aligned: AlignedTrees
    used_index_order: bool


# ----------------------------------------------------------------------------- prepared trees


@dataclass
class _Tree:
    """One tree in the form the solver uses (float64; branch lists per node)."""

    points: Tensor  # (N, T, d), as given (keeps autograd)
    q: Tensor  # (N, M, d) float64, detached
    s: np.ndarray  # (N,) the compared positions (see _prepare)
    frac: np.ndarray  # (N,) the tree's own bifurcation parameters (what a layout is decoded with)
    parent: list[int]
    children: list[list[int]]  # sorted by s
    depth: list[int]
    sqrt_len: np.ndarray  # (N,) sqrt(||q||^2)
    norm: np.ndarray  # (N,) recursive subtree squared norms


def _prepare(tree: Trees, lambdas: Lambdas, positions: str = "warped") -> _Tree:
    """The solver's form of a single tree. ``positions`` (see :func:`_child_positions`): ``"warped"``: ``s`` as given;
    ``"arclength"``: ``s`` as arc-length fractions of the parents (the parameters themselves for uniformly resampled
    trees); ``"rank"``: ``s`` as node ranks along the parents (:func:`_node_ranks`)."""
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
        seg = q.square().sum(-1).numpy() / q.shape[1]
        arc = np.concatenate([np.zeros((len(parent), 1)), np.cumsum(seg, axis=1)], axis=1)
        grid = np.linspace(0.0, 1.0, arc.shape[1])
        for i, p in enumerate(parent):
            if p >= 0:
                s[i] = np.interp(s[i], grid, arc[p]) / max(float(arc[p, -1]), 1e-12)
        if positions == "rank":
            s = _node_ranks(s, parent, children, lengths)
    return _Tree(tree.points, q, s, frac, parent, children, tree.depth.tolist(), np.sqrt(lengths),
                 np.asarray(subtree_sq_norms(lengths.tolist(), parent, lambdas)))


# positions="rank" (the main branch's children): siblings closer than RANK_NODE_TOL (fraction of its length) form one
# node; a node counts 1 - exp(-(l / (RANK_SIGNIFICANT * L_parent))^2) towards the ranks above it, l its largest
# subtree's total length (a skeleton spur a few % of the parent long barely counts, an organ counts 1). A node is
# one unit in the position term: with lp relative, a child one node off costs lp x RELATIVE_LP_SCALE x L.
RANK_NODE_TOL = 0.02
RANK_SIGNIFICANT = 0.1


def _node_ranks(s_arc: np.ndarray, parent: list[int], children: list[list[int]], lengths: np.ndarray) -> np.ndarray:
    """The main branch's children's positions as the weighted count of nodes below them on it (``s_arc``:
    arc-length fractions, kept for deeper children; siblings of one node share a rank). Plants of one kind at
    different stages share their basal nodes (node k of one is node k of the other), while the arc length of node k
    grows with the internodes below it and a fraction of the stem shifts as it elongates. Only the main branch:
    ranks on leaves too (leaflets, their spurs and young tip leaflets count differently from plant to plant)
    left tomato leaflets unmatched: cross-plant recall 93.9 % with ranks at every level, 98.7 % with the main
    branch's alone (precision 96.5 / 95.5; bean 93.5 / 98.8 and 92.9 / 99.8; benchmarks/README.md)."""
    total = lengths.astype(np.float64).copy()  # subtree total lengths, children after parents in packed order
    for i in range(len(parent) - 1, 0, -1):
        if parent[i] >= 0:
            total[parent[i]] += total[i]
    out = s_arc.copy()
    if not children or not children[0]:
        return out
    stem = np.asarray(children[0])  # deeper children keep their arc fractions
    scale = max(RANK_SIGNIFICANT * float(lengths[0]), 1e-12)
    below = 0.0
    for grp in _order_groups(s_arc[stem], RANK_NODE_TOL):
        members = stem[grp]
        out[members] = below
        below += 1.0 - math.exp(-((float(total[members].max()) / scale) ** 2))
    return out


@dataclass
class _Config:
    """A registration candidate: matches (moving -> reference), warps of the moving branches, rotation."""

    energy: float
    match: dict[int, int]
    gamma: np.ndarray  # (Nm, T)
    O: Tensor  # (d, d) float64


# ----------------------------------------------------------------------------- the recursive solver


# points per branch of the curves on which rotation starts are ranked
RANK_T = 24
# a rotation start whose energy is this many times the best start's of the same pair is dropped
STOP_START_RATIO = 1.5
# ... and at most this many starts per pair keep alternating after the first round
KEEP_STARTS = 2

# below this many pairs the serial DP kernel beats the thread-parallel one (measured on 2 busy cores)
SERIAL_DP_BELOW = 256


def _batched_dp(q1: Tensor, q2: Tensor, dp_opts: dict) -> DPWarp:
    """One batched :func:`dp_warp` call, single-threaded for small batches (thread start-up dominates)."""
    if len(q1) >= SERIAL_DP_BELOW:
        return dp_warp(q1, q2, **dp_opts)
    try:
        import numba
    except ImportError:  # pragma: no cover - torch backend
        return dp_warp(q1, q2, **dp_opts)
    before = numba.get_num_threads()
    numba.set_num_threads(1)  # thread-local setting: does not affect other threads
    try:
        return dp_warp(q1, q2, **dp_opts)
    finally:
        numba.set_num_threads(before)


def _rotate(x: Tensor, O: Tensor) -> Tensor:
    """``x @ O.T`` for ``x (..., d)``, elementwise: tiny batched matmuls wake torch's thread pool, which costs
    milliseconds per call on a busy machine."""
    return (x.unsqueeze(-2) * O).sum(-1)


# ----------------------------------------------------------------------------- children's matching

# default tolerance of ordered matching (fraction of the parent): siblings closer than this along their parent are
# one group, matched in any order (opposite leaves, whorls and leaflet pairs share a node: their s are equal)
ORDER_TOL = 0.02


def _assignment(cost: np.ndarray, null_mov: np.ndarray, null_ref: np.ndarray) -> tuple[float, list[tuple[int, int]]]:
    """Any partial matching: one linear assignment on the augmented ``(k1 + k2) x (k2 + k1)`` matrix (SPEC §3).

    ``cost (k1, k2)``: cost of matching moving child ``i`` to reference child ``j`` (``inf``: excluded);
    ``null_mov (k1,)`` / ``null_ref (k2,)``: cost of leaving each unmatched. Returns ``(total, [(i, j), ...])``.
    """
    k1, k2 = cost.shape
    C = np.full((k1 + k2, k2 + k1), np.inf)
    C[:k1, :k2] = cost
    np.fill_diagonal(C[:k1, k2:], null_mov)  # (a view: written through)
    np.fill_diagonal(C[k1:, :k2], null_ref)
    C[k1:, k2:] = 0.0
    rows, cols = linear_sum_assignment(C)
    real = (rows < k1) & (cols < k2)
    return float(C[rows, cols].sum()), list(zip(rows[real].tolist(), cols[real].tolist()))


def _order_groups(s: np.ndarray, tol: float) -> list[list[int]]:
    """Indices sorted by ``s``, cut into groups wherever consecutive values differ by more than ``tol``."""
    groups: list[list[int]] = []
    order = np.argsort(s, kind="stable").tolist()
    for prev, i in zip([None] + order[:-1], order):
        if prev is None or s[i] - s[prev] > tol:
            groups.append([i])
        else:
            groups[-1].append(i)
    return groups


def _never_crosses(pairs: list[tuple[int, int]], G1: list[list[int]], G2: list[list[int]]) -> bool:
    """Whether no two pairs of a matching sit in opposite group orders on the two sides (siblings within one group
    may cross): the order-preservation :func:`_ordered_assignment` stands for."""
    group1 = {i: g for g, grp in enumerate(G1) for i in grp}
    group2 = {j: g for g, grp in enumerate(G2) for j in grp}
    links = sorted((group1[i], group2[j]) for i, j in pairs)
    return all(a2 <= b2 for (_, a2), (_, b2) in zip(links, links[1:]))


def _ordered_assignment(cost: np.ndarray, null_mov: np.ndarray, null_ref: np.ndarray, s_mov: np.ndarray,
                        s_ref: np.ndarray, tol: float) -> tuple[float, list[tuple[int, int]]]:
    """The cheapest partial matching that keeps the order of the children along their parents.

    Each side's children are grouped by position (:func:`_order_groups`, ``s_mov (k1,)`` after the parent's warp,
    ``s_ref (k2,)``). The matching is a sequence of blocks in order along both parents: one group of one side
    against a run of consecutive groups of the other (any partial matching inside a block, :func:`_assignment`,
    so siblings at one node may swap, and two siblings sharing a node may part into two nodes of the next
    frame); groups outside the blocks are unmatched. Exact over that family by an edit-distance DP over the two
    group lists (``O(g1 g2)`` cells; runs only start from groups of two or more). With singleton groups this is
    the plain order-preserving alignment. It never crosses two pairs whose groups differ on both sides; it
    misses only staircases (two adjacent multi-member groups each shared by two blocks), unless the unconstrained
    assignment, tried first, is one (any assignment that crosses no groups is returned as it is). Costs as
    :func:`_assignment`. Why: organs along a parent never pass each other as a plant grows, while the assignment
    lets a long leaf match a similar one two nodes away and a tiny one take its place.
    """
    G1, G2 = _order_groups(s_mov, tol), _order_groups(s_ref, tol)
    m1, m2 = len(G1), len(G2)
    # the unconstrained optimum is a lower bound; where it never crosses it is the answer (the usual case between
    # consecutive frames, and inside the children refits that call this many times), staircases included
    free_cost, free_pairs = _assignment(cost, null_mov, null_ref)
    if _never_crosses(free_pairs, G1, G2):
        return free_cost, free_pairs
    pair = np.minimum(cost, null_mov[:, None] + null_ref[None, :])  # one child each: matched or both null

    def block(x0: int, x1: int, y0: int, y1: int) -> tuple[float, list[tuple[int, int]]]:
        g = [i for grp in G1[x0:x1] for i in grp]
        h = [j for grp in G2[y0:y1] for j in grp]
        if len(g) == 1 and len(h) == 1:
            i, j = g[0], h[0]
            return float(pair[i, j]), [(i, j)] if cost[i, j] < null_mov[i] + null_ref[j] else []
        c, p = _assignment(cost[np.ix_(g, h)], null_mov[g], null_ref[h])
        return c, [(g[i], h[j]) for i, j in p]

    skip1 = [float(null_mov[g].sum()) for g in G1]
    skip2 = [float(null_ref[h].sum()) for h in G2]
    D = np.zeros((m1 + 1, m2 + 1))
    D[1:, 0] = np.cumsum(skip1)
    D[0, 1:] = np.cumsum(skip2)
    # back pointer: (groups of moving, groups of reference) consumed by the last step; (n, 0) / (0, n): skips
    back: dict[tuple[int, int], tuple[int, int]] = {(x, 0): (1, 0) for x in range(1, m1 + 1)}
    back.update({(0, y): (0, 1) for y in range(1, m2 + 1)})
    for x in range(1, m1 + 1):
        for y in range(1, m2 + 1):
            best, how = D[x - 1, y] + skip1[x - 1], (1, 0)
            if D[x, y - 1] + skip2[y - 1] < best:
                best, how = D[x, y - 1] + skip2[y - 1], (0, 1)
            runs = [(1, 1)]  # moving group x - 1 against ref groups y - r .. y - 1, or the converse
            if len(G1[x - 1]) > 1:
                runs += [(1, r) for r in range(2, y + 1)]
            if len(G2[y - 1]) > 1:
                runs += [(r, 1) for r in range(2, x + 1)]
            for r1, r2 in runs:
                c = D[x - r1, y - r2] + block(x - r1, x, y - r2, y)[0]
                if c < best:
                    best, how = c, (r1, r2)
            D[x, y], back[(x, y)] = best, how
    pairs: list[tuple[int, int]] = []
    x, y = m1, m2
    while x > 0 or y > 0:
        r1, r2 = back[(x, y)]
        if r1 and r2:
            pairs += block(x - r1, x, y - r2, y)[1]
        x, y = x - r1, y - r2
    return float(D[m1, m2]), sorted(pairs)


def _match_children(cost: np.ndarray, null_mov: np.ndarray, null_ref: np.ndarray, s_mov: np.ndarray,
                    s_ref: np.ndarray, order_tol: float | None) -> tuple[float, list[tuple[int, int]]]:
    """Children's matching of one parent pair: any (``order_tol=None``) or order-preserving (see
    :func:`_ordered_assignment`). Returns ``(total cost, [(moving i, reference j), ...])``."""
    if order_tol is None:
        return _assignment(cost, null_mov, null_ref)
    return _ordered_assignment(cost, null_mov, null_ref, s_mov, s_ref, order_tol)


# blends tried between a parent's own warp and the warp that puts its matched children exactly on theirs
LANDMARK_STEPS = (0.25, 0.5, 0.75, 1.0)
# rounds of (refit the parent warp to the matched children, re-solve their assignment)
LANDMARK_ROUNDS = 3
# ... tried only where the children's parameter terms are at least this share of the node's cost
LANDMARK_MIN_SHARE = 0.01


POSITIONS = ("warped", "arclength", "rank")
# register_trees' default: children compared by node rank along the main branch (deeper ones by arc fraction).
# Measured at the library's lp = 1 (relative), any-order matching, realistic synthetic plants (consecutive frames
# of 6 plants per kind, 9 pairs each; cross-plant frames 3 / 6 / 9, 45 pairs; precision %,
# benchmarks/README.md "Library default positions"): warped -> rank, consecutive tomato 99.2 -> 99.7,
# maize 94.7 -> 100, bean 99.7 -> 100; across plants 89.5 -> 92.0, 87.2 -> 98.4, 59.2 -> 80.9. The cost, on the
# paper's .mat trees (64 consecutive pairs, T = 256): length on null-matched branches 2.70 -> 2.90 % (tomato),
# 0.04 -> 0.05 % (maize), mapped cycle consistency 0 % either way. Layout-averaging callers (the Karcher mean,
# the joint hierarchy, the tree space) keep "warped": their registrations must minimise the layout's own metric.
DEFAULT_POSITIONS = "rank"


def _child_positions(mov: _Tree, ref: _Tree, a: int, b: int, children: Sequence[int], gamma_ab: np.ndarray,
                     grid: np.ndarray, positions: str) -> np.ndarray:
    """Where moving branch ``a``'s ``children`` sit on reference branch ``b``, to be compared with the reference
    children's ``s`` (both trees prepared with the same ``positions``, :func:`_prepare`): ``gamma_ab^{-1}(s_c)``
    (``"warped"``, SPEC §3); with ``"arclength"`` their arc length from the parent's base whatever the warp, in units
    of the reference parent's length (may exceed 1); with ``"rank"`` their node ranks as they are."""
    if not len(children):
        return np.zeros(0)
    s_c = mov.s[list(children)]
    if positions == "arclength":
        return s_c * mov.sqrt_len[a] ** 2 / max(float(ref.sqrt_len[b]) ** 2, 1e-12)
    if positions == "rank":
        return s_c.copy()
    return np.interp(s_c, gamma_ab, grid)


def _landmark_warp(s_ref: np.ndarray, s_now: np.ndarray, grid: np.ndarray) -> np.ndarray | None:
    """``phi (T,)``: the piecewise-linear warp with ``phi(s_ref[i]) = s_now[i]`` (increasing subset), or None."""
    xs, ys = [0.0], [0.0]
    for x, y in sorted(zip(s_ref.tolist(), s_now.tolist())):
        if xs[-1] + 1e-9 < x < 1.0 - 1e-9 and ys[-1] + 1e-9 < y < 1.0 - 1e-9:
            xs.append(x)
            ys.append(y)
    if len(xs) == 1:
        return None
    return np.interp(grid, xs + [1.0], ys + [1.0])


def _refit_to_children(ref_q: Tensor, mov_q: Tensor, gamma: np.ndarray, s_mov: np.ndarray, s_ref: np.ndarray,
                       sub: np.ndarray, null_mov: np.ndarray, null_ref: np.ndarray, pairs: list[tuple[int, int]],
                       total: float, lm: float, lp: float, order_tol: float | None
                       ) -> tuple[float, list[tuple[int, int]], float, np.ndarray, np.ndarray]:
    """Children-aware warp of one parent pair: the metric charges ``lp (gamma^{-1}(s_c) - s_e)^2`` for every
    matched child, but the DP warp is chosen on the parent curves alone (as in the paper), which leaves the
    children where a nearly straight stem happens to put them. Compose the warp with a piecewise-linear
    ``phi`` that carries each matched child onto its partner (``gamma o ((1 - a) id + a phi)``), keep the best
    blend ``a`` by the exact node cost (parent energy + the re-solved matching) and repeat with the new
    matching. Never increases the node cost. ``sub (k1, k2)`` is the subtree part of the children's matching
    costs (``ls D``, ``inf`` where excluded), ``null_mov`` / ``null_ref`` their unmatched costs
    (:func:`_match_children`); ``total`` and ``pairs`` the node cost and matching under ``gamma``.

    Returns ``(total, pairs, parent energy, gamma, children's s')``.
    """
    T = gamma.shape[0]
    grid = np.linspace(0.0, 1.0, T)
    sc = np.interp(s_mov, gamma, grid)

    def matching(s_now: np.ndarray) -> tuple[float, list[tuple[int, int]]]:
        cost = sub + lp * (s_now[:, None] - s_ref[None, :]) ** 2
        return _match_children(cost, null_mov, null_ref, s_now, s_ref, order_tol)

    E0 = float(warp_energies(ref_q, mov_q, gamma[None])[0])
    c0, _ = matching(sc)
    best = (lm * E0 + c0, pairs, E0, gamma, sc)  # the same node cost, recomputed here
    for _ in range(LANDMARK_ROUNDS):
        _, pairs_now, _, gam_now, sc_now = best
        phi = _landmark_warp(s_ref[[j for _, j in pairs_now]], sc_now[[i for i, _ in pairs_now]], grid)
        if phi is None:
            break
        cands = np.stack([np.interp((1 - a) * grid + a * phi, grid, gam_now) for a in LANDMARK_STEPS])
        E = warp_energies(ref_q, mov_q, cands)
        improved = False
        for g, e in zip(cands, E.tolist()):
            s_new = np.interp(s_mov, g, grid)
            c, p = matching(s_new)
            t = lm * e + c
            if t < best[0] - 1e-12 * max(1.0, abs(best[0])):
                best = (t, p, e, g, s_new)
                improved = True
        if not improved:
            break
    if best[3] is gamma:
        return total, pairs, (total - c0) / lm, gamma, sc  # unchanged
    return best


def _solve(movs: Sequence[_Tree], refs: Sequence[_Tree], jobs: Sequence[tuple[int, int, Tensor]],
           lambdas: Sequence[Lambdas], dp_opts: dict, prune: bool, max_depth: int | None = None,
           landmarks: bool = True, positions: str = "warped", order_tol: float | None = None) -> list[_Config]:
    """Warps + assignments for fixed rotations. ``jobs[k] = (moving index, reference index, O (d, d))``;
    ``lambdas[m]`` are the weights of moving tree ``m`` (with ``lp_relative`` each pair has its own ``lp``; the
    DP warps do not depend on the weights, so pairs of different weights still share the batched DP calls).

    ``max_depth`` stops exploring pairs below that layer (their subtrees then count as unmatched): a cheap,
    approximate solve used to rank starting rotations. ``landmarks`` refits each parent's warp to its
    matched children (:func:`_refit_to_children`; only with ``"warped"`` positions: otherwise a warp does not move
    children). ``positions``: how children's places are compared (:func:`_child_positions`). ``order_tol``: children's
    matching, see :func:`_match_children`.
    """
    landmarks = landmarks and positions == "warped"
    T = movs[0].q.shape[1] + 1
    grid = np.linspace(0.0, 1.0, T)
    qrot = [_rotate(movs[m].q, O) for m, _, O in jobs]
    # top-down: candidate pairs per depth, one batched DP per depth
    level: list[tuple[int, int, int, float]] = [(k, 0, 0, 0.0) for k in range(len(jobs))]
    levels: list[list[tuple[int, int, int, float]]] = []
    info: dict[tuple[int, int, int], tuple[float, np.ndarray, np.ndarray]] = {}  # -> (E, gamma, children's s')
    depth = 0
    while level:
        levels.append(level)
        q1 = torch.stack([refs[jobs[k][1]].q[b] for k, _, b, _ in level])
        q2 = torch.stack([qrot[k][a] for k, a, _, _ in level])
        res = _batched_dp(q1, q2, dp_opts)
        gam, E = res.gamma.numpy(), res.energy.numpy()
        nxt: list[tuple[int, int, int, float]] = []
        for p, (k, a, b, sa) in enumerate(level):
            mov, ref = movs[jobs[k][0]], refs[jobs[k][1]]
            lm, ls, lp = lambdas[jobs[k][0]]
            if depth > 0 and prune and lp * (sa - ref.s[b]) ** 2 + ls * lm * E[p] >= ls * (mov.norm[a] + ref.norm[b]):
                continue  # never better than leaving both unmatched: do not explore
            ca, cb = mov.children[a], ref.children[b]
            sc = _child_positions(mov, ref, a, b, ca, gam[p], grid, positions)
            info[(k, a, b)] = (float(E[p]), gam[p], sc)
            if max_depth is not None and depth >= max_depth:
                continue
            for c, s_c in zip(ca, sc):
                for e in cb:
                    if prune:
                        lb = lp * (s_c - ref.s[e]) ** 2 + ls * lm * (mov.sqrt_len[c] - ref.sqrt_len[e]) ** 2
                        if lb >= ls * (mov.norm[c] + ref.norm[e]):
                            continue
                    nxt.append((k, c, e, float(s_c)))
        level = nxt
        depth += 1
    # bottom-up: assignments from the children's costs
    D: dict[tuple[int, int, int], float] = {}
    assign: dict[tuple[int, int, int], list[tuple[int, int]]] = {}
    for lev in reversed(levels):
        for k, a, b, _ in lev:
            key = (k, a, b)
            if key not in info:
                continue
            E, _, sc = info[key]
            mov, ref = movs[jobs[k][0]], refs[jobs[k][1]]
            lm, ls, lp = lambdas[jobs[k][0]]
            ca, cb = mov.children[a], ref.children[b]
            total = lm * E
            if not ca or not cb:
                total += ls * (sum(mov.norm[c] for c in ca) + sum(ref.norm[e] for e in cb))
                assign[key] = []
            else:
                # the children's matching costs: subtree part (inf where pruned) + position part
                sub = np.full((len(ca), len(cb)), np.inf)
                for i, c in enumerate(ca):
                    for j, e in enumerate(cb):
                        d_ce = D.get((k, c, e))
                        if d_ce is not None:
                            sub[i, j] = ls * d_ce
                null_mov, null_ref = ls * mov.norm[ca], ls * ref.norm[cb]
                s_ref = ref.s[cb]
                cost, pairs = _match_children(sub + lp * (sc[:, None] - s_ref[None, :]) ** 2, null_mov, null_ref,
                                              sc, s_ref, order_tol)
                total += cost
                s_cost = lp * sum((sc[i] - s_ref[j]) ** 2 for i, j in pairs)  # the most a refit can save
                if landmarks and pairs and s_cost > LANDMARK_MIN_SHARE * total:
                    ref_q, mov_q = ref.q[b], qrot[k][a]
                    total, pairs, E, gam_ab, sc = _refit_to_children(
                        ref_q, mov_q, info[key][1], mov.s[ca], s_ref, sub, null_mov, null_ref, pairs, total, lm,
                        lp, order_tol)
                    info[key] = (E, gam_ab, sc)
                assign[key] = [(ca[i], cb[j]) for i, j in pairs]
            D[key] = total
    out = []
    for k, (m, _, O) in enumerate(jobs):
        gamma = np.tile(grid, (len(movs[m].parent), 1))
        match: dict[int, int] = {}
        stack = [(0, 0)]
        while stack:
            a, b = stack.pop()
            match[a] = b
            gamma[a] = info[(k, a, b)][1]
            stack.extend(assign[(k, a, b)])
        out.append(_Config(D[(k, 0, 0)], match, gamma, O))
    return out


def _rotation_update(mov: _Tree, ref: _Tree, cfg: _Config, lambdas: Lambdas, rotation: str, up: Tensor
                     ) -> tuple[Tensor, float]:
    """Best rotation for fixed matches and warps (weighted over all matched branches) and the new energy."""
    a_idx = list(cfg.match.keys())
    b_idx = [cfg.match[a] for a in a_idx]
    w = slot_weights(torch.tensor([mov.depth[a] for a in a_idx]), lambdas)[0]
    qw = warp_srvf(mov.q[a_idx], torch.from_numpy(cfg.gamma[a_idx]))
    qr = ref.q[b_idx]
    M = qr.shape[1]
    A = (w[:, None, None, None] * qr.unsqueeze(-1) * qw.unsqueeze(-2)).sum((0, 1)) / M  # elementwise: see _rotate
    O = kabsch(A[None])[0] if rotation == "so3" else vertical_rotation(A[None], up)[0]

    def matched_energy(R: Tensor) -> float:
        return float((w * srvf_sq_norm(qr - _rotate(qw, R))).sum())

    return O, cfg.energy - matched_energy(cfg.O) + matched_energy(O)


def _initial_rotations(mov: _Tree, ref: _Tree, rotation: str, up: Tensor, n_starts: int,
                       dp_opts: dict) -> list[Tensor]:
    """Starting rotations: identity, then the main branches' registration spun about an axis."""
    d = mov.q.shape[-1]
    eye = torch.eye(d, dtype=torch.float64)
    if rotation == "none":
        return [eye]
    opts = {k: v for k, v in dp_opts.items() if k in ("neighbourhood", "band", "coarse", "refine")}
    reg = register_curves(mov.q[0], ref.q[0], rotation=rotation, srvf_input=True, up=up, **opts)
    starts = [eye, reg.rotation.to(torch.float64)]
    if d == 3 and n_starts > 1:
        if rotation == "vertical":
            axis = up
        else:  # spin about the reference main branch's chord, the direction least fixed by it
            chord = (ref.q[0] * ref.q[0].norm(dim=-1, keepdim=True)).sum(0)
            axis = chord if bool(chord.norm() > 0) else up
        angles = torch.arange(1, n_starts, dtype=torch.float64) * (2 * math.pi / n_starts)
        spins = axis_rotation(axis.to(torch.float64), angles)
        starts += [R @ starts[1] for R in spins]
    return starts


def _rank_starts(movs: Sequence[_Tree], refs: Sequence[_Tree], jobs: list[tuple[int, int, Tensor]],
                 lambdas: Sequence[Lambdas], dp_opts: dict, prune: bool, rotation: str, up: Tensor,
                 positions: str = "warped", order_tol: float | None = None) -> list[tuple[int, int, Tensor]]:
    """The ``KEEP_STARTS`` best starting rotations of each pair, ranked on the top two layers only
    (one rotation update each): the full recursion then runs for those alone."""
    configs = _solve(movs, refs, jobs, lambdas, dp_opts, prune, max_depth=1, positions=positions,
                     order_tol=order_tol)
    scored = []
    for (m, r, _), cfg in zip(jobs, configs):
        O_new, e_new = _rotation_update(movs[m], refs[r], cfg, lambdas[m], rotation, up)
        scored.append((min(e_new, cfg.energy), m, r, O_new if e_new < cfg.energy else cfg.O))
    kept: dict[int, int] = {}
    out = []
    for _, m, r, O in sorted(scored, key=lambda x: x[0]):
        if kept.get(m, 0) < KEEP_STARTS:
            kept[m] = kept.get(m, 0) + 1
            out.append((m, r, O))
    return out


# Tried and removed (commit bf60447): solving an inverted registration's warps again in the requested direction for
# the same matches brings that direction's distance back to a one-way solve's (Pheno4D .mat T = 64, day k + 1 onto
# k: 13.089 one-way, 13.090 rewarped, 13.181 inverted), but the warps are then no longer inverse to each other and
# .mat cycle consistency at T = 256 is 0.27 / 0.40 / 0.85 / 2.76 % (mapped) instead of 0.00 %.


def _size_key(tree: _Tree) -> tuple[float, int, bytes]:
    """Orders trees independently of argument order: total length, branch count, then the SRVFs' bytes."""
    return float((tree.sqrt_len ** 2).sum()), len(tree.parent), hashlib.sha1(tree.q.numpy().tobytes()).digest()


def _solve_reversed(mov: _Tree, ref: _Tree) -> bool:
    """Whether a symmetric registration of ``mov`` onto ``ref`` solves ``ref`` onto ``mov`` and inverts it: the
    smaller tree (by :func:`_size_key`) is always the one registered onto the larger. The inverted direction's
    distance is above a one-way solve of it (the DP warps and the position term ``lp (gamma^{-1}(s_c) - s_e)^2``
    are not symmetric): Pheno4D consecutive days at T = 64, day k + 1 onto k, mean 13.089 -> 13.181 (.mat),
    16.231 -> 16.287 (SWC). Larger onto smaller keeps that direction and costs the same in the other (13.132 ->
    13.219), but lost identities where smaller onto larger (the direction frames are chained in) keeps them:
    realistic synthetic maize, seeds 3-7, lp 9, consecutive precision 97.6 -> 96.6 %, tomato seeds 0-2 99.8 ->
    99.6 % (unchanged with smaller onto larger)."""
    lm, lr = float((mov.sqrt_len ** 2).sum()), float((ref.sqrt_len ** 2).sum())
    if lm != lr:  # the hash is only needed for exact ties
        return lm > lr
    return _size_key(mov) >= _size_key(ref)


def _inverse_config(cfg: _Config, n_moving: int) -> _Config:
    """The registration of the other tree from ``cfg`` (reference onto moving): matches transposed, every matched
    warp inverted, branches matched to null keep the identity, rotation transposed."""
    T = cfg.gamma.shape[1]
    gamma = np.tile(np.linspace(0.0, 1.0, T), (n_moving, 1))
    match = {a: b for b, a in cfg.match.items()}
    if match:
        src, dst = list(match.values()), list(match.keys())
        gamma[dst] = invert_warp(torch.from_numpy(cfg.gamma[src])).numpy()
    return _Config(cfg.energy, match, gamma, cfg.O.T.contiguous())


def _index_order_match(mov: _Tree, ref: _Tree) -> dict[int, int]:
    match: dict[int, int] = {}
    stack = [(0, 0)]
    while stack:
        a, b = stack.pop()
        match[a] = b
        stack.extend(zip(mov.children[a], ref.children[b]))
    return match


def index_order_matches(moving: Trees, reference: Trees) -> list[tuple[int, int]]:
    """The index-order correspondence: children matched by order of ``s`` at every node, extras to null."""
    lam = (1.0, 1.0, 1.0)
    m = _index_order_match(_prepare(moving, lam), _prepare(reference, lam))
    return sorted(m.items())


def _build_aligned(mov: _Tree, ref: _Tree, match: dict[int, int], gamma: np.ndarray, O: Tensor,
                   lambdas: Lambdas, positions: str = "warped") -> tuple[AlignedTrees, Tensor]:
    """Write the registered moving tree and the reference in one layout (differentiable in the points).

    Returns the layout and the ``(2, S)`` positions the registration compared. The layout's ``s`` are always
    bifurcation parameters on the parents (a moving child at ``gamma^{-1}(s)`` of its matched parent's warp), so
    it decodes to the trees and its geodesic to trees in between. With ``"arclength"`` / ``"rank"`` positions the
    compared ones differ (arc lengths on the reference parent's scale, node ranks: :func:`_child_positions`): the
    registered distance is the layout's with them in place of ``s`` (:func:`_pair_distance`); with ``"warped"``
    they are the layout's ``s``."""
    Nm, Nr = len(mov.parent), len(ref.parent)
    dtype = torch.float64
    pts_m = mov.points.to(dtype)
    dev = pts_m.device
    pts_r = ref.points.to(device=dev, dtype=dtype)
    T = pts_r.shape[1]
    grid = np.linspace(0.0, 1.0, T)
    slot_of = [-1] * Nm
    slot_parent = list(ref.parent)
    slot_depth = list(ref.depth)
    for a in range(Nm):  # parents before children, so a parent's slot exists
        if a in match:
            slot_of[a] = match[a]
        else:
            slot_of[a] = len(slot_parent)
            ps = slot_of[mov.parent[a]]
            slot_parent.append(ps)
            slot_depth.append(slot_depth[ps] + 1)
    S = len(slot_parent)
    g = torch.from_numpy(gamma).to(device=dev, dtype=dtype)
    qm = _rotate(warp_srvf(srvf(pts_m), g), O.to(device=dev, dtype=dtype))
    qr = srvf(pts_r)
    M, d = qr.shape[1:]
    # a child's parameter moves with its parent's warp (identity for unmatched parents: a null partner at the same s)
    s_m, cmp_m = np.zeros(Nm), np.zeros(Nm)
    for a in range(1, Nm):
        p = mov.parent[a]
        if p not in match:
            s_m[a], cmp_m[a] = mov.frac[a], mov.s[a]
        else:
            s_m[a] = np.interp(mov.frac[a], gamma[p], grid)
            cmp_m[a] = _child_positions(mov, ref, p, match[p], [a], gamma[p], grid, positions)[0]
    q = torch.zeros(2, S, M, d, dtype=dtype, device=dev)
    present = torch.zeros(2, S, dtype=torch.bool, device=dev)
    source = torch.full((2, S), -1, dtype=torch.long, device=dev)
    idx_m = torch.tensor(slot_of, dtype=torch.long, device=dev)
    ar_m, ar_r = torch.arange(Nm, device=dev), torch.arange(Nr, device=dev)
    q = q.index_put((torch.zeros(Nm, dtype=torch.long, device=dev), idx_m), qm)
    q = q.index_put((torch.ones(Nr, dtype=torch.long, device=dev), ar_r), qr)

    def slot_positions(s_ref: np.ndarray, s_mov: np.ndarray) -> Tensor:
        out = torch.zeros(2, S, dtype=dtype, device=dev)
        out[1, :Nr] = torch.from_numpy(s_ref).to(dev)
        out[0, :Nr] = out[1, :Nr]  # null partners sit at the same s
        out[0, idx_m] = torch.from_numpy(s_mov).to(dev)
        out[1, Nr:] = out[0, Nr:]
        return out

    s = slot_positions(ref.frac, s_m)
    compared = s if positions == "warped" else slot_positions(ref.s, cmp_m)
    present[0, idx_m] = True
    present[1, :Nr] = True
    source[0, idx_m] = ar_m
    source[1, :Nr] = ar_r
    root = torch.stack([pts_m[0, 0], pts_r[0, 0]])
    aligned = AlignedTrees(q, s, present, root, torch.tensor(slot_parent, device=dev),
                           torch.tensor(slot_depth, device=dev), source, tuple(float(x) for x in lambdas))
    return aligned, compared


def _pair_distance(aligned: AlignedTrees, positions: Tensor | None = None) -> Tensor:
    """The layout's distance between its two trees, with ``positions (2, S)`` in place of its ``s`` if given."""
    f = (aligned if positions is None else replace(aligned, s=positions)).features()
    e = (f[0] - f[1]).square().sum()
    return torch.where(e > 0, e.clamp_min(1e-300).sqrt(), torch.zeros_like(e))


# ----------------------------------------------------------------------------- public API


def _check_lambdas(lambdas: Sequence[float]) -> Lambdas:
    lam = tuple(float(x) for x in lambdas)
    if len(lam) != 3 or any(not math.isfinite(x) or x < 0 for x in lam) or lam[0] <= 0 or lam[1] <= 0:
        raise ValueError(f"lambdas must be (lm > 0, ls > 0, lp >= 0) in the SPEC's order, got {tuple(lambdas)}")
    return lam  # type: ignore[return-value]


# with lp_relative, lp = 1 weighs bifurcation positions like RELATIVE_LP_SCALE x the reference's main-branch
# length. A trade-off, measured (T = 32 / 128): consecutive-frame identity precision on realistic synthetic maize
# 90 % / 94 % / 97 % at 0.1 / 0.3 / 1 x L (tomato and bean 98 % at all three), while cycle consistency on the
# paper's .mat trees (24 pairs, T = 128, eps 0.1 / 0.05 / 0.02 / 0.01) was 0 / 0 / 0.7 / 2.2 % (as with the old
# absolute lp = 1), 0 / 0.1 / 1.2 / 3.2 % and 3.3 / 3.9 / 5.4 / 7.6 %: position terms pull matches away from what
# a stem's weakly determined warp implies, and the reverse registration does not undo them. The library default
# keeps cycle consistency; within-sequence registration, where identities are chained, uses lp = 9 (0.9 x L).
# With L the reference's length alone (before issue 11's fix) the two directions used different lp; the pair's
# geometric mean makes them one metric (see effective_lambdas). What remains at T = 256 (0.62 % vs 0.32 % with the
# absolute lp = 1) is a few near-tied leaflet assignments on growing tomato leaves (costs within 0.1-0.4 of ~115)
# that the position term, measured after a weakly determined parent warp, tips differently each way.
RELATIVE_LP_SCALE = 0.1


def effective_lambdas(lambdas: Sequence[float], reference: Trees, moving: Trees | None = None) -> Lambdas:
    """``(lm, ls, lp * RELATIVE_LP_SCALE * L)``: the weights a registration of ``moving`` onto ``reference`` uses
    with ``lp_relative``. ``L = sqrt(L_moving * L_reference)``, the geometric mean of the two main-branch lengths:
    symmetric in the pair, so ``A -> B`` and ``B -> A`` minimise the same metric (with ``L_reference`` alone, a
    plant whose stem doubled in a day was registered with twice the ``lp`` one way as the other, and near-tied
    assignments of leaflets resolved differently in the two directions). Measured on the .mat trees (64 pairs,
    mapped points, eps 0.1): 0.81 -> 0.62 % at T = 256, 0.75 -> 0.56 % at 128, 0.69 -> 0.58 % at 64; the longer
    main branch instead of the geometric mean gave 0.54 / 0.87 / 0.69 %. Identity precision / recall on the
    realistic synthetic plants is unchanged (bench.hierarchy.identity_accuracy, seeds 0-2, lp 1 and 9). Without
    ``moving``: ``L_reference``."""
    lm, ls, lp = _check_lambdas(lambdas)
    length = float(reference.branch_lengths()[0].detach())
    if moving is not None:
        length = math.sqrt(length * float(moving.branch_lengths()[0].detach()))
    return lm, ls, lp * RELATIVE_LP_SCALE * length


def register_to_reference(trees: Trees, reference: Trees, lambdas: Sequence[float] = (1.0, 1.0, 1.0),
                          rotation: str = "none", up: Sequence[float] | Tensor | None = None, n_starts: int = 12,
                          max_iters: int = 10, tol: float = 1e-3, neighbourhood: int = 4, band: int | None = None,
                          coarse: int | None = 32, refine: int = 0, prune: bool = True,
                          lp_relative: bool = True, positions: str = DEFAULT_POSITIONS, order_tol: float | None = None,
                          symmetric: bool = True) -> list[TreeRegistration]:
    """Register every tree of ``trees`` (moving) onto the single tree ``reference``, all at once.

    Args:
        trees: ``n`` moving trees (any numbers of branches); resampled to ``reference.T`` if needed.
        reference: one tree.
        lambdas: ``(lm, ls, lp)`` weights of the main-branch SRVF, the subtrees and the bifurcation parameters
            (the SPEC's order).
        rotation: ``"none"``, ``"vertical"`` (about ``up``, default z) or ``"so3"``.
        n_starts: starting rotations spun about the vertical (or the reference main branch) axis, besides
            the identity; they are ranked on the top two layers and the best ``KEEP_STARTS`` run in full.
            12 (30 degrees apart): with 4, tomato plants with spiral leaves got stuck in a wrong local
            minimum (cross-plant branch accuracy at the last synthetic frame 83% -> 96% with 12).
        max_iters, tol: rounds of (warps + assignments, rotation); stop when the energy decreases by
            less than ``tol`` relatively (1e-3: on Pheno4D tomato with a vertical rotation, 1e-4 took 50%
            longer for distances at most 4e-5 relatively lower).
        neighbourhood, band, coarse, refine: DP settings, see :func:`torch4dtree.curves.dp_warp`. The
            default (full lattice, slopes up to 4) was the fastest at T = 64 on Pheno4D and gave the most
            cycle-consistent correspondences; use ``neighbourhood=6`` for strongly non-uniform warps.
            ``refine > 0`` lowers each energy but made cycle consistency worse at every eps on Pheno4D
            (``.mat`` trees, T = 256: 0.27 -> 0.59 % at eps 0.1 with ``refine=4``), so it is off.
        prune: skip subtree pairs that provably cannot be matched (exact: does not change the result).
        lp_relative: the bifurcation weight scales with the trees: the effective ``lp`` is ``lambdas[2]`` times
            ``RELATIVE_LP_SCALE`` (0.1) times ``L``, the geometric mean of the moving and the reference main-branch
            lengths (:func:`effective_lambdas`: one ``lp`` per pair, the same both ways; default). The shape terms
            are lengths (``||q||^2`` = length, in the data's units) while ``s`` is a fraction, so a fixed ``lp``
            means nothing for plants in mm (absolute lp = 1 let similar maize leaves two nodes apart swap: 83 %
            identity precision between consecutive synthetic frames, 97 % with ``lp = 9`` relative; the scale
            trades identities against cycle consistency, see ``RELATIVE_LP_SCALE``). ``False`` uses ``lambdas[2]`` as it
            is. The effective weights (per moving tree) are in the results' ``aligned.lambdas``.
        positions: how a matched child's place on its parent is compared in the position term.
            ``"rank"`` (default, :data:`DEFAULT_POSITIONS`): a child of the main branch by its node rank, the
            weighted count of nodes below it (siblings within 2 % of the main branch's length are one node; a node
            counts ~1 if its largest subtree is longer than 10 % of the main branch, a short spur ~0), deeper
            children by their arc-length fraction of the parent. Plants grow at their apices: node k of a plant
            stays node k from day to day, and plants of a kind at different stages share their basal nodes, while
            a fraction of a growing stem shifts as it elongates, arc lengths stretch with the internodes, and an
            elastic warp of a nearly straight stem carries children almost freely (similar maize leaves two nodes
            apart then swap). Measured at lp 1, any-order matching (see :data:`DEFAULT_POSITIONS`): consecutive
            synthetic maize frames 94.7 % precision with ``"warped"``, 100 % with ``"rank"``; across bean plants
            59 -> 81 %. ``"warped"`` (SPEC §3): ``s'_c = gamma^{-1}(s_c)``, the child moves with its parent's warp
            (and the parent's warp is refitted to carry matched children onto their partners): the distance is
            then the layout's own metric (what means and geodesics average), which is why the Karcher mean and the
            tree space register with it. ``"arclength"``: its arc length from the parent's
            base, in units of the reference parent's length, whatever the warp (not symmetric in the pair: the
            reference parent's length is the unit). Across plants ``"rank"`` is best with ``lp`` 12 and
            ``order_tol`` (bean 92.9 / 99.8 % precision / recall on 180 pairs, :mod:`torch4dtree.bench.hierarchy`).
            Whatever ``positions``, the results' ``aligned`` holds bifurcation parameters (a moving child at
            ``gamma^{-1}(s)`` on its matched parent), so it decodes and :func:`~torch4dtree.trees.geodesic` works;
            with ``"rank"`` / ``"arclength"`` ``distance`` compares the children by those positions instead, so it
            is not the layout's own distance (nor the geodesic's length).
        order_tol: ``None`` (default, SPEC §3): the side subtrees of each node are matched by one linear assignment,
            any permutation. A number (e.g. :data:`ORDER_TOL`): order-preserving matching, for frames of one
            growing plant, whose organs never pass each other along a parent: the matched children keep their
            order along the parent (positions ``s`` after the parent's warp), except that siblings within
            ``order_tol`` of each other (one node: opposite leaves, whorls, leaflet pairs) may match in any order
            (:func:`_ordered_assignment`). Null partners are allowed either way.
        symmetric: the answer does not depend on which tree is the reference: each pair is solved in one
            canonical direction (the smaller tree onto the larger, :func:`_solve_reversed`) and the other
            direction is its inverse (matches transposed, warps inverted, rotation transposed), so
            ``A -> B -> A`` returns every point to where it started up to the inversion of the warps. The solver
            is not symmetric by itself (discrete DP warps, the position term measured after the moving tree's
            warp, children refits): on the .mat trees at T = 256 near-tied leaflet assignments resolved
            differently each way and 0.62 / 0.75 / 1.20 / 3.11 % of the mapped points missed by more than
            eps = 0.1 / 0.05 / 0.02 / 0.01 x the height (0.00 % at every eps with ``symmetric``). In the
            inverted direction the distance is that of the inverted solution (0.3-0.7 % above a one-way solve
            on average on Pheno4D, see :func:`_solve_reversed`). ``False``: solve the given
            direction (one-way uses: chaining a sequence with a weight from one frame, comparing candidates
            by their distances onto one tree, aligning trees onto a mean or a layout). Symmetric for trees of
            equal ``T`` (others are resampled to the reference's).

    Returns:
        One :class:`TreeRegistration` per moving tree. Every depth of every registration (and every
        rotation start) shares one batched DP call.
    """
    lam = _check_lambdas(lambdas)
    check_rotation_mode(rotation, reference.dim)
    if positions not in POSITIONS:
        raise ValueError(f"unknown positions {positions!r}; expected one of {POSITIONS}")
    if order_tol is not None and not (math.isfinite(order_tol) and order_tol >= 0):
        raise ValueError(f"order_tol must be None or a finite number >= 0, got {order_tol}")
    if reference.num_trees != 1:
        raise ValueError(f"reference must be a single tree, got {reference.num_trees}")
    if trees.dim != reference.dim:
        raise ValueError(f"dimensions differ: {trees.dim} vs {reference.dim}")
    if trees.T != reference.T:
        trees = trees.resample(reference.T)
    singles = trees.split()
    # per moving tree: lp scaled by the pair (the DP warps, the norms and the rotation weights use lm and ls only)
    lams = [effective_lambdas(lam, reference, t) if lp_relative else lam for t in singles]
    up_t = torch.as_tensor((0.0, 0.0, 1.0) if up is None else up, dtype=torch.float64)
    dp_opts = {"neighbourhood": neighbourhood, "band": band, "coarse": coarse, "refine": refine}
    ref = _prepare(reference, lam, positions)
    movs = [_prepare(t, lt, positions) for t, lt in zip(singles, lams)]
    # the pair is solved in its canonical direction (the same whichever tree is given as the reference):
    # problem m registers svs[m] onto srs[m]; flipped ones are inverted at the end
    flip = [symmetric and _solve_reversed(mv, ref) for mv in movs]
    svs = [_prepare(reference, lt, positions) if f else mv for mv, lt, f in zip(movs, lams, flip)]
    srs = [mv if f else ref for mv, f in zip(movs, flip)]
    with torch.no_grad():
        starts = [_initial_rotations(sv, sr, rotation, up_t, n_starts, dp_opts) for sv, sr in zip(svs, srs)]
        best: list[_Config | None] = [None] * len(movs)
        jobs = [(m, m, O) for m, Os in enumerate(starts) for O in Os]
        if rotation != "none" and max(len(Os) for Os in starts) > KEEP_STARTS:
            if reference.T > RANK_T:  # ranking only compares starts: coarser curves do (DP cost ~ T^2)
                c_ref = reference.resample(RANK_T)
                c_movs = [_prepare(t, lt, positions) for t, lt in zip(trees.resample(RANK_T).split(), lams)]
                c_refm = [_prepare(c_ref, lt, positions) if f else None for lt, f in zip(lams, flip)]
                c_ref0 = _prepare(c_ref, lam, positions)
                jobs = _rank_starts([cr if f else cm for cm, cr, f in zip(c_movs, c_refm, flip)],
                                    [cm if f else c_ref0 for cm, f in zip(c_movs, flip)], jobs, lams, dp_opts,
                                    prune, rotation, up_t, positions, order_tol)
            else:
                jobs = _rank_starts(svs, srs, jobs, lams, dp_opts, prune, rotation, up_t, positions, order_tol)
            # the identity always runs in full, so a rotation search never ends worse than rotation="none"
            # (ranking on the top layers could drop it: vertical was worse than none on 3 of 102 Pheno4D pairs)
            eye = torch.eye(reference.dim, dtype=torch.float64)
            kept_identity = {m for m, _, O in jobs if torch.equal(O, eye)}
            jobs += [(m, m, eye) for m in range(len(movs)) if m not in kept_identity]
        last = [math.inf] * len(jobs)
        for _ in range(max(max_iters, 1)):
            configs = _solve(svs, srs, jobs, lams, dp_opts, prune, positions=positions, order_tol=order_tol)
            nxt, nlast = [], []
            for (m, _, _), cfg, prev in zip(jobs, configs, last):
                cur = best[m]
                if cur is None or cfg.energy < cur.energy:
                    best[m] = cfg
                if rotation == "none":
                    continue
                O_new, e_new = _rotation_update(svs[m], srs[m], cfg, lams[m], rotation, up_t)
                cand = _Config(e_new, cfg.match, cfg.gamma, O_new)
                if e_new < best[m].energy:  # type: ignore[union-attr]
                    best[m] = cand
                e = min(e_new, cfg.energy)
                # a start far behind the best one of its pair will not catch up: stop it
                if e > STOP_START_RATIO * best[m].energy + 1e-12:  # type: ignore[union-attr]
                    continue
                if not math.isfinite(prev) or e < prev - tol * prev:
                    nxt.append((m, m, O_new))
                    nlast.append(e)
            # only the KEEP_STARTS most promising starts of each pair keep alternating
            kept: dict[int, int] = {}
            sel: list[int] = []
            for i in sorted(range(len(nxt)), key=lambda i: nlast[i]):
                if kept.get(nxt[i][0], 0) < KEEP_STARTS:
                    kept[nxt[i][0]] = kept.get(nxt[i][0], 0) + 1
                    sel.append(i)
            sel.sort()
            nxt, nlast = [nxt[i] for i in sel], [nlast[i] for i in sel]
            if not nxt:
                break
            jobs, last = nxt, nlast
    # where the reference was registered onto a tree: the inverse correspondence, warps and rotation
    inverse = {m: _inverse_config(cfg, len(movs[m].parent)) for m, cfg in enumerate(best) if flip[m] and cfg}
    out = []
    eye = torch.eye(reference.dim, dtype=torch.float64)
    for m, (mov, cfg, lam_m) in enumerate(zip(movs, best, lams)):
        assert cfg is not None
        cfg = inverse.get(m, cfg)
        aligned, compared = _build_aligned(mov, ref, cfg.match, cfg.gamma, cfg.O, lam_m, positions)
        dist = _pair_distance(aligned, compared)
        ident = np.tile(np.linspace(0.0, 1.0, reference.T), (len(mov.parent), 1))
        base_match = _index_order_match(mov, ref)
        base, base_compared = _build_aligned(mov, ref, base_match, ident, eye, lam_m, positions)
        dist_before = _pair_distance(base, base_compared)
        used_base = bool(dist_before < dist)
        # the index-order solution is a valid candidate: never return worse (kept over an inverted solution too,
        # the one place a symmetric registration can differ between the two argument orders)
        if used_base:
            cfg = _Config(float(dist_before) ** 2, base_match, ident, eye)
            aligned, dist = base, dist_before
        matches = sorted(cfg.match.items())
        matched_ref = set(cfg.match.values())
        out.append(TreeRegistration(
            dist, dist_before, cfg.O.to(device=trees.device, dtype=trees.dtype),
            torch.from_numpy(cfg.gamma).to(device=trees.device, dtype=trees.dtype), matches,
            [a for a in range(len(mov.parent)) if a not in cfg.match],
            [b for b in range(len(ref.parent)) if b not in matched_ref], aligned, used_base,
        ))
    return out


def register_trees(moving: Trees, reference: Trees, lambdas: Sequence[float] = (1.0, 1.0, 1.0),
                   rotation: str = "none", **kwargs: object) -> TreeRegistration:
    """Register one tree onto another (SPEC §3). See :func:`register_to_reference` for the settings.

    Returns a :class:`TreeRegistration`; ``distance`` is the tree-shape distance (never above
    ``distance_before``, the index-order one).
    """
    if moving.num_trees != 1:
        raise ValueError(f"moving must be a single tree, got {moving.num_trees}")
    return register_to_reference(moving, reference, lambdas, rotation, **kwargs)[0]  # type: ignore[arg-type]


# ----------------------------------------------------------------------------- all pairs

MIN_PAIRS_PER_PROCESS = 32

_WORKER_TREES: list[Trees] = []
_WORKER_KW: dict = {}


def _worker_init(trees: list[Trees], kwargs: dict) -> None:
    """Pool initializer: one thread per process (the processes are the parallelism)."""
    global _WORKER_TREES, _WORKER_KW
    torch.set_num_threads(1)
    try:
        import numba

        numba.set_num_threads(1)
    except (ImportError, ValueError):  # pragma: no cover - numba missing or already single-threaded
        pass
    _WORKER_TREES, _WORKER_KW = trees, kwargs


def _row(i: int) -> tuple[int, list[float]]:
    """Distances from tree ``i`` (reference) to all trees after it (moving)."""
    trees = _WORKER_TREES
    if i + 1 >= len(trees):
        return i, []
    res = register_to_reference(Trees.cat(trees[i + 1:]), trees[i], **_WORKER_KW)
    return i, [float(r.distance) for r in res]


def pairwise_distances(trees: Trees, processes: int | None = None, progress: bool = True,
                       **kwargs: object) -> Tensor:
    """All-pairs tree-shape distances ``(n, n)`` (symmetric, zero diagonal), over all cores.

    Tree ``j > i`` is registered onto tree ``i`` (one batched :func:`register_to_reference` per row);
    rows are spread over a process pool (``processes`` defaults to the CPU count; 1 runs inline; fewer
    than ``MIN_PAIRS_PER_PROCESS`` pairs per process also run inline, as a worker takes seconds to
    start) with a tqdm progress bar. ``kwargs`` are passed to :func:`register_to_reference`.
    """
    from tqdm.auto import tqdm

    n = trees.num_trees
    split = trees.split()
    out = torch.zeros(n, n, dtype=torch.float64)
    procs = processes if processes is not None else (os.cpu_count() or 1)
    # a spawned worker pays seconds of start-up (torch import, numba cache load): small jobs run inline
    procs = max(1, min(procs, n * (n - 1) // 2 // MIN_PAIRS_PER_PROCESS))
    bar = tqdm(total=n * (n - 1) // 2, disable=not progress, desc="pairwise distances", unit="pair")
    rows = range(n - 1)

    def fill(i: int, vals: list[float]) -> None:
        for k, v in enumerate(vals):
            out[i, i + 1 + k] = out[i + 1 + k, i] = v
        bar.update(len(vals))

    if procs == 1:
        global _WORKER_TREES, _WORKER_KW
        saved = (_WORKER_TREES, _WORKER_KW)
        _WORKER_TREES, _WORKER_KW = split, dict(kwargs)
        try:
            for i in rows:
                fill(*_row(i))
        finally:
            _WORKER_TREES, _WORKER_KW = saved
    else:
        import multiprocessing as mp

        ctx = mp.get_context("spawn")  # fork after torch/numba threads started is unsafe
        with ctx.Pool(procs, initializer=_worker_init, initargs=(split, dict(kwargs))) as pool:
            for i, vals in pool.imap_unordered(_row, rows):
                fill(i, vals)
    bar.close()
    return out
