"""The space of 3D trees: Karcher mean (union layout, pruning, energy, state) and tree PCA."""

from __future__ import annotations

import copy
import dataclasses
import math

import numpy as np
import pytest
import torch
from samples import random_tree, transformed_copy

from torch4dtree.curves import srvf, srvf_sq_norm
from torch4dtree.settings import RegistrationSettings
from torch4dtree.space import KarcherMean, NotFittedError, SlotLimitError, TreePCA
from torch4dtree.space.karcher import _Mean, _Registered
from torch4dtree.trees import AlignedTrees, Trees, register_trees

T = 16


def small_tree(seed: int, extra: tuple[float, float] | None = None, n_side=(2, 3), depth: int = 2) -> Trees:
    """A main branch (length 30) with a few side branches; ``extra = (s, length)`` adds one more on the main."""
    return random_tree(np.random.default_rng(seed), n_side=n_side, depth=depth, T=T, extra=extra)


def stretched_copy(tree: Trees, seed: int = 0) -> Trees:
    """Every branch stretched about its start by its own factor (0.7 to 1.4), children kept at the same ``s``.

    The SRVFs are multiples of the tree's (``sqrt(c) q``), so the identity is the optimal registration (by
    Cauchy-Schwarz) and the pair is already in correspondence.
    """
    a = AlignedTrees.from_trees(tree)
    c = torch.from_numpy(np.random.default_rng(seed).uniform(0.7, 1.4, size=a.num_slots))
    return AlignedTrees(a.q * c.sqrt()[None, :, None, None], a.s, a.present, a.root, a.slot_parent, a.slot_depth,
                        a.source, a.lambdas).to_trees()


def fit(trees: Trees, **kw) -> KarcherMean:
    return KarcherMean(progress=False, **kw).fit(trees)


def tree_norm(tree: Trees) -> float:
    return math.sqrt(float(AlignedTrees.from_trees(tree).sq_norm()[0]))


@pytest.fixture(scope="module")
def population() -> Trees:
    """Five small trees with different numbers of branches (depth 3)."""
    return Trees.cat([small_tree(s, n_side=(2, 4), depth=3) for s in range(5)])


@pytest.fixture(scope="module")
def fitted(population):
    km = KarcherMean(progress=False, prune_length=0.02, max_iters=6, tol=0.0)
    return km, km.fit_transform(population)


# ----------------------------------------------------------------------------- Karcher mean


def test_mean_of_copies_is_the_tree():
    A = small_tree(0, depth=3)
    shift = torch.tensor([[0.0, 0.0, 0.0], [1.0, 2.0, 3.0], [-1.0, -2.0, 0.0]], dtype=A.dtype)
    km = fit(Trees.cat([A, A, A]).translate(shift), prune_length=0.0)
    assert km.history[0]["energy"] == pytest.approx(0.0, abs=1e-9) and km.converged_ and km.n_iter_ == 1
    # the layout is canonical (depth-first, children by s), which is the order Trees.from_branches gives
    assert km.slot_parent.tolist() == A.parent.tolist()
    assert torch.allclose(km.mean_q, srvf(A.points), atol=1e-10)
    assert torch.allclose(km.mean_s, A.s, atol=1e-12)
    assert torch.allclose(km.mean_root, shift.mean(0), atol=1e-12)  # roots are averaged


def test_mean_of_reparameterised_copies_is_the_tree():
    A = small_tree(1, depth=3)
    gen = torch.Generator().manual_seed(0)
    copies = Trees.cat([A] + [transformed_copy(A, gen, strength=0.5) for _ in range(3)])
    km = fit(copies, prune_length=0.0)
    assert km.num_slots == A.points.shape[0]
    d = float(register_trees(km.mean_tree(), A).distance)
    assert d < 0.02 * tree_norm(A)


