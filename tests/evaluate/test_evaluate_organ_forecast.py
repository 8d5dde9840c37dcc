"""The organ model's forecast in the ground metric (evaluate/generative_organs.py): its point is ``forecast_point``
of its continuations in the layout (their mean at the observed plant's slots, averaged with the training plants'
average elsewhere), their plain mean and one continuation's error beside it; seeds reproduce."""

from __future__ import annotations

import pytest
import torch

from torch4dtree.data.synthetic import synthetic_plant
from torch4dtree.evaluate import generative_organs
from torch4dtree.evaluate.generative_organs import organ_forecasts, training_average
from torch4dtree.model import FourDTreeModel, OrganModel
from torch4dtree.model.organ_forecast import NEW_SLOT_WEIGHT, forecast_point
from torch4dtree.settings import ModelSettings
from torch4dtree.trees.structures import TreeSequence


@pytest.fixture(scope="module")
def fold() -> tuple[FourDTreeModel, OrganModel, list[TreeSequence], list[TreeSequence]]:
    plants = [synthetic_plant("maize", seed, n_frames=4, T=8).sequence for seed in range(5)]
    paper = FourDTreeModel(ModelSettings(n_t=4, medoid_candidates=1)).fit(plants[:3])
    return paper, OrganModel().fit(plants[:3]), plants[3:], plants[:3]


def _run(fold: tuple[FourDTreeModel, OrganModel, list[TreeSequence], list[TreeSequence]], seed: int) -> list[dict]:
    paper, organs, held, train = fold
    encs = [paper.population.transform(s) for s in held]
    enc_train = [paper.population.transform(s) for s in train]
    return organ_forecasts(paper, organs, held, encs, train, enc_train, torch.Generator().manual_seed(seed))


def test_continuations_mean_is_no_farther_than_a_continuation_on_average(
        fold: tuple[FourDTreeModel, OrganModel, list[TreeSequence], list[TreeSequence]]) -> None:
    rows = _run(fold, 0)
    for r in rows:
        assert set(r) >= {"organs", "organs_mean", "organs_draw", "last", "mean", "final_length"}
        assert all(r[k] >= 0 for k in ("organs", "organs_mean", "organs_draw", "last", "mean"))
    # the mean of continuations is within the spread of a continuation (the norm is convex): over plants and seeds
    # its error is not above a single continuation's on average
    draws = [r for s in range(3) for r in _run(fold, s)]
    assert sum(r["organs_mean"] for r in draws) <= sum(r["organs_draw"] for r in draws) + 1e-9


def test_forecast_point_is_the_rule_on_the_continuations_and_the_training_average(
        fold: tuple[FourDTreeModel, OrganModel, list[TreeSequence], list[TreeSequence]],
        monkeypatch: pytest.MonkeyPatch) -> None:
    paper, _, held, train = fold
    calls: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]] = []

    def recorded(draws: torch.Tensor, seen: torch.Tensor, prior: torch.Tensor) -> torch.Tensor:
        point = forecast_point(draws, seen, prior)
        calls.append((draws, seen, prior, point))
        return point

    monkeypatch.setattr(generative_organs, "forecast_point", recorded)
    rows = _run(fold, 0)
    assert len(calls) == len(held) == len(rows)
    S = paper.population.ref_points.shape[0]
    enc_train = [paper.population.transform(s) for s in train]
    for (draws, seen, prior, point), seq, e, r in zip(calls, held, [paper.population.transform(s) for s in held], rows):
        half = len(seq) // 2
        truth = e.aligned.features()[half:]
        assert draws.shape == (generative_organs.FORECAST_DRAWS, *truth.shape) and seen.shape == (len(truth), S)
        # the prior: the training plants written in the layout, read at the plant's time since its first frame
        expected = training_average([t.aligned.features().to(truth) for t in enc_train], [s.times for s in train],
                                    seq.times[half:] - seq.times[0])
        assert torch.allclose(prior, expected)
        # the point's error is the reported one, the plain mean's beside it
        assert r["organs"] == pytest.approx(float((point - truth).norm(dim=-1).mean()))
        assert r["organs_mean"] == pytest.approx(float((draws.mean(0) - truth).norm(dim=-1).mean()))
        assert seen.any() and not seen.all()  # the rule differs from the plain mean here
        blend = NEW_SLOT_WEIGHT * draws.mean(0) + (1 - NEW_SLOT_WEIGHT) * prior
        assert not torch.allclose(point, draws.mean(0)) or torch.allclose(blend, draws.mean(0))


def test_forecast_seeds_reproduce(fold: tuple[FourDTreeModel, OrganModel, list[TreeSequence]]) -> None:
    assert _run(fold, 5) == _run(fold, 5)


def test_remembered_pairs_change_no_forecast(fold: tuple[FourDTreeModel, OrganModel, list[TreeSequence]],
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    remembered = _run(fold, 7)
    monkeypatch.setattr(generative_organs.RepeatedPairs, "of", classmethod(lambda cls, settings: settings))
    assert _run(fold, 7) == remembered  # every pair searched again
