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

__all__ = ["OrganLinks", "OrganTable", "azimuth", "frame_ages", "organ_links", "organ_table", "plant_organs",
           "rooted_frames"]

# the vertical axis (the plants' "up"; the azimuth of an organ is its direction about it)
UP = 2
# an organ first seen in a frame emerged at an unknown time since the frame before: the k-th organ of a plant at the
# share frac(k x this) of that interval (the golden ratio's conjugate spreads the shares evenly over [0, 1))
EMERGENCE_STEP = (math.sqrt(5.0) - 1.0) / 2.0
# frame ages this close to evenly spaced ones are evenly spaced (times stored in float32 round them)
EVEN_AGES_TOL = 1e-6
# a main branch rises from its root: a frame whose main branch's chord climbs less than this share of its length
# (about 20 degrees above the horizontal) is rooted off the stem, at a drooping leaf tip that hangs below the stem base
# (a skeleton's root is its lowest node), so its hierarchy names other organs than the plant's other frames
MIN_RISE = 0.35


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


def rooted_frames(seq: TreeSequence) -> list[int]:
    """The frames of a 4D tree whose main branch rises from its root (:data:`MIN_RISE`): all of them, unless fewer
    than two would be left.

    Example:
        >>> from torch4dtree.data.synthetic import synthetic_plant
        >>> rooted_frames(synthetic_plant(kind="tomato", seed=0, n_frames=3, T=8).sequence)
        [0, 1, 2]
    """
    frames = seq.frames
    main = frames.points[frames.ptr[:-1]]  # (n, T, d) each frame's main branch
    chord = main[:, -1] - main[:, 0]
    rise = chord[:, UP] / chord.norm(dim=-1).clamp_min(torch.finfo(chord.dtype).tiny)
    keep = torch.nonzero(rise >= MIN_RISE).reshape(-1).tolist()
    return keep if len(keep) >= min(2, len(seq)) else list(range(len(seq)))


