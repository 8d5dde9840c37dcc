"""OrganModel on hand-made stems whose leaves are known: samples keep the leaves' number and places where a small
extra organ shifts the ranks of the leaves above it, and the forecast adds the organs that keep appearing."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from torch4dtree.model import organ_forecast
from torch4dtree.model.organ_forecast import forecast_organs
from torch4dtree.model.organs import OrganModel
from torch4dtree.trees.structures import Trees, TreeSequence

FRAMES = 5
SPACING = 1.2  # stem length between two leaves
BUD = 0.15  # length of the small extra organ (a bud) some plants carry


def stem_plant(seed: int, first_leaves: int, bud: bool, frames: int = FRAMES) -> TreeSequence:
    """A vertical stem with ``first_leaves`` leaves at the first frame and one more at each later frame, each
    above the last (alternating sides, places jittered), leaves growing to length 3, and a small organ (a bud) just
    above the first leaf (``bud``: every leaf above it one rank higher than in the other plants) or else above the
    last one (once the stem reaches it): the plants differ in the ranks of their leaves, not in their counts."""
    rng = np.random.default_rng(seed)
    n_leaves = first_leaves + frames - 1
    place = 1.0 + SPACING * np.arange(n_leaves) + rng.normal(0.0, 0.08, n_leaves)
    side = np.pi * np.arange(n_leaves) + rng.normal(0.0, 0.2, n_leaves)
    bud_at = place[0 if bud else -1] + 0.5
    trees = []
    for f in range(frames):
        n = first_leaves + f
        top = place[n - 1] + 1.0
        branches = [np.linspace([0.0, 0.0, 0.0], [0.0, 0.0, top], 5)]
        for j in range(n):
            size = min(3.0, 0.8 + 0.8 * (f - max(0, j - first_leaves + 1)))
            base = np.array([0.0, 0.0, place[j]])
            tip = base + size * np.array([math.cos(side[j]), math.sin(side[j]), 0.3]) / math.hypot(1.0, 0.3)
            branches.append(np.linspace(base, tip, 3))
        if bud_at < top:
            base = np.array([0.0, 0.0, bud_at])
            branches.append(np.linspace(base, base + BUD * np.array([0.0, 1.0, 0.2]), 3))
        trees.append(Trees.from_branches([branches], [[-1] + [0] * (len(branches) - 1)], T=16, dtype=torch.float64))
    return TreeSequence(Trees.cat(trees), torch.arange(float(frames), dtype=torch.float64), f"stem_{seed}")


def big_leaf_places(plant: TreeSequence) -> list[float]:
    """Heights of the main branch's children at least a tenth of the largest one, at the last frame, in order."""
    f = plant.frames[len(plant) - 1]
    lengths = f.branch_lengths()
    kids = torch.nonzero(f.parent == 0).reshape(-1)
    big = kids[lengths[kids] >= 0.1 * lengths[kids].max()]
    return sorted(float(f.points[b, 0, 2]) for b in big)


@pytest.fixture(scope="module")
def stems() -> list[TreeSequence]:
    return [stem_plant(seed, first_leaves=2, bud=seed % 2 == 1) for seed in range(10)]


def test_samples_keep_the_leaves_where_buds_shift_the_ranks(stems: list[TreeSequence]) -> None:
    model = OrganModel().fit(stems)
    real = [big_leaf_places(p) for p in stems]
    n_leaves = len(real[0])
    assert all(len(r) == n_leaves for r in real)
    samples = [big_leaf_places(p) for p in model.sample(60, generator=torch.Generator().manual_seed(0))]
    # every leaf once: neither a leaf twice (copied from two plants) nor one left out
    assert np.mean([len(x) == n_leaves for x in samples]) >= 0.9
    whole = np.array([x for x in samples if len(x) == n_leaves])
    gaps = np.diff(whole, axis=1)
    assert (gaps > 0.5 * SPACING).mean() >= 0.95
    # each leaf at its height: the median height of the j-th leaf as in the training plants
    assert np.abs(np.median(whole, 0) - np.median(np.array(real), 0)).max() < 0.25 * SPACING


def test_forecast_adds_the_organs_that_keep_appearing(monkeypatch: pytest.MonkeyPatch) -> None:
    # every plant gains one leaf a frame whatever it has: the final count is the count now plus the frames to come
    train = [stem_plant(seed, first_leaves=1 + seed % 3, bud=False) for seed in range(9)]
    plant = stem_plant(20, first_leaves=4, bud=False)  # more leaves now than any training plant had
    model = OrganModel().fit(train)
    expected = int(plant.frames.num_branches[-1])

    def final_counts() -> list[int]:
        futures = forecast_organs(model, plant[[0, 1]], n=6, generator=torch.Generator().manual_seed(0))
        return [int(f.frames.num_branches[-1]) for f in futures]

    dist = organ_forecast.forecast_distribution(model, plant[[0, 1]])
    assert dist.count_slope > 0.8
    assert all(c >= expected for c in final_counts())
    observe = organ_forecast._observe

    def no_count_slope(*args: object) -> tuple[object, organ_forecast.ForecastDistribution]:
        observed, d = observe(*args)
        return observed, dataclasses.replace(d, count_slope=0.0)

    monkeypatch.setattr(organ_forecast, "_observe", no_count_slope)
    assert all(c < expected for c in final_counts())  # without the slope the forecast ends with a donor's count
