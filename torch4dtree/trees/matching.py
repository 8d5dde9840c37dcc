"""Matching the children of one parent pair: any partial matching, or one that keeps their order along the parents.

Both are exact over their families and leave children unmatched (to a null partner) where that is cheaper
(docs/method.md §3).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

__all__ = ["assignment", "match_children", "order_groups", "ordered_assignment"]


def assignment(cost: np.ndarray, null_mov: np.ndarray, null_ref: np.ndarray) -> tuple[float, list[tuple[int, int]]]:
    """Any partial matching: one linear assignment on the augmented ``(k1 + k2) x (k2 + k1)`` matrix
    (docs/method.md §3).

    ``cost (k1, k2)``: cost of matching moving child ``i`` to reference child ``j`` (``inf``: excluded);
    ``null_mov (k1,)`` / ``null_ref (k2,)``: cost of leaving each unmatched. Returns ``(total, [(i, j), ...])``.

    Example:
        >>> import numpy as np
        >>> assignment(np.array([[1.0, 5.0], [5.0, 1.0]]), np.array([3.0, 3.0]), np.array([3.0, 3.0]))
        (2.0, [(0, 0), (1, 1)])
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


def order_groups(s: np.ndarray, tol: float) -> list[list[int]]:
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
    may cross): the order-preservation :func:`ordered_assignment` stands for."""
    group1 = {i: g for g, grp in enumerate(G1) for i in grp}
    group2 = {j: g for g, grp in enumerate(G2) for j in grp}
    links = sorted((group1[i], group2[j]) for i, j in pairs)
    return all(a2 <= b2 for (_, a2), (_, b2) in zip(links, links[1:]))


def ordered_assignment(cost: np.ndarray, null_mov: np.ndarray, null_ref: np.ndarray, s_mov: np.ndarray,
                        s_ref: np.ndarray, tol: float) -> tuple[float, list[tuple[int, int]]]:
    """The cheapest partial matching that keeps the order of the children along their parents.

    Each side's children are grouped by position (:func:`order_groups`, ``s_mov (k1,)`` after the parent's warp,
    ``s_ref (k2,)``). The matching is a sequence of blocks in order along both parents: one group of one side
    against a run of consecutive groups of the other (any partial matching inside a block, :func:`assignment`,
    so siblings at one node may swap, and two siblings sharing a node may part into two nodes of the next
    frame); groups outside the blocks are unmatched. Exact over that family by an edit-distance DP over the two
    group lists (``O(g1 g2)`` cells; runs only start from groups of two or more). With singleton groups this is
    the plain order-preserving alignment. It never crosses two pairs whose groups differ on both sides; it
    misses only staircases (two adjacent multi-member groups each shared by two blocks), unless the unconstrained
    assignment, tried first, is one (any assignment that crosses no groups is returned as it is). Costs as
    :func:`assignment`. Why: organs along a parent never pass each other as a plant grows, while the assignment
    lets a long leaf match a similar one two nodes away and a tiny one take its place.
    """
    G1, G2 = order_groups(s_mov, tol), order_groups(s_ref, tol)
    m1, m2 = len(G1), len(G2)
    # the unconstrained optimum is a lower bound; where it never crosses it is the answer (the usual case between
    # consecutive frames, and inside the children refits that call this many times), staircases included
    free_cost, free_pairs = assignment(cost, null_mov, null_ref)
    if _never_crosses(free_pairs, G1, G2):
        return free_cost, free_pairs
    pair = np.minimum(cost, null_mov[:, None] + null_ref[None, :])  # one child each: matched or both null

    def block(x0: int, x1: int, y0: int, y1: int) -> tuple[float, list[tuple[int, int]]]:
        g = [i for grp in G1[x0:x1] for i in grp]
        h = [j for grp in G2[y0:y1] for j in grp]
        if len(g) == 1 and len(h) == 1:
            i, j = g[0], h[0]
            return float(pair[i, j]), [(i, j)] if cost[i, j] < null_mov[i] + null_ref[j] else []
        c, p = assignment(cost[np.ix_(g, h)], null_mov[g], null_ref[h])
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


def match_children(cost: np.ndarray, null_mov: np.ndarray, null_ref: np.ndarray, s_mov: np.ndarray,
                    s_ref: np.ndarray, order_tol: float | None) -> tuple[float, list[tuple[int, int]]]:
    """Children's matching of one parent pair: any (``order_tol=None``) or order-preserving (see
    :func:`ordered_assignment`). Returns ``(total cost, [(moving i, reference j), ...])``."""
    if order_tol is None:
        return assignment(cost, null_mov, null_ref)
    return ordered_assignment(cost, null_mov, null_ref, s_mov, s_ref, order_tol)


