"""Organs of growing plants keyed by botanical position: the training table of :class:`OrganModel`.

A 4D tree is registered within itself (:func:`torch4dtree.temporal.register_sequence`, docs/method.md §5): every
slot is one organ over the whole sequence. Each organ gets a **botanical key**: its parent's key followed by its
rank among its parent's organs ordered by attachment position (``()`` the main branch, ``(3,)`` the fourth organ
from the base of the main branch, ``(3, 0)`` the first organ on that one). Keys are open-ended: any plant can be
written in them, and the same key names the same place in every plant.

Per organ the table keeps size apart from shape and from timing: its largest length ``L`` (log), its unit-length
curve (translated to start at 0) at each age, its growth curve ``r(u) = length(u) / L`` on a common grid of
normalised ages ``u`` (0 before it appears and after it was last seen; monotone in between, as organs grow), where
it attaches on its parent (``s``) and its azimuth about the vertical relative to its parent's.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from ..settings import RegistrationSettings
from ..trees.structures import Trees, TreeSequence

__all__ = ["OrganTable", "azimuth", "organ_table", "plant_organs"]

# the vertical axis (the plants' "up"; the azimuth of an organ is its direction about it)
UP = 2


@dataclass
class OrganTable:
    """Organ records of ``P`` plants (``R`` organs in all, ``K`` keys, ``G`` ages, ``T`` points, dimension ``d``).

    Attributes:
        keys: the ``K`` botanical keys (tuples of ranks), parents before children.
        key_parent: ``(K,)`` long, index of each key's parent key (``-1`` for the main branch ``()``).
        plant: ``(R,)`` long, the plant of each organ.
        key: ``(R,)`` long, the key of each organ.
        log_length: ``(R,)`` log of the organ's largest length.
        shape: ``(R, G, T, d)`` unit-length curve starting at the origin at each age (organs bend as they grow).
        growth: ``(R, G)`` length over largest length at each age of ``ages`` (in ``[0, 1]``; monotone while the
            organ is seen, 0 before it appears and after it was last seen).
        s: ``(R, G)`` attachment parameter on the parent at each age (0 for the main branch): organs keep their place
            on a stem that grows at its tip, so the share of the parent below them changes with age.
        azimuth: ``(R,)`` the organ's azimuth (radians) about the vertical.
        parent_azimuth: ``(R,)`` its parent's azimuth (the main branch's own).
        ages: ``(G,)`` normalised ages in ``[0, 1]``.
        summary: ``(P, 3)`` per plant: log total length at the last and the middle age, log(1 + organs at the last).
    """

    keys: list[tuple[int, ...]]
    key_parent: Tensor
    plant: Tensor
    key: Tensor
    log_length: Tensor
    shape: Tensor
    growth: Tensor
    s: Tensor
    azimuth: Tensor
    parent_azimuth: Tensor
    ages: Tensor
    summary: Tensor


def azimuth(curves: Tensor) -> Tensor:
    """``(..., T, d) -> (...)`` the angle about the vertical of each curve's chord (first to last point).

    Example:
        >>> round(float(azimuth(torch.tensor([[0.0, 0.0, 0.0], [0.0, 1.0, 1.0]]))), 4)
        1.5708
    """
    chord = curves[..., -1, :] - curves[..., 0, :]
    horizontal = [i for i in range(curves.shape[-1]) if i != UP][:2]
    return torch.atan2(chord[..., horizontal[1]], chord[..., horizontal[0]])


def plant_organs(seq: TreeSequence, ages: Tensor, registration: RegistrationSettings | None = None
                 ) -> list[dict[str, object]]:
    """The organs of one 4D tree, keyed by botanical position (module doc).

    Args:
        seq: the 4D tree (``n`` frames).
        ages: ``(G,)`` normalised ages at which growth curves are read (linear between frames).
        registration: how the within-sequence registration searches (:func:`torch4dtree.temporal.register_sequence`'s
            ``registration``; ``None``: the defaults).

    Returns:
        One dict per organ, parents first: ``key`` (tuple), ``length`` (float), ``shape (G, T, d)``, ``growth (G,)``,
        ``s`` (float), ``azimuth`` (float), ``parent_azimuth`` (float).
    """
    from ..temporal.within import register_sequence

    frames = seq.frames.to(torch.float64)
    n = len(seq)
    if n >= 2:
        aligned = register_sequence(TreeSequence(frames, seq.times.to(torch.float64), seq.name),
                                    registration=registration)
        identity = aligned.identity  # (n, S)
        slot_parent = aligned.aligned.slot_parent.tolist()
    else:
        identity = torch.arange(int(frames.num_branches[0]))[None]
        slot_parent = frames.parent.tolist()
    S = identity.shape[1]
    ptr = frames.ptr[:-1]
    lengths = frames.branch_lengths()
    glob = torch.where(identity >= 0, identity + ptr[:, None], torch.full_like(identity, -1))  # (n, S)
    slot_len = torch.where(glob >= 0, lengths[glob.clamp(min=0)], torch.zeros((), dtype=lengths.dtype))  # (n, S)
    best = slot_len.argmax(0)  # frame of each slot's largest length
    u = seq.normalized_times().to(torch.float64)
    children: list[list[int]] = [[] for _ in range(S)]
    for k in range(1, S):
        if slot_len[:, k].max() > 0 and slot_parent[k] >= 0:
            children[slot_parent[k]].append(k)
    s_best = frames.s[glob[best, torch.arange(S)].clamp(min=0)]
    organs: list[dict[str, object]] = []
    stack: list[tuple[int, tuple[int, ...], float]] = [(0, (), math.nan)]
    while stack:
        k, key, parent_az = stack.pop()
        g = int(glob[best[k], k])
        if g < 0:
            continue
        curve = frames.points[g]
        L = float(slot_len[best[k], k])
        if not L > 0:
            continue
        az = float(azimuth(curve))
        growth, shape, s_age = _growth_and_shapes(slot_len[:, k] / L, glob[:, k], frames, lengths, u, ages)
        organs.append({"key": key, "length": L, "shape": shape, "growth": growth,
                       "s": s_age if key else torch.zeros_like(s_age), "azimuth": az,
                       "parent_azimuth": az if not key else parent_az})
        kids = sorted(children[k], key=lambda c: float(s_best[c]))
        stack.extend((c, key + (rank,), az) for rank, c in reversed(list(enumerate(kids))))
    return organs


def _growth_and_shapes(r: Tensor, glob: Tensor, frames: Trees, lengths: Tensor, u: Tensor, ages: Tensor
                       ) -> tuple[Tensor, Tensor, Tensor]:
    """One organ's growth curve ``(G,)``, unit-length shapes ``(G, T, d)`` and attachment ``s (G,)`` at ``ages``,
    from its relative length ``r (n,)`` and packed branch ``glob (n,)`` (-1 where absent) in each of the ``n`` frames
    of ``frames`` (branch lengths ``lengths``) at normalised times ``u``."""
    seen = torch.nonzero(glob >= 0).reshape(-1)
    first, last = int(seen[0]), int(seen[-1])
    r = r.clone()
    r[first:last + 1] = torch.cummax(r[first:last + 1], 0).values  # growing: a dip or a missed frame is no growth
    uu, aa = u.numpy(), ages.numpy()
    if len(u) < 2:
        return r.expand(len(ages)).clone(), *_nearest_shapes(seen, glob, frames, lengths, u, ages)
    # between frames the length is linear, but the organ is there only nearer to a frame that holds it: it appears
    # and goes at the midpoints (a count read between frames then matches the frames' own, linearly interpolated)
    growth = torch.from_numpy(np.interp(aa, uu, r.numpy()))
    if first > 0:
        growth[torch.from_numpy(aa < 0.5 * (uu[first - 1] + uu[first]))] = 0.0
    if last + 1 < len(uu):  # where tracking split an organ in two, the parts meet at the midpoint, never overlap
        after = torch.from_numpy(aa > uu[last])
        growth[after] = float(r[last])
        growth[torch.from_numpy(aa > 0.5 * (uu[last] + uu[last + 1]))] = 0.0
    return growth, *_nearest_shapes(seen, glob, frames, lengths, u, ages)


def _nearest_shapes(seen: Tensor, glob: Tensor, frames: Trees, lengths: Tensor, u: Tensor, ages: Tensor
                    ) -> tuple[Tensor, Tensor]:
    """Unit-length shapes ``(G, T, d)`` and attachments ``(G,)`` of an organ at ``ages``, each from the frame
    nearest to the age among those ``seen`` (indices of the frames holding it)."""
    nearest = seen[(ages[:, None] - u[seen][None]).abs().argmin(1)]
    curves = frames.points[glob[nearest]]
    shape = (curves - curves[:, :1]) / lengths[glob[nearest]][:, None, None]
    return shape, frames.s[glob[nearest]]


def organ_table(sequences: Sequence[TreeSequence], n_ages: int, registration: RegistrationSettings | None = None
                ) -> OrganTable:
    """Register every 4D tree within itself and tabulate its organs by botanical key (:class:`OrganTable`).

    Example:
        >>> from torch4dtree.data.synthetic import synthetic_plant
        >>> table = organ_table([synthetic_plant(kind="bean", seed=0, n_frames=3, T=16).sequence], n_ages=3)
        >>> table.keys[0], table.growth.shape[1], bool((table.growth <= 1).all())
        ((), 3, True)
    """
    ages = torch.linspace(0, 1, n_ages, dtype=torch.float64)
    per_plant = [plant_organs(seq, ages, registration) for seq in sequences]
    keys = sorted({o["key"] for organs in per_plant for o in organs}, key=lambda k: (len(k), k))
    index = {k: i for i, k in enumerate(keys)}
    key_parent = torch.tensor([index[k[:-1]] if k else -1 for k in keys], dtype=torch.long)
    rows = [(p, o) for p, organs in enumerate(per_plant) for o in organs]
    summary = []
    for organs in per_plant:
        final = sum(o["length"] * float(o["growth"][-1]) for o in organs)
        middle = sum(o["length"] * float(o["growth"][n_ages // 2]) for o in organs)
        count = sum(float(o["growth"][-1]) > 0 for o in organs)
        summary.append([math.log(max(final, 1e-12)), math.log(max(middle, 1e-12)), math.log1p(count)])
    return OrganTable(
        keys=keys, key_parent=key_parent,
        plant=torch.tensor([p for p, _ in rows], dtype=torch.long),
        key=torch.tensor([index[o["key"]] for _, o in rows], dtype=torch.long),
        log_length=torch.tensor([math.log(o["length"]) for _, o in rows], dtype=torch.float64),
        shape=torch.stack([o["shape"] for _, o in rows]),
        growth=torch.stack([o["growth"] for _, o in rows]),
        s=torch.stack([o["s"] for _, o in rows]),
        azimuth=torch.tensor([o["azimuth"] for _, o in rows], dtype=torch.float64),
        parent_azimuth=torch.tensor([o["parent_azimuth"] for _, o in rows], dtype=torch.float64),
        ages=ages, summary=torch.tensor(summary, dtype=torch.float64),
    )
