"""Batched decoding of SRVF trees (`AlignedTrees.to_trees`).

Checked against the former tree-by-tree, slot-by-slot implementation, kept here as the reference
(`reference_to_trees`), and against properties that hold whatever the implementation: straight
branches decode exactly (lengths, attachment points), children start on their parents, dropped
slots take their descendants with them, gradients agree with the reference.
"""

from __future__ import annotations

import warnings

import pytest
import torch
from torch import Tensor

from torch4dtree.curves.srvf import (
    curve_length,
    interpolate_curve,
    inverse_srvf,
    resample_polylines,
    srvf,
    srvf_sq_norm,
)
from torch4dtree.trees.aligned import AlignedTrees
from torch4dtree.trees.structures import Trees

# ------------------------------------------------------------------------------ reference


def _ref_arc_fraction(curve: Tensor, s: Tensor) -> Tensor:
    T = curve.shape[0]
    seg = (curve[1:] - curve[:-1]).norm(dim=-1)
    total = seg.sum()
    if not bool(total > 0):
        return s
    cum = torch.cat([seg.new_zeros(1), seg.cumsum(0)])
    x = s * (T - 1)
    lo = int(torch.clamp(x.detach().floor(), 0, T - 2))
    frac = x - lo
    return ((cum[lo] + frac * seg[lo]) / total).clamp(0, 1)


def _ref_resample_or_keep(points: Tensor, T: int) -> Tensor:
    length = curve_length(points)
    out = points.clone()
    ok = length > 0
    if bool(ok.any()):
        counts = torch.full((int(ok.sum()),), points.shape[1], device=points.device)
        out[ok] = resample_polylines(points[ok], counts, T)
    return out


def reference_to_trees(a: AlignedTrees, eps: float = 1e-6) -> Trees:
    """The former implementation of ``AlignedTrees.to_trees``: a Python loop over trees and slots."""
    n, S, M, d = a.q.shape
    parent = a.slot_parent.tolist()
    lengths = srvf_sq_norm(a.q)
    pts_all: list[Tensor] = []
    par_all: list[int] = []
    s_all: list[Tensor] = []
    lab_all: list[int] = []
    counts: list[int] = []
    for t in range(n):
        keep = [True] * S
        for k in range(1, S):
            keep[k] = keep[parent[k]] and bool(lengths[t, k] > eps)
        curves: dict[int, Tensor] = {}
        arc_s: dict[int, Tensor] = {}
        for k in range(S):
            if not keep[k]:
                continue
            if k == 0:
                start = a.root[t]
                arc_s[k] = a.s.new_zeros(())
            else:
                pc = curves[parent[k]]
                sk = a.s[t, k].clamp(0, 1)
                start = interpolate_curve(pc[None], sk.reshape(1, 1))[0, 0]
                arc_s[k] = _ref_arc_fraction(pc, sk)
            curves[k] = inverse_srvf(a.q[t, k], start)
        children: dict[int, list[int]] = {k: [] for k in curves}
        for k in curves:
            if k > 0:
                children[parent[k]].append(k)
        order: list[int] = []
        stack = [0]
        while stack:
            k = stack.pop()
            order.append(k)
            stack.extend(sorted(children[k], key=lambda c: -float(arc_s[c].detach())))
        new = {k: i for i, k in enumerate(order)}
        pts_all.append(torch.stack([curves[k] for k in order]))
        par_all += [-1 if k == 0 else new[parent[k]] for k in order]
        s_all += [arc_s[k] for k in order]
        lab_all += order
        counts.append(len(order))
    raw = torch.cat(pts_all)
    T = M + 1
    dev = raw.device
    out = Trees(_ref_resample_or_keep(raw, T), torch.tensor(par_all, dtype=torch.long, device=dev),
                torch.stack(s_all).to(raw.dtype).clamp(0, 1), torch.tensor(counts, dtype=torch.long, device=dev),
                torch.tensor(lab_all, dtype=torch.long, device=dev))
    side = out.parent >= 0
    if bool(side.any()):
        pts = out.points.clone()
        gp = out.global_parent.tolist()
        for i in side.nonzero()[:, 0].tolist():
            # clone: the former code read a view of pts here, which made backward fail after the next
            # in-place write (the only change to it, values are the same)
            pts[i, 0] = interpolate_curve(pts[gp[i]].clone()[None], out.s[i].reshape(1, 1))[0, 0]
        out = out.with_points(pts)
    return out


