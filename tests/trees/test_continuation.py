"""Which child continues a branch at a branch point (torch4dtree.trees.skeleton, the directed rules)."""

from __future__ import annotations

import numpy as np
import pytest

from torch4dtree.trees.skeleton import skeleton_to_branches


def _chain(xyz: list[np.ndarray], parent: list[int], start: int, direction: np.ndarray, length: float,
           step: float) -> list[int]:
    """Append a straight chain of nodes ``step`` apart from node ``start`` along ``direction``; its node indices."""
    d = direction / np.linalg.norm(direction)
    nodes, prev = [], start
    for k in range(1, int(round(length / step)) + 1):
        xyz.append(xyz[start] + k * step * d)
        parent.append(prev)
        prev = len(xyz) - 1
        nodes.append(prev)
    return nodes


def _shoot_with_upright_lateral(lateral: float, step: float = 10.0):
    """A vertical stem 300 mm; at 200 mm a shoot leaves at 50 degrees from the vertical, its first internode 10 mm
    long; at that first node an upright lateral (``lateral`` mm, parallel to the stem) leaves, while the shoot goes
    on 150 mm in its own direction. Returns ``(xyz, parent, shoot nodes after the first, lateral nodes)``."""
    xyz, parent = [np.zeros(3)], [-1]
    stem = _chain(xyz, parent, 0, np.array([0.0, 0, 1]), 300.0, step)
    node = stem[int(round(200.0 / step)) - 1]
    tilt = np.array([np.sin(np.radians(50)), 0.0, np.cos(np.radians(50))])
    first = _chain(xyz, parent, node, tilt, 10.0, 10.0)[-1]
    shoot = _chain(xyz, parent, first, tilt, 150.0, step)
    up = _chain(xyz, parent, first, np.array([0.0, 0.2, 1.0]), lateral, step)
    return np.array(xyz), np.array(parent), shoot, up


@pytest.mark.parametrize("lateral", [20.0, 100.0, 200.0])
@pytest.mark.parametrize("step", [10.0, 2.5])
def test_a_shoot_goes_on_past_an_upright_lateral_at_its_first_node(lateral: float, step: float) -> None:
    """The incoming direction at a shoot's first node is the shoot's first internode, not the stem it left: a
    lateral that grows up parallel to the stem must not take the shoot over once it is long (the window, half the
    lateral's length, then reaches far past the shoot's 10 mm first internode). The same branch on every day of
    the lateral's growth."""
    xyz, parent, shoot, up = _shoot_with_upright_lateral(lateral, step)
    _, parents, paths = skeleton_to_branches(xyz, parent, hierarchy="straightest")
    carrying = [i for i, p in enumerate(paths) if shoot[-1] in p]
    assert len(carrying) == 1 and shoot[0] in paths[carrying[0]]  # the shoot is one branch through its first node
    side = [i for i, p in enumerate(paths) if up[-1] in p]
    assert parents[side[0]] == carrying[0]  # the lateral hangs off the shoot
    assert parents[carrying[0]] == 0  # and the shoot off the stem
