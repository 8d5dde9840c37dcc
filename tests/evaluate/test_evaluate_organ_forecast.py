"""The organ model's forecast in the ground metric (evaluate/generative_organs.py): its point is the mean of its
continuations in the layout, one continuation's error beside it; seeds reproduce."""

from __future__ import annotations

import pytest
import torch

from torch4dtree.data.synthetic import synthetic_plant
from torch4dtree.evaluate import generative_organs
from torch4dtree.evaluate.generative_organs import organ_forecasts
from torch4dtree.model import FourDTreeModel, OrganModel
from torch4dtree.settings import ModelSettings
from torch4dtree.trees.structures import TreeSequence


@pytest.fixture(scope="module")
def fold() -> tuple[FourDTreeModel, OrganModel, list[TreeSequence]]:
    plants = [synthetic_plant("maize", seed, n_frames=4, T=8).sequence for seed in range(5)]
    paper = FourDTreeModel(ModelSettings(n_t=4, medoid_candidates=1)).fit(plants[:3])
    return paper, OrganModel().fit(plants[:3]), plants[3:]


def _run(fold: tuple[FourDTreeModel, OrganModel, list[TreeSequence]], seed: int) -> list[dict]:
    paper, organs, held = fold
    encs = [paper.population.transform(s) for s in held]
    return organ_forecasts(paper, organs, held, encs, torch.Generator().manual_seed(seed))


def test_forecast_point_is_no_farther_than_a_continuation_on_average(
        fold: tuple[FourDTreeModel, OrganModel, list[TreeSequence]]) -> None:
    rows = _run(fold, 0)
    for r in rows:
        assert set(r) >= {"organs", "organs_draw", "last", "mean", "final_length"}
        assert all(r[k] >= 0 for k in ("organs", "organs_draw", "last", "mean"))
    # the mean of continuations is within the spread of a continuation (the norm is convex): over plants and seeds
    # its error is not above a single continuation's on average
    draws = [r for s in range(3) for r in _run(fold, s)]
    assert sum(r["organs"] for r in draws) <= sum(r["organs_draw"] for r in draws) + 1e-9


def test_forecast_seeds_reproduce(fold: tuple[FourDTreeModel, OrganModel, list[TreeSequence]]) -> None:
    assert _run(fold, 5) == _run(fold, 5)


def test_remembered_pairs_change_no_forecast(fold: tuple[FourDTreeModel, OrganModel, list[TreeSequence]],
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    remembered = _run(fold, 7)
    monkeypatch.setattr(generative_organs.RepeatedPairs, "of", classmethod(lambda cls, settings: settings))
    assert _run(fold, 7) == remembered  # every pair searched again
