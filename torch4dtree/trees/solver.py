"""The recursive registration solver for fixed rotations: warps of every matched branch pair, then the
children's matchings, bottom-up (docs/method.md §3).

The candidate pairs are generated top-down, depth by depth (children pairs of every non-pruned parent pair), and each
depth is ONE batched :func:`~torch4dtree.curves.dp_warp` call over every pair of every registration in flight (all
the moving trees of a registration, all rotation starts). The matchings are then solved bottom-up from those costs.
Pruning is exact: a pair whose lower bound ``lp ds^2 + ls lm E_branch`` already costs as much as leaving both subtrees
unmatched can never be used by an optimal matching, so its subtrees are not explored.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from ..curves.register import DPWarp, dp_warp
from .aligned import Lambdas
from .matching import match_children
from .prepare import MIN_LENGTH, PreparedTree, arc_fractions, child_positions
from .refit import refit_to_children

__all__ = ["Candidate", "FRACTION_GROWTH_MAX", "LANDMARK_MIN_SHARE", "SERIAL_DP_BELOW", "children_positions",
           "closest_positions", "rotate_rows", "solve"]


@dataclass
class Candidate:
    """A registration candidate: matches (moving -> reference), warps of the moving branches, rotation."""

    energy: float
    match: dict[int, int]
    gamma: np.ndarray  # (Nm, T)
    O: Tensor  # (d, d) float64


# children refits (refit.py) run only where the children's position terms are at least this share of the node's
# cost (a negligible share cannot pay for the extra DP energies and matchings)
LANDMARK_MIN_SHARE = 0.01
# below this many pairs the serial DP kernel beats the thread-parallel one (thread start-up dominates)
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


def rotate_rows(x: Tensor, O: Tensor) -> Tensor:
    """``x @ O.T`` for ``x (..., d)``, elementwise: tiny batched matmuls wake torch's thread pool, which costs
    milliseconds per call on a busy machine."""
    return (x.unsqueeze(-2) * O).sum(-1)


# "closest" positions compare a main-branch child's share of the stem only where the stem grew by at most this factor
# between the two trees (either way): where it grew more (sparse frames of an elongating stem) node ranks hold and a
# share moves onto a neighbour's, while a stem that grows a little throughout keeps its organs' shares
# (docs/experiments.md)
FRACTION_GROWTH_MAX = 1.3


def _place_candidates(mov: PreparedTree, ref: PreparedTree, a: int, b: int, children: Sequence[int],
                      arc_m: np.ndarray, arc_r: np.ndarray) -> np.ndarray:
    """``(c, k)``: moving branch ``a``'s ``children`` placed on reference branch ``b`` (``arc_m``, ``arc_r`` the
    trees' :func:`.arc_fractions`), on the scale of the reference children's ``s``: row 0 by their arc length from
    the parent's base (in the reference parent's length; the parent grew at its tip), row 1 (``c = 2``, see
    :func:`_compares_fractions`) by their fraction of the parent's length (the parent elongated evenly). On the main
    branch each is read as the reference's node rank at that place (linear between its nodes, its mean node spacing
    beyond them), elsewhere it is a fraction."""
    f = arc_m[list(children)]
    x = f * mov.sqrt_len[a] ** 2 / max(float(ref.sqrt_len[b]) ** 2, MIN_LENGTH)
    x = np.stack([x, f]) if _compares_fractions(mov, ref, a, b) else x[None]
    cb = ref.children[b]
    if a != 0 or not cb:
        return x
    xr, sr = arc_r[cb], ref.s[cb]
    spacing = max(float(xr[-1]) / (float(sr[-1]) + 1.0), MIN_LENGTH)  # the base to the first node counts as one
    inside = np.interp(x, xr, sr)
    return np.where(x < xr[0], sr[0] - (xr[0] - x) / spacing,
                    np.where(x > xr[-1], sr[-1] + (x - xr[-1]) / spacing, inside))


def _compares_fractions(mov: PreparedTree, ref: PreparedTree, a: int, b: int) -> bool:
    """Whether ``"closest"`` compares the children's fractions of branches ``a`` and ``b``: below the main branch
    always, on it where it grew by at most :data:`FRACTION_GROWTH_MAX` (either way)."""
    if a != 0:
        return True
    grew = float(ref.sqrt_len[b]) ** 2 / max(float(mov.sqrt_len[a]) ** 2, MIN_LENGTH)
    return 1.0 / FRACTION_GROWTH_MAX <= grew <= FRACTION_GROWTH_MAX


def children_positions(mov: PreparedTree, ref: PreparedTree, a: int, b: int, sc: np.ndarray, positions: str,
                       arcs: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray:
    """``(k1, k2)``: the squared position differences of moving branch ``a``'s children (compared positions
    ``sc (k1,)``, :func:`child_positions`) and reference branch ``b``'s, ``(sc - s_e)^2``.

    ``"closest"`` (``arcs`` the two trees' :func:`.arc_fractions`): on the main branch the smallest of the node
    ranks' difference, the arc lengths' and, where the stem grew by at most :data:`FRACTION_GROWTH_MAX`, the
    fractions' (as node ranks of the reference, :func:`_place_candidates`), so an organ keeps its node rank
    (internodes below it elongated), its distance from the base (the stem grew at its tip while a node below it
    became significant) or its share of the stem (the stem elongated throughout); below the main branch the smaller
    of the arc lengths' difference in the reference parent's length (woody axes and a simulator's organs grow at
    their tip) and the fractions' (the parent elongated throughout).

    Example (a stem grows at its tip from 4 to 6 while a child appears at 0.5: every older child's node rank rises
    by one, its height stays):
        >>> import numpy as np
        >>> from torch4dtree import Trees
        >>> from torch4dtree.trees.prepare import prepare_tree
        >>> z = np.linspace(0, 1, 8)[:, None]
        >>> def plant(h, at):
        ...     kids = [np.hstack([z, 0 * z, a + 0 * z]) for a in at]
        ...     return Trees.from_branches([[np.hstack([0 * z, 0 * z, h * z]), *kids]], [[-1] + [0] * len(at)], T=8)
        >>> later = prepare_tree(plant(6.0, [0.5, 1.0, 2.0, 3.0]), (1, 1, 1), "closest")
        >>> earlier = prepare_tree(plant(4.0, [1.0, 2.0, 3.0]), (1, 1, 1), "closest")
        >>> sc, arcs = earlier.s[earlier.children[0]], (arc_fractions(earlier.q, earlier.frac, earlier.parent),
        ...                           arc_fractions(later.q, later.frac, later.parent))
        >>> own = [0, 1, 2], [1, 2, 3]  # each older child and itself in the later tree
        >>> children_positions(earlier, later, 0, 0, sc, "rank", None)[own].round(2).tolist()
        [0.88, 0.77, 0.67]
        >>> children_positions(earlier, later, 0, 0, sc, "closest", arcs)[own].round(2).tolist()
        [0.0, 0.0, 0.0]
    """
    s_ref = ref.s[ref.children[b]][None, :]
    d2 = (sc[:, None] - s_ref) ** 2
    if positions != "closest" or arcs is None:
        return d2
    alt = _place_candidates(mov, ref, a, b, mov.children[a], *arcs)
    d2_alt = ((alt[:, :, None] - s_ref[None]) ** 2).min(0)
    return np.minimum(d2, d2_alt) if a == 0 else d2_alt


def closest_positions(mov: PreparedTree, ref: PreparedTree, match: dict[int, int], compared: np.ndarray
                      ) -> np.ndarray:
    """``(Nm,)``: for ``"closest"`` positions, the moving tree's compared positions ``compared (Nm,)``
    (:func:`child_positions` on the matched parents) replaced, for every matched child of a matched parent, by the
    place the solver compared it at (:func:`children_positions`): whichever of its candidate places is closest to
    its partner's. A layout's distance with these positions is then the cost the solver minimised."""
    out = compared.copy()
    arc_m, arc_r = (arc_fractions(t.q, t.frac, t.parent) for t in (mov, ref))
    for a, b in match.items():
        ca = [c for c in mov.children[a] if c in match]
        if not ca:
            continue
        alt = _place_candidates(mov, ref, a, b, ca, arc_m, arc_r)
        if a == 0:  # node ranks are a candidate on the main branch
            alt = np.concatenate([out[ca][None], alt])
        targets = ref.s[[match[c] for c in ca]]
        out[ca] = alt[np.abs(alt - targets[None]).argmin(0), np.arange(len(ca))]
    return out


def solve(movs: Sequence[PreparedTree], refs: Sequence[PreparedTree], jobs: Sequence[tuple[int, int, Tensor]],
          lambdas: Sequence[Lambdas], dp_opts: dict, prune: bool, max_depth: int | None = None,
          landmarks: bool = True, positions: str = "warped", order_tol: float | None = None) -> list[Candidate]:
    """One :class:`Candidate` per job: warps + matchings for fixed rotations.

    ``jobs[k] = (moving index, reference index, O (d, d))``; ``lambdas[m]`` are the weights of moving tree ``m``
    (each pair may have its own ``lp``; the DP warps do not depend on the weights, so pairs of different weights
    share the batched DP calls). ``dp_opts`` are :func:`~torch4dtree.curves.dp_warp` settings.

    ``max_depth`` stops exploring pairs below that layer (their subtrees then count as unmatched): a cheap,
    approximate solve used to rank starting rotations. ``landmarks`` refits each parent's warp to its
    matched children (:func:`refit_to_children`; only with ``"warped"`` positions: otherwise a warp does not move
    children). ``positions``: how children's places are compared (:func:`child_positions`,
    :func:`children_positions`). ``order_tol``: children's matching, see :func:`match_children`.
    """
    landmarks = landmarks and positions == "warped"
    T = movs[0].q.shape[1] + 1
    grid = np.linspace(0.0, 1.0, T)
    qrot = [rotate_rows(movs[m].q, O) for m, _, O in jobs]
    arcs: dict[int, np.ndarray] = {}
    if positions == "closest":
        for t in [*movs, *refs]:
            if id(t) not in arcs:
                arcs[id(t)] = arc_fractions(t.q, t.frac, t.parent)
    # top-down: candidate pairs per depth, one batched DP per depth
    level: list[tuple[int, int, int, float]] = [(k, 0, 0, 0.0) for k in range(len(jobs))]
    levels: list[list[tuple[int, int, int, float]]] = []
    # (k, a, b) -> (E, gamma, children's s', children's position costs); a level's pairs carry their position cost
    info: dict[tuple[int, int, int], tuple[float, np.ndarray, np.ndarray, np.ndarray]] = {}
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
            if depth > 0 and prune and sa + ls * lm * E[p] >= ls * (mov.norm[a] + ref.norm[b]):
                continue  # never better than leaving both unmatched: do not explore
            ca, cb = mov.children[a], ref.children[b]
            sc = child_positions(mov, ref, a, b, ca, gam[p], grid, positions)
            pos = lp * children_positions(mov, ref, a, b, sc, positions,
                                          (arcs[id(mov)], arcs[id(ref)]) if arcs else None)
            info[(k, a, b)] = (float(E[p]), gam[p], sc, pos)
            if max_depth is not None and depth >= max_depth:
                continue
            pos_l = pos.tolist()  # python floats: fast scalar access
            for i, c in enumerate(ca):
                for j, e in enumerate(cb):
                    if prune:
                        lb = pos_l[i][j] + ls * lm * (mov.sqrt_len[c] - ref.sqrt_len[e]) ** 2
                        if lb >= ls * (mov.norm[c] + ref.norm[e]):
                            continue
                    nxt.append((k, c, e, pos_l[i][j]))
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
            E, _, sc, pos = info[key]
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
                cost, pairs = match_children(sub + pos, null_mov, null_ref, sc, s_ref, order_tol)
                total += cost
                s_cost = lp * sum((sc[i] - s_ref[j]) ** 2 for i, j in pairs)  # the most a refit can save
                if landmarks and pairs and s_cost > LANDMARK_MIN_SHARE * total:
                    ref_q, mov_q = ref.q[b], qrot[k][a]
                    total, pairs, E, gam_ab, sc = refit_to_children(
                        ref_q, mov_q, info[key][1], mov.s[ca], s_ref, sub, null_mov, null_ref, pairs, total, lm,
                        lp, order_tol)
                    info[key] = (E, gam_ab, sc, pos)
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
        out.append(Candidate(D[(k, 0, 0)], match, gamma, O))
    return out

