"""Branch identities across plants of a kind with ``"nodes"`` positions (:func:`torch4dtree.trees.prepare.
prepare_tree`: node ranks on the stem and every shoot, an axillary shoot half a node above the leaf of its node,
leaflets at their arc-length fractions) and lp 100, the setting measured on simulator plants (docs/experiments.md,
"Identities across plants on simulator crops").

Two plants of one kind carry a leaf at every node of the stem and of each side shoot, and side shoots at some nodes
only, with internodes of different lengths: "the same organ" is the leaf (or shoot) at node n of the same parent.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from torch4dtree.bench.hierarchy import registration_settings
from torch4dtree.data import identity_scores
from torch4dtree.settings import POSITIONS
from torch4dtree.trees import Trees
from torch4dtree.trees import prepare as prepare_module
from torch4dtree.trees.prepare import AXIL_OFFSET, prepare_tree
from torch4dtree.trees.registration import register_trees

GOLDEN = math.radians(137.5)
NODES = registration_settings(100.0, "nodes")  # the simulator plants' setting


def _line(start: np.ndarray, direction: np.ndarray, length: float, n: int = 12) -> np.ndarray:
    d = direction / np.linalg.norm(direction)
    return start + np.linspace(0.0, length, n)[:, None] * d


def _leaf(base: np.ndarray, k: int, length: float) -> np.ndarray:
    """A straight leaf leaving at 50 degrees from the vertical, spiral phyllotaxis."""
    a = GOLDEN * k
    return _line(base, np.array([math.cos(a), math.sin(a), 0.8]), length)


def plant(internode: float, shoots: dict[int, int], nodes: int = 9) -> Trees:
    """A stem (label 5) of ``nodes`` nodes ``internode`` mm apart, a 150 mm leaf at each (node ``n`` from 0: label
    ``10 * n + 11``), and at the nodes of ``shoots`` a side shoot (``10 * n + 15``, 260 mm, carrying
    ``shoots[n]`` leaves of 60 mm at its own nodes 30 mm apart, labels ``1000 * (10 * n + 15) + 10 * k + 11``)."""
    stem = _line(np.zeros(3), np.array([0.0, 0.0, 1.0]), internode * (nodes + 1), n=40)
    branches, parents, labels = [stem], [-1], [5]
    for n in range(nodes):
        base = np.array([0.0, 0.0, internode * (n + 1)])
        branches.append(_leaf(base, n, 150.0))
        parents.append(0)
        labels.append(10 * n + 11)
        if n in shoots:
            a = GOLDEN * n  # in the leaf's axil: the leaf's azimuth, steeper
            shoot = _line(base, np.array([math.cos(a), math.sin(a), 1.2]), 260.0, n=30)
            branches.append(shoot)
            parents.append(0)
            labels.append(10 * n + 15)
            me = len(branches) - 1
            for k in range(shoots[n]):
                branches.append(_leaf(shoot[0] + (shoot[-1] - shoot[0]) * (30.0 * (k + 1) / 260.0), n + k + 3, 60.0))
                parents.append(me)
                labels.append(1000 * (10 * n + 15) + 10 * k + 11)
    return Trees.from_branches([branches], [parents], T=32, labels=[labels], dtype=torch.float64)


def scores(moving: Trees, reference: Trees, **overrides: object) -> tuple[float, float]:
    kw = {**NODES, **overrides}
    r = register_trees(moving, reference, rotation="vertical", **kw)
    s = identity_scores(r.matches, moving.label.tolist(), reference.label.tolist())
    return s.precision, s.recall


def test_nodes_positions_count_nodes_on_every_branch():
    """Leaves at node k of the stem and of a shoot sit at rank k; the shoot half a node above its node's leaf;
    ``"rank"`` keeps the shoot's leaves at their arc-length fractions."""
    tree = plant(60.0, {2: 8})
    lab = tree.label.tolist()
    nodes = prepare_tree(tree, (1.0, 1.0, 1.0), "nodes").s
    rank = prepare_tree(tree, (1.0, 1.0, 1.0), "rank").s
    at = {label: float(nodes[i]) for i, label in enumerate(lab)}
    assert [round(at[10 * n + 11], 6) for n in range(9)] == list(range(9))
    assert at[31] + 0.8 * AXIL_OFFSET < at[35] <= at[31] + AXIL_OFFSET  # the shoot carries 1.8x its length
    assert [round(at[35000 + 10 * k + 11], 6) for k in range(8)] == list(range(8))
    shoot_leaves = [float(rank[i]) for i, label in enumerate(lab) if label > 1000]
    assert max(shoot_leaves) < 1.0  # arc-length fractions
    assert "nodes" in POSITIONS


