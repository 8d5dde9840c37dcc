"""Forecasting with :class:`~torch4dtree.model.organs.OrganModel`: the same model, given a plant's first frames.

The observed plant is registered within itself and written in botanical keys (docs/method.md §5, forecasting).
The training plants are weighted by how close their total length and organ count at the observed age are to the
plant's (the kernel of the model, read at that age instead of at the end). Then key by key, as in sampling, every
organ follows a training plant (persistence and switches): an observed organ keeps its size, shape and place at the
last observed frame and grows on by what its donor organ grows from that age; an organ not yet there appears where
its donor's organ appears after that age. Observed organs at keys the training plants never had are left out.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from ..trees.structures import TreeSequence
from .organ_table import azimuth, plant_organs
from .organs import OrganModel, assemble_frames, rotate_about_up

__all__ = ["forecast_organs"]


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


def forecast_organs(model: OrganModel, partial: TreeSequence, n: int = 1, generator: torch.Generator | None = None
                    ) -> list[TreeSequence]:
    """``n`` continuations of a plant seen in ``partial`` (its first frames, times in the training plants' units).

    Returns:
        ``n`` 4D trees at the model's ages after the last observed one (:meth:`OrganModel.times`; at least the
        last age), ``label`` = botanical key index.

    Example:
        >>> from torch4dtree.data.synthetic import synthetic_plant
        >>> train = [synthetic_plant(kind="bean", seed=i, n_frames=4, T=16).sequence for i in range(3)]
        >>> model = OrganModel().fit(train)
        >>> future = forecast_organs(model, train[0][[0, 1]], n=2, generator=torch.Generator().manual_seed(0))
        >>> len(future), len(future[0]) >= 1
        (2, True)
    """
    model.check_fitted()
    g = generator if generator is not None else torch.Generator().manual_seed(0)
    ages = model.ages
    u_obs = float(((partial.times[-1].double() - model.time_start) / model.duration).clamp(0, 1))
    future = ages > u_obs + 1e-9
    if not bool(future.any()):
        future[-1] = True
    # the observed organs, each at the last observed frame (a single grid age of 1 is that frame)
    observed = {tuple(o["key"]): o for o in plant_organs(partial, torch.ones(1, dtype=torch.float64),
                                                         model.settings.registration)}
    total, count = _plant_curves(model)
    x = torch.tensor([sum(o["length"] * float(o["growth"][-1]) for o in observed.values()),
                      float(sum(float(o["growth"][-1]) > 0 for o in observed.values()))], dtype=torch.float64)
    at = [torch.tensor([float(np.interp(u_obs, ages.numpy(), c.numpy())) for c in curve]) for curve in (total, count)]
    feats = torch.stack([a.log1p() for a in at], 1)  # (P, 2)
    scale = feats.std(0).clamp_min(1e-9)
    w = torch.exp(-0.5 * ((feats - x.log1p()) / scale).square().sum(-1) / model.settings.bandwidth ** 2)
    w = w / w.sum() if float(w.sum()) > 0 else torch.full_like(w, 1 / len(w))
    j_obs = int((ages - u_obs).abs().argmin())
    has = model.record >= 0
    G = len(ages)
    out = []
    for i in range(n):
        sizes: dict[int, Tensor] = {}
        shapes: dict[int, Tensor] = {}
        s: dict[int, Tensor] = {}
        donor_of: dict[int, int] = {}
        az: dict[int, float] = {}  # each organ's azimuth in the forecast
        for k, key in enumerate(model.keys):
            cond = int(model.key_condition[k])
            if k == 0:
                donor = int(torch.multinomial(w, 1, generator=g))
            else:
                if cond not in donor_of:
                    continue
                donor = donor_of[cond]
                if float(torch.rand((), generator=g, dtype=torch.float64)) >= model.settings.persistence:
                    donor = int(torch.multinomial(torch.where(has[:, cond], w, torch.zeros_like(w)), 1, generator=g))
            seen = observed.get(key)
            r = int(model.record[donor, k])
            if seen is None and (r < 0 or float(model.growth[r, j_obs]) > 0):
                continue  # not there now, and its donor does not grow it later
            if r < 0:  # observed, but this donor lacks it: any training plant with the key lends its growth
                holders = torch.nonzero(has[:, k]).reshape(-1)
                if len(holders) == 0:
                    continue
                r = int(model.record[holders[0], k])
            donor_of[k] = donor
            if seen is not None:
                now = seen["length"] * float(seen["growth"][-1])
                donor_len = model.log_length[r].exp() * model.growth[r]
                sizes[k] = now + (donor_len - donor_len[j_obs]).clamp_min(0.0)  # the donor's growth from now on
                az[k] = float(azimuth(seen["shape"][-1]))
                shapes[k] = rotate_about_up(model.shape[r], az[k] - float(model.azimuth[r]))
                shapes[k][: j_obs + 1] = seen["shape"][-1]
                s[k] = seen["s"][-1].expand(G).clone()
            else:
                parent = int(model.key_parent[k])
                turn = (az[parent] - float(model.parent_azimuth[r]) if parent in az
                        else 2 * math.pi * float(torch.rand((), generator=g, dtype=torch.float64)))
                az[k] = float(model.azimuth[r]) + turn
                sizes[k] = model.log_length[r].exp() * model.growth[r]
                shapes[k] = rotate_about_up(model.shape[r], turn)
                s[k] = model.s[r].clone()
        if 0 not in sizes:  # the main branch is always observed; a model without its key keeps it as seen
            main = observed[()]
            sizes[0] = torch.full((G,), main["length"] * float(main["growth"][-1]), dtype=torch.float64)
            shapes[0] = main["shape"][-1].expand(G, *main["shape"].shape[1:]).clone()
            s[0] = torch.zeros(G, dtype=torch.float64)
        plant = assemble_frames(sizes, shapes, s, model.key_parent, model.times().clone(), f"forecast_{i:03d}")
        out.append(plant[torch.nonzero(future).reshape(-1).tolist()])
    return out
