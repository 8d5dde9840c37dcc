"""Population's union layout: a branch the reference lacks opens one slot that later plants share; ``max_slots``
bounds the layout and the registrations onto it, reports the dropped share of the training norm, and leaves a
population under the bound unchanged; a new plant's organ the registration leaves unmatched under a matched parent
takes that parent's free child slot."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from torch4dtree.settings import CrossSettings
from torch4dtree.temporal.population import SLOT_SLACK, Population
from torch4dtree.temporal.spatiotemporal import bounded_slots
from torch4dtree.trees.aligned import slot_weights
from torch4dtree.trees.structures import Trees, TreeSequence

T = 32
# a stem, two leaves every plant has, and two extra leaves: X (plants a, b) and Y (plants c, d), pointing away
# from each other so that matching X to Y costs more than leaving both null; Z (no training plant) sits where X
# does but points down, so that the registration leaves it unmatched
LEAVES = {"L1": (0.35, (1.0, 0.0, 0.3)), "L2": (0.65, (0.0, 1.0, 0.3)),
          "X": (0.5, (-1.0, 0.0, 0.3)), "Y": (0.8, (0.6, -0.8, 0.3)), "Z": (0.5, (0.0, 0.0, -1.0))}


def _tree(extra: str, size: float, bend: float) -> list[np.ndarray]:
    t = np.linspace(0, 1, 20)[:, None]
    stem = t * np.array([bend, 0.0, 30.0 * size])
    branches = [stem]
    for name in ("L1", "L2", extra):
        s, d = LEAVES[name]
        d = np.asarray(d) / np.linalg.norm(d)
        start = stem[0] + s * (stem[-1] - stem[0])
        branches.append(start + t * d * 10.0 * size)
    return branches


def _plant(name: str, extra: str, size: float, bend: float) -> TreeSequence:
    frames = [_tree(extra, size * f, bend) for f in (0.8, 1.0)]  # a young and a grown frame, same organs
    trees = Trees.from_branches(frames, [[-1, 0, 0, 0]] * 2, T=T, dtype=torch.float64)
    return TreeSequence(trees, torch.tensor([0.0, 1.0], dtype=torch.float64), name=name)


@pytest.fixture(scope="module")
def fitted() -> tuple[Population, list[TreeSequence]]:
    seqs = [_plant("a", "X", 1.0, 0.0), _plant("b", "X", 1.05, 0.5), _plant("c", "Y", 0.97, -0.4),
            _plant("d", "Y", 1.02, 0.3)]
    # children placed by their fraction of the stem: X sits between L1 and L2 in half of the plants, which shifts
    # L2's node rank by one between the groups; with the default node ranks at lp 12 that mismatch costs more than
    # a second Y slot (6 slots), a property of ranks, not of the union this file tests
    return Population(cross=CrossSettings(positions="warped")).fit(seqs), seqs


def test_same_extra_branch_of_two_plants_shares_one_slot(fitted):
    pop, seqs = fitted
    # stem + L1 + L2 + the reference's extra leaf + ONE slot for the other extra leaf (two plants hold it)
    assert pop.report_["reference_slots"] == 4
    assert pop.report_["slots"] == 5
    # every frame fills every slot but the other group's extra leaf: each plant has 4 of the 5 slots
    assert pop.layout_.present.sum(1).tolist() == [4] * 8
    ref = pop.report_["reference"]
    other = [i for i, s in enumerate(seqs) if (s.name in "ab") != (ref in "ab")]
    assert pop.layout_.present[[2 * i for i in other], 4].all()
    # the union representative carries the opened slot (its branch is the other plants' leaf) for transform
    assert pop.reference_tree().points.shape[0] == 5


def test_new_plant_lands_in_an_opened_slot(fitted):
    pop, _ = fitted
    extra = "Y" if pop.report_["reference"] in "ab" else "X"  # the leaf the reference lacks
    enc = pop.transform(_plant("e", extra, 0.99, 0.1))
    assert enc.aligned.present[:, 4].all()
    assert float(enc.dropped_sq_norm.max()) < 1e-9


def test_an_unmatched_organ_takes_its_parents_free_child_slot(fitted, monkeypatch):
    """Z, between the two leaves every plant has, is left unmatched by the registration; the X slot between them is
    free under the same parent, so Z is written there (by place, in order between the matched siblings) instead of
    being dropped with its whole squared norm."""
    pop, _ = fitted
    x_slot = [k for k in range(5) if k not in (0, 1, 2) and abs(float(pop.ref_s[k]) - 0.5) < 1e-9]
    assert len(x_slot) == 1 and int(pop.ref_parent[x_slot[0]]) == 0
    new = _plant("z", "Z", 1.0, 0.2)
    enc = pop.transform(new)
    assert enc.aligned.present.sum(1).tolist() == [4, 4]
    assert enc.aligned.present[:, x_slot[0]].all()
    assert float(enc.dropped_sq_norm.max()) < 1e-9
    # the registration's matches alone leave Z out: its squared norm (a leaf of length 10) is dropped
    with monkeypatch.context() as m:
        m.setattr("torch4dtree.temporal.population.completed_matches", lambda matches, *_: list(matches))
        alone = pop.transform(new)
    assert alone.aligned.present.sum(1).tolist() == [3, 3]
    assert float(alone.dropped_sq_norm.min()) > 5.0


def test_union_does_not_depend_on_input_order(fitted):
    pop, seqs = fitted
    rev = Population(cross=CrossSettings(positions="warped")).fit(seqs[::-1])
    assert rev.report_["reference"] == pop.report_["reference"] and rev.report_["slots"] == pop.report_["slots"]
    assert torch.allclose(rev.ref_points, pop.ref_points)
    assert torch.allclose(rev.trajectories.flip(0), pop.trajectories, atol=1e-8)


def _plants() -> list[TreeSequence]:
    # stem, two shared leaves, an extra leaf X (plants a, b) or Y (c, d): 5 slots unbounded
    return [_plant("a", "X", 1.0, 0.0), _plant("b", "X", 1.05, 0.5), _plant("c", "Y", 0.97, -0.4),
            _plant("d", "Y", 1.02, 0.3)]


def _fit(max_slots: int | None) -> Population:
    return Population(cross=CrossSettings(positions="warped"), max_slots=max_slots).fit(_plants())


@pytest.fixture(scope="module")
def unbounded() -> Population:
    return _fit(None)


def test_under_the_bound_the_population_is_unchanged(unbounded):
    assert unbounded.report_["slots"] == 5
    bounded = _fit(5)
    assert bounded.report_["dropped_share"] == 0.0 and bounded.report_["slots_opened"] == 5
    mine, theirs = bounded.state_dict(), unbounded.state_dict()
    for name, value in theirs.items():
        if isinstance(value, torch.Tensor):
            assert torch.equal(mine[name], value), name
    assert torch.equal(bounded.layout_.q, unbounded.layout_.q)


def _slot_masses(pop: Population) -> torch.Tensor:
    layout = pop.layout_
    w = slot_weights(layout.slot_depth, pop.lambdas_)[0].to(layout.q)
    return (layout.q.square().sum((-1, -2)) * layout.present).sum(0) / layout.q.shape[2] * w


@pytest.mark.parametrize("max_slots", [4, 3])
def test_max_slots_bounds_the_layout_and_reports_the_dropped_share(unbounded, max_slots):
    pop = _fit(max_slots)
    rep = pop.report_
    assert rep["slots"] == max_slots and rep["slots_opened"] == 5 and rep["max_slots"] == max_slots
    assert pop.reference_tree().points.shape[0] == max_slots == pop.pca.num_slots
    # the slots kept are the ones carrying the most norm: the dropped share is the rest of the unbounded layout's
    mass = _slot_masses(unbounded)
    kept = bounded_slots(mass.tolist(), unbounded.layout_.slot_parent.tolist(), max_slots)
    expected = 1 - float(mass[kept].sum() / mass.sum())
    assert 0 < rep["dropped_share"] == pytest.approx(expected, rel=1e-6)
    # a new plant is written in the bounded layout; its branches in dropped slots are reported
    enc = pop.transform(_plant("e", "X", 0.99, 0.1))
    assert enc.aligned.num_slots == max_slots and torch.isfinite(enc.trajectory).all()


def test_the_registrations_onto_the_union_stay_bounded(monkeypatch):
    sizes = []
    original = Population._register_cross

    def spy(self, trees, reference, lam):
        sizes.append(reference.points.shape[0])
        return original(self, trees, reference, lam)

    monkeypatch.setattr(Population, "_register_cross", spy)
    pop = _fit(2)  # the union passes 2 x 2 slots and is cut back to 2 while it grows
    assert pop.report_["slots"] == 2 and pop.report_["dropped_share"] > 0
    assert sizes and max(sizes) <= SLOT_SLACK * 2


def test_bounded_slots_keeps_parents():
    parent = [-1, 0, 1, 1, 0, 4]
    mass = [1.0, 0.1, 5.0, 0.2, 0.3, 0.4]
    for k in range(1, 7):
        kept = bounded_slots(mass, parent, k)
        assert len(kept) == k and all(parent[u] in kept for u in kept if parent[u] >= 0)
    assert bounded_slots(mass, parent, 3) == [0, 1, 2]


@pytest.mark.parametrize("positions, lp", [("nodes", 100.0), ("rank", 12.0)])
def test_transform_writes_a_training_plant_as_the_fit_did(positions: str, lp: float) -> None:
    """The union representative carries every plant's organs at its nodes; a plant registered onto it is compared
    with the node ranks its branches had on the plants they came from (``ref_ranks``), so ``transform`` writes a
    training plant exactly as the fit did, nothing outside the layout. Ranks counted on the union itself shift every
    organ above an extra one: with ``nodes`` the reference plant then matches 29 of its 47 branches and its last
    frame leaves a squared norm of 413 outside the layout."""
    from torch4dtree.data import synthetic_dataset

    plants = [p.sequence for p in synthetic_dataset("tomato", plants=4, seed=0, n_frames=4, T=12)][:3]
    pop = Population(n_t=6, medoid_candidates=2, cross=CrossSettings(positions=positions, lp=lp)).fit(plants)
    assert pop.ref_ranks.shape == (pop.ref_parent.shape[0],)
    assert pop.layout_ is not None and pop.report_["slots_opened"] > pop.report_["reference_slots"]
    start = 0
    for seq in plants:
        enc = pop.transform(seq)
        n = len(seq)
        assert torch.allclose(enc.aligned.q, pop.layout_.q[start:start + n], atol=1e-9)
        assert torch.equal(enc.aligned.present, pop.layout_.present[start:start + n])
        assert float(enc.dropped_sq_norm.max()) < 1e-12
        start += n
    # a checkpoint saved without the ranks loads (the union's own ranks)
    state = pop.state_dict()
    del state["ref_ranks"]
    old = Population().to(torch.float64)
    old.load_state_dict(state)
    assert old.ref_ranks.numel() == 0 and old.reference_tree().points.shape[0] == pop.ref_parent.shape[0]
