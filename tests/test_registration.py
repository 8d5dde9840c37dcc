"""Registration of 3D trees: invariances, null branches, the metric, batching, real and synthetic data."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from torch4dtree.curves import random_warp, srvf_sq_norm, warp_curve
from torch4dtree.curves.rotation import axis_rotation, random_rotation
from torch4dtree.trees.aligned import AlignedTrees, subtree_sq_norms
from torch4dtree.trees.correspondence import branch_accuracy, cycle_consistency, map_points
from torch4dtree.trees.registration import (
    index_order_matches,
    pairwise_distances,
    register_to_reference,
    register_trees,
)
from torch4dtree.trees.structures import Trees

T = 24


# ----------------------------------------------------------------------------- tree generators


def _curve(rng, n, length, start, direction):
    d = np.asarray(direction, float)
    d /= np.linalg.norm(d)
    bend = rng.normal(scale=0.5, size=(2, 3))
    t = np.linspace(0, 1, n)[:, None]
    pts = t * d + t**2 * bend[0] * 0.4 + np.sin(np.pi * t) * bend[1] * 0.3
    return pts / np.linalg.norm(np.diff(pts, axis=0), axis=1).sum() * length + start


def random_tree(rng, n_side=(3, 5), depth=3, T=T, extra=None):
    """A plant-like random tree, labels 0..N-1 in generation order; ``extra`` = (s, length) adds one branch."""
    main = _curve(rng, 40, 30.0, np.zeros(3), [0, 0, 1])
    br, par, lengths, frontier = [main], [-1], [30.0], [0]
    for lev in range(depth - 1):
        new = []
        for b in frontier:
            k = int(rng.integers(n_side[0], n_side[1] + 1)) if lev == 0 else int(rng.integers(0, 3))
            for s in np.sort(rng.uniform(0.1, 0.9, size=k)):
                p = br[b]
                frac = np.concatenate([[0], np.linalg.norm(np.diff(p, axis=0), axis=1).cumsum()]) / lengths[b]
                ang = rng.uniform(0, 2 * math.pi)
                length = lengths[b] * rng.uniform(0.25, 0.5)
                br.append(_curve(rng, 25, length, p[int(np.searchsorted(frac, s))], [math.cos(ang), math.sin(ang),
                                                                                      rng.uniform(0.2, 1.0)]))
                par.append(b)
                lengths.append(length)
                new.append(len(br) - 1)
        frontier = new
    if extra is not None:
        s, length = extra
        k = int(s * (len(main) - 1))
        br.append(_curve(np.random.default_rng(99), 25, length, main[k], [-1.0, 0.3, 0.5]))
        par.append(0)
    return Trees.from_branches([br], [par], T=T, labels=[list(range(len(br)))], dtype=torch.float64)


def _restore_order(points, parent, s, label):
    """Depth-first order with children sorted by ``s`` (the Trees convention), from any parent-first order."""
    N = len(parent)
    children = [[] for _ in range(N)]
    for i, p in enumerate(parent):
        if p >= 0:
            children[p].append(i)
    order, stack = [], [0]
    while stack:
        k = stack.pop()
        order.append(k)
        stack.extend(sorted(children[k], key=lambda c: -float(s[c])))
    new = {k: i for i, k in enumerate(order)}
    return Trees(points[order], torch.tensor([-1 if parent[k] < 0 else new[parent[k]] for k in order]),
                 s[order], torch.tensor([N]), label[order])


def transformed_copy(tree, gen, rotation="none", strength=0.8):
    """The same tree rotated about its root, translated, every branch reparameterised (children moved
    with their parent's warp, so their order along the parent may change), stored in a new order."""
    N, Tn, _ = tree.points.shape
    g = random_warp(N, Tn, generator=gen, strength=strength)
    pts = warp_curve(tree.points, g)
    grid = np.linspace(0, 1, Tn)
    s = tree.s.clone()
    parent = tree.parent.tolist()
    for i, p in enumerate(parent):
        if p >= 0:
            s[i] = float(np.interp(float(tree.s[i]), g[p].numpy(), grid))
    if rotation == "so3":
        O = random_rotation(1, 3, generator=gen)[0]
    elif rotation == "vertical":
        O = axis_rotation(torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64), torch.tensor([2.0]))[0]
    else:
        O = torch.eye(3, dtype=torch.float64)
    root = tree.points[0, 0]
    pts = (pts - root) @ O.T + root + torch.tensor([1.0, -2.0, 0.5], dtype=torch.float64)
    # the warps move children along their parents, so re-sorting by s permutes the side subtrees
    # (the labels keep the ground truth)
    return _restore_order(pts, parent, s, tree.label)


