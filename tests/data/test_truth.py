"""Identity scores against organ ground truth, on hand-made cases."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from torch4dtree.data import (
    SPUR_LABEL,
    IdentityScores,
    identity_scores,
    longest_path_organ,
    main_branch_organs,
    score_registration,
    synthetic_plant,
)
from torch4dtree.trees.structures import Trees


def test_perfect_match():
    labels = [0, 3, 4, 305]
    s = identity_scores([(0, 0), (1, 1), (2, 2), (3, 3)], labels, labels)
    assert s == IdentityScores(1.0, 1.0, 4, 4)


def test_swap_of_two_leaves():
    # moving branches 1 and 2 are leaves 3 and 4; the registration swapped them
    s = identity_scores([(0, 0), (1, 2), (2, 1)], [0, 3, 4], [0, 3, 4])
    assert s.precision == pytest.approx(1 / 3) and s.recall == pytest.approx(1 / 3)
    assert (s.n_matched, s.n_common) == (3, 3)


def test_missing_organ_and_null_matches():
    # leaf 5 grew since the reference: matched to null, which costs nothing; leaf 4 was left unmatched: recall
    s = identity_scores([(0, 0), (1, 1)], [0, 3, 4, 5], [0, 3, 4])
    assert s.precision == 1.0 and s.recall == pytest.approx(2 / 3) and (s.n_matched, s.n_common) == (2, 3)
    # a label that labels two branches (the hierarchy split an organ): one right pair is enough for recall
    s = identity_scores([(0, 0), (1, 1), (2, 1)], [0, 3, 3], [0, 3])
    assert s.recall == 1.0 and s.precision == 1.0


def test_ignored_labels_and_empty_cases():
    s = identity_scores([(0, 0), (1, 1), (2, 2)], [0, SPUR_LABEL, -1], [0, 3, 4])
    assert (s.precision, s.n_matched, s.n_common) == (1.0, 1, 1)
    s = identity_scores([(0, 0), (1, 1)], [0, SPUR_LABEL], [0, SPUR_LABEL], ignore=())
    assert s.n_common == 2 and s.recall == 1.0
    s = identity_scores([], [SPUR_LABEL], [-1])
    assert math.isnan(s.precision) and math.isnan(s.recall) and (s.n_matched, s.n_common) == (0, 0)
    with pytest.raises(IndexError):
        identity_scores([(0, 3)], [0], [0, 1])


def _tree(labels: list[int]) -> Trees:
    stem = np.stack([np.zeros(5), np.zeros(5), np.linspace(0, 4, 5)], 1)
    branches = [stem] + [np.array([[0.0, 0.0, 1.0 + i], [1.0, 0.0, 1.5 + i]]) for i in range(len(labels) - 1)]
    return Trees.from_branches([branches], [[-1] + [0] * (len(labels) - 1)], T=8, labels=[labels])


def test_score_registration_reads_matches_and_tree_labels():
    a, b = _tree([0, 3, 4]), _tree([0, 4, 3])
    reg = SimpleNamespace(matches=[(0, 0), (1, 2), (2, 1)])
    assert score_registration(reg, a, b) == IdentityScores(1.0, 1.0, 3, 3)
    with pytest.raises(ValueError):
        score_registration(reg, Trees.cat([a, a]), b)


def test_longest_path_organ_on_a_hand_made_skeleton():
    # stem 0 -> 1 -> 2 -> 3 (3 mm), leaf 7 from node 2 going 5 mm sideways, spur at node 1
    xyz = np.array([[0, 0, 0], [0, 0, 1], [0, 0, 2], [0, 0, 3], [2.5, 0, 2], [5, 0, 2], [0, 0.5, 1]], float)
    parent = np.array([-1, 0, 1, 2, 2, 4, 1])
    organ = np.array([0, 0, 0, 0, 7, 7, SPUR_LABEL])
    assert longest_path_organ(xyz, parent, organ) == 7
    xyz[3, 2] = 9.0  # a taller stem wins
    assert longest_path_organ(xyz, parent, organ) == 0


def test_main_branch_organs_of_a_plant():
    p = synthetic_plant("maize", 2, n_frames=4, T=16)
    organs = main_branch_organs(p)
    assert all(o in present for o, present in zip(organs, p.organs_per_frame()))
    p1 = synthetic_plant("maize", 2, n_frames=4, T=16, hierarchy_kwargs={"max_layers": 1})
    assert main_branch_organs(p1) == organs
