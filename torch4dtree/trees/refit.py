"""Children-aware warps: refit a parent's warp so its matched children land on their partners.

The metric charges ``lp (gamma^{-1}(s_c) - s_e)^2`` for every matched child, which the parent's own DP warp ignores
(a nearly straight stem leaves its children wherever the identity puts them). Where those terms are a share of a
node's cost (``solver.LANDMARK_MIN_SHARE``), the parent warp is composed with a piecewise-linear warp carrying the
matched children onto their partners (best of a few blends, by the exact node cost) and the children's matching is
re-solved; this never raises the energy (docs/method.md §3).
"""

from __future__ import annotations

import numpy as np
from torch import Tensor

from ..curves.register import warp_energies
from .matching import match_children

__all__ = ["LANDMARK_ROUNDS", "LANDMARK_STEPS", "refit_to_children"]

# blends tried between a parent's own warp and the warp that puts its matched children exactly on theirs
LANDMARK_STEPS = (0.25, 0.5, 0.75, 1.0)
# rounds of (refit the parent warp to the matched children, re-solve their matching)
LANDMARK_ROUNDS = 3
# landmarks closer than this to the previous one or to the ends are dropped: the warp stays strictly increasing
KNOT_GAP = 1e-9
# a blend replaces the current warp only if it lowers the node cost by more than this share (rounding noise)
IMPROVEMENT_RTOL = 1e-12


def _landmark_warp(s_ref: np.ndarray, s_now: np.ndarray, grid: np.ndarray) -> np.ndarray | None:
    """``phi (T,)``: the piecewise-linear warp with ``phi(s_ref[i]) = s_now[i]`` (increasing subset), or None."""
    xs, ys = [0.0], [0.0]
    for x, y in sorted(zip(s_ref.tolist(), s_now.tolist())):
        if xs[-1] + KNOT_GAP < x < 1.0 - KNOT_GAP and ys[-1] + KNOT_GAP < y < 1.0 - KNOT_GAP:
            xs.append(x)
            ys.append(y)
    if len(xs) == 1:
        return None
    return np.interp(grid, xs + [1.0], ys + [1.0])


def refit_to_children(ref_q: Tensor, mov_q: Tensor, gamma: np.ndarray, s_mov: np.ndarray, s_ref: np.ndarray,
                      sub: np.ndarray, null_mov: np.ndarray, null_ref: np.ndarray, pairs: list[tuple[int, int]],
                      total: float, lm: float, lp: float, order_tol: float | None
                      ) -> tuple[float, list[tuple[int, int]], float, np.ndarray, np.ndarray]:
    """Children-aware warp of one parent pair; never increases the node cost.

    Composes the parent's warp ``gamma (T,)`` with a piecewise-linear ``phi`` that carries each matched child onto
    its partner (``gamma o ((1 - a) id + a phi)``), keeps the best blend ``a`` by the exact node cost (``lm`` x the
    parent energy between ``ref_q`` and ``mov_q (M, d)`` + the re-solved matching) and repeats with the new
    matching. ``s_mov (k1,)`` are the moving children's parameters before the warp, ``s_ref (k2,)`` the reference
    children's; ``sub (k1, k2)`` is the subtree part of the children's matching costs (``ls D``, ``inf`` where
    excluded), ``null_mov`` / ``null_ref`` their unmatched costs (:func:`match_children`); ``total`` and ``pairs``
    the node cost and matching under ``gamma``.

    Returns ``(total, pairs, parent energy, gamma, children's s')``.
    """
    T = gamma.shape[0]
    grid = np.linspace(0.0, 1.0, T)
    sc = np.interp(s_mov, gamma, grid)

    def matching(s_now: np.ndarray) -> tuple[float, list[tuple[int, int]]]:
        cost = sub + lp * (s_now[:, None] - s_ref[None, :]) ** 2
        return match_children(cost, null_mov, null_ref, s_now, s_ref, order_tol)

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
            if t < best[0] - IMPROVEMENT_RTOL * max(1.0, abs(best[0])):
                best = (t, p, e, g, s_new)
                improved = True
        if not improved:
            break
    if best[3] is gamma:
        return total, pairs, (total - c0) / lm, gamma, sc  # unchanged
    return best