def _tree_norm(tree, lambdas=(1.0, 1.0, 1.0)):
    return math.sqrt(float(AlignedTrees.from_trees(tree, lambdas).sq_norm()[0]))


# ----------------------------------------------------------------------------- invariances


def test_self_distance_is_zero():
    A = random_tree(np.random.default_rng(0))
    r = register_trees(A, A)
    assert float(r.distance) < 1e-9 and float(r.distance_before) < 1e-9
    assert r.matches == [(i, i) for i in range(int(A.num_branches[0]))]
    assert r.unmatched_moving == [] and r.unmatched_reference == []


@pytest.mark.parametrize("rotation", ["none", "vertical", "so3"])
def test_invariance_to_rotation_warps_and_permutations(rotation):
    rng = np.random.default_rng(1)
    gen = torch.Generator().manual_seed(1)
    A = random_tree(rng, n_side=(6, 8), T=32)  # close siblings: the warps reorder some of them
    B = transformed_copy(A, gen, rotation, strength=1.2)
    assert any(int(B.label[a]) != int(A.label[b]) for a, b in index_order_matches(B, A))  # order is wrong
    # strong warps (slopes beyond 4): the DP needs the larger neighbourhood of the reference (6)
    r = register_trees(B, A, rotation=rotation, neighbourhood=6)
    norm = _tree_norm(A)
    assert float(r.distance) < 0.12 * norm, (float(r.distance), norm)
    assert float(r.distance) < 0.5 * float(r.distance_before)
    assert branch_accuracy(r, B, A) == 1.0
    if rotation != "none":  # the recovered rotation undoes the applied one (up to the residual)
        assert torch.linalg.det(r.rotation).item() == pytest.approx(1.0, abs=1e-9)
    cc = cycle_consistency(B, A, rotation=rotation, neighbourhood=6)
    assert float(cc.error[1]) < 0.02 and cc.unmatched == 0.0


def test_symmetry():
    rng = np.random.default_rng(2)
    A, B = random_tree(rng), random_tree(rng)
    d12 = float(register_trees(A, B).distance)
    d21 = float(register_trees(B, A).distance)
    assert abs(d12 - d21) <= 0.1 * max(d12, d21)


@pytest.mark.parametrize("rotation", ["none", "vertical"])
def test_never_worse_than_index_order(rotation):
    rng = np.random.default_rng(3)
    for _ in range(4):
        A, B = random_tree(rng, n_side=(1, 6)), random_tree(rng, n_side=(1, 6))
        r = register_trees(A, B, rotation=rotation, lambdas=(1.0, 2.0, 0.5))
        assert float(r.distance) <= float(r.distance_before) + 1e-9


def test_added_branch_costs_its_length():
    rng_seed = 4
    A = random_tree(np.random.default_rng(rng_seed))
    B = random_tree(np.random.default_rng(rng_seed), extra=(0.6, 7.0))
    extra = int((B.label == int(B.num_branches[0]) - 1).nonzero()[0])
    length = float(B.branch_lengths()[extra])
    for ls in (1.0, 2.0):
        r = register_trees(B, A, lambdas=(1.0, ls, 1.0))
        assert r.unmatched_moving == [extra] and r.unmatched_reference == []
        assert float(r.distance) ** 2 == pytest.approx(ls * length, rel=0.05)


# ----------------------------------------------------------------------------- the metric


def _recursive_sq(al: AlignedTrees, slot: int) -> float:
    lm, ls, lp = al.lambdas
    out = lm * float(srvf_sq_norm(al.q[0, slot] - al.q[1, slot]))
    for c in (al.slot_parent == slot).nonzero()[:, 0].tolist():
        out += lp * float(al.s[0, c] - al.s[1, c]) ** 2 + ls * _recursive_sq(al, c)
    return out