def plant_organs(seq: TreeSequence, ages: Tensor, registration: RegistrationSettings | None = None
                 ) -> list[dict[str, object]]:
    """The organs of one 4D tree, keyed by botanical position (module doc). Frames rooted off the stem
    (:func:`rooted_frames`) are left out, as if not scanned: every organ of theirs would sit under another parent.

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

    u = seq.normalized_times().to(torch.float64)
    kept = rooted_frames(seq)
    if len(kept) < len(seq):
        seq, u = seq[kept], u[kept]
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
        growth, shape, s_age = _growth_and_shapes(slot_len[:, k] / L, glob[:, k], frames, lengths, u, ages,
                                                  (len(organs) + 1) * EMERGENCE_STEP % 1.0)
        organs.append({"key": key, "length": L, "shape": shape, "growth": growth,
                       "s": s_age if key else torch.zeros_like(s_age), "azimuth": az,
                       "parent_azimuth": az if not key else parent_az})
        kids = sorted(children[k], key=lambda c: float(s_best[c]))
        stack.extend((c, key + (rank,), az) for rank, c in reversed(list(enumerate(kids))))
    return organs


def _growth_and_shapes(r: Tensor, glob: Tensor, frames: Trees, lengths: Tensor, u: Tensor, ages: Tensor,
                       phase: float = 0.5) -> tuple[Tensor, Tensor, Tensor]:
    """One organ's growth curve ``(G,)``, unit-length shapes ``(G, T, d)`` and attachment ``s (G,)`` at ``ages``,
    from its relative length ``r (n,)`` and packed branch ``glob (n,)`` (-1 where absent) in each of the ``n`` frames
    of ``frames`` (branch lengths ``lengths``) at normalised times ``u``; it emerges the share ``phase`` in ``(0, 1)``
    of the way from the last frame without it to the first with it, and goes as far from the last frame with it."""
    seen = torch.nonzero(glob >= 0).reshape(-1)
    first, last = int(seen[0]), int(seen[-1])
    r = r.clone()
    r[first:last + 1] = torch.cummax(r[first:last + 1], 0).values  # growing: a dip or a missed frame is no growth
    uu, aa = u.numpy(), ages.numpy()
    if len(u) < 2:
        return r.expand(len(ages)).clone(), *_nearest_shapes(seen, glob, frames, lengths, u, ages)
    # between frames the length is linear; the organ emerges (and goes) at some time between the frames, the share
    # ``phase`` of the way: spread evenly over the organs, so that the count of a population read between frames is
    # the frames' own, linearly interpolated
    growth = torch.from_numpy(np.interp(aa, uu, r.numpy()))
    if first > 0:
        growth[torch.from_numpy(aa < uu[first - 1] + phase * (uu[first] - uu[first - 1]))] = 0.0
    if last + 1 < len(uu):
        after = torch.from_numpy(aa > uu[last])
        growth[after] = float(r[last])
        growth[torch.from_numpy(aa >= uu[last] + phase * (uu[last + 1] - uu[last]))] = 0.0
    return growth, *_nearest_shapes(seen, glob, frames, lengths, u, ages)


def _nearest_shapes(seen: Tensor, glob: Tensor, frames: Trees, lengths: Tensor, u: Tensor, ages: Tensor
                    ) -> tuple[Tensor, Tensor]:
    """Unit-length shapes ``(G, T, d)`` and attachments ``(G,)`` of an organ at ``ages``, each from the frame
    nearest to the age among those ``seen`` (indices of the frames holding it)."""
    nearest = seen[(ages[:, None] - u[seen][None]).abs().argmin(1)]
    curves = frames.points[glob[nearest]]
    shape = (curves - curves[:, :1]) / lengths[glob[nearest]][:, None, None]
    return shape, frames.s[glob[nearest]]


def frame_ages(sequences: Sequence[TreeSequence], n_ages: int) -> Tensor:
    """``(n_ages,)`` normalised ages in ``[0, 1]`` (first 0, last 1, increasing) at which a model grows its plants:
    the training plants' own frame ages (per frame, the median over the plants) when every plant has ``n_ages``
    frames, else ``linspace(0, 1, n_ages)``. Plants scanned more often late in their growth (days 0, 2, ..., 10, 13,
    15, 17, 18) are then generated at those ages, so a sample's frames hold as many organs as a real plant's.

    Example:
        >>> from torch4dtree.trees.structures import Trees
        >>> one = torch.ones(3, dtype=torch.long)
        >>> frames = Trees(torch.zeros(3, 4, 3), -one, torch.zeros(3), one, -one)
        >>> frame_ages([TreeSequence(frames, torch.tensor([0.0, 3.0, 4.0]))], 3).tolist()
        [0.0, 0.75, 1.0]
        >>> frame_ages([TreeSequence(frames, torch.tensor([0.0, 3.0, 4.0]))], 4).round(decimals=4).tolist()
        [0.0, 0.3333, 0.6667, 1.0]
    """
    even = torch.linspace(0, 1, n_ages, dtype=torch.float64)
    if not sequences or any(len(seq) != n_ages for seq in sequences):
        return even
    times = [seq.times.to(torch.float64) for seq in sequences]
    ages = torch.stack([(t - t[0]) / (t[-1] - t[0]).clamp_min(torch.finfo(t.dtype).tiny) for t in times])
    ages = ages.median(0).values
    ages[0], ages[-1] = 0.0, 1.0
    if not bool((ages.diff() > 0).all()) or torch.allclose(ages, even, rtol=0.0, atol=EVEN_AGES_TOL):
        return even
    return ages


def organ_table(sequences: Sequence[TreeSequence], n_ages: int, registration: RegistrationSettings | None = None
                ) -> OrganTable:
    """Register every 4D tree within itself and tabulate its organs by botanical key (:class:`OrganTable`), at the
    ages :func:`frame_ages` gives.

    Example:
        >>> from torch4dtree.data.synthetic import synthetic_plant
        >>> table = organ_table([synthetic_plant(kind="bean", seed=0, n_frames=3, T=16).sequence], n_ages=3)
        >>> table.keys[0], table.growth.shape[1], bool((table.growth <= 1).all())
        ((), 3, True)
    """
    ages = frame_ages(sequences, n_ages)
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


@dataclass
class OrganLinks:
    """How the ``R`` organs of a fitted table hang together and which organ of another plant stands in for each
    (derived from the table's buffers, so any fitted model can rebuild them).

    Attributes:
        plant: ``(R,)`` each organ's plant.
        parent: ``(R,)`` each organ's parent organ in its plant (-1: the main branch).
        kids: ``(R, C)`` each organ's children in order of place (-1 padded; the organs of one node in one order
            in every plant: fewer descendants, then shorter, first); ``n_kids (R,)`` how many.
        features: ``(R, 4)`` place on the parent (attachment share at the last age), emergence age, log length and
            log(1 + descendants), standardised and weighted (:data:`MATCH_WEIGHTS`): what makes organs of two plants
            the same organ (:func:`organ_links`).
        equivalent: ``(R, P)`` the organ of each plant that stands in for each organ (-1: none): the main branch
            for the main branch, else among the children of the parent's equivalent the nearest in ``features``.
        landmark: ``(R,)`` whether an organ is at least :data:`LANDMARK_SHARE` of its largest sibling: a small organ
            (a bud, a leaf just emerged) has many look-alikes on a parent, so it is a poor landmark to match by.
        same_node: ``(R,)`` whether an organ attaches at the node of the sibling before it in ``kids`` (within
            :data:`SAME_NODE_TOL` of its attachment share at every age): the second of an opposite pair of leaflets,
            a side shoot beside its leaf. A node's organs are one unit: copying them from two plants would place them
            at two nodes (two branch points instead of one).
    """

    plant: np.ndarray
    parent: np.ndarray
    kids: np.ndarray
    n_kids: np.ndarray
    features: np.ndarray
    equivalent: np.ndarray
    landmark: np.ndarray
    same_node: np.ndarray

    def node_start(self, of: int, rank: int) -> int:
        """The first rank at or after ``rank`` among ``of``'s children that starts a node (not :attr:`same_node`);
        ``n_kids[of]`` when none does."""
        n = int(self.n_kids[of])
        while 0 < rank < n and self.same_node[self.kids[of, rank]]:
            rank += 1
        return rank

    def nearest_kid(self, organ: int, of: int) -> int:
        """The rank among ``of``'s children of the one nearest to organ ``organ`` in ``features`` (-1: none)."""
        n = int(self.n_kids[of])
        if n == 0:
            return -1
        d = np.square(self.features[self.kids[of, :n]] - self.features[organ]).sum(1)
        return int(d.argmin())