# ------------------------------------------------------------------------------ random layouts


def random_layout(gen: torch.Generator, S: int, max_depth: int = 3) -> Tensor:
    """``(S,)`` slot parents (parents first) with layers up to ``max_depth``."""
    parent, depth = [-1], [0]
    for _ in range(1, S):
        allowed = [k for k in range(len(parent)) if depth[k] < max_depth]
        p = allowed[int(torch.randint(len(allowed), (1,), generator=gen))]
        parent.append(p)
        depth.append(depth[p] + 1)
    return torch.tensor(parent)


def random_aligned(gen: torch.Generator, n: int, S: int, T: int = 12, dtype: torch.dtype = torch.float64,
                   eps: float = 0.05, straight: bool = False) -> AlignedTrees:
    """Random trees in one layout with null slots, slots just below ``eps``, and equal-``s`` siblings."""
    parent = random_layout(gen, S)
    M = T - 1
    if straight:  # constant SRVF: straight branches
        q = torch.randn(n, S, 1, 3, generator=gen, dtype=torch.float64).expand(n, S, M, 3).clone()
    else:
        q = torch.randn(n, S, M, 3, generator=gen, dtype=torch.float64)
    u = torch.rand(n, S, generator=gen)
    q[u < 0.15] = 0  # null branches
    short = (u >= 0.15) & (u < 0.3)  # nearly null: length eps / 2 (dropped with their descendants)
    q[short] *= (eps / 2 / srvf_sq_norm(q[short])).sqrt()[:, None, None]
    s = torch.rand(n, S, generator=gen, dtype=torch.float64) * 1.2 - 0.1  # some outside [0, 1]: clamped
    # ties: siblings sharing a parent take the same s in half of the trees
    for p in set(parent[1:].tolist()):
        sib = (parent == p).nonzero()[:, 0]
        if len(sib) > 1:
            s[: n // 2, sib[1:]] = s[: n // 2, sib[:1]]
    s[:, 0] = 0
    s[:, 1] = 0.0  # exactly at a parent's start ...
    if S > 2:
        s[:, 2] = 1.0  # ... and end
    root = torch.randn(n, 3, generator=gen, dtype=torch.float64)
    depth = torch.zeros(S, dtype=torch.long)
    for k in range(1, S):
        depth[k] = depth[parent[k]] + 1
    present = srvf_sq_norm(q) > 0
    source = torch.full((n, S), -1, dtype=torch.long)
    return AlignedTrees(q.to(dtype), s.to(dtype), present, root.to(dtype), parent, depth, source)


def assert_same_trees(a: Trees, b: Trees, atol: float) -> None:
    assert torch.equal(a.num_branches, b.num_branches)
    assert torch.equal(a.label, b.label)
    assert torch.equal(a.parent, b.parent)
    assert a.dtype == b.dtype
    torch.testing.assert_close(a.s, b.s, atol=atol, rtol=0)
    torch.testing.assert_close(a.points, b.points, atol=atol, rtol=0)


# ------------------------------------------------------------------------------ tests


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_matches_reference(dtype: torch.dtype, seed: int) -> None:
    gen = torch.Generator().manual_seed(seed)
    eps = 0.05
    a = random_aligned(gen, n=12, S=25, dtype=dtype, eps=eps)
    out, ref = a.to_trees(eps), reference_to_trees(a, eps)
    assert out.num_branches.min() < 25 and out.num_branches.max() > 1  # slots really were dropped and kept
    assert out.depth.max() >= 2
    assert_same_trees(out, ref, atol=1e-10 if dtype == torch.float64 else 1e-4)


def test_matches_reference_on_ties_and_single_slot() -> None:
    gen = torch.Generator().manual_seed(5)
    a = random_aligned(gen, n=4, S=8)
    a = AlignedTrees(a.q, torch.full_like(a.s, 0.5), a.present, a.root, a.slot_parent, a.slot_depth, a.source)
    assert_same_trees(a.to_trees(0.05), reference_to_trees(a, 0.05), atol=1e-10)
    one = a[[0]]
    one = AlignedTrees(one.q[:, :1], one.s[:, :1], one.present[:, :1], one.root, one.slot_parent[:1],
                       one.slot_depth[:1], one.source[:, :1])
    assert_same_trees(one.to_trees(), reference_to_trees(one), atol=1e-12)


def test_dropped_slots_take_their_descendants() -> None:
    gen = torch.Generator().manual_seed(3)
    eps = 0.05
    a = random_aligned(gen, n=10, S=30, eps=eps)
    out = a.to_trees(eps)
    parent = a.slot_parent.tolist()
    long_enough = (srvf_sq_norm(a.q) > eps).tolist()
    ptr = out.ptr.tolist()
    for t in range(a.num_trees):
        labels = out.label[ptr[t]: ptr[t + 1]].tolist()
        expected = []
        for k in range(a.num_slots):
            chain, ok = k, True
            while chain > 0:
                ok = ok and long_enough[t][chain]
                chain = parent[chain]
            if ok:
                expected.append(k)
        assert sorted(labels) == expected
        local_parent = out.parent[ptr[t]: ptr[t + 1]].tolist()
        assert [parent[k] for k in labels[1:]] == [labels[p] for p in local_parent[1:]]


def test_depth_first_children_by_increasing_s() -> None:
    gen = torch.Generator().manual_seed(4)
    out = random_aligned(gen, n=8, S=30).to_trees(0.05)
    gp, s = out.global_parent.tolist(), out.s.tolist()
    ptr = out.ptr.tolist()
    for t in range(out.num_trees):
        idx = range(ptr[t], ptr[t + 1])
        for i in idx:  # the subtree of i is the contiguous range after it
            kids = [j for j in idx if gp[j] == i]
            assert [s[j] for j in kids] == sorted(s[j] for j in kids)
            sub, end = {i}, i + 1
            while end < ptr[t + 1] and gp[end] in sub:
                sub.add(end)
                end += 1
            assert all(gp[j] not in sub for j in range(end, ptr[t + 1]))


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_straight_branches_decode_exactly(dtype: torch.dtype) -> None:
    """Straight branches survive resampling unchanged: lengths and attachment points are exact."""
    gen = torch.Generator().manual_seed(6)
    eps = 0.05
    a = random_aligned(gen, n=6, S=20, eps=eps, straight=True, dtype=dtype)
    out = a.to_trees(eps)
    tol = 1e-10 if dtype == torch.float64 else 1e-4
    lengths = srvf_sq_norm(a.q).reshape(-1)[out.tree_index * a.num_slots + out.label]
    torch.testing.assert_close(out.branch_lengths(), lengths, atol=tol, rtol=tol)
    torch.testing.assert_close(out.points[:, 0], out.attachment_points(), atol=tol, rtol=0)
    torch.testing.assert_close(out.root(), a.root, atol=tol, rtol=0)
    # the arc-length fraction of a straight parent is its parameter s (clamped)
    side = out.parent >= 0
    s_in = a.s.clamp(0, 1).reshape(-1)[out.tree_index * a.num_slots + out.label]
    torch.testing.assert_close(out.s[side], s_in[side], atol=tol, rtol=0)


def test_children_start_on_their_parents() -> None:
    gen = torch.Generator().manual_seed(7)
    out = random_aligned(gen, n=6, S=30).to_trees(0.05)
    torch.testing.assert_close(out.points[:, 0], out.attachment_points(), atol=1e-12, rtol=0)


def test_round_trip_of_a_tree() -> None:
    gen = torch.Generator().manual_seed(8)
    tree = random_aligned(gen, n=1, S=12, T=16, straight=True).to_trees(0.05)  # exact: no chord effects
    back = AlignedTrees.from_trees(tree).to_trees(0.0)
    assert torch.equal(back.label, torch.arange(len(tree.label)))  # slot i = branch i
    assert torch.equal(back.parent, tree.parent)
    torch.testing.assert_close(back.s, tree.s, atol=1e-9, rtol=0)
    torch.testing.assert_close(back.points, tree.points, atol=1e-9, rtol=0)


@pytest.fixture
def no_scalars_with_grad(monkeypatch: pytest.MonkeyPatch) -> None:
    """``float()`` / ``.item()`` of a tensor that requires grad raises (torch only warns, and only once)."""
    for name in ("__float__", "item"):
        original = getattr(torch.Tensor, name)

        def guarded(self: Tensor, *args: object, _original=original, _name=name) -> object:
            if self.requires_grad:
                raise AssertionError(f"{_name} of a tensor that requires grad")
            return _original(self, *args)

        monkeypatch.setattr(torch.Tensor, name, guarded)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_gradients_match_reference_without_warnings(dtype: torch.dtype, no_scalars_with_grad: None) -> None:
    gen = torch.Generator().manual_seed(9)
    a = random_aligned(gen, n=5, S=15, dtype=dtype)
    # s away from 0 and 1, where the clamps' one-sided gradients hinge on rounding
    a = AlignedTrees(a.q, a.s.clamp(0.05, 0.95), a.present, a.root, a.slot_parent, a.slot_depth, a.source)
    weights = None
    grads = []
    for decode in (AlignedTrees.to_trees, reference_to_trees):
        q, s, root = (x.detach().clone().requires_grad_(True) for x in (a.q, a.s, a.root))
        b = AlignedTrees(q, s, a.present, root, a.slot_parent, a.slot_depth, a.source)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            out = decode(b, 0.05)
        if weights is None:
            w = torch.Generator().manual_seed(0)
            weights = (torch.randn(out.points.shape, generator=w).to(dtype),
                       torch.randn(out.s.shape, generator=w).to(dtype))
        ((out.points * weights[0]).sum() + (out.s * weights[1]).sum()).backward()
        grads.append((q.grad, s.grad, root.grad))
    tol = 1e-9 if dtype == torch.float64 else 1e-3
    for g, g_ref in zip(*grads):
        assert g is not None and torch.isfinite(g).all()
        torch.testing.assert_close(g, g_ref, atol=tol, rtol=tol)
    assert grads[0][0].abs().sum() > 0 and grads[0][1][:, 1:].abs().sum() > 0


def test_decode_is_differentiable_in_coefficients(no_scalars_with_grad: None) -> None:
    """Decoding features with gradients (the generative model's path) neither warns nor breaks."""
    gen = torch.Generator().manual_seed(10)
    a = random_aligned(gen, n=3, S=10)
    f = a.features().detach().requires_grad_(True)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = AlignedTrees.from_features(f, a, a.root).to_trees(0.05)
    out.points.square().sum().backward()
    assert f.grad is not None and torch.isfinite(f.grad).all() and f.grad.abs().sum() > 0


def test_device_and_dtype_follow_q() -> None:
    gen = torch.Generator().manual_seed(11)
    a = random_aligned(gen, n=2, S=6).to(torch.float32)
    out = a.to_trees(0.05)
    assert out.dtype == torch.float32 and out.s.dtype == torch.float32
    assert out.parent.dtype == torch.long and out.label.dtype == torch.long
    assert out.device == a.q.device


def test_srvf_of_decoded_main_branch() -> None:
    """The decoded main branch has the SRVF of slot 0 up to arc-length resampling (a smooth branch)."""
    t = torch.linspace(0, 1, 33, dtype=torch.float64)[:, None]
    curve = torch.cat([t, 0.3 * t.square(), torch.sin(t)], dim=1)
    a = AlignedTrees(srvf(curve)[None, None], torch.zeros(1, 1, dtype=torch.float64),
                     torch.ones(1, 1, dtype=torch.bool), curve[:1], torch.tensor([-1]), torch.tensor([0]),
                     torch.full((1, 1), -1))
    out = a.to_trees()
    torch.testing.assert_close(out.branch_lengths(), curve_length(curve)[None], atol=1e-3, rtol=0)
    torch.testing.assert_close(out.points[0, [0, -1]], curve[[0, -1]], atol=1e-12, rtol=0)


def test_empty_batch_and_mixed_dtypes() -> None:
    gen = torch.Generator().manual_seed(12)
    a = random_aligned(gen, n=3, S=6)
    empty = a[[]].to_trees(0.05)
    assert empty.num_trees == 0 and empty.points.shape == (0, a.T, 3)
    # s and root in float64 with q in float32: the output follows q
    b = AlignedTrees(a.q.float(), a.s, a.present, a.root, a.slot_parent, a.slot_depth, a.source)
    out, ref = b.to_trees(0.05), a.to_trees(0.05)
    assert out.points.dtype == out.s.dtype == torch.float32
    torch.testing.assert_close(out.points, ref.points.float(), atol=1e-4, rtol=0)


# ------------------------------------------------------------------------------ fast paths


@pytest.mark.parametrize("seed", [0, 1])
def test_compiled_placement_matches_the_torch_path(seed: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """The compiled kernels (no gradient, float64) and the differentiable torch code place branches alike."""
    from torch4dtree.trees import aligned

    if not aligned.HAVE_NUMBA:
        pytest.skip("numba is not installed")
    a = random_aligned(torch.Generator().manual_seed(seed), n=9, S=30, eps=0.05)
    assert aligned._compiled(a.q, a.s, a.root)
    compiled = a.to_trees(0.05)
    monkeypatch.setattr(aligned, "COMPILED_DECODE", False)
    assert_same_trees(compiled, a.to_trees(0.05), atol=1e-12)
    assert compiled.depth.max() >= 2 and compiled.num_branches.min() < 30


@pytest.mark.parametrize("compiled", [True, False])
def test_pca_decode_matches_to_trees_where_lengths_cancel(compiled: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    """``TreePCA.decode`` (lengths as quadratic forms in the coefficients, only long slots integrated) gives
    ``inverse_transform(c).to_trees``, also for a branch ~1e-6 as long as its slot's mean, right at the threshold,
    where the quadratic form cancels: its relative error there is far above the band around the threshold tried."""
    from torch4dtree.space.pca import TreePCA
    from torch4dtree.trees import aligned

    monkeypatch.setattr(aligned, "COMPILED_DECODE", compiled)
    gen = torch.Generator().manual_seed(4)
    a = random_aligned(gen, n=8, S=12, eps=0.05)
    j = next(k for k in range(1, 12) if int(a.slot_parent[k]) == 0 and bool(a.present[1:, k].all()))
    q = a.q.clone()
    q[:, 0] = torch.randn(8, 1, 3, generator=gen, dtype=q.dtype)  # no null main branch (children on rounding noise)
    q[0, j] = 1e-6 * q[1, j]  # tree 0's branch in slot j: tiny, the others' of full size
    # siblings at distinct s: a tie reconstructed from the PCA is one up to rounding, ordered by rounding
    s = torch.rand(8, 12, generator=gen, dtype=q.dtype)
    a = AlignedTrees(q, s, a.present, a.root, a.slot_parent, a.slot_depth, a.source)
    pca = TreePCA(n_components=7).fit(a)
    c = pca.transform(a)
    L = float(srvf_sq_norm(pca.inverse_transform(c[:1]).q[0, j]))
    for eps, kept in ((L * (1 - 1e-6), True), (L * (1 + 1e-6), False), (0.05, None)):
        new, old = pca.decode(c, eps), pca.inverse_transform(c).to_trees(eps)
        # the tiny branch itself is known to ~1e-16 / 1e-6 relative (rounding of the full-size terms that cancel):
        # so are the arc fractions of its children
        assert_same_trees(new, old, atol=1e-9)
        if kept is not None:
            assert (j in new[0].label.tolist()) == kept
    default = pca.decode(c)  # the default threshold (a fraction of the mean's main branch)
    assert default.num_trees == 8 and bool(torch.isfinite(default.points).all())
    # gradients flow to the coefficients through the torch path
    cg = c.clone().requires_grad_(True)
    pca.decode(cg, 0.05).points.square().sum().backward()
    assert cg.grad is not None and bool(torch.isfinite(cg.grad).all()) and float(cg.grad.abs().sum()) > 0


def test_pca_decode_tables_follow_the_fit() -> None:
    """The cached per-slot tables are rebuilt when the PCA is refitted, cast or modified in place."""
    from torch4dtree.space.pca import TreePCA

    gen = torch.Generator().manual_seed(6)
    a, b = random_aligned(gen, n=6, S=8), random_aligned(gen, n=6, S=8)
    b = AlignedTrees(b.q, b.s, b.present, b.root, a.slot_parent, a.slot_depth, b.source)
    pca = TreePCA(n_components=4).fit(a)
    c = pca.transform(a)
    pca.decode(c, 0.05)
    for change in (lambda: pca.fit(b), lambda: pca.mean.mul_(0.5), lambda: pca.to(torch.float32).to(torch.float64)):
        change()
        assert_same_trees(pca.decode(c, 0.05), pca.inverse_transform(c).to_trees(0.05), atol=1e-10)


def test_a_run_of_trees_is_sliced_like_a_list() -> None:
    trees = random_aligned(torch.Generator().manual_seed(7), n=6, S=10).to_trees(0.05)
    for index in (slice(1, 4), [2, 3, 4], slice(0, 6), [5]):
        listed = list(range(6))[index] if isinstance(index, slice) else index
        got = trees[index]
        want = Trees.cat([trees[[i]] for i in listed])
        assert_same_trees(got, want, atol=0)


def test_compiled_depth_first_order_matches_the_torch_one() -> None:
    """The compiled pre-order of kept slots equals the torch one, siblings ordered by arc with ties (equal arcs:
    higher slot first) and dropped subtrees."""
    from torch4dtree.trees import aligned, decode_numba

    if not aligned.HAVE_NUMBA:
        pytest.skip("numba is not installed")
    gen = torch.Generator().manual_seed(5)
    S, n = 40, 12
    slot_parent = torch.tensor([-1] + [int(torch.randint(0, k, (1,), generator=gen)) for k in range(1, S)])
    depth = aligned._slot_depth(slot_parent)
    depth_slots = [(depth == k).nonzero()[:, 0] for k in range(1, int(depth.max()) + 1)]
    depth_parents = [slot_parent[x] for x in depth_slots]
    keep = torch.rand(n, S, generator=gen) < 0.7
    keep[:, 0] = True
    for slots, parents in zip(depth_slots, depth_parents):
        keep[:, slots] &= keep[:, parents]
    arc = torch.randint(0, 4, (n, S), generator=gen).to(torch.float64) / 4  # many equal arcs
    want = aligned._depth_first_order(keep, arc, slot_parent, depth_slots, depth_parents)
    got = decode_numba.depth_first_order(keep, arc, slot_parent)
    for g, w in zip(got, want):
        assert torch.equal(g, w)
    assert int(keep.sum()) < n * S and int((arc[:, 1:, None] == arc[:, None, 1:]).sum()) > n * S
