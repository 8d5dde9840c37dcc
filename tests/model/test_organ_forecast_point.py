"""The forecast's point in a slot layout (model/organ_forecast.py ``forecast_point``): the continuations' mean at the
observed plant's slots, their average with the population's expectation elsewhere."""

from __future__ import annotations

import pytest
import torch
from torch import Tensor

from torch4dtree.model.organ_forecast import NEW_SLOT_WEIGHT, forecast_point, seen_slots

SLOTS, PER_SLOT, FRAMES, DRAWS, PLANTS = 12, 3, 2, 8, 400
OLD = SLOTS // 2  # slots 0 .. OLD - 1 may hold observed organs, the others only new ones
P_OLD, P_NEW = 0.7, 0.3


def features(q: Tensor, s: Tensor) -> Tensor:
    """``(..., S, PER_SLOT)`` SRVF values and ``(..., S)`` positions -> layout features (slot 0 has no position)."""
    return torch.cat([q.flatten(-2), s[..., 1:]], dim=-1)



def population(g: torch.Generator) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Per plant: its truth ``(P, m, F)``, ``DRAWS`` continuations ``(P, K, m, F)`` from its conditional
    distribution, the slots it was seen with ``(P, m, S)`` and the population's expectation ``(m, F)``.

    The observed half determines the observed organs' future (a plant's own vector, known to its continuations);
    where new organs appear is independent of it (each new slot present with ``P_NEW``, at that slot's vector)."""
    slot_vec = torch.randn(SLOTS, PER_SLOT, generator=g, dtype=torch.float64)
    slot_s = torch.rand(SLOTS, generator=g, dtype=torch.float64)
    growth = torch.linspace(1.0, 2.0, FRAMES, dtype=torch.float64)[:, None, None]

    def new_organs(shape: tuple[int, ...]) -> Tensor:
        on = torch.rand(*shape, SLOTS, generator=g, dtype=torch.float64) < P_NEW
        on[..., :OLD] = False
        return on

    seen = torch.rand(PLANTS, SLOTS, generator=g, dtype=torch.float64) < P_OLD
    seen[:, OLD:] = False
    own = torch.randn(PLANTS, SLOTS, PER_SLOT, generator=g, dtype=torch.float64)

    def plants(on_new: Tensor) -> Tensor:
        """Features of plants with their seen organs and the new organs ``on_new (P, [K,] S)``."""
        extra = on_new.dim() - seen.dim()
        sn = seen.reshape(PLANTS, *([1] * extra), SLOTS)
        ow = own.reshape(PLANTS, *([1] * extra), SLOTS, PER_SLOT)
        q = torch.where(sn[..., None], ow, 0.0) + torch.where(on_new[..., None], slot_vec, 0.0)
        s = torch.where(sn | on_new, slot_s, 0.0)
        qt = q.unsqueeze(-3) * growth  # (..., m, S, PER_SLOT)
        return features(qt, s.unsqueeze(-2).expand(*s.shape[:-1], FRAMES, SLOTS))

    truth = plants(new_organs((PLANTS,)))
    draws = plants(new_organs((PLANTS, DRAWS)))
    # the population's expectation: observed organs have mean zero vectors, new ones are at their slot's vector
    q_mean = torch.zeros(SLOTS, PER_SLOT, dtype=torch.float64)
    q_mean[OLD:] = P_NEW * slot_vec[OLD:]
    s_mean = torch.cat([torch.full((OLD,), P_OLD), torch.full((SLOTS - OLD,), P_NEW)]).to(slot_s) * slot_s
    prior = features(q_mean * growth, s_mean.expand(FRAMES, SLOTS))
    return truth, draws, seen[:, None, :].expand(PLANTS, FRAMES, SLOTS), prior


def error(x: Tensor, truth: Tensor) -> Tensor:
    """Per plant, the mean over frames of the distance (the section's forecast error)."""
    return (x - truth).norm(dim=-1).mean(-1)


def test_the_point_takes_the_continuations_at_seen_slots_and_their_blend_with_the_prior_elsewhere() -> None:
    g = torch.Generator().manual_seed(0)
    draws = torch.randn(3, FRAMES, SLOTS * PER_SLOT + SLOTS - 1, generator=g, dtype=torch.float64)
    prior = torch.randn(FRAMES, SLOTS * PER_SLOT + SLOTS - 1, generator=g, dtype=torch.float64)
    seen = torch.rand(FRAMES, SLOTS, generator=g) < 0.5
    point = forecast_point(draws, seen, prior)
    assert torch.equal(forecast_point(draws, seen, prior, weight=1.0), draws.mean(0))
    assert torch.equal(seen_slots(point, SLOTS), point[:, :SLOTS * PER_SLOT].reshape(FRAMES, SLOTS, -1).ne(0).any(-1))
    w = NEW_SLOT_WEIGHT
    blend = w * draws.mean(0) + (1 - w) * prior
    q, s = point[:, :SLOTS * PER_SLOT].reshape(FRAMES, SLOTS, PER_SLOT), point[:, SLOTS * PER_SLOT:]
    mean = draws.mean(0)
    mq, ms = mean[:, :SLOTS * PER_SLOT].reshape(FRAMES, SLOTS, PER_SLOT), mean[:, SLOTS * PER_SLOT:]
    pq, ps = blend[:, :SLOTS * PER_SLOT].reshape(FRAMES, SLOTS, PER_SLOT), blend[:, SLOTS * PER_SLOT:]
    assert torch.equal(q[seen], mq[seen]) and torch.equal(q[~seen], pq[~seen])
    assert torch.equal(s[seen[:, 1:]], ms[seen[:, 1:]]) and torch.equal(s[~seen[:, 1:]], ps[~seen[:, 1:]])
    assert torch.equal(forecast_point(draws, torch.ones_like(seen), prior), mean)
    with pytest.raises(ValueError):
        forecast_point(draws, seen[:, 1:], prior)


def test_the_point_beats_the_population_mean_where_the_observed_half_tells() -> None:
    truth, draws, seen, prior = population(torch.Generator().manual_seed(1))
    point = torch.stack([forecast_point(draws[i], seen[i], prior) for i in range(PLANTS)])
    to_point, to_prior = error(point, truth), error(prior.expand_as(truth), truth)
    to_draws = error(draws.mean(1), truth)
    # the observed organs' future is known: the point beats the population's mean on (nearly) every plant with one
    assert float((to_point < to_prior).double().mean()) >= 0.95
    # where new organs appear is not: blended with the population's expectation there, the point beats a few
    # continuations' mean
    assert float(to_point.mean()) < float(to_draws.mean())