def test_mean_of_two_trees_in_correspondence_is_the_geodesic_midpoint():
    A = small_tree(2, depth=3)
    B = stretched_copy(A)
    km = fit(Trees.cat([A, B]), prune_length=0.0)
    res = km.fit_transform(Trees.cat([A, B]))
    r = register_trees(B, A, positions="warped")  # the mean's own metric
    mid = r.aligned[0].lerp(r.aligned[1], torch.tensor([0.5]))
    assert km.num_slots == A.points.shape[0]
    d_ab = float(r.distance)
    assert res.distance.tolist() == pytest.approx([d_ab / 2, d_ab / 2], rel=1e-6)
    assert km.history[-1]["energy"] == pytest.approx(d_ab**2 / 2, rel=1e-6)
    # same layout order (both canonical): the mean's SRVFs and positions are the midpoint's (compared directly, not
    # as features: the pair's registration weighs lp by both main branches, the space by its reference's)
    assert km.slot_parent.tolist() == mid.slot_parent.tolist()
    mean = km.mean_aligned()
    assert torch.allclose(mean.q, mid.q, atol=1e-6) and torch.allclose(mean.s, mid.s, atol=1e-6)
    assert torch.allclose(km.mean_root, mid.root[0])


def test_energy_never_increases(fitted):
    km, _ = fitted
    energies = [h["energy"] for h in km.history]
    # tol = 0: every round runs, unless the mean stops moving exactly (a fixed point)
    assert len(energies) == km.n_iter_
    assert km.n_iter_ == 6 or (km.converged_ and km.history[-1]["rel_change"] == 0.0)
    assert all(b <= a * (1 + 1e-12) for a, b in zip(energies, energies[1:])), energies
    assert energies[-1] < energies[0]
    assert [h["num_slots"] for h in km.history][-1] == km.num_slots
    assert all(h["union_slots"] >= h["num_slots"] for h in km.history[:-1])


def test_energy_never_increases_with_a_coarse_registration(population):
    # DP slopes of 1 only: fresh registrations onto a moved mean can miss what the previous round found, and
    # then each tree keeps its previous correspondence (without that fallback the energy rises here)
    km = fit(population, prune_length=0.02, max_iters=6, tol=0.0, registration=RegistrationSettings(neighbourhood=1))
    energies = [h["energy"] for h in km.history]
    assert all(b <= a * (1 + 1e-12) for a, b in zip(energies, energies[1:])), energies
    assert sum(h["kept_previous"] for h in km.history) > 0


def test_pruning_an_old_slot_never_raises_the_energy():
    # a stationary mean whose side slot's average length (4.2 / 3) is below 5% of the main (1.5): pruning it
    # would add 3 |mean branch|^2 = 1.4 to the energy, so the slot stays; the same slot opened anew is pruned
    M, d = 15, 3
    q_main = torch.zeros(M, d, dtype=torch.float64)
    q_main[:, 2] = math.sqrt(30.0)
    q_side = torch.zeros(M, d, dtype=torch.float64)
    q_side[:, 0] = math.sqrt(4.2)
    km = KarcherMean(prune_length=0.05, progress=False)
    parent = torch.tensor([-1, 0])
    mean = _Mean(torch.stack([q_main, q_side / 3]), torch.tensor([0.0, 0.5], dtype=torch.float64),
                 torch.zeros(3, dtype=torch.float64), parent)

    def form(q_b, present, sq):
        return _Registered(torch.stack([q_main, q_b]), torch.tensor([0.0, 0.5], dtype=torch.float64),
                           torch.tensor([True, present]), torch.tensor([0, 1 if present else -1]), parent,
                           torch.zeros(3, dtype=torch.float64), sq)

    forms = [form(q_side, True, 4 / 9 * 4.2), form(0 * q_side, False, 4.2 / 9), form(0 * q_side, False, 4.2 / 9)]
    energy = sum(f.sq_dist for f in forms)
    new, carry, change, _ = km._update(mean, forms, energy)
    assert new.num_slots == 2 and change == pytest.approx(0.0, abs=1e-12)
    assert float(carry.sq_dist.sum()) == pytest.approx(energy, rel=1e-12)
    # the same branch in a new slot (the mean has the main branch only): pruned, and the energy does not rise
    mean1 = _Mean(q_main[None], torch.zeros(1, dtype=torch.float64), torch.zeros(3, dtype=torch.float64),
                  torch.tensor([-1]))
    main_only = _Registered(q_main[None], torch.zeros(1, dtype=torch.float64), torch.tensor([True]),
                            torch.tensor([0]), torch.tensor([-1]), torch.zeros(3, dtype=torch.float64), 0.0)
    new1, carry1, _, union = km._update(mean1, [form(q_side, True, 4.2), main_only, main_only], 4.2)
    assert union == 2 and new1.num_slots == 1 and float(carry1.sq_dist.sum()) == pytest.approx(4.2, rel=1e-12)


