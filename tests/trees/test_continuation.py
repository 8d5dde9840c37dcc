"""The continuation rule at a grass stem's apex: two like leaves a millimetre apart, the stem's apex between them."""

import math

import numpy as np
import pytest

from torch4dtree.trees.skeleton import skeleton_to_branches


def _leaf(start: np.ndarray, side: float, bend: float, n: int = 30, step: float = 10.0) -> np.ndarray:
    """``(n, 3)`` points of a leaf leaving ``start`` at 14 degrees from the vertical towards ``side * x`` and bending
    away by ``bend`` degrees in all over its length (evenly)."""
    angles = np.radians(14.0 + bend * np.arange(n) / (n - 1))
    steps = step * np.stack([side * np.sin(angles), np.zeros(n), np.cos(angles)], 1)
    return start + np.cumsum(steps, 0)


def _grass_top(stem_step: float = 10.0, jitter: float = 0.0) -> tuple[np.ndarray, np.ndarray, int, int]:
    """A straight stem 200 mm tall, leaf 3 leaving its top node, the stem running on 1 mm to its apex where leaf 4
    leaves on the other side, bending more than leaf 3 (so over any window the stem's side turns more). Returns
    ``(xyz, parent, top node, apex node)``; ``jitter`` (mm) moves the stem's nodes sideways (a scanned stem)."""
    rng = np.random.default_rng(0)
    z = np.arange(0.0, 200.0 + stem_step / 2, stem_step)
    stem = np.stack([np.zeros_like(z), np.zeros_like(z), z], 1)
    stem[1:-1, :2] += jitter * rng.standard_normal((len(z) - 2, 2))
    top = len(stem) - 1
    apex = np.array([[0.0, 0.0, 201.0]])
    leaf3, leaf4 = _leaf(stem[-1], 1.0, 30.0), _leaf(apex[0], -1.0, 60.0)
    xyz = np.concatenate([stem, leaf3, apex, leaf4])
    parent = [-1, *range(top)]
    parent += [top, *range(top + 1, top + len(leaf3))]
    apex_node = len(parent)
    parent += [top, apex_node, *range(apex_node + 1, apex_node + len(leaf4))]
    return xyz, np.asarray(parent), top, apex_node


@pytest.mark.parametrize("stem_step", [10.0, 2.5])
def test_a_straight_stem_goes_on_through_its_apex_between_two_like_leaves(stem_step):
    """Over the direction window the stem's side (1 mm of stem, then the more bent leaf 4) turns more than leaf 3;
    only the stem's first stretch, in line with the stem, says that the stem goes on there. Node spacing along the
    stem does not matter."""
    xyz, parent, top, apex = _grass_top(stem_step)
    main = skeleton_to_branches(xyz, parent)[2][0]
    assert top in main and apex in main, "the main branch left the stem for leaf 3"


def test_a_jittered_stem_keeps_the_straightest_child():
    """A stem that is not straight at its last edges (a scan, our synthetic kinds) gets no first-edge term: the
    child that turns least over the window goes on, as without the term."""
    xyz, parent, top, apex = _grass_top(jitter=1.5)
    main = skeleton_to_branches(xyz, parent)[2][0]
    assert top in main and apex not in main
    assert math.isclose(float(np.linalg.norm(xyz[apex] - xyz[top])), 1.0)
