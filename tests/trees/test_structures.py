import numpy as np
import pytest
import torch
from conftest import random_tree_branches

from torch4dtree.curves import curve_length, project_on_polyline
from torch4dtree.trees.structures import TreeError, Trees, TreeSequence


def make_trees(rng, n=3, T=24):
    data = [random_tree_branches(rng, n_side=3, depth=3) for _ in range(n)]
    return Trees.from_branches([d[0] for d in data], [d[1] for d in data], T=T, dtype=torch.float64), data


def test_packing_invariants(rng):
    trees, data = make_trees(rng)
    assert trees.num_trees == 3 and trees.T == 24 and trees.dim == 3
    assert trees.num_branches.tolist() == [len(d[0]) for d in data]
    assert trees.ptr.tolist() == [0, *np.cumsum([len(d[0]) for d in data]).tolist()]
    depth, gp = trees.depth, trees.global_parent
    assert (depth[trees.main_index] == 0).all()
    side = gp >= 0
    assert torch.equal(depth[side], depth[gp[side]] + 1)
    assert (gp[side] < torch.arange(len(gp))[side]).all()
    assert trees.branches_per_layer()[0] == [1, 3, 6]


def test_children_start_on_their_parent_at_s(rng):
    trees, _ = make_trees(rng)
    side = trees.parent >= 0
    torch.testing.assert_close(trees.attachment_points()[side], trees.points[side, 0])
    # and s is where the child's first point projects on the parent
    gp = trees.global_parent[side]
    s, dist = project_on_polyline(trees.points[gp], trees.points[side, 0])
    assert dist.max() < 1e-9
    torch.testing.assert_close(s, trees.s[side])


def test_branches_are_uniform_in_arc_length(rng):
    trees, _ = make_trees(rng)
    seg = (trees.points[:, 1:] - trees.points[:, :-1]).norm(dim=-1)
    rel = (seg - seg.mean(1, keepdim=True)).abs() / seg.mean(1, keepdim=True)
    assert rel.max() < 0.05  # chords of a smooth curve at equal arc-length steps


def test_children_sorted_by_s_and_order_independent(rng):
    branches, parents = random_tree_branches(rng, n_side=4, depth=2)
    a = Trees.from_branches([branches], [parents], T=16, dtype=torch.float64)
    perm = [0, *(rng.permutation(len(branches) - 1) + 1).tolist()]
    inv = {old: new for new, old in enumerate(perm)}
    b = Trees.from_branches([[branches[i] for i in perm]], [[-1 if parents[i] < 0 else inv[parents[i]] for i in perm]],
                            T=16, dtype=torch.float64)
    torch.testing.assert_close(a.points, b.points)
    torch.testing.assert_close(a.s, b.s)
    side_s = a.s[a.parent == 0]
    assert (torch.diff(side_s) >= 0).all()


def test_index_cat_split_to_roundtrip(rng):
    trees, _ = make_trees(rng)
    parts = trees.split()
    again = Trees.cat(parts)
    for name in ("points", "parent", "s", "num_branches", "label"):
        assert torch.equal(getattr(again, name), getattr(trees, name))
    sub = trees[[2, 0]]
    assert sub.num_branches.tolist() == [trees.num_branches[2].item(), trees.num_branches[0].item()]
    torch.testing.assert_close(sub[1].points, trees[0].points)
    torch.testing.assert_close(trees[-1].points, trees[2].points)
    f32 = trees.to(torch.float32)
    assert f32.points.dtype == torch.float32 and f32.s.dtype == torch.float32 and f32.parent.dtype == torch.long
    with pytest.raises(IndexError):
        trees[5]
    # lists take negative indices like ints, and out-of-range ones fail instead of selecting nothing
    assert torch.equal(trees[[-1, 0]].points, trees[[2, 0]].points)
    assert torch.equal(trees[[-2, -1]].points, trees[1:].points)
    for bad in ([3], [0, -4]):
        with pytest.raises(IndexError):
            trees[bad]


def test_measures(rng):
    trees, data = make_trees(rng)
    raw_len = [sum(float(curve_length(torch.as_tensor(b))) for b in d[0]) for d in data]
    # resampling inscribes the curves and children are snapped onto their (resampled) parents
    for got, want in zip(trees.total_length().tolist(), raw_len):
        assert got == pytest.approx(want, rel=0.02)
    h = trees.height()
    for t, hh in enumerate(h.tolist()):
        pts = trees[t].points
        assert hh == pytest.approx(float(pts[..., 2].max() - pts[0, 0, 2]))


def test_translate_and_resample(rng):
    trees, _ = make_trees(rng)
    moved = trees.translate(torch.ones(3, 3, dtype=torch.float64))
    torch.testing.assert_close(moved.root(), trees.root() + 1)
    finer = trees.resample(48)
    assert finer.T == 48
    torch.testing.assert_close(finer.branch_lengths(), trees.branch_lengths(), rtol=1e-3, atol=0)


def test_bad_trees_are_rejected(rng):
    main = np.stack([np.zeros(5), np.zeros(5), np.linspace(0, 4, 5)], 1)
    with pytest.raises(TreeError, match="exactly one main branch"):
        Trees.from_branches([[main, main]], [[-1, -1]])
    with pytest.raises(TreeError, match="degenerate"):
        Trees.from_branches([[main, np.zeros((3, 3))]], [[-1, 0]])
    with pytest.raises(TreeError, match="NaN"):
        Trees.from_branches([[main + np.nan]], [[-1]])
    side = main + [1, 0, 0]
    with pytest.raises(TreeError, match="not connected"):
        Trees.from_branches([[main, side, side + 1]], [[-1, 2, 1]])
    with pytest.raises(TreeError, match="at least a main branch"):
        Trees.from_branches([[]], [[]])


def test_sequence_times_and_selection(rng):
    trees, _ = make_trees(rng)
    seq = TreeSequence(trees, torch.tensor([1.0, 3.0, 7.0], dtype=torch.float64), "p")
    torch.testing.assert_close(seq.normalized_times(), torch.tensor([0.0, 1 / 3, 1.0], dtype=torch.float64))
    assert len(seq[1:]) == 2 and seq[1:].times.tolist() == [3.0, 7.0]
    with pytest.raises(TreeError, match="increase"):
        TreeSequence(trees, torch.tensor([1.0, 1.0, 2.0]))
    with pytest.raises(TreeError, match="frames"):
        TreeSequence(trees, torch.tensor([1.0, 2.0]))


def test_to_branches_round_trip_and_sequence_to(rng):
    trees, _ = make_trees(rng, n=2)
    per_tree = trees.to_branches()
    again = Trees.from_branches([b for b, _ in per_tree], [p for _, p in per_tree], T=trees.T, dtype=torch.float64)
    # rebuilding re-resamples each polyline: points move along it by a small fraction of the spacing
    assert torch.equal(again.parent, trees.parent)
    spacing = trees.branch_lengths() / (trees.T - 1)
    assert ((again.points - trees.points).norm(dim=-1).amax(1) < 0.02 * spacing).all()
    torch.testing.assert_close(again.s, trees.s, atol=1e-3, rtol=0)
    seq = TreeSequence(trees, torch.tensor([0.0, 1.0]))
    f32 = seq.to(torch.float32)
    assert f32.times.dtype == torch.float32 and f32.frames.points.dtype == torch.float32