def test_a_branch_shared_by_a_third_of_the_trees_gets_one_slot():
    # each tree with the extra branch opens its own slot first (average length 15/6 = 2.5 > 5% of 30), the
    # next round merges them; pruning by the length of the mean branch (15/36) would have dropped them
    base, extra = small_tree(4), small_tree(4, extra=(0.5, 15.0))
    trees = Trees.cat([base] * 4 + [extra] * 2)
    km = fit(trees, prune_length=0.05)
    res = km.fit_transform(trees)
    assert km.num_slots == base.points.shape[0] + 1
    j = int((~res.aligned.present.all(0)).nonzero()[0, 0])
    assert res.aligned.present[:, j].tolist() == [False] * 4 + [True] * 2
    assert torch.allclose(km.mean_q[j], res.aligned.q[4:, j].sum(0) / 6, atol=1e-9)


def test_distances_split_into_layout_and_dropped_parts(fitted, population):
    km, res = fitted
    f = res.aligned.features()
    f_mean = km.mean_aligned().features()
    sq = (f - f_mean).square().sum(1) + res.dropped_sq_norm
    assert torch.allclose(res.distance.square(), sq, rtol=1e-9)
    # the final round kept, for each tree, the better of a fresh registration and its previous one
    again = km.transform(population)
    assert bool((again.distance >= res.distance - 1e-9).all())
    assert float(res.distance.square().sum()) == pytest.approx(km.history[-1]["energy"], rel=1e-9)


def test_result_does_not_depend_on_input_order(population):
    perm = [3, 0, 4, 2, 1]
    # a subsample of 3 for the medoid: which 3 must not depend on the order either
    km = KarcherMean(progress=False, prune_length=0.02, max_iters=6, tol=0.0, medoid_subsample=3).fit(population)
    km2 = KarcherMean(progress=False, prune_length=0.02, max_iters=6, tol=0.0, medoid_subsample=3
                      ).fit(population[perm])
    assert km2.init_index_ == perm.index(km.init_index_)  # the same medoid
    assert km2.history[-1]["energy"] == pytest.approx(km.history[-1]["energy"], rel=1e-6)
    assert km2.slot_parent.tolist() == km.slot_parent.tolist()
    assert torch.allclose(km2.mean_q, km.mean_q, atol=1e-6)


def test_union_layout_opens_a_slot_for_an_extra_branch():
    base, extra = small_tree(4), small_tree(4, extra=(0.5, 15.0))
    km = fit(Trees.cat([base, base, extra]), prune_length=0.01)
    res = km.fit_transform(Trees.cat([base, base, extra]))
    n_base = base.points.shape[0]
    assert km.num_slots == n_base + 1
    present = res.aligned.present
    new = [j for j in range(km.num_slots) if present[:, j].tolist() == [False, False, True]]
    assert len(new) == 1  # exactly one slot, held by the tree with the extra branch only
    j = new[0]
    assert bool(present[:, [k for k in range(km.num_slots) if k != j]].all())
    # the mean of a branch held by 1 of 3 trees is a third of its SRVF (a ninth of its length)
    assert torch.allclose(km.mean_q[j], res.aligned.q[2, j] / 3, atol=1e-9)
    assert float(srvf_sq_norm(res.aligned.q[2, j])) == pytest.approx(15.0, rel=0.02)
    assert float(km.mean_s[j]) == pytest.approx(float(res.aligned.s[2, j]))  # s from the trees that have it
    assert res.aligned.s[:2, j].tolist() == pytest.approx([float(km.mean_s[j])] * 2)  # null partners: same s
    assert res.dropped == [[], [], []]


def test_pruning_drops_short_slots():
    base, extra = small_tree(4), small_tree(4, extra=(0.5, 1.0))
    trees = Trees.cat([base, base, extra])
    n_base = base.points.shape[0]
    kept = fit(trees, prune_length=0.0)
    assert kept.num_slots == n_base + 1
    pruned = KarcherMean(prune_length=0.05, lambdas=(1.0, 0.5, 1.0), progress=False)
    res = pruned.fit_transform(trees)  # average length 1/3 < 5% of the 30-long main branch
    assert pruned.num_slots == n_base
    short = int((extra.branch_lengths() - 1.0).abs().argmin())
    assert res.dropped == [[], [], [short]]
    assert float(res.dropped_sq_norm[2]) == pytest.approx(0.5, rel=0.02)  # lm * ls * its length
    assert res.dropped_sq_norm[:2].tolist() == [0.0, 0.0]


