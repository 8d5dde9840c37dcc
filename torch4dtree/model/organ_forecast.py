"""Forecasting with :class:`~torch4dtree.model.organs.OrganModel`: the same model, given a plant's first frames.

The observed plant is registered within itself and written in botanical keys (docs/method.md §5, forecasting).
Its **stated conditional distribution** (:func:`forecast_distribution`): the training plants weighted by how close
their total length and organ count at the observed age are to the plant's (the model's kernel, read at that age, its
width chosen by leave-one-out over the training plants, one-standard-error rule); a continuation draws one of them
(the *donor*) by these weights and its final log total length as

    log L(1) = log L_donor(1) + beta * (log L(u_obs) - log L_donor(u_obs)) + jitter * eps,    eps ~ N(0, 1),

the donor's final length moved by the share ``beta`` of how much larger the plant is now (``beta`` the least-squares
slope of log L(1) on log L(u_obs) over the training plants, clipped to [0, 1]: 1 when size now is all that tells
plants apart later, 0 when it tells nothing): a Gaussian mixture over the donors with the stated mean and variance.

The organs then follow the donor as in sampling (persistence and switches): an observed organ keeps its size, shape
and place (arc length along its parent) at the last observed frame, grows on as its donor organ grows after that
age and vanishes where its donor organ vanishes (leaves that die); new organs are the donor's organs on the
corresponding parent, appended after the observed ones: as many as make the parent's final count
``m + beta_n * (n - m_now)`` (``n`` the plant's children there now; ``m``, ``m_now`` the donor's at the end and at
the observed age; ``beta_n`` the least-squares slope of the final organ count on the count at the observed age over
the training plants, clipped to [0, 1]: 1 adds what the donor adds after that age, 0 makes the donor's final count),
the donor's latest (by rank along the parent). All growth after the observed age (the observed organs' increments
and the new organs) is scaled by one factor so that the final frame's total length is the drawn one (the draw is
met unless it is below the length of the observed organs that remain): one factor for all growth keeps every organ
near its donor organ's size. Observed organs at keys no training plant has stay as seen.

The forecast's **point** in a slot layout (:func:`forecast_point`): the continuations' mean at the slots where the
observed plant has an organ, averaged with the population's expectation at every other slot.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from ..trees.structures import TreeSequence
from .organ_table import azimuth, plant_organs
from .organs import OrganModel, assemble_frames, carry_parents, rotate_about_up

__all__ = ["ForecastDistribution", "forecast_distribution", "forecast_organs", "forecast_point", "seen_slots"]

# the donor kernel's widths (standard deviations of size and organ count at the observed age) that the forecast
# chooses from by leave-one-out over the training plants; the widest is nearly the population as a whole
BANDWIDTHS = (0.25, 0.5, 1.0, 2.0, 4.0)
# a continuation whose organs add no length after the observed age (nothing left to grow) keeps the observed size
NO_GROWTH = 1e-12
# the continuations' share of the forecast point at slots the observed plant has no organ in (forecast_point): an
# equal average of their mean and the population's (0.25-0.75 measured on synthetic tomato, bean and maize, fresh
# populations included: docs/experiments.md)
NEW_SLOT_WEIGHT = 0.5


@dataclass
class ForecastDistribution:
    """The forecast's stated conditional distribution of a plant's final log total length (module doc).

    Attributes:
        age: the observed normalised age ``u_obs`` (the last observed frame's time on the model's age scale).
        weights: ``(P,)`` each training plant's chance to be the donor (sum 1).
        components: ``(P,)`` the mean final log total length with each training plant as the donor.
        slope: ``beta``.
        log_length_now: the observed plant's log total length at its last observed frame.
        jitter: standard deviation of the Gaussian noise added to the log final length (the model's ``jitter``).
        bandwidth: the donor kernel's width, chosen by leave-one-out over the training plants (:data:`BANDWIDTHS`).
        count_slope: ``beta_n``, the least-squares slope of the final organ count on the organ count at the observed
            age over the training plants, clipped to [0, 1] (how many new organs a continuation gets, module doc).
    """

    age: float
    weights: Tensor
    components: Tensor
    slope: float
    log_length_now: float
    jitter: float
    bandwidth: float
    count_slope: float = 0.0

    @property
    def mean(self) -> Tensor:
        """``(1,)`` mean of the final log total length."""
        return (self.weights * self.components).sum().reshape(1)

    @property
    def covariance(self) -> Tensor:
        """``(1, 1)`` its variance: the donors' spread plus the jitter's."""
        return ((self.weights * (self.components - self.mean).square()).sum() + self.jitter ** 2).reshape(1, 1)

    def draw(self, generator: torch.Generator) -> tuple[int, float]:
        """One donor plant and final log total length from the distribution."""
        donor = int(torch.multinomial(self.weights, 1, generator=generator))
        eps = float(torch.randn((), generator=generator, dtype=torch.float64))
        return donor, float(self.components[donor]) + self.jitter * eps


def _plant_curves(model: OrganModel) -> tuple[Tensor, Tensor]:
    """Per training plant, total length and organ count at each age of the model: two ``(P, G)`` tensors."""
    has = model.record >= 0
    P = has.shape[0]
    plant = torch.zeros(len(model.log_length), dtype=torch.long)
    rows, cols = torch.nonzero(has, as_tuple=True)
    plant[model.record[rows, cols]] = rows
    sizes = model.log_length.exp()[:, None] * model.growth  # (R, G)
    total = torch.zeros(P, sizes.shape[1], dtype=torch.float64).index_add_(0, plant, sizes)
    count = torch.zeros(P, sizes.shape[1], dtype=torch.float64).index_add_(0, plant, (sizes > 0).to(torch.float64))
    return total, count


def _bandwidth(d2: Tensor, final: Tensor, shift: Tensor) -> float:
    """The donor kernel's width (standard deviations, one of :data:`BANDWIDTHS`) for predicting each training
    plant's standardised final log length and log organ count ``final (P, 2)`` from the others (leave-one-out squared
    error): the widest whose mean error is within one standard error of the best width's (a narrow kernel wins only
    where it predicts clearly better; it draws from fewer donors). ``d2 (P, P)``: squared standardised distances
    between the plants at the observed age; ``shift (P, P)``: the size adjustment of donor ``j`` for plant ``i``
    (standardised log length)."""
    off = ~torch.eye(len(d2), dtype=torch.bool)
    errors = []
    for h in BANDWIDTHS:
        k = torch.exp(-0.5 * d2 / h ** 2) * off
        k = k / k.sum(1, keepdim=True).clamp_min(torch.finfo(k.dtype).tiny)
        pred = torch.stack([(k * (final[None, :, 0] + shift)).sum(1), (k * final[None, :, 1]).sum(1)], 1)
        errors.append((pred - final).square().sum(1))  # (P,) per plant
    means = torch.stack([e.mean() for e in errors])
    best = int(means.argmin())
    bound = float(means[best] + errors[best].std() / math.sqrt(len(d2)))
    return max(h for h, m in zip(BANDWIDTHS, means.tolist()) if m <= bound)


def _slope(x: Tensor, y: Tensor) -> float:
    """The least-squares slope of ``y (P,)`` on ``x (P,)``, clipped to [0, 1] (0 when ``x`` does not vary)."""
    dx = x - x.mean()
    var = float(dx.square().sum())
    return min(max(float((dx * (y - y.mean())).sum()) / var, 0.0), 1.0) if var > 0 else 0.0


def _observe(model: OrganModel, partial: TreeSequence) -> tuple[dict[tuple[int, ...], dict], ForecastDistribution]:
    """The observed organs by key (each at the last observed frame) and the stated distribution."""
    model.check_fitted()
    ages = model.ages
    u_obs = float(((partial.times[-1].double() - model.time_start) / model.duration).clamp(0, 1))
    # the observed organs, each at the last observed frame (a single grid age of 1 is that frame)
    observed = {tuple(o["key"]): o for o in plant_organs(partial, torch.ones(1, dtype=torch.float64),
                                                         model.settings.registration)}
    now = sum(o["length"] * float(o["growth"][-1]) for o in observed.values())
    total, count = _plant_curves(model)
    x = torch.tensor([now, float(sum(float(o["growth"][-1]) > 0 for o in observed.values()))], dtype=torch.float64)
    at = [torch.tensor([float(np.interp(u_obs, ages.numpy(), c.numpy())) for c in curve]) for curve in (total, count)]
    feats = torch.stack([a.log1p() for a in at], 1)  # (P, 2)
    scale = feats.std(0).clamp_min(1e-9)
    log_final, log_at = total[:, -1].clamp_min(NO_GROWTH).log(), at[0].clamp_min(NO_GROWTH).log()
    beta = _slope(log_at, log_final)
    d2 = ((feats[:, None] - feats[None]) / scale).square().sum(-1)  # (P, P) between training plants
    final = torch.stack([log_final, count[:, -1].log1p()], 1)
    sd = final.std(0).clamp_min(1e-9)
    bandwidth = _bandwidth(d2, final / sd, beta * (log_at[:, None] - log_at[None]) / sd[0])
    w = torch.exp(-0.5 * ((feats - x.log1p()) / scale).square().sum(-1) / bandwidth ** 2)
    w = w / w.sum() if float(w.sum()) > 0 else torch.full_like(w, 1 / len(w))
    log_now = math.log(max(now, NO_GROWTH))
    dist = ForecastDistribution(age=u_obs, weights=w, components=log_final + beta * (log_now - log_at), slope=beta,
                                log_length_now=log_now, jitter=model.settings.jitter, bandwidth=bandwidth,
                                count_slope=_slope(at[1], count[:, -1]))
    return observed, dist


def forecast_distribution(model: OrganModel, partial: TreeSequence) -> ForecastDistribution:
    """The stated conditional distribution of :func:`forecast_organs` for a plant seen in ``partial`` (module doc):
    the continuations' final log total lengths have its ``mean`` and ``covariance``.

    Example:
        >>> from torch4dtree.data.synthetic import synthetic_plant
        >>> train = [synthetic_plant(kind="bean", seed=i, n_frames=4, T=16).sequence for i in range(3)]
        >>> dist = forecast_distribution(OrganModel().fit(train), train[0][[0, 1]])
        >>> dist.weights.shape, dist.covariance.shape, bool(dist.mean > dist.log_length_now)
        (torch.Size([3]), torch.Size([1, 1]), True)
    """
    return _observe(model, partial)[1]


def _holder(model: OrganModel, w: Tensor, key: int, g: torch.Generator) -> int:
    """A training plant that has organ ``key``, drawn by the weights ``w`` (uniformly if they vanish there)."""
    has = model.record[:, key] >= 0
    p = torch.where(has, w, torch.zeros_like(w))
    if not float(p.sum()) > 0:
        p = has.to(torch.float64)
    return int(torch.multinomial(p, 1, generator=g))


def forecast_organs(model: OrganModel, partial: TreeSequence, n: int = 1, generator: torch.Generator | None = None
                    ) -> list[TreeSequence]:
    """``n`` continuations of a plant seen in ``partial`` (its first frames, times in the training plants' units),
    drawn from :func:`forecast_distribution` (module doc).

    Returns:
        ``n`` 4D trees at the model's ages after the last observed one (:meth:`OrganModel.times`; at least the
        last age), ``label`` = the organ's index in the continuation (one identity over its frames).

    Example:
        >>> from torch4dtree.data.synthetic import synthetic_plant
        >>> train = [synthetic_plant(kind="bean", seed=i, n_frames=4, T=16).sequence for i in range(3)]
        >>> model = OrganModel().fit(train)
        >>> future = forecast_organs(model, train[0][[0, 1]], n=2, generator=torch.Generator().manual_seed(0))
        >>> len(future), len(future[0]) >= 1
        (2, True)
    """
    g = generator if generator is not None else torch.Generator().manual_seed(0)
    observed, dist = _observe(model, partial)
    ages = model.ages
    future = ages > dist.age + 1e-9
    if not bool(future.any()):
        future[-1] = True
    j_obs = int((ages - dist.age).abs().argmin())
    index = {k: i for i, k in enumerate(model.keys)}
    children: list[list[int]] = [[] for _ in model.keys]
    for k in range(1, len(model.keys)):
        children[int(model.key_parent[k])].append(k)  # keys are sorted: siblings in rank order
    out = []
    for i in range(n):
        donor, log_final = dist.draw(g)
        plant = _continuation(model, observed, donor, log_final, dist, j_obs, index, children, g, f"forecast_{i:03d}")
        out.append(plant[torch.nonzero(future).reshape(-1).tolist()])
    return out


def _new_children(model: OrganModel, plant: int, keys: list[int], observed: dict[tuple[int, ...], dict],
                  key: tuple[int, ...], j_obs: int, slope: float, was_seen: bool) -> list[int]:
    """The key indices of the new children a continuation takes from training ``plant`` on the organ at ``key``
    (``keys``: all children keys of that organ, in rank order): on a new organ, all of the plant's; on an observed
    organ with ``n`` children now, of the plant's ``m`` children (``m_now`` of them at the observed age) the last
    ``round(m + slope * (n - m_now)) - n`` (module doc)."""
    rows = {c: int(model.record[plant, c]) for c in keys}
    has = [c for c in keys if rows[c] >= 0 and float(model.growth[rows[c]].max()) > 0]
    if not was_seen:
        return has
    n = sum(1 for o in observed if len(o) == len(key) + 1 and o[:-1] == key)
    m_now = sum(1 for c in has if float(model.growth[rows[c], j_obs]) > 0)
    new = max(0, round(len(has) + slope * (n - m_now)) - n)
    return has[len(has) - new:] if new else []


def _continuation(model: OrganModel, observed: dict[tuple[int, ...], dict], donor: int, log_final: float,
                  dist: ForecastDistribution, j_obs: int, index: dict[tuple[int, ...], int],
                  children: list[list[int]], g: torch.Generator, name: str) -> TreeSequence:
    """One continuation given its donor plant and final log total length (module doc), at all the model's ages."""
    G = len(model.ages)
    w = dist.weights
    fixed: list[Tensor] = []  # per organ: its size at the observed age (kept), and what it grows after
    grow: list[Tensor] = []
    shapes: list[Tensor] = []
    s: list[Tensor] = []
    parent: list[int] = []
    az: list[float] = []
    source: list[tuple[int, int, bool]] = []  # per organ: its donor plant, the donor's key (-1: none), observed
    local = {}
    for key, o in observed.items():  # parents first
        if key and key[:-1] not in local:
            continue
        k = index.get(key, -1)
        plant = donor if k >= 0 and int(model.record[donor, k]) >= 0 else (_holder(model, w, k, g) if k >= 0 else -1)
        now = o["length"] * float(o["growth"][-1])
        a = float(azimuth(o["shape"][-1]))
        shape = o["shape"][-1].expand(G, *o["shape"].shape[1:]).clone()
        inc = torch.zeros(G, dtype=torch.float64)
        kept = torch.full((G,), now, dtype=torch.float64)
        if plant >= 0:
            r = int(model.record[plant, k])
            donor_len = model.log_length[r].exp() * model.growth[r]
            inc = (donor_len - donor_len[j_obs]).clamp_min(0.0)
            inc[: j_obs + 1] = 0.0
            shape[j_obs + 1:] = rotate_about_up(model.shape[r], a - float(model.azimuth[r]))[j_obs + 1:]
            gone = (model.growth[r] <= 0) & (torch.arange(G) > j_obs)  # the donor organ has vanished by then
            kept[gone], inc[gone] = 0.0, 0.0
        local[key] = len(fixed)
        fixed.append(kept)
        grow.append(inc)
        shapes.append(shape)
        s.append(o["s"][-1].expand(G).clone())
        parent.append(local[key[:-1]] if key else -1)
        az.append(a)
        source.append((plant, k, True))
    # new organs: each organ's donor (or, by switching, another plant with that organ) lends its later children
    j = 0
    while j < len(fixed):
        plant, k, was_seen = source[j]
        if k >= 0:
            if float(torch.rand((), generator=g, dtype=torch.float64)) >= model.settings.persistence:
                plant = _holder(model, w, k, g)
            key = model.keys[k]
            for c in _new_children(model, plant, children[k], observed, key, j_obs, dist.count_slope, was_seen):
                r = int(model.record[plant, c])
                turn = az[j] - float(model.parent_azimuth[r])
                fixed.append(torch.zeros(G, dtype=torch.float64))
                grow.append(model.log_length[r].exp() * model.growth[r])
                shapes.append(rotate_about_up(model.shape[r], turn))
                s.append(model.s[r].clone())
                parent.append(j)
                az.append(float(model.azimuth[r]) + turn)
                source.append((plant, c, False))
        j += 1
    # all growth after the observed age (observed organs' increments, new organs) is scaled by one factor so that
    # the final total length is the drawn one
    seen = [m for m in range(len(fixed)) if source[m][2]]
    room = math.exp(log_final) - sum(float(fixed[m][-1]) for m in seen)
    growth = sum(float(grow[m][-1]) for m in range(len(fixed)))
    factor = max(room, 0.0) / growth if growth > NO_GROWTH else 0.0
    sizes = {m: fixed[m] + factor * grow[m] for m in range(len(fixed))}
    for m in seen[1:]:  # an observed organ keeps its place (arc length) on a parent that grows at its tip
        p = parent[m]
        s[m] = s[m] * fixed[p][-1].clamp_min(NO_GROWTH) / sizes[p].clamp_min(fixed[p][-1].clamp_min(NO_GROWTH))
    depth = []
    for m in range(len(parent)):
        d, up = 0, parent[m]
        while up >= 0:
            d, up = d + 1, parent[up]
        depth.append(d)
    carried = carry_parents(torch.stack([sizes[m] for m in range(len(fixed))])[None], torch.tensor(parent), depth)[0]
    return assemble_frames(dict(enumerate(carried)), dict(enumerate(shapes)), dict(enumerate(s)),
                           torch.tensor(parent), model.times().clone(), name)


