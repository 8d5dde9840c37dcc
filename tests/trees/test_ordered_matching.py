"""Order-preserving children's matching (``order_tol``): DP optimality by brute force, and a tree pair that the
unconstrained assignment matches crosswise."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch

from torch4dtree.trees.matching import assignment, ordered_assignment
from torch4dtree.trees.registration import register_trees
from torch4dtree.trees.structures import Trees

TOL = 0.02


def _matchings(k1: int, k2: int):
    """Every partial injective matching of ``range(k1)`` into ``range(k2)``, as lists of pairs."""
    for m in range(min(k1, k2) + 1):
        for rows in itertools.combinations(range(k1), m):
            for cols in itertools.permutations(range(k2), m):
                yield list(zip(rows, cols))


def _cost(pairs, cost, null_mov, null_ref) -> float:
    used_i, used_j = {i for i, _ in pairs}, {j for _, j in pairs}
    return (sum(cost[i, j] for i, j in pairs) + sum(null_mov[i] for i in range(len(null_mov)) if i not in used_i)
            + sum(null_ref[j] for j in range(len(null_ref)) if j not in used_j))


def _no_strict_crossing(pairs, g1, g2) -> bool:
    """No two pairs whose groups are in opposite orders on the two sides (ties inside a group may cross)."""
    return all(not ((g1[i] - g1[k]) * (g2[j] - g2[m]) < 0) for (i, j), (k, m) in itertools.combinations(pairs, 2))


def _group_one_to_one(pairs, g1, g2) -> bool:
    """Strictly monotone in groups, each group matched with at most one group (the narrower family)."""
    return all(((g1[i] == g1[k]) == (g2[j] == g2[m])) and (g1[i] - g1[k]) * (g2[j] - g2[m]) >= 0
               for (i, j), (k, m) in itertools.combinations(pairs, 2))


def _random_case(rng, k1: int, k2: int, levels: int, ties_ref: bool):
    """Positions on a few levels 0.2 apart (jitter << TOL, so the groups are the levels), costs with some ``inf``."""
    lv1 = rng.integers(0, levels, k1)
    lv2 = rng.integers(0, levels, k2) if ties_ref else rng.permutation(max(levels, k2))[:k2]
    s1 = 0.1 + 0.2 * lv1 + rng.uniform(0, TOL / 4, k1)
    s2 = 0.1 + 0.2 * lv2 + rng.uniform(0, TOL / 4, k2)
    cost = rng.uniform(0, 4, (k1, k2))
    cost[rng.uniform(size=(k1, k2)) < 0.15] = np.inf  # pruned pairs
    return cost, rng.uniform(0.5, 3, k1), rng.uniform(0.5, 3, k2), s1, s2, lv1, lv2


@pytest.mark.parametrize("ties_ref", [False, True])
def test_ordered_dp_against_brute_force(ties_ref: bool) -> None:
    rng = np.random.default_rng(5)
    for trial in range(150):
        k1, k2 = int(rng.integers(0, 5)), int(rng.integers(0, 5))
        cost, n1, n2, s1, s2, g1, g2 = _random_case(rng, k1, k2, levels=int(rng.integers(1, 5)), ties_ref=ties_ref)
        total, pairs = ordered_assignment(cost, n1, n2, s1, s2, TOL)
        # the DP's matching is admissible, finite, and its cost is the one it reports
        assert len({i for i, _ in pairs}) == len(pairs) == len({j for _, j in pairs})
        assert _no_strict_crossing(pairs, g1, g2)
        assert total == pytest.approx(_cost(pairs, cost, n1, n2), rel=1e-12, abs=1e-12)
        costs = [(_cost(p, cost, n1, n2), p) for p in _matchings(k1, k2)]
        best_free = min(c for c, p in costs if _no_strict_crossing(p, g1, g2))
        best_groups = min(c for c, p in costs if _group_one_to_one(p, g1, g2))
        if not ties_ref:  # one-sided ties: the DP is exact over all matchings without strict crossings
            assert total == pytest.approx(best_free, rel=1e-12, abs=1e-12), trial
        else:  # both sides tied: between that minimum and the group one-to-one one (staircases are left out)
            assert best_free - 1e-12 <= total <= best_groups + 1e-12, trial
        # never below the unconstrained assignment, equal to it when all positions are distinct and it is monotone
        assert total >= assignment(cost, n1, n2)[0] - 1e-12


def test_ordered_dp_distinct_positions_is_monotone_alignment() -> None:
    """Without ties the family is the plain order-preserving alignment: the minimum over strictly monotone ones."""
    rng = np.random.default_rng(11)
    for _ in range(100):
        k1, k2 = int(rng.integers(1, 5)), int(rng.integers(1, 5))
        s1, s2 = np.sort(rng.uniform(0, 1, k1)), np.sort(rng.uniform(0, 1, k2))
        s1 += np.arange(k1) * 0.1  # spaced beyond TOL
        s2 += np.arange(k2) * 0.1
        cost, n1, n2 = rng.uniform(0, 4, (k1, k2)), rng.uniform(0.5, 3, k1), rng.uniform(0.5, 3, k2)
        total, _ = ordered_assignment(cost, n1, n2, s1, s2, TOL)
        mono = [p for p in _matchings(k1, k2) if all(j < m for (_, j), (_, m) in itertools.combinations(p, 2))]
        assert total == pytest.approx(min(_cost(p, cost, n1, n2) for p in mono), rel=1e-12)


# ----------------------------------------------------------------------------- a tree pair


def _leaf(start: np.ndarray, length: float, direction: float, n: int = 30) -> np.ndarray:
    """An arching leaf of the given length, leaving ``start`` along ``+x`` (``direction = 1``) or ``-x``."""
    t = np.linspace(0, 1, n)[:, None]
    pts = np.concatenate([direction * t, 0 * t, 0.6 * t - 0.5 * t**2], axis=1)
    return start + pts / np.linalg.norm(np.diff(pts, axis=0), axis=1).sum() * length


def _plant(leaves: list[tuple[float, float, float]]) -> Trees:
    """A straight 100 mm stem with leaves ``(s, length, direction)``."""
    stem = np.linspace(0, 1, 60)[:, None] * np.array([0.0, 0.0, 100.0])
    branches = [stem] + [_leaf(np.array([0.0, 0.0, 100.0 * s]), length, d) for s, length, d in leaves]
    return Trees.from_branches([branches], [[-1] + [0] * len(leaves)], T=32, dtype=torch.float64)


def _s_of(tree: Trees, pairs, side: int) -> list[float]:
    return [float(tree.s[p[side]]) for p in pairs if p[0] != 0]


def test_ordered_registration_does_not_cross() -> None:
    """The maize case in small: a leaf that grows from 3 to 147 mm in one step. The assignment matches the older
    86 mm leaf (lower) with it and the tiny one with the 99 mm leaf below; the ordered matching keeps them apart."""
    moving = _plant([(0.3, 86.0, 1.0), (0.8, 3.0, 1.0)])  # leaves 2 and 4 of maize: one side
    reference = _plant([(0.25, 99.0, 1.0), (0.85, 147.0, 1.0)])
    lam = (1.0, 1.0, 0.01)  # positions nearly free, as after a weakly determined stem warp
    free = register_trees(moving, reference, lam, lp_relative=False, order_tol=None)
    ordered = register_trees(moving, reference, lam, lp_relative=False, order_tol=TOL)

    def crossing(reg) -> bool:
        pairs = [(a, b) for a, b in reg.matches if a != 0]
        return any((moving.s[a] - moving.s[c]) * (reference.s[b] - reference.s[d]) < 0
                   for (a, b), (c, d) in itertools.combinations(pairs, 2)) or len(pairs) < 2

    assert crossing(free)  # the case is a real one: the unconstrained optimum crosses (or drops a leaf)
    assert not crossing(ordered)
    assert sorted(ordered.matches) == [(0, 0), (1, 1), (2, 2)]
    assert float(ordered.distance) >= float(free.distance) - 1e-9  # a minimum over fewer matchings


@pytest.mark.parametrize("swap", [False, True])
def test_ordered_siblings_at_one_node_match_either_way(swap: bool) -> None:
    """Opposite leaves at one node (equal ``s``) are matched by shape whatever their index order."""
    a, b = (0.5, 50.0, 1.0), (0.5, 20.0, -1.0)
    moving = _plant([a, b])
    ra, rb = (0.5, 55.0, 1.0), (0.5, 22.0, -1.0)
    reference = _plant([rb, ra] if swap else [ra, rb])
    reg = register_trees(moving, reference, (1.0, 1.0, 1.0), lp_relative=False, order_tol=TOL)
    L_m, L_r = moving.branch_lengths(), reference.branch_lengths()
    pairs = [(x, y) for x, y in reg.matches if x != 0]
    assert len(pairs) == 2
    for x, y in pairs:  # the long leaf with the long one, the short with the short
        assert (float(L_m[x]) > 30) == (float(L_r[y]) > 30)