def test_slot_cap():
    base, extra = small_tree(4), small_tree(4, extra=(0.5, 15.0))
    n_base = base.points.shape[0]
    with pytest.raises(SlotLimitError, match="max_slots"):
        fit(Trees.cat([base, extra]), max_slots=n_base - 1)  # the initial tree alone is too big
    with pytest.raises(SlotLimitError, match="max_slots"):
        fit(Trees.cat([base, base, extra]), max_slots=n_base, prune_length=0.01)  # the union is too big
    assert fit(Trees.cat([base, base, extra]), max_slots=n_base + 1, prune_length=0.01).num_slots == n_base + 1


def test_state_dict_round_trip(tmp_path):
    trees = Trees.cat([small_tree(s) for s in range(3)])
    km = fit(trees, lambdas=(1.0, 0.5, 2.0), registration=RegistrationSettings(neighbourhood=3), max_iters=3)
    torch.save(km.state_dict(), tmp_path / "km.pt")
    km2 = KarcherMean()
    km2.load_state_dict(torch.load(tmp_path / "km.pt", weights_only=True))
    assert km2.lambdas == km.lambdas and km2.lp_relative == km.lp_relative is False  # the effective weights
    assert km2.registration == RegistrationSettings(neighbourhood=3)
    assert str(km2.history) == str(km.history) and km2.n_iter_ == km.n_iter_ and km2.converged_ == km.converged_
    for name, buf in km.named_buffers():
        assert torch.equal(buf, getattr(km2, name)), name
    a, b = km.transform(trees), km2.transform(trees)
    assert torch.equal(a.aligned.q, b.aligned.q) and torch.equal(a.distance, b.distance)
    assert a.dropped == b.dropped


def test_cast_to_float64():
    trees = Trees.cat([small_tree(s) for s in range(3)]).to(torch.float32)
    km = fit(trees, max_iters=2)
    assert km.mean_q.dtype == torch.float32
    km64 = copy.deepcopy(km).to(torch.float64)
    assert km64.mean_q.dtype == km64.mean_root.dtype == torch.float64 and km64.slot_parent.dtype == torch.long
    r32, r64 = km.transform(trees), km64.transform(trees)
    assert r64.aligned.q.dtype == r64.distance.dtype == torch.float64 and r32.aligned.q.dtype == torch.float32
    assert torch.allclose(r64.distance.float(), r32.distance, rtol=1e-4)
    assert km64.mean_tree().points.dtype == torch.float64


def test_karcher_errors():
    A = small_tree(0)
    with pytest.raises(NotFittedError):
        KarcherMean().transform(A)
    with pytest.raises(ValueError, match="lambdas"):
        KarcherMean(lambdas=(1.0, 0.0, 1.0))
    with pytest.raises(TypeError, match="RegistrationSettings"):
        KarcherMean(registration={"max_iter": 3})
    with pytest.raises(ValueError, match="unknown setting"):
        RegistrationSettings.from_dict({"max_iter": 3})
    with pytest.raises(ValueError, match="rotation"):
        KarcherMean(rotation="spin")
    with pytest.raises(ValueError, match="init"):
        fit(Trees.cat([A, A]), init=5)
    with pytest.raises(TypeError):
        KarcherMean().fit(AlignedTrees.from_trees(A))


# ----------------------------------------------------------------------------- tree PCA


def known_spectrum(variances, n: int = 8, seed: int = 0) -> AlignedTrees:
    """``n`` trees in one layout whose centred features have exactly the given covariance eigenvalues."""
    like = AlignedTrees.from_trees(small_tree(7))
    F = like.features().shape[1]
    g = torch.Generator().manual_seed(seed)
    k = len(variances)
    A = torch.randn(n, k, generator=g, dtype=torch.float64)
    U = torch.linalg.qr(A - A.mean(0))[0]  # orthonormal scores, orthogonal to the ones vector (centred)
    V = torch.linalg.qr(torch.randn(F, k, generator=g, dtype=torch.float64))[0]
    sing = torch.tensor(variances, dtype=torch.float64).mul(n - 1).sqrt()
    X = like.features() + (U * sing) @ V.T
    return AlignedTrees.from_features(X, like)