def test_features_norm_is_the_recursive_metric():
    rng = np.random.default_rng(5)
    A, B = random_tree(rng), random_tree(rng)
    lam = (1.5, 0.7, 0.6)
    r = register_trees(A, B, lambdas=lam)
    al = r.aligned
    f = al.features()
    assert float((f[0] - f[1]).norm()) == pytest.approx(float(r.distance), rel=1e-9)
    assert float((f[0] - f[1]).square().sum()) == pytest.approx(_recursive_sq(al, 0), rel=1e-9)
    # norm of a tree = its recursive subtree norm (distance to the null tree)
    one = AlignedTrees.from_trees(A, lam)
    norms = subtree_sq_norms(A.branch_lengths().tolist(), A.parent.tolist(), lam)
    assert float(one.sq_norm()[0]) == pytest.approx(norms[0], rel=1e-9)
    back = AlignedTrees.from_features(f, al)
    assert torch.allclose(back.q, al.q) and torch.allclose(back.s[:, 1:], al.s[:, 1:])
    # .to casts the float parts and keeps the layout; the metric survives the round trip
    low = al.to(torch.float32)
    assert low.q.dtype == low.s.dtype == low.root.dtype == torch.float32 and low.source.dtype == torch.long
    assert torch.equal(low.slot_parent, al.slot_parent) and torch.equal(low.present, al.present)
    assert float(low.to("cpu", torch.float64).sq_distances()[0, 1]) == pytest.approx(float(r.distance) ** 2, rel=1e-5)


def test_distance_before_is_index_order_and_differentiable():
    rng = np.random.default_rng(6)
    A, B = random_tree(rng), random_tree(rng)
    m = index_order_matches(A, B)
    assert m[0] == (0, 0) and len(m) <= min(int(A.num_branches[0]), int(B.num_branches[0]))
    assert len(m) == len({j for _, j in m})
    pts = A.points.clone().requires_grad_(True)
    r = register_trees(A.with_points(pts), B)
    r.distance.backward()
    assert pts.grad is not None and torch.isfinite(pts.grad).all() and pts.grad.abs().sum() > 0


def test_many_to_one_matches_one_by_one_and_pairwise():
    rng = np.random.default_rng(7)
    trees = [random_tree(rng, n_side=(2, 3), depth=2) for _ in range(3)]
    batch = Trees.cat(trees)
    many = register_to_reference(batch[1:], trees[0])
    for k, res in enumerate(many):
        single = register_trees(trees[k + 1], trees[0])
        assert float(res.distance) == pytest.approx(float(single.distance), rel=1e-9)
        assert res.matches == single.matches
    D = pairwise_distances(batch, processes=1, progress=False)
    assert torch.allclose(D, D.T) and torch.all(D.diagonal() == 0)
    assert float(D[0, 1]) == pytest.approx(float(many[0].distance), rel=1e-9)


def test_pairwise_distances_in_processes(monkeypatch):
    import torch4dtree.trees.registration as reg

    monkeypatch.setattr(reg, "MIN_PAIRS_PER_PROCESS", 1)  # force the pool even for 3 pairs
    rng = np.random.default_rng(8)
    batch = Trees.cat([random_tree(rng, n_side=(1, 2), depth=2, T=16) for _ in range(3)])
    D1 = pairwise_distances(batch, processes=1, progress=False)
    D2 = pairwise_distances(batch, processes=2, progress=False)
    assert torch.allclose(D1, D2)


def test_map_points_follows_the_warp():
    rng = np.random.default_rng(9)
    A = random_tree(rng, depth=2)
    r = register_trees(A, A)
    b, t = map_points(r, torch.tensor([0, 1, 1]), torch.tensor([0.0, 0.5, 1.0], dtype=torch.float64))
    assert b.tolist() == [0, 1, 1] and torch.allclose(t, torch.tensor([0.0, 0.5, 1.0], dtype=torch.float64))


# ----------------------------------------------------------------------------- data


def test_pheno4d_consecutive_days():
    from conftest import PHENO4D, pheno4d

    from torch4dtree.bench.trees import consecutive_pairs

    pheno4d("swc")  # skips (fails in CI) without the data
    pairs = consecutive_pairs(PHENO4D, T=T, max_pairs=None)
    picked = [p for p in pairs if p[1].startswith(("Tomato_4:T04_0311", "tomato_2:T02_0311", "Maize01:M01_0319"))]
    assert picked
    for _, name, a, b in picked:
        r = register_trees(b, a)
        assert float(r.distance) < float(r.distance_before), name


