"""Within-sequence spatial registration (SPEC §5): one branch identity and one parameterisation per slot.

Every frame ``j`` is registered onto frame ``j + 1`` (:func:`torch4dtree.trees.register_trees`). Identities
are then chained backwards from the last frame, whose branches are the first slots (in its packed order):
a branch of frame ``j`` matched to a branch of frame ``j + 1`` takes that branch's slot; an unmatched
branch opens a new slot, child of its parent's slot (so an organ that appears late is a null branch in
the earlier frames, and one that vanishes is a null branch in the later ones).

Warps compose along the chain so that every frame is written in one parameterisation per slot, that of the
latest frame holding the slot. The registration of frame ``j`` gives warps ``g_j`` with
``beta_j o g_j ~ beta_{j+1}`` (``warp_srvf(q_j, g_j) ~ q_{j+1}``); if ``G_{j+1}`` carries frame ``j + 1``
into the common parameterisation (``beta_{j+1} o G_{j+1}``), then ``beta_j o g_j o G_{j+1}`` is frame ``j`` in
it, i.e. ``G_j = g_j o G_{j+1}`` (``compose_warps(g_j, G_{j+1})``). A child's parameter moves with its
parent's composed warp (``s -> G^{-1}(s)``). Rotations compose the same way: frame ``j``'s rotation ``O_j``
maps it into frame ``j + 1``'s orientation, so ``R_j = R_{j+1} O_j`` (about each frame's root).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import torch
from torch import Tensor

from ..curves.srvf import interpolate_curve, inverse_srvf, srvf, uniform_grid, warp_srvf
from ..curves.warps import compose_warps
from ..trees.aligned import AlignedTrees
from ..trees.registration import ORDER_TOL, TreeRegistration, effective_lambdas, register_trees
from ..trees.structures import Trees, TreeSequence

__all__ = ["AlignedSequence", "IdentityAccuracy", "identity_accuracy", "register_sequence"]


@dataclass(frozen=True, eq=False)
class AlignedSequence:
    """A 4D tree whose frames share one slot layout (``n`` frames, ``S`` slots, ``T`` points, dimension ``d``).

    Attributes:
        aligned: :class:`AlignedTrees` of the ``n`` frames (in time order) in the sequence layout: slot ``k``
            is one branch identity over the whole sequence, written in the parameterisation and
            orientation of the latest frame holding it.
        times: ``(n,)`` acquisition times.
        identity: ``(n, S)`` long, the index of the frame's own packed branch (within its tree) in each slot,
            ``-1`` where the frame has none.
        distances: ``(n - 1,)`` tree-shape distance of each consecutive registration (frame ``j`` onto ``j + 1``).
        warps: ``(n, S, T)`` composed warp of each frame's branch into its slot's parameterisation
            (identity where absent): slot ``k`` of frame ``j`` is ``beta(warps[j, k])`` rotated.
        rotations: ``(n, d, d)`` composed rotation of each frame into the last frame's orientation (about the
            frame's root, acting on row vectors as ``x @ R.T``).
        name: the sequence's name.
    """

    aligned: AlignedTrees
    times: Tensor
    identity: Tensor
    distances: Tensor
    warps: Tensor
    rotations: Tensor
    name: str = ""

    def __post_init__(self) -> None:
        n, S = self.aligned.q.shape[:2]
        for name, shape in (("times", (n,)), ("identity", (n, S)), ("distances", (max(n - 1, 0),)),
                            ("warps", (n, S, self.aligned.T)),
                            ("rotations", (n, self.aligned.q.shape[3], self.aligned.q.shape[3]))):
            if tuple(getattr(self, name).shape) != shape:
                raise ValueError(f"{name} must have shape {shape}, got {tuple(getattr(self, name).shape)}")

    def __len__(self) -> int:
        return self.aligned.num_trees

    @property
    def num_slots(self) -> int:
        return self.aligned.num_slots

    def normalized_times(self) -> Tensor:
        """Times mapped affinely onto ``[0, 1]`` (a single frame sits at 0), ``(n,)``."""
        span = self.times[-1] - self.times[0]
        return (self.times - self.times[0]) / span if len(self.times) > 1 else torch.zeros_like(self.times)

    def to(self, *args, **kwargs) -> AlignedSequence:
        """Move / cast like ``Tensor.to`` (integer tables only change device)."""
        aligned = self.aligned.to(*args, **kwargs)
        dev, dt = aligned.q.device, aligned.q.dtype
        return AlignedSequence(aligned, self.times.to(device=dev, dtype=dt), self.identity.to(dev),
                               self.distances.to(device=dev, dtype=dt), self.warps.to(device=dev, dtype=dt),
                               self.rotations.to(device=dev, dtype=dt), self.name)

    def latest_frame(self) -> Tensor:
        """``(S,)`` long: for every slot, the latest frame where it is present."""
        n = len(self)
        frame = torch.arange(n, device=self.identity.device)[:, None].expand_as(self.identity)
        return torch.where(self.identity >= 0, frame, -1).amax(0)

    def representative(self) -> Trees:
        """One tree holding every slot's branch from the latest frame where it is present (``label`` = slot, packed
        order = slot order), rooted at the last frame's root.

        Each slot's SRVF is integrated as it is, in the sequence's own parameterisation (not resampled in arc
        length), so a registration of this tree gives warps that act directly on the sequence's slots: register two
        sequences through their representatives (:func:`~torch4dtree.temporal.register4d` does). Each child sits on
        its parent's curve (from a frame at least as late) at its own ``s``.
        """
        a = self.aligned
        last = self.latest_frame()
        S = self.num_slots
        slots = torch.arange(S, device=last.device)
        q, s = a.q[last, slots], a.s[last, slots]
        parent = a.slot_parent.tolist()
        curves: list[Tensor] = []
        for k in range(S):  # parents come first
            start = a.root[-1] if k == 0 else interpolate_curve(curves[parent[k]][None], s[k].reshape(1, 1))[0, 0]
            curves.append(inverse_srvf(q[k], start))
        s_out = torch.where(a.slot_parent >= 0, s, torch.zeros_like(s)).clamp(0, 1)
        return Trees(torch.stack(curves), a.slot_parent.clone(), s_out, torch.tensor([S], device=last.device),
                     slots.clone())


def _rotate(q: Tensor, R: Tensor) -> Tensor:
    """``q @ R.T`` per branch: ``q (N, M, d)``, ``R (N, d, d)``."""
    return torch.einsum("nmd,ned->nme", q, R)


def register_sequence(seq: TreeSequence, lambdas: Sequence[float] = (1.0, 1.0, 9.0), rotation: str = "none",
                      progress: bool = False, lp_relative: bool = True, order_tol: float | None = ORDER_TOL,
                      **registration_kwargs: object) -> AlignedSequence:
    """Register every frame of a 4D tree onto its next frame and write all frames in one layout.

    Args:
        seq: the 4D tree (frames in time order).
        lambdas: ``(lm, ls, lp)`` metric weights (SPEC §3 order), also those of the returned layout. ``lp = 9``
            (relative: 0.9 x the reference's main-branch length) favours identities between consecutive frames
            over the cycle consistency that the library default ``lp = 1`` keeps (see
            :data:`torch4dtree.trees.registration.RELATIVE_LP_SCALE`): realistic synthetic maize, seed 3, whole
            sequence identity 84 % at 0.3 x L, >= 95 % at 0.9 x L.
        lp_relative: ``lp`` is relative to the plant's size (:func:`torch4dtree.trees.effective_lambdas`): each
            registration of frame ``j`` onto ``j + 1`` scales it by frame ``j + 1``'s main-branch length (a
            child shifted by a share of its parent costs the same at every age; scaling every pair by the last
            frame's length over-weighted positions in young frames and swapped their leaves), and the layout's
            metric uses the last frame's. For plants in mm an absolute ``lp = 1`` is negligible and similar
            leaves at neighbouring nodes swap.
        rotation: ``"none"`` (frames share a frame of reference, as scans do), ``"vertical"`` or ``"so3"``.
        order_tol: order-preserving matching of each node's children (``register_trees``' ``order_tol``): organs
            never pass each other along a parent as a plant grows, so matched children keep their order in ``s``,
            except siblings within ``order_tol`` (a fraction of the parent, default
            :data:`~torch4dtree.trees.registration.ORDER_TOL`) of each other, which share a node. ``None``: any
            permutation, as across plants. Without the order, a leaf that grew from 3 to 147 mm in one step swapped
            with a similar long leaf two nodes below it (realistic synthetic maize: 64-70 % identity on 4 of 8 plants'
            worst frame pair).
        progress: show a progress bar over the ``n - 1`` registrations.
        registration_kwargs: passed to :func:`torch4dtree.trees.register_trees` (DP settings, ``up``, ...).

    Returns:
        :class:`AlignedSequence` (module doc: slot order, warp and rotation composition). The aligned SRVFs
        are float64 and differentiable in the frames' points given the discrete choices.
    """
    if not isinstance(seq, TreeSequence):
        raise TypeError(f"register_sequence needs a TreeSequence, got {type(seq).__name__}")
    lam = tuple(float(x) for x in lambdas)
    if len(lam) != 3 or not all(math.isfinite(x) and x >= 0 for x in lam) or lam[0] <= 0 or lam[1] <= 0:
        raise ValueError(f"lambdas must be (lm > 0, ls > 0, lp >= 0), got {tuple(lambdas)}")
    frames = seq.frames
    n = len(seq)
    if n >= 2:
        from tqdm.auto import tqdm

        single = frames.split()
        # lp relative to the next frame alone (not the pair's mean, which keeps A -> B and B -> A one metric for
        # cycle consistency): chaining registers one way only, and a young frame's shorter stem would lower lp
        # where similar leaves at neighbouring nodes are most easily swapped (realistic maize seed 3: worst pair
        # 57 % with the pair's mean, 100 % with the next frame's length)
        regs: list[TreeRegistration] = [
            register_trees(single[j], single[j + 1], effective_lambdas(lam, single[j + 1]) if lp_relative else lam,
                           rotation, lp_relative=False, order_tol=order_tol, **registration_kwargs)
            for j in tqdm(range(n - 1), disable=not progress, desc=f"registering {seq.name or 'sequence'}",
                          unit="pair")
        ]
    else:
        regs = []
    layout_lambdas = effective_lambdas(lam, frames[n - 1]) if lp_relative else lam
    return _chain(frames, seq.times, regs, layout_lambdas, seq.name)  # type: ignore[arg-type]


def _chain(frames: Trees, times: Tensor, regs: list[TreeRegistration], lambdas: tuple[float, float, float],
           name: str) -> AlignedSequence:
    """Chain consecutive registrations backwards into one layout (module doc)."""
    dev, dt = frames.device, torch.float64
    n, T, d = frames.num_trees, frames.T, frames.dim
    ptr = frames.ptr.tolist()
    parent = frames.parent.tolist()
    ident_T = uniform_grid(T, torch.empty(0, dtype=dt, device=dev))
    # per packed branch: slot, composed warp; per frame: composed rotation
    slot_of = [0] * len(parent)
    G = ident_T.expand(len(parent), T).clone()
    R = torch.eye(d, dtype=dt, device=dev).expand(n, d, d).clone()
    slot_parent: list[int] = []
    for a in range(ptr[n - 1], ptr[n]):  # the last frame's branches are the first slots
        slot_of[a] = a - ptr[n - 1]
        p = parent[a]
        slot_parent.append(-1 if p < 0 else p)
    for j in range(n - 2, -1, -1):
        reg = regs[j]
        base, nxt = ptr[j], ptr[j + 1]
        match = dict(reg.matches)
        mine, theirs = [], []
        for a in range(ptr[j + 1] - base):  # parents before children: a parent's slot exists
            if a in match:
                slot_of[base + a] = slot_of[nxt + match[a]]
                mine.append(base + a)
                theirs.append(nxt + match[a])
            else:
                slot_of[base + a] = len(slot_parent)
                slot_parent.append(slot_of[base + parent[base + a]] if parent[base + a] >= 0 else -1)
        if mine:
            gam = reg.gamma.to(device=dev, dtype=dt)[[m - base for m in mine]]
            G[mine] = compose_warps(gam, G[theirs])
        R[j] = R[j + 1] @ reg.rotation.to(device=dev, dtype=dt)
    if sum(1 for p in slot_parent if p < 0) != 1:
        raise RuntimeError("internal error: the chained layout must have exactly one main slot")
    S = len(slot_parent)
    depth = [0] * S
    for k in range(1, S):  # parents come first in slot order
        depth[k] = depth[slot_parent[k]] + 1
    tree = frames.tree_index
    slot = torch.tensor(slot_of, dtype=torch.long, device=dev)
    pts = frames.points.to(dt)
    q_packed = _rotate(warp_srvf(srvf(pts), G), R[tree])
    # a child's parameter moves with its parent's composed warp: s -> G_parent^{-1}(s)
    gp = frames.global_parent
    s_packed = _inverse_at(G[gp.clamp(min=0)], frames.s.to(dt))
    s_packed = torch.where(gp >= 0, s_packed, torch.zeros_like(s_packed))
    M = T - 1
    q = torch.zeros(n, S, M, d, dtype=dt, device=dev).index_put((tree, slot), q_packed)
    present = torch.zeros(n, S, dtype=torch.bool, device=dev).index_put(
        (tree, slot), torch.ones_like(slot, dtype=torch.bool))
    identity = torch.full((n, S), -1, dtype=torch.long, device=dev).index_put((tree, slot), frames.local_index)
    warps = ident_T.expand(n, S, T).clone().index_put((tree, slot), G)
    s = _fill_null_s(torch.zeros(n, S, dtype=dt, device=dev).index_put((tree, slot), s_packed), present)
    aligned = AlignedTrees(q, s, present, frames.root().to(dt), torch.tensor(slot_parent, device=dev),
                           torch.tensor(depth, device=dev), identity.clone(), lambdas)
    distances = torch.stack([r.distance.to(device=dev, dtype=dt) for r in regs]) if regs else \
        torch.zeros(0, dtype=dt, device=dev)
    return AlignedSequence(aligned, times.to(device=dev, dtype=dt), identity, distances, warps, R, name)


def _inverse_at(gamma: Tensor, s: Tensor) -> Tensor:
    """``gamma^{-1}(s)`` of piecewise-linear warps: ``gamma (N, T)`` nondecreasing, ``s (N,)`` -> ``(N,)``.

    Exact for the piecewise-linear warp (sampling ``invert_warp`` on the grid first would add an
    interpolation error); on a flat piece, the first parameter reaching ``s``.
    """
    T = gamma.shape[1]
    g = gamma.contiguous()
    hi = torch.searchsorted(g, s.unsqueeze(1).contiguous(), right=True)[:, 0].clamp(1, T - 1)
    lo = hi - 1
    g_lo, g_hi = g.gather(1, lo[:, None])[:, 0], g.gather(1, hi[:, None])[:, 0]
    width = g_hi - g_lo
    frac = torch.where(width > 0, (s - g_lo) / torch.where(width > 0, width, 1), 0).clamp(0, 1)
    return ((lo.to(s.dtype) + frac) / (T - 1)).clamp(0, 1)


def _fill_null_s(s: Tensor, present: Tensor) -> Tensor:
    """Give absent slots the ``s`` of the nearest later frame holding them (else the nearest earlier one).

    A null branch then sits where its partner does in the neighbouring frame, as in a pairwise registration,
    so consecutive frames' distance in the layout charges nothing for it.
    """
    rows, filled = list(s.unbind(0)), list(present.unbind(0))
    n = len(rows)
    steps = [(j, j + 1) for j in range(n - 2, -1, -1)] + [(j, j - 1) for j in range(1, n)]
    for j, k in steps:  # first from later frames (backwards), then from earlier ones
        take = ~filled[j] & filled[k]
        rows[j] = torch.where(take, rows[k], rows[j])
        filled[j] = filled[j] | take
    return torch.stack(rows)


class IdentityAccuracy(NamedTuple):
    """Branch identities of an :class:`AlignedSequence` against ground-truth labels.

    * ``per_pair (n - 1,)``: for frames ``j, j + 1``, the share of their branches whose slot holds the same
      organ in the other frame (or is empty there when that frame lacks the organ).
    * ``sequence``: the share of all branches of all frames sitting in their organ's slot, that of the
      organ's latest appearance (so a slot's branches over the whole sequence are one organ).
    """

    per_pair: Tensor
    sequence: float


def identity_accuracy(aligned: AlignedSequence, labels: Tensor, ignore: Sequence[int] = (-1, 99)
                      ) -> IdentityAccuracy:
    """Score the identity table against ground-truth ``labels (N,)`` of the sequence's packed branches.

    ``labels`` is e.g. ``seq.frames.label``; branches whose label is in ``ignore`` are left out: ``-1`` (unknown)
    and ``99``, the synthetic plants' skeletonisation spurs (:data:`torch4dtree.data.SPUR_LABEL`), which are
    different bits of noise in every frame.
    """
    skip = set(ignore)
    ident = aligned.identity.cpu()
    n, S = ident.shape
    counts = (ident >= 0).sum(1)
    if labels.shape != (int(counts.sum()),):
        raise ValueError(f"labels must have one entry per packed branch ({int(counts.sum())}), "
                         f"got {tuple(labels.shape)}")
    ptr = torch.cat([counts.new_zeros(1), counts.cumsum(0)]).tolist()
    lab = labels.cpu().tolist()
    # slot_label[j][k]: the label of frame j's branch in slot k (None where absent)
    slot_label = [[None if i < 0 else lab[ptr[j] + i] for i in ident[j].tolist()] for j in range(n)]
    per_pair = []
    for j in range(n - 1):
        ok = tot = 0
        for x, y in ((j, j + 1), (j + 1, j)):
            there = set(v for v in slot_label[y] if v is not None)
            for k, v in enumerate(slot_label[x]):
                if v is None or v in skip:
                    continue
                tot += 1
                ok += slot_label[y][k] == v if v in there else slot_label[y][k] is None
        per_pair.append(ok / max(tot, 1))
    home: dict[int, int] = {}
    for j in range(n):  # later frames overwrite: the organ's slot at its latest appearance
        for k, v in enumerate(slot_label[j]):
            if v is not None and v not in skip:
                home[v] = k
    ok = tot = 0
    for j in range(n):
        for k, v in enumerate(slot_label[j]):
            if v is not None and v not in skip:
                tot += 1
                ok += home[v] == k
    return IdentityAccuracy(torch.tensor(per_pair, dtype=torch.float64), ok / max(tot, 1))