def test_pca_full_rank_reconstructs_exactly(fitted):
    _, res = fitted
    shift = torch.arange(res.aligned.num_trees * 3, dtype=torch.float64).reshape(-1, 3)
    x = dataclasses.replace(res.aligned, root=res.aligned.root + shift)  # roots are not features: kept apart
    n = x.num_trees
    pca = TreePCA(n_components=n).fit(x)
    back = pca.inverse_transform(pca.transform(x))
    assert torch.allclose(back.features(), x.features(), atol=1e-9)
    assert TreePCA(variance=1.0).fit(x).n_components_ == n - 1  # centred rank
    # decode(encode(x)) is the training tree (up to the discarded variance, none here)
    dec, ref = pca.decode(pca.transform(x[[0]]), min_length=1e-6), x[[0]].to_trees(1e-6)
    assert dec.num_branches.tolist() == ref.num_branches.tolist()
    assert torch.allclose(pca.mean_root, x.root.mean(0))
    assert torch.allclose(dec.points, ref.points + (pca.mean_root - x.root[0]), atol=1e-6)  # starts at the mean root


def test_pca_variance_threshold_picks_k():
    x = known_spectrum([5.0, 3.0, 1.5, 0.5])
    for share, k in ((0.4, 1), (0.75, 2), (0.85, 3), (0.96, 4), (0.99, 4)):
        pca = TreePCA(variance=share).fit(x)
        assert pca.n_components_ == k, share
    assert pca.explained_variance.tolist() == pytest.approx([5.0, 3.0, 1.5, 0.5], rel=1e-9)
    assert pca.explained_variance_ratio.tolist() == pytest.approx([0.5, 0.3, 0.15, 0.05], rel=1e-9)
    assert TreePCA(n_components=2).fit(x).n_components_ == 2