# organs of other plants matched to an organ, at most this many at once (bounds the matching's memory)
MATCH_CHUNK = 256
# the weights of place, emergence, log length and log(1 + descendants) (each in standard deviations) in matching
# organs of two plants: place first, so that a small organ stands in for the organ at its place rather than for a
# small one elsewhere; descendants tell a side shoot from the leaf at its node
MATCH_WEIGHTS = (6.0, 1.0, 0.5, 1.0)
# an organ at least this share of its largest sibling's length is a landmark (OrganLinks.landmark)
LANDMARK_SHARE = 0.1
# two siblings attach at one node when their attachment shares differ by at most this at every age (a node's
# organs are read from one frame of one skeleton, so theirs agree to rounding)
SAME_NODE_TOL = 1e-6


def organ_links(record: Tensor, key_parent: Tensor, s: Tensor, growth: Tensor, log_length: Tensor) -> OrganLinks:
    """The :class:`OrganLinks` of a table given as a fitted :class:`~torch4dtree.model.OrganModel` holds it:
    ``record (P, K)`` each plant's organ at each key (-1: none), ``key_parent (K,)``, and per organ ``s (R, G)``,
    ``growth (R, G)``, ``log_length (R,)``.

    Ranks alone do not name the same organ in two plants: one small extra organ (a bud, a shoot at a leaf's node)
    shifts the ranks of all organs above it. An organ is matched instead by its place, its emergence, its size and
    how much grows on it, each standardised over all organs but the main branches and weighted by
    :data:`MATCH_WEIGHTS` (docs/method.md §5, generative models).

    Example:
        >>> record = torch.tensor([[0, 1, -1], [2, 3, 4]])  # plant 1 has an extra small organ first
        >>> s = torch.tensor([[0.0], [0.5], [0.0], [0.2], [0.5]]).double().expand(5, 2)
        >>> growth = torch.ones(5, 2, dtype=torch.float64)
        >>> log_length = torch.tensor([1.0, 0.5, 1.0, -2.0, 0.5], dtype=torch.float64)
        >>> organ_links(record, torch.tensor([-1, 0, 0]), s, growth, log_length).equivalent[1].tolist()
        [1, 4]
    """
    rec = record.numpy()
    P, K = rec.shape
    R = len(log_length)
    plant, key = np.zeros(R, dtype=np.int64), np.zeros(R, dtype=np.int64)
    rows, cols = np.nonzero(rec >= 0)
    plant[rec[rows, cols]], key[rec[rows, cols]] = rows, cols
    kp = key_parent.numpy()[key]
    parent = np.where(kp >= 0, rec[plant, np.maximum(kp, 0)], -1)
    depth = np.zeros(K, dtype=np.int64)
    for k in range(K):  # keys are sorted parents first
        depth[k] = depth[key_parent[k]] + 1 if key_parent[k] >= 0 else 0
    n_kids = np.bincount(parent[parent >= 0], minlength=R)
    organ_depth = depth[key]
    below = np.zeros(R)  # descendants of each organ (a leaf has none, a side shoot many)
    for d in range(int(organ_depth.max(initial=0)), 0, -1):
        at = np.nonzero(organ_depth == d)[0]
        np.add.at(below, parent[at], below[at] + 1.0)
    G = growth.shape[1]
    onset = (growth > 0).double().argmax(1).numpy() / max(G - 1, 1)
    raw = np.stack([s[:, -1].numpy(), onset, log_length.numpy(), np.log1p(below)], 1)
    # children in order of place, then (organs of one node) fewer descendants, then shorter first: one order for the
    # organs of a node in every plant
    order = np.lexsort((raw[:, 2], raw[:, 3], raw[:, 0], parent))
    order = order[parent[order] >= 0]
    kids = np.full((R, max(int(n_kids.max(initial=0)), 1)), -1, dtype=np.int64)
    start = np.concatenate([[0], np.cumsum(n_kids)[:-1]])
    kids[parent[order], np.arange(len(order)) - start[parent[order]]] = order
    side = parent >= 0
    scale = raw[side].std(0) if side.sum() > 1 else np.ones(raw.shape[1])
    features = raw / np.where(scale > 0, scale, 1.0) * np.asarray(MATCH_WEIGHTS)
    equivalent = np.full((R, P), -1, dtype=np.int64)
    mains = np.nonzero(~side)[0]
    equivalent[mains] = rec[:, 0][None]
    for d in range(1, int(organ_depth.max(initial=0)) + 1):
        at = np.nonzero(organ_depth == d)[0]
        for lo in range(0, len(at), MATCH_CHUNK):
            rs = at[lo:lo + MATCH_CHUNK]
            up = equivalent[parent[rs]]  # (n, P)
            cand = kids[np.maximum(up, 0)]  # (n, P, C)
            dist = np.square(features[np.maximum(cand, 0)] - features[rs][:, None, None]).sum(-1)
            dist[(cand < 0) | (up < 0)[..., None]] = np.inf
            best = dist.argmin(-1)
            pick = np.take_along_axis(cand, best[..., None], -1)[..., 0]
            equivalent[rs] = np.where(np.isfinite(dist.min(-1)), pick, -1)
    length = np.exp(log_length.numpy())
    largest = np.zeros(R)
    np.maximum.at(largest, np.maximum(parent, 0), np.where(side, length, 0.0))
    landmark = ~side | (length >= LANDMARK_SHARE * largest[np.maximum(parent, 0)])
    same_node = np.zeros(R, dtype=bool)
    prev, nxt = kids[:, :-1], kids[:, 1:]
    pair = nxt >= 0
    s_np = s.numpy()
    same_node[nxt[pair]] = (np.abs(s_np[nxt[pair]] - s_np[prev[pair]]) <= SAME_NODE_TOL).all(1)
    return OrganLinks(plant=plant, parent=parent, kids=kids, n_kids=n_kids, features=features, equivalent=equivalent,
                      landmark=landmark, same_node=same_node)