def test_register_cli(tmp_path, capsys):
    import json

    from torch4dtree.io import write_swc

    rng = np.random.default_rng(13)
    a, b = tmp_path / "a.swc", tmp_path / "b.swc"
    write_swc(a, random_tree(rng, depth=2, T=16))
    write_swc(b, random_tree(rng, depth=2, T=16))
    from torch4dtree.cli import main

    out = tmp_path / "out"
    assert main(["register", str(a), str(b), "--json", "--T", "16", "--out", str(out), "--steps", "3"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["distance_after"] <= res["distance_before"] + 1e-9 and res["matches"][0] == [0, 0]
    assert len(list(out.glob("*.swc"))) == 5
    assert main(["register", str(a), str(b), "--T", "16", "--out", str(out)]) == 2  # never overwrites
    assert main(["register", str(a), str(b), "--T", "16", "--out", str(out), "--overwrite"]) == 0


def test_invariance_with_default_settings_moderate_warps():
    A = random_tree(np.random.default_rng(14), T=32)
    B = transformed_copy(A, torch.Generator().manual_seed(14), "vertical", strength=0.5)
    r = register_trees(B, A, rotation="vertical")
    assert float(r.distance) < 0.12 * _tree_norm(A) and branch_accuracy(r, B, A) == 1.0


def test_children_aware_parent_warp():
    """A straight stem carries one child at s = 0.3 in A and 0.6 in B. The stem's own DP warp is the
    identity (any other stretches it), which leaves the child 0.3 away: with a large lp the metric's
    infimum instead warps the stem so the child lands on its partner (stem cost L int (1 - sqrt(g'))^2)."""
    import torch4dtree.trees.registration as reg

    stem = torch.stack([torch.zeros(T), torch.zeros(T), torch.linspace(0, 1, T)], 1).double()
    leaf = torch.stack([torch.linspace(0, 0.8, T), torch.zeros(T), torch.zeros(T)], 1).double()
    A = Trees.from_branches([[stem.numpy(), (leaf + torch.tensor([0, 0, 0.3])).numpy()]], [[-1, 0]], T=T,
                            dtype=torch.float64)
    B = Trees.from_branches([[stem.numpy(), (leaf + torch.tensor([0, 0, 0.6])).numpy()]], [[-1, 0]], T=T,
                            dtype=torch.float64)
    lam = (1.0, 1.0, 10.0)  # matching the children (<= 0.9) beats leaving both unmatched (1.6)
    with_refit = register_trees(A, B, lambdas=lam, lp_relative=False)  # lp in the data's units
    rounds = reg.LANDMARK_ROUNDS
    try:
        reg.LANDMARK_ROUNDS = 0
        stem_only = register_trees(A, B, lambdas=lam, lp_relative=False)
    finally:
        reg.LANDMARK_ROUNDS = rounds
    assert with_refit.matches == stem_only.matches == [(0, 0), (1, 1)]
    assert float(stem_only.distance) ** 2 == pytest.approx(10 * 0.3 ** 2, rel=0.05)
    # the piecewise-linear warp through (0.6, 0.3) costs 0.6 (1 - sqrt(0.5))^2 + 0.4 (1 - sqrt(1.75))^2 = 0.093
    assert float(with_refit.distance) ** 2 < 0.2
    s_child = with_refit.aligned.s[0, 1]
    assert abs(float(s_child) - 0.6) < 0.1


def test_all_pairs_benchmark_counts_every_frame():
    from conftest import PHENO4D, pheno4d

    from torch4dtree.bench.trees import benchmark_all_pairs, plant_frames

    pheno4d("swc")
    n = sum(t is not None for _, _, _, ts in plant_frames(PHENO4D, T=8, kinds=("maize",)) for t in ts)
    r = benchmark_all_pairs(PHENO4D, T=8, kind="maize", processes=1)
    assert r["trees"] == n > 10 and r["pairs"] == n * (n - 1) // 2 and r["finite"] and r["seconds"] > 0


def test_lambdas_checked_in_the_specs_order():
    A = random_tree(np.random.default_rng(21), depth=2)
    assert float(register_trees(A, A, lambdas=(1.0, 1.0, 0.0)).distance) < 1e-9  # lp = 0: positions ignored
    for bad in ((1.0, 0.0, 1.0), (0.0, 1.0, 1.0), (1.0, 1.0, -1.0), (1.0, 1.0), (1.0, float("nan"), 1.0)):
        with pytest.raises(ValueError, match="lm > 0, ls > 0, lp >= 0"):
            register_trees(A, A, lambdas=bad)