@pytest.mark.parametrize("shoots_a, shoots_b", [({3: 8}, {3: 8, 6: 8}), ({2: 8}, {5: 7})])
def test_leaf_is_not_matched_to_the_shoot_in_its_axil(shoots_a, shoots_b):
    """Plant B has a shoot at a node where plant A has only the leaf (and its internodes are 20 % shorter).
    ``"nodes"`` positions match every leaf to the leaf of its node and leave an unshared shoot unmatched. Node
    ranks on the main branch alone ("rank"), with the axil offset off (a planted bug) or with the old weight
    (lp 12), match a leaf to the larger shoot (in SRVF a longer curve is closer than none) or a shoot to one at
    another node."""
    a, b = plant(60.0, shoots_a), plant(48.0, shoots_b)
    precision, recall = scores(a, b)
    assert precision == 1.0 and recall == 1.0, (precision, recall)
    assert min(scores(a, b, positions="rank", lambdas=(1.0, 1.0, 12.0))) < 0.95


@pytest.mark.parametrize("bug", [{"AXIL_OFFSET": 0.0}, {"AXIS_CARRIES": 100.0}])
def test_planted_bug_pairs_a_leaf_with_the_shoot_in_its_axil(monkeypatch, bug):
    """Without the axil offset (or with no child taken for an axis) the leaf at node 3 of plant A goes to the shoot
    that plant B carries there."""
    a, b = plant(60.0, {}), plant(48.0, {3: 8})
    for name, value in bug.items():
        monkeypatch.setattr(prepare_module, name, value)
    assert scores(a, b)[0] < 1.0


def _with_extra(tree: Trees, parent: int, start: np.ndarray, direction: np.ndarray, length: float,
                label: int) -> Trees:
    """``tree`` with one more straight branch on branch ``parent``."""
    branches = [p.numpy() for p in tree.points]
    return Trees.from_branches([[*branches, _line(start, direction, length)]], [[*tree.parent.tolist(), parent]],
                               T=32, labels=[[*tree.label.tolist(), label]], dtype=torch.float64)


def _positions(tree: Trees) -> dict[int, float]:
    s = prepare_tree(tree, (1.0, 1.0, 1.0), "nodes").s
    return {label: float(s[i]) for i, label in enumerate(tree.label.tolist())}


@pytest.mark.parametrize("bug", [None, {"AXIS_MIN_WEIGHT": 0.0}])
def test_leaflets_keep_their_arc_length_fractions(monkeypatch, bug):
    """A leaf carrying four 20 mm leaflets is no axis (it carries 0.5x its length): its leaflets keep their
    arc-length fractions (paired leaflets a few % apart come in either order between plants, and a rachis's spurs
    are long beside it); ranked like a shoot's leaves (a planted bug) they count nodes."""
    for name, value in (bug or {}).items():
        monkeypatch.setattr(prepare_module, name, value)
    tree = plant(30.0, {})
    leaf = tree.points[1].numpy()
    for k in range(4):
        tree = _with_extra(tree, 1, leaf[0] + (leaf[-1] - leaf[0]) * (0.2 + 0.2 * k), np.array([0.0, 1.0, 0.0]),
                           20.0, 9000 + k)
    at = _positions(tree)
    fractions = [at[9000 + k] for k in range(4)]
    if bug:
        assert fractions[-1] > 2.0
    else:
        assert np.allclose(fractions, [0.2, 0.4, 0.6, 0.8], atol=0.05), fractions


def test_a_spur_on_a_stem_shorter_than_its_leaves_counts_no_node():
    """A 5 mm skeleton spur below the first leaf of an 80 mm stem carrying 150 mm leaves: measured against the stem's
    length it would count 0.69 of a node and shift every leaf above it (every leaf of a plant without the spur a
    node off: our synthetic tomatoes' hypocotyl spurs); measured against the stem's organs (the median node) it counts
    under 0.1, and the leaves of two such plants, one with the spur, pair with each other."""
    a, b = plant(8.0, {}), plant(7.0, {})
    a = _with_extra(a, 0, np.array([0.0, 0.0, 4.0]), np.array([1.0, 0.0, 0.0]), 5.0, 99)
    at = _positions(a)
    assert 1.0 - math.exp(-((5.0 / (prepare_module.NODE_SIGNIFICANT * 80.0)) ** prepare_module.NODE_POWER)) > 0.6
    assert at[99] == 0.0 and 0.0 < at[11] < 0.1, at  # the case is real: the stem's length alone would count 0.69
    assert np.allclose([at[10 * n + 11] - at[11] for n in range(9)], range(9), atol=1e-6)
    precision, recall = scores(a, b)
    assert precision == 1.0 and recall == 1.0, (precision, recall)
