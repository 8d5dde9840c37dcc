"""The organ model's forecast: its samples have the spread of its stated conditional distribution; seeds reproduce."""

from __future__ import annotations

import math

import pytest
import torch

from torch4dtree.data.synthetic import synthetic_plant
from torch4dtree.model.fourd import sequence_validity
from torch4dtree.model.organ_forecast import ForecastDistribution, forecast_distribution, forecast_organs
from torch4dtree.model.organs import OrganModel
from torch4dtree.trees.structures import TreeSequence

DRAWS = 300
# a sample mean or variance off by more than this many of its standard errors fails (about 6e-5 two-sided each)
Z = 4.0


@pytest.fixture(scope="module")
def fitted() -> tuple[OrganModel, TreeSequence]:
    plants = [synthetic_plant("bean", seed, n_frames=4, T=16).sequence for seed in range(9)]
    return OrganModel().fit(plants[:8]), plants[8]


def mixture_moments(dist: ForecastDistribution) -> tuple[float, float, float]:
    """Mean, variance and fourth central moment of the stated Gaussian mixture."""
    w, c, s2 = dist.weights, dist.components, dist.jitter ** 2
    m = float((w * c).sum())
    d = c - m
    var = float((w * (d.square() + s2)).sum())
    mu4 = float((w * (d ** 4 + 6 * d.square() * s2 + 3 * s2 ** 2)).sum())
    return m, var, mu4


def test_forecast_samples_have_the_stated_spread(fitted: tuple[OrganModel, TreeSequence]) -> None:
    model, plant = fitted
    partial = plant[[0, 1]]
    dist = forecast_distribution(model, partial)
    m, var, mu4 = mixture_moments(dist)
    assert math.isclose(float(dist.mean), m) and math.isclose(float(dist.covariance), var)
    assert 0.0 <= dist.slope <= 1.0 and 0.0 <= dist.count_slope <= 1.0
    futures = forecast_organs(model, partial, n=DRAWS, generator=torch.Generator().manual_seed(0))
    x = torch.tensor([math.log(float(f.frames[-1].total_length()[0])) for f in futures], dtype=torch.float64)
    # the standard errors of a sample mean and a sample variance of DRAWS independent draws
    assert abs(float(x.mean()) - m) <= Z * math.sqrt(var / DRAWS)
    assert abs(float(x.var()) - var) <= Z * math.sqrt((mu4 - var ** 2) / DRAWS)


def test_forecast_seeds_reproduce(fitted: tuple[OrganModel, TreeSequence]) -> None:
    model, plant = fitted
    a = forecast_organs(model, plant[[0, 1]], n=3, generator=torch.Generator().manual_seed(7))
    b = forecast_organs(model, plant[[0, 1]], n=3, generator=torch.Generator().manual_seed(7))
    assert all(torch.equal(x.frames.points, y.frames.points) for x, y in zip(a, b))
    assert [x.name for x in a] == ["forecast_000", "forecast_001", "forecast_002"]
    for f in a:
        assert sequence_validity(f) == []
        assert float(f.times[0]) > float(plant.times[1])


def test_observed_organs_keep_their_size_and_place(fitted: tuple[OrganModel, TreeSequence]) -> None:
    model, plant = fitted
    partial = plant[[0, 1]]
    seen = partial.frames[1]
    for f in forecast_organs(model, partial, n=4, generator=torch.Generator().manual_seed(3)):
        first = f.frames[0]
        # the main branch never shrinks; the plant has at least the organs it had
        assert float(first.branch_lengths()[0]) >= float(seen.branch_lengths()[0]) - 1e-6
        assert int(f.frames.num_branches[-1]) >= int(seen.num_branches[0])
        grown = f.frames.total_length()
        assert (grown[1:] >= grown[:-1] - 1e-6).all()


@pytest.mark.parametrize("seed", [1, 3])
def test_forecast_from_the_plant_itself_keeps_its_organ_counts(seed: int) -> None:
    # a model of two copies of one plant has that plant as every donor: its continuation has the plant's organs
    # frame by frame, leaves that die included (maize seeds 1 and 3 lose a leaf after the observed half)
    plant = synthetic_plant("maize", seed, n_frames=6, T=16).sequence
    model = OrganModel().fit([plant, plant])
    for f in forecast_organs(model, plant[[0, 1, 2]], n=2, generator=torch.Generator().manual_seed(0)):
        assert f.frames.num_branches.tolist() == plant.frames.num_branches[-len(f):].tolist()