def test_pca_round_trip_and_distances(fitted):
    _, res = fitted
    x = res.aligned
    pca = TreePCA(n_components=3).fit(x)
    c = torch.randn(6, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    assert torch.allclose(pca.transform(pca.inverse_transform(c)), c, atol=1e-9)
    comps = pca.components
    assert torch.allclose(comps @ comps.T, torch.eye(3, dtype=torch.float64), atol=1e-10)
    full = TreePCA(n_components=x.num_trees).fit(x)
    a = full.transform(x)
    assert torch.allclose(torch.cdist(a, a), x.sq_distances().sqrt(), atol=1e-8)
    a3 = pca.transform(x)
    assert bool((torch.cdist(a3, a3) <= x.sq_distances().sqrt() + 1e-9).all())  # a projection shrinks


def test_pca_decoded_trees_are_valid(fitted):
    _, res = fitted
    pca = TreePCA(n_components=2).fit(res.aligned)
    g = torch.Generator().manual_seed(2)
    c = torch.randn(2, 3, 2, generator=g, dtype=torch.float64) * pca.explained_variance.sqrt()
    trees = pca.decode(c)
    assert trees.num_trees == 6 and bool(torch.isfinite(trees.points).all())
    side = trees.parent >= 0
    assert torch.allclose(trees.points[side, 0], trees.attachment_points()[side], atol=1e-6)
    # labels are slots: each branch's parent holds the slot's parent slot
    gp = trees.global_parent[side]
    assert trees.label[gp].tolist() == pca.slot_parent[trees.label[side]].tolist()


def test_pca_inverse_transform_is_differentiable(fitted):
    _, res = fitted
    pca = TreePCA(n_components=2).fit(res.aligned)
    c = torch.zeros(1, 2, dtype=torch.float64, requires_grad=True)
    out = pca.inverse_transform(c)
    (out.features().square().sum() + out.s.sum()).backward()
    assert c.grad is not None and bool(torch.isfinite(c.grad).all()) and float(c.grad.abs().sum()) > 0
    assert torch.autograd.gradcheck(lambda z: pca.inverse_transform(z).q, (torch.randn(1, 2, dtype=torch.float64,
                                                                                         requires_grad=True),))
    pts = pca.decode(c.detach().requires_grad_()).points
    assert pts.requires_grad


def test_pca_state_dict_and_errors(tmp_path, fitted):
    _, res = fitted
    pca = TreePCA(variance=0.9).fit(res.aligned)
    torch.save(pca.state_dict(), tmp_path / "pca.pt")
    pca2 = TreePCA()
    pca2.load_state_dict(torch.load(tmp_path / "pca.pt", weights_only=True))
    assert torch.equal(pca2.transform(res.aligned), pca.transform(res.aligned))
    c = pca.transform(res.aligned)
    assert torch.equal(pca2.decode(c).points, pca.decode(c).points)
    p64 = copy.deepcopy(pca).to(torch.float32)
    assert p64.components.dtype == torch.float32 and p64.transform(res.aligned).dtype == torch.float32
    with pytest.raises(NotFittedError):
        TreePCA().transform(res.aligned)
    with pytest.raises(ValueError, match="layout"):
        pca.transform(AlignedTrees.from_trees(small_tree(0)))
    with pytest.raises(ValueError, match="at least 2"):
        TreePCA().fit(res.aligned[[0]])
    with pytest.raises(ValueError, match="n_components"):
        TreePCA(n_components=50).fit(res.aligned)
    with pytest.raises(ValueError, match="variance"):
        TreePCA(variance=0.0)


@pytest.mark.parametrize("shape", [(7, 40), (40, 7), (6, 6)])
def test_principal_axes_are_the_svd_of_the_rows(shape: tuple[int, int]) -> None:
    """Wide (computed through the transpose), tall and square inputs: the singular values of the SVD, orthonormal
    axes, and ``x`` rebuilt from its projections on them."""
    from torch4dtree.space.pca import principal_axes

    x = torch.randn(*shape, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    sing, axes = principal_axes(x)
    r = min(shape)
    assert sing.shape == (r,) and axes.shape == (r, shape[1])
    torch.testing.assert_close(sing, torch.linalg.svdvals(x))
    torch.testing.assert_close(axes @ axes.T, torch.eye(r, dtype=x.dtype))
    torch.testing.assert_close((x @ axes.T) @ axes, x)
    # the axes come in the order of the singular values: x's energy along axis i is sing[i]^2
    torch.testing.assert_close((x @ axes.T).square().sum(0), sing.square())


@pytest.mark.parametrize("n_components", [None, 2])
def test_pca_gram_path_gives_the_svd_components(fitted, monkeypatch, n_components):
    """The Gram path (the fit's memory-light default) and the SVD of the dense features give the same mean, variances
    and components (up to rounding; signs fixed the same way), and feature blocks are the features."""
    import torch4dtree.space.pca as P

    aligned = fitted[1].aligned
    blocks = list(P.feature_blocks(aligned, columns=7))
    assert torch.equal(torch.cat(blocks, dim=1), aligned.features())
    assert aligned.features().numel() * 8 < P.GRAM_MIN_BYTES  # small fits keep the SVD ...
    monkeypatch.setattr(P, "GRAM_MIN_BYTES", 0)  # ... here the Gram path runs
    used = []
    real = P.gram_axes
    monkeypatch.setattr(P, "gram_axes", lambda *a: used.append(1) or real(*a))
    gram = TreePCA(n_components=n_components).fit(aligned)
    assert used
    monkeypatch.setattr(P, "gram_axes", lambda *a: None)
    svd = TreePCA(n_components=n_components).fit(aligned)
    assert gram.n_components_ == svd.n_components_
    assert torch.allclose(gram.mean, svd.mean, rtol=0, atol=1e-14)
    assert torch.allclose(gram.explained_variance, svd.explained_variance, rtol=1e-10, atol=0)
    assert torch.allclose(gram.components, svd.components, rtol=0, atol=1e-9)
    assert gram.total_variance_ == pytest.approx(svd.total_variance_, rel=1e-12)


def test_pca_gram_path_falls_back_on_weak_components(fitted, monkeypatch):
    """A kept component weaker than GRAM_MIN_SHARE of the first takes the SVD path."""
    import torch4dtree.space.pca as P

    aligned = fitted[1].aligned
    n = aligned.q.shape[0]
    assert P.gram_axes(aligned, lambda var: 1) is not None
    monkeypatch.setattr(P, "GRAM_MIN_SHARE", 2.0)  # every component but the first counts as weak
    assert P.gram_axes(aligned, lambda var: min(2, n)) is None
