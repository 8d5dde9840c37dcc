"""Geodesics between registered 3D trees and decoding of the aligned layout."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from samples import random_tree

from torch4dtree.curves import interpolate_curve
from torch4dtree.trees.aligned import AlignedTrees
from torch4dtree.trees.geodesic import geodesic, geodesic_aligned
from torch4dtree.trees.registration import register_trees


@pytest.fixture(scope="module")
def registration():
    rng = np.random.default_rng(11)
    A = random_tree(rng, n_side=(3, 4), T=24)
    B = random_tree(rng, n_side=(4, 5), T=24)
    return A, B, register_trees(A, B, positions="warped")  # the layout's metric: the geodesic's length


def _same_tree(x, y, atol=5e-2):  # decoding re-resamples in arc length: points move by < 1e-3 of the size
    assert x.num_branches.tolist() == y.num_branches.tolist()
    assert x.parent.tolist() == y.parent.tolist()
    assert torch.allclose(x.s, y.s, atol=atol)
    assert torch.allclose(x.points, y.points, atol=atol)


def test_roundtrip_one_tree():
    A = random_tree(np.random.default_rng(10), T=24)
    back = AlignedTrees.from_trees(A).to_trees()
    _same_tree(back, A)
    assert back.label.tolist() == list(range(int(A.num_branches[0])))


def test_endpoints(registration):
    A, B, r = registration
    path = geodesic(r, 5)
    assert path.num_trees == 5
    # last = the reference, first = the registered moving tree (A with its warps and null slots dropped)
    _same_tree(path[4], B.to(torch.float64))
    first = path[0]
    assert int(first.num_branches[0]) == int(A.num_branches[0])
    assert sorted(first.label.tolist()) == sorted(r.aligned.source[0].ge(0).nonzero()[:, 0].tolist())
    assert torch.allclose(first.root(), A.root()) and torch.allclose(path[4].root(), B.root())
    assert torch.allclose(first.total_length(), A.total_length(), rtol=1e-2)  # warps cut corners slightly


def test_midpoints_children_on_parents(registration):
    _, _, r = registration
    path = geodesic(r, 5)
    for k in range(1, 4):
        tree = path[k]
        side = tree.parent >= 0
        assert torch.allclose(tree.points[side, 0], tree.attachment_points()[side], atol=1e-6)


def test_path_is_straight_at_constant_speed(registration):
    _, _, r = registration
    line = geodesic_aligned(r, 6)
    f = line.features()
    steps = (f[1:] - f[:-1]).norm(dim=1)
    assert torch.allclose(steps, torch.full_like(steps, float(r.distance) / 5), rtol=1e-9)
    assert float(steps.sum()) == pytest.approx(float(r.distance), rel=1e-9)
    with pytest.raises(ValueError):
        geodesic(r, 1)


def test_decode_interpolated_s_on_parent():
    # a midpoint decoded: its side branches start at the parent's curve at the interpolated s
    rng = np.random.default_rng(12)
    A = random_tree(rng, depth=2, T=16)
    r = register_trees(A, A)
    mid = geodesic_aligned(r, 3)[1]
    tree = mid.to_trees()
    main = tree.points[0]
    for i in range(1, int(tree.num_branches[0])):
        on = interpolate_curve(main[None], tree.s[i].reshape(1, 1))[0, 0]
        assert torch.allclose(on, tree.points[i, 0], atol=1e-6)


@pytest.mark.parametrize("positions", ["arclength", "rank"])
def test_geodesic_of_registrations_comparing_other_positions(positions):
    """Registrations that compare children by arc length or node rank still write bifurcation parameters in their
    layout: the geodesic's ends are the two trees (children at their own places, not at a rank or an arc length
    read as a parameter), its midpoints keep every child on its parent, and the distance is the one with the
    compared positions (the layout's own, with warped positions, differs by the position terms only)."""
    rng = np.random.default_rng(15)
    A = random_tree(rng, n_side=(4, 5), T=24)
    B = random_tree(rng, n_side=(4, 5), T=24)
    assert len(set(B.s.tolist())) == len(B.s)  # no tied siblings: the decoded reference keeps B's branch order
    r = register_trees(A, B, positions=positions)
    path = geodesic(r, 3)
    _same_tree(path[2], B.to(torch.float64))
    first = path[0]
    matched_parent = {a for a, _ in r.matches}
    for i, label in enumerate(first.label.tolist()):  # children of unmatched parents keep A's own parameter
        a = int(r.aligned.source[0, label])
        if a > 0 and int(A.parent[a]) not in matched_parent:
            assert float(first.s[i]) == pytest.approx(float(A.s[a]), abs=1e-3)  # decoding re-resamples
    assert bool((path.s >= 0).all() and (path.s <= 1).all())
    side = path.parent >= 0
    assert torch.allclose(path.points[side, 0], path.attachment_points()[side], atol=1e-6)
    assert torch.allclose(first.total_length(), A.total_length().double(), rtol=1e-2)
    # the layout differs from the compared positions in the s terms only: with lp = 0 the distances are equal
    free = register_trees(A, B, lambdas=(1.0, 1.0, 0.0), positions=positions)
    f = free.aligned.features()
    assert float(free.distance) == pytest.approx(float((f[0] - f[1]).norm()), rel=1e-9)
