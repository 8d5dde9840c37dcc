"""The identity benchmark's scoring (torch4dtree.bench.identities) on hand-made trees: every cause named right."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from torch4dtree import Trees
from torch4dtree.bench.identities import (
    CAUSES,
    ErrorCauses,
    branch_composition,
    error_causes,
    score_pair,
    sequence_matches,
    sum_causes,
)


def _pure(labels: list[int]) -> list[dict[int, float]]:
    return [{x: 1.0} for x in labels]


def _causes(matches: list[tuple[int, int]], lm: list[int], lr: list[int], comp_m: list[dict[int, float]] | None = None,
            comp_r: list[dict[int, float]] | None = None, len_m: list[float] | None = None,
            len_r: list[float] | None = None) -> ErrorCauses:
    return error_causes(matches, lm, lr, comp_m or _pure(lm), comp_r or _pure(lr), len_m or [100.0] * len(lm),
                        len_r or [100.0] * len(lr))


def test_swap_of_two_whole_organs_is_a_swap() -> None:
    e = _causes([(0, 0), (1, 2), (2, 1)], [1, 3, 4], [1, 3, 4])
    assert e.pairs == [(1, 2, "swap"), (2, 1, "swap")]
    assert e.counts == {"inherited": 0, "spur": 0, "apex_chain": 0, "split": 0, "swap": 2, "other": 0}
    assert (e.mismatched, e.unmatched) == (2, 0)


def test_one_way_mismatch_is_other() -> None:
    e = _causes([(0, 0), (1, 2)], [1, 3, 4], [1, 3, 4])  # 3 onto 4, 4 left unmatched
    assert e.pairs == [(1, 2, "other")]
    assert (e.mismatched, e.unmatched) == (2, 0)  # 3 matched elsewhere, 4 (reference side) matched by 3


def test_organ_cut_into_two_branches_matched_to_two_organs_is_a_split() -> None:
    # organ 5 is branches 1 and 2 of the moving tree; branch 1 matched to 5, branch 2 to organ 6
    lm, lr = [1, 5, 5], [1, 5, 6]
    e = _causes([(0, 0), (1, 1), (2, 2)], lm, lr, len_m=[100.0, 40, 30])
    assert e.pairs == [(2, 2, "split")]
    # 5 cut in both trees, a piece of 5 onto 6 and 6 onto a piece of 5: splits (the organ is cut), not a swap
    e = _causes([(0, 0), (1, 2), (3, 1), (2, 3)], [1, 5, 5, 6], [1, 5, 6, 5])
    assert e.pairs == [(1, 2, "split"), (3, 1, "split")]
    # whole organs 5 and 6 each matched to the other: a swap
    e = _causes([(0, 0), (1, 2), (2, 1)], [1, 5, 6], [1, 5, 6])
    assert [c for *_, c in e.pairs] == ["swap", "swap"]


def test_short_piece_is_a_spur_whatever_else() -> None:
    e = _causes([(0, 0), (1, 2), (2, 1)], [1, 3, 4], [1, 3, 4], len_m=[100.0, 2, 100])
    assert [c for *_, c in e.pairs] == ["spur", "swap"]  # the stub's pair is a spur, its partner still a swap


def test_branch_running_into_a_younger_organ_is_an_apex_chain() -> None:
    # the moving main branch holds stem 1 (40 %) then leaf 7 (60 %): majority 7, matched to the stem of the
    # reference, which is all organ 1
    lm, lr = [7, 2], [1, 2]
    e = _causes([(0, 0), (1, 1)], lm, lr, comp_m=[{1: 0.4, 7: 0.6}, {2: 1.0}])
    assert e.pairs == [(0, 0, "apex_chain")]


def test_children_of_a_wrong_pair_are_inherited() -> None:
    # the swapped organs 3 and 4 carry organs 5 and 6, whose branches follow their parents
    lm, lr = [1, 3, 4, 5, 6], [1, 3, 4, 5, 6]
    parents = [-1, 0, 0, 1, 2]
    e = error_causes([(0, 0), (1, 2), (2, 1), (3, 4), (4, 3)], lm, lr, _pure(lm), _pure(lr), [100.0] * 5,
                     [100.0] * 5, parents, parents)
    assert e.pairs == [(1, 2, "swap"), (2, 1, "swap"), (3, 4, "inherited"), (4, 3, "inherited")]
    # without the parents the children's pairs are swaps of their own
    e = _causes([(0, 0), (1, 2), (2, 1), (3, 4), (4, 3)], lm, lr)
    assert [c for *_, c in e.pairs] == ["swap"] * 4


def test_ignored_labels_and_order_of_causes() -> None:
    e = _causes([(0, 0), (1, 1)], [1, 99], [1, 3])  # 99: the synthetic generator's spur label, ignored
    assert e.pairs == [] and set(e.counts) == set(CAUSES)
    total = sum_causes([_causes([(1, 2), (2, 1)], [1, 3, 4], [1, 3, 4]), _causes([(1, 2)], [1, 3, 4], [1, 3, 4])])
    assert total["swap"] == 2 and total["other"] == 1 and total["mismatched"] == 4


def test_composition_and_score_pair_on_a_skeleton() -> None:
    # stem 0-10 (organ 1) continued to 15 by organ 2 at its apex; a leaf (organ 3) at height 5
    xyz = np.array([[0.0, 0, 0], [0, 0, 5], [0, 0, 10], [0, 0, 15], [5, 0, 5]])
    parent, organ = np.array([-1, 0, 1, 2, 1]), np.array([1, 1, 1, 2, 3])
    stem, leaf = xyz[[0, 1, 2, 3]], xyz[[1, 4]]
    tree = Trees.from_branches([[stem, leaf]], [[-1, 0]], T=16, labels=[[1, 3]], dtype=torch.float64)
    comp = branch_composition(tree, xyz, parent, organ)
    assert comp[0][1] == pytest.approx(10 / 15) and comp[0][2] == pytest.approx(5 / 15)
    assert comp[1] == {3: 1.0}
    scores, causes = score_pair([(0, 0), (1, 1)], tree, tree, (xyz, parent, organ), (xyz, parent, organ))
    assert (scores.precision, scores.recall) == (1.0, 1.0) and causes.pairs == []


def test_sequence_matches_reads_the_identity_table() -> None:
    ident = torch.tensor([[0, -1, 1], [0, 1, 2], [1, 0, 2]])
    assert sequence_matches(ident, 0) == [(0, 0), (1, 2)]
    assert sequence_matches(ident, 1) == [(0, 1), (1, 0), (2, 2)]