def forecast_point(draws: Tensor, seen: Tensor, prior: Tensor, weight: float = NEW_SLOT_WEIGHT) -> Tensor:
    """The forecast's point in a slot layout (features as :meth:`~torch4dtree.trees.aligned.AlignedTrees.features`:
    each of ``S`` slots' SRVF values, then the positions of slots ``1 .. S - 1``): per slot and frame, the mean of
    the continuations where the observed plant has that organ; at every other slot, ``weight`` times that mean plus
    ``1 - weight`` times the population's ``prior`` there.

    Why: an observed organ's future is the plant's own (its continuations carry it at its slot, their mean is its
    conditional expectation), while a new organ's slot is uncertain: a few continuations put it at a few donors'
    slots at full norm, farther in the tree metric than the population's expectation of each slot at that age;
    the two are averaged there (docs/method.md §5, forecasting).

    Args:
        draws: ``(K, m, F)`` the continuations' features at the ``m`` forecast frames (``K >= 1``).
        seen: ``(m, S)`` bool, the slots where the observed plant has an organ (its last observed frame carried to
            the forecast frames, written in the layout as the continuations are).
        prior: ``(m, F)`` the population's features at the same ages (e.g. the 4D mean).
        weight: the continuations' share at the slots not seen (1: their mean everywhere; 0: the prior there).

    Returns:
        ``(m, F)`` the point.

    Example:
        >>> draws = torch.tensor([[[1.0, 1.0, 2.0, 2.0, 0.5]], [[3.0, 3.0, 0.0, 0.0, 0.7]]])  # K=2, m=1, S=2
        >>> forecast_point(draws, torch.tensor([[True, False]]), torch.full((1, 5), 0.1))
        tensor([[2.0000, 2.0000, 0.5500, 0.5500, 0.3500]])
    """
    if draws.dim() != 3 or draws.shape[0] < 1 or prior.shape != draws.shape[1:]:
        raise ValueError(f"draws must be (K >= 1, m, F) and prior (m, F), got {tuple(draws.shape)} and "
                         f"{tuple(prior.shape)}")
    m, S = seen.shape
    F = draws.shape[-1]
    if seen.shape[0] != draws.shape[1] or F < S - 1 or (F - (S - 1)) % S:
        raise ValueError(f"seen {tuple(seen.shape)} does not match features of {F} values in {m} frames")
    per_slot = (F - (S - 1)) // S
    keep = torch.cat([seen.repeat_interleave(per_slot, dim=1), seen[:, 1:]], dim=1)  # (m, F)
    mean = draws.mean(0)
    return torch.where(keep, mean, weight * mean + (1 - weight) * prior.to(draws))


def seen_slots(features: Tensor, slots: int) -> Tensor:
    """``(m, S)`` bool: the slots with an organ (a nonzero SRVF) in layout features ``(m, F)`` of ``S = slots``
    slots, e.g. of the observed plant's last frame carried to the forecast frames (:func:`forecast_point`).

    Example:
        >>> seen_slots(torch.tensor([[1.0, 0.0, 0.0, 0.0, 0.3]]), 2)
        tensor([[ True, False]])
    """
    per_slot = (features.shape[-1] - (slots - 1)) // slots
    return features[..., :slots * per_slot].reshape(*features.shape[:-1], slots, per_slot).ne(0).any(-1)
