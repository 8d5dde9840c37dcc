"""SRVF trees in a dense common slot layout (`AlignedTrees`).

Registration writes trees into one **layout**: a template tree of ``S`` slots (``slot_parent``,
``slot_depth``; slot 0 is the main branch, parents come before children). Every tree of the batch
has one SRVF per slot, a null branch (``q = 0``) where it has nothing. In that layout the metric of
docs/method.md §3,

    d^2(Q, Q') = lm ||q0 - q0'||^2 + sum_i [ lp (s_i - s_i')^2 + ls d^2(Q_i, Q_i') ]   (recursively),

is the squared Euclidean norm of :meth:`AlignedTrees.features` differences: the SRVF of a slot
at depth ``k`` has weight ``lm ls^k`` and its bifurcation parameter ``lp ls^(k-1)`` (``k >= 1``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import torch
from torch import Tensor

from ..curves.srvf import srvf, srvf_sq_norm
from .decode_numba import HAVE_NUMBA, depth_first_order, integrate_rows, place_branches
from .structures import Trees

__all__ = ["AlignedTrees", "Lambdas", "SlotRows", "rows_to_trees", "segment_lengths", "slot_weights",
           "subtree_sq_norms"]

Lambdas = tuple[float, float, float]
# decode with the compiled kernel where it applies (see _compiled); False: always the torch path
COMPILED_DECODE = True


def slot_weights(slot_depth: Tensor, lambdas: Lambdas) -> tuple[Tensor, Tensor]:
    """Metric weights per slot: ``(w_q (S,), w_s (S,))`` with ``w_s = 0`` at the main branch."""
    lm, ls, lp = lambdas
    depth = slot_depth.to(torch.float64)
    w_q = lm * torch.pow(torch.as_tensor(ls, dtype=torch.float64), depth)
    w_s = torch.where(depth >= 1, lp * torch.pow(torch.as_tensor(ls, dtype=torch.float64), depth - 1),
                      torch.zeros_like(depth))
    return w_q, w_s


def subtree_sq_norms(lengths: Sequence[float], parent: Sequence[int], lambdas: Lambdas) -> list[float]:
    """Recursive squared norm ``||Q||^2 = lm ||q||^2 + ls sum_children ||Q_c||^2`` of every subtree.

    ``lengths[i] = ||q_i||^2`` (branch length), ``parent[i]`` within the same list (parents first).
    This is the squared distance of subtree ``i`` to the null tree.
    """
    lm, ls, _ = lambdas
    out = [lm * float(x) for x in lengths]
    for i in range(len(parent) - 1, -1, -1):  # children after parents: accumulate bottom-up
        p = parent[i]
        if p >= 0:
            out[p] += ls * out[i]
    return out


@dataclass(frozen=True, eq=False)
class AlignedTrees:
    """``n`` trees written in one common layout of ``S`` slots (``M = T - 1`` segments, dimension ``d``).

    Attributes:
        q: ``(n, S, M, d)`` SRVF per tree and slot; zeros for a null branch.
        s: ``(n, S)`` bifurcation parameter of each slot on its parent slot (0 for slot 0).
        present: ``(n, S)`` bool, the tree has a real branch in that slot.
        root: ``(n, d)`` position of the main branch's first point (the pre-shape drops it).
        slot_parent: ``(S,)`` long, parent slot (``-1`` for slot 0); parents come first.
        slot_depth: ``(S,)`` long, layer of each slot (0 = main branch).
        source: ``(n, S)`` long, index of the original branch (within its tree) or ``-1``.
        lambdas: ``(lm, ls, lp)`` metric weights (docs/method.md §3 order).

    Example:
        >>> import torch
        >>> from torch4dtree.trees import register_trees
        >>> from torch4dtree.data.examples import leaf_pair
        >>> tree, other = leaf_pair(T=8)  # a stem with a straight leaf, and with a bent one
        >>> layout = register_trees(other, tree, positions="warped").aligned  # [registered other, tree] in one layout
        >>> layout.q.shape, layout.slot_parent.tolist()
        (torch.Size([2, 2, 7, 3]), [-1, 0])
        >>> f = layout.features()  # the metric is the Euclidean one on the features
        >>> bool(torch.isclose((f[0] - f[1]).norm(), register_trees(other, tree, positions="warped").distance))
        True
        >>> AlignedTrees.from_trees(tree).to_trees().num_branches
        tensor([2])
    """

    q: Tensor
    s: Tensor
    present: Tensor
    root: Tensor
    slot_parent: Tensor
    slot_depth: Tensor
    source: Tensor
    lambdas: Lambdas = (1.0, 1.0, 1.0)

    def __post_init__(self) -> None:
        n, S = self.q.shape[:2]
        if self.q.dim() != 4:
            raise ValueError(f"q must be (n, S, M, d), got {tuple(self.q.shape)}")
        for name, shape in (("s", (n, S)), ("present", (n, S)), ("source", (n, S)),
                            ("root", (n, self.q.shape[3])), ("slot_parent", (S,)), ("slot_depth", (S,))):
            if tuple(getattr(self, name).shape) != shape:
                raise ValueError(f"{name} must have shape {shape}, got {tuple(getattr(self, name).shape)}")
        if S < 1 or int(self.slot_parent[0]) != -1:
            raise ValueError("slot 0 must be the main branch (parent -1)")
        idx = torch.arange(S, device=self.slot_parent.device)
        if bool((self.slot_parent[1:] >= idx[1:]).any()) or bool((self.slot_parent[1:] < 0).any()):
            raise ValueError("every slot but 0 needs a parent slot that comes before it")

    # ------------------------------------------------------------------------ basics
    @property
    def num_trees(self) -> int:
        return self.q.shape[0]

    def __len__(self) -> int:
        return self.num_trees

    @property
    def num_slots(self) -> int:
        return self.q.shape[1]

    @property
    def T(self) -> int:
        """Points per branch (``M + 1``)."""
        return self.q.shape[2] + 1

    def __getitem__(self, index: int | slice | Sequence[int] | Tensor) -> AlignedTrees:
        """Select trees (the layout is shared)."""
        if isinstance(index, int):
            index = [index]
        return AlignedTrees(self.q[index], self.s[index], self.present[index], self.root[index],
                            self.slot_parent, self.slot_depth, self.source[index], self.lambdas)

    @staticmethod
    def cat(batches: Sequence[AlignedTrees]) -> AlignedTrees:
        """Concatenate batches that share one layout."""
        a = batches[0]
        for b in batches[1:]:
            if not torch.equal(a.slot_parent, b.slot_parent) or a.lambdas != b.lambdas:
                raise ValueError("AlignedTrees.cat needs batches with the same layout and lambdas")
        return AlignedTrees(torch.cat([b.q for b in batches]), torch.cat([b.s for b in batches]),
                            torch.cat([b.present for b in batches]), torch.cat([b.root for b in batches]),
                            a.slot_parent, a.slot_depth, torch.cat([b.source for b in batches]), a.lambdas)

    def to(self, *args, **kwargs) -> AlignedTrees:
        """Move / cast like ``Tensor.to``: ``q``, ``s`` and ``root`` take the dtype, every tensor the device."""
        q = self.q.to(*args, **kwargs)
        dev = q.device
        return AlignedTrees(q, self.s.to(device=dev, dtype=q.dtype), self.present.to(dev),
                            self.root.to(device=dev, dtype=q.dtype), self.slot_parent.to(dev),
                            self.slot_depth.to(dev), self.source.to(dev), self.lambdas)

    def weights(self) -> tuple[Tensor, Tensor]:
        """``(w_q (S,), w_s (S,))`` metric weights of each slot's SRVF and ``s``."""
        w_q, w_s = slot_weights(self.slot_depth, self.lambdas)
        return w_q.to(self.q.dtype), w_s.to(self.q.dtype)

    # ------------------------------------------------------------------------ metric
    def features(self) -> Tensor:
        """Flattened weighted SRVFT ``(n, S*M*d + S - 1)``: Euclidean norms of differences are the metric."""
        n, S, M, d = self.q.shape
        w_q, w_s = self.weights()
        fq = (self.q * (w_q / M).sqrt()[None, :, None, None]).reshape(n, S * M * d)
        fs = self.s[:, 1:] * w_s[1:].sqrt()
        return torch.cat([fq, fs], dim=1)

    @staticmethod
    def from_features(features: Tensor, like: AlignedTrees, root: Tensor | None = None) -> AlignedTrees:
        """Inverse of :meth:`features` in the layout of ``like``. ``(n, F) -> AlignedTrees`` (n trees).

        ``present`` marks slots with a nonzero SRVF; ``source`` is -1; ``root`` defaults to zeros.
        """
        n = features.shape[0]
        S, M, d = like.q.shape[1:]
        w_q, w_s = like.weights()
        w_q, w_s = w_q.to(features), w_s.to(features)
        q = features[:, : S * M * d].reshape(n, S, M, d) / (w_q / M).sqrt()[None, :, None, None]
        s = torch.zeros(n, S, dtype=features.dtype, device=features.device)
        if S > 1:
            s[:, 1:] = features[:, S * M * d:] / w_s[1:].sqrt()
        present = (q != 0).flatten(2).any(-1)
        root = features.new_zeros(n, d) if root is None else root
        source = torch.full((n, S), -1, dtype=torch.long, device=features.device)
        return AlignedTrees(q, s, present, root, like.slot_parent, like.slot_depth, source, like.lambdas)

    def sq_norm(self) -> Tensor:
        """``(n,)`` squared recursive norm of each tree (its squared distance to the null tree, s terms aside).

        Equals ``||features||^2`` minus the ``s`` terms: what matching the whole tree to nothing costs.
        """
        w_q, _ = self.weights()
        return (srvf_sq_norm(self.q) * w_q).sum(-1)

    def sq_distances(self, other: AlignedTrees | None = None) -> Tensor:
        """Squared metric distances ``(n, n')`` between the trees of two batches in the same layout."""
        f1 = self.features()
        f2 = f1 if other is None else other.features()
        return torch.cdist(f1, f2).square()

    def lerp(self, other: AlignedTrees, t: Tensor) -> AlignedTrees:
        """Straight line ``(1 - t) self + t other`` (1-tree batches) at ``t (k,)`` -> ``k`` trees (a geodesic)."""
        if self.num_trees != 1 or other.num_trees != 1:
            raise ValueError("lerp needs two single-tree batches")
        t = t.to(self.q.dtype).reshape(-1)
        tq = t[:, None, None, None]
        q = (1 - tq) * self.q + tq * other.q
        s = (1 - t[:, None]) * self.s + t[:, None] * other.s
        root = (1 - t[:, None]) * self.root + t[:, None] * other.root
        present = (self.present | other.present).expand(len(t), -1).clone()
        present[t == 0] = self.present[0]
        present[t == 1] = other.present[0]
        source = torch.full_like(present, -1, dtype=torch.long)
        return AlignedTrees(q, s, present, root, self.slot_parent, self.slot_depth, source, self.lambdas)

    # ------------------------------------------------------------------------ construction
    @staticmethod
    def from_trees(trees: Trees, lambdas: Lambdas = (1.0, 1.0, 1.0), dtype: torch.dtype = torch.float64
                   ) -> AlignedTrees:
        """One tree in its own layout (slot ``i`` = branch ``i``). Needs a single-tree batch.

        Use registration (:func:`torch4dtree.trees.registration.register_trees`) to put several trees in one layout.
        """
        if trees.num_trees != 1:
            raise ValueError("AlignedTrees.from_trees needs a single tree; register trees to share a layout")
        pts = trees.points.to(dtype)
        N = pts.shape[0]
        parent = trees.parent.to(torch.long)
        return AlignedTrees(
            srvf(pts)[None], trees.s.to(dtype)[None], torch.ones(1, N, dtype=torch.bool, device=pts.device),
            pts[0, 0][None], parent, trees.depth, torch.arange(N, device=pts.device)[None],
            tuple(float(x) for x in lambdas),
        )

    # ------------------------------------------------------------------------ decoding
    def to_trees(self, eps: float = 1e-6) -> Trees:
        """Decode to ragged trees (``Trees`` in float ``q.dtype``), one per tree of the batch.

        Each slot is integrated with the inverse SRVF, starting at the root (slot 0) or on its parent's
        curve at its ``s``; slots whose branch is shorter than ``eps`` (null or nearly so) are dropped
        with their descendants. The curves are then resampled uniformly in arc length, so ``s`` is
        converted to the arc-length fraction of the attachment point. The branch ``label`` is the slot
        index, so branches keep their identity across a geodesic. The main branch is always kept.
        Within a tree, branches are in depth-first order, children by increasing arc-length ``s`` (equal
        ``s``: the higher slot first).

        Batched over trees: slots are processed depth by depth for the whole batch. The points are
        differentiable in ``q``, ``s`` and ``root`` given the discrete choices (kept slots, order).
        """
        n, S, M, d = self.q.shape
        flat = torch.arange(n * S, device=self.q.device)
        return rows_to_trees(SlotRows.of(self.q.reshape(n * S, M, d)), flat, self.s, self.root, self.slot_parent, eps)


class SlotRows(NamedTuple):
    """SRVFs of ``R`` (tree, slot) rows, factored: row ``r`` is ``mean[slot[r]] + c[r] @ comp[slot[r]]`` (flat,
    ``M*d`` values), as a PCA decodes them (:meth:`torch4dtree.space.TreePCA.decode`); ``slot`` None: row ``r`` is
    ``mean[r]`` (``k = 0``, the SRVFs themselves, :meth:`of`). Rows are grouped by slot, in increasing order.

    The compiled decode computes each row once, straight into its curve, without storing them (:mod:`.decode_numba`).
    """

    c: Tensor  # (R, k)
    slot: Tensor | None  # (R,) long
    mean: Tensor  # (S', M*d)
    comp: Tensor  # (S', k, M*d)

    @staticmethod
    def of(q: Tensor) -> SlotRows:
        """The rows of SRVFs ``q (R, M, d)`` themselves."""
        R, MD = q.shape[0], q.shape[1] * q.shape[2]
        return SlotRows(q.new_zeros(R, 0), None, q.reshape(R, MD), q.new_zeros(R, 0, MD))

    def dense(self, d: int) -> Tensor:
        """The SRVFs ``(R, M, d)`` (differentiable in ``c``, ``mean`` and ``comp``)."""
        R, MD = len(self.c), self.mean.shape[1]
        if self.slot is None:
            return self.mean.reshape(R, MD // d, d)
        counts = torch.bincount(self.slot, minlength=len(self.mean)).tolist()
        groups = [(j, cj) for j, cj in enumerate(self.c.split(counts)) if len(cj)]  # one small product per slot
        if torch.is_grad_enabled() and any(x.requires_grad for x in (self.c, self.mean, self.comp)):
            q = torch.cat([torch.addmm(self.mean[j], cj, self.comp[j]) for j, cj in groups])
        else:  # straight into one buffer
            q = self.c.new_empty(R, MD)
            for (j, cj), part in zip(groups, q.split([len(cj) for _, cj in groups])):
                torch.addmm(self.mean[j], cj, self.comp[j], out=part)
        return q.reshape(R, MD // d, d)


def segment_lengths(q: Tensor) -> Tensor:
    """``|q_m|^2 / M`` of SRVFs ``q (R, M, d)``: the segment lengths of their curves, ``(R, M)``."""
    M, d = q.shape[1:]
    # a product with ones: torch reduces over a last dim of size 3 several times slower
    return (q * q) @ q.new_ones(d) / M


def rows_to_trees(srvfs: SlotRows, flat: Tensor, s: Tensor, root: Tensor, slot_parent: Tensor, eps: float) -> Trees:
    """:meth:`AlignedTrees.to_trees` from the SRVFs of some of the slots (``R`` rows).

    Args:
        srvfs: the SRVFs of ``R`` (tree, slot) rows (``M*d`` values each).
        flat: ``(R,)`` distinct ``tree * S + slot`` of each row. A slot without a row is too short: a caller that
            knows which slots are short (e.g. from their lengths alone) skips computing their SRVFs.
        s: ``(n, S)``, root ``(n, d)``, slot_parent ``(S,)``, eps: as in :meth:`AlignedTrees.to_trees`.

    Returns:
        the decoded trees (float ``srvfs.mean.dtype``), as :meth:`AlignedTrees.to_trees`.
    """
    n, S = s.shape
    d = root.shape[1]
    M = srvfs.mean.shape[1] // d
    dev = srvfs.mean.device
    compiled = _compiled(srvfs.mean, srvfs.c, srvfs.comp, s, root)
    if compiled:
        seg, raw = integrate_rows(srvfs, M, d)  # (R, M) and the curves; the SRVFs themselves are never stored
    else:
        q = srvfs.dense(d)
        seg = segment_lengths(q)
    slot_depth = _slot_depth(slot_parent)
    depth_slots = [(slot_depth == k).nonzero()[:, 0] for k in range(1, int(slot_depth.max()) + 1)]
    depth_parents = [slot_parent[x] for x in depth_slots]
    row_of = torch.full((n * S,), -1, dtype=torch.long, device=dev)
    row_of[flat] = torch.arange(len(flat), device=dev)
    # which slots survive: long enough and every ancestor kept (a detached comparison, no grad needed)
    long_enough = torch.zeros(n * S, dtype=torch.bool, device=dev)
    long_enough[flat] = seg.detach().sum(-1) > eps
    long_enough = long_enough.reshape(n, S)
    if S and n:
        long_enough[:, 0] = True  # the main branch is always kept, even when it has no row
    keep = long_enough.clone()
    for slots, parents in zip(depth_slots, depth_parents):
        keep[:, slots] = keep[:, parents] & long_enough[:, slots]
    # arc-length fraction of each kept slot's attachment on its parent (K kept slots, parents first)
    kept = keep.reshape(-1).nonzero()[:, 0]  # (K,) flat index tree * S + slot
    if bool((row_of[kept] < 0).any()):
        raise ValueError("every main branch needs a row (its SRVF), even a null one")
    slot = kept % S
    parent_flat = kept - slot + slot_parent[slot].clamp(min=0)  # (K,) a main branch points to itself
    sc_all = s.to(seg.dtype).clamp(0, 1).reshape(n * S)
    arc_table = torch.zeros(n * S, dtype=seg.dtype, device=dev)
    arc_table[kept] = torch.where(slot > 0, _arc_fractions(seg, row_of[parent_flat], sc_all[kept]), 0)
    # packed depth-first order; from here on everything is in that order
    if compiled:
        order, local_parent, counts = depth_first_order(keep, arc_table.detach().reshape(n, S), slot_parent)
    else:
        order, local_parent, counts = _depth_first_order(keep, arc_table.detach().reshape(n, S), slot_parent,
                                                         depth_slots, depth_parents)
    slot, tree = order % S, order // S
    packed_index = torch.full((n * S,), -1, dtype=torch.long, device=dev)
    packed_index[order] = torch.arange(len(order), device=dev)
    gp = packed_index[order - slot + slot_parent[slot].clamp(min=0)]  # (K,) a main branch: itself
    depth = slot_depth[slot]
    sc = sc_all[order]
    rows = row_of[order]
    start = root.to(seg.dtype)[tree]  # (K, d); main branches start at the root
    s_out = arc_table[order].clamp(0, 1)
    if compiled:
        pts = place_branches(raw, seg, rows, gp, sc, s_out, start)
    else:
        layers = [(depth == k).nonzero()[:, 0] for k in range(1, len(depth_slots) + 1)]
        pts = _place_torch(q, seg, rows, gp, sc, s_out, start, layers)
    return Trees(pts, local_parent, s_out, counts, slot)


def _compiled(*tensors: Tensor) -> bool:
    """Whether the compiled kernels (:mod:`.decode_numba`) compute from ``tensors`` (the first one sets dtype and
    device): float64 on the CPU, no gradient wanted (the torch path is the differentiable one)."""
    q = tensors[0]
    grad = torch.is_grad_enabled() and any(x.requires_grad for x in tensors)
    return COMPILED_DECODE and HAVE_NUMBA and q.dtype == torch.float64 and q.device.type == "cpu" and not grad


def _place_torch(q: Tensor, seg: Tensor, rows: Tensor, gp: Tensor, sc: Tensor, s_out: Tensor, start: Tensor,
                 layers: list[Tensor]) -> Tensor:
    """The branches' points ``(K, T, d)`` in packed order, differentiable (the arguments of
    :func:`~torch4dtree.trees.decode_numba.place_branches`; ``layers``: packed branches of each layer 1, 2, ...)."""
    M = q.shape[1]
    if len(rows) < len(q):  # integrate the kept rows only
        q, seg, rows = q[rows], seg[rows], torch.arange(len(rows), device=q.device)
    # every curve from its own origin: its steps q |q| / M and their running sums (the points after the first)
    steps = _steps(q, seg)  # (R, M, d)
    ends = steps.cumsum(1)
    # place the branches layer by layer: a child starts on its parent's curve (before resampling) at s
    start = start.clone()
    for idx in layers:
        par = rows[gp[idx], None]
        x = sc[idx, None].clamp(0, 1) * M
        lo = x.detach().floor().clamp(max=M - 1).long()
        start[idx] = start[gp[idx]] + _curve_points(steps, ends, par, lo, x - lo.to(x.dtype))[:, 0]
    # resampled uniformly in arc length: T points, gathered in packed order straight from the steps
    lo, frac = _arc_length_grid(seg[rows])
    pts = _curve_points(steps, ends, rows[:, None], lo, frac).add_(start[:, None])
    # resampling moves a parent's points by chord effects: snap each child back onto its parent,
    # layer by layer so that a parent is final before its children
    for idx in layers:
        if len(idx):
            pts[idx, 0] = _points_at(pts, gp[idx], s_out[idx])
    return pts


def _slot_depth(slot_parent: Tensor) -> Tensor:
    """``(S,)`` layer of every slot, from ``slot_parent (S,)`` (parents first)."""
    par = slot_parent.tolist()
    depth = [0] * len(par)
    for k in range(1, len(par)):  # one pass over small integers: parents come first
        depth[k] = depth[par[k]] + 1
    return torch.tensor(depth, dtype=torch.long, device=slot_parent.device)


def _arc_fractions(seg: Tensor, rows: Tensor, s: Tensor) -> Tensor:
    """Arc-length fraction of the point at parameter ``s (m,)`` in [0, 1] of polylines ``rows (m,)`` of the segment
    lengths ``seg (R, M)`` (on the uniform parameter grid). A zero-length polyline gives ``s`` back.

    Running sums of each row once, then two gathers per point (rows are shared: siblings have one parent).
    """
    M = seg.shape[1]
    cum = seg.cumsum(1)  # (R, M): the arc length at the end of each segment
    x = s * M
    lo = x.detach().floor().clamp(0, M - 1).long()
    frac = x - lo.to(x.dtype)
    idx = rows * M + lo
    # start of segment lo plus frac of it; s = 0 and s = 1 give exactly 0 and the total
    at = cum.reshape(-1)[idx] - (1 - frac) * seg.reshape(-1)[idx]
    total = cum[rows, -1]
    positive = total > 0
    return torch.where(positive, (at / torch.where(positive, total, 1)).clamp(0, 1), s)


def _depth_first_order(keep: Tensor, arc: Tensor, slot_parent: Tensor, depth_slots: list[Tensor],
                       depth_parents: list[Tensor]) -> tuple[Tensor, Tensor, Tensor]:
    """Packed depth-first order of the kept slots of every tree, children by increasing ``arc``.

    Args:
        keep: ``(n, S)`` bool kept slots (slot 0 always; a kept slot's parent is kept).
        arc: ``(n, S)`` sort key of each slot among its siblings (ties: higher slot first).
        slot_parent: ``(S,)``.
        depth_slots, depth_parents: per layer 1, 2, ..., its slots and their parent slots (``(k,)`` long each).

    Returns:
        ``order (N,)`` flat index ``tree * S + slot`` of each packed branch, ``parent (N,)`` its parent's
        index within its tree (``-1`` for the main branch), ``counts (n,)`` branches per tree.
    """
    n, S = keep.shape
    dev = keep.device
    # subtree sizes, deepest layer first (dropped slots count 0)
    size = keep.long()
    for slots, parents in zip(reversed(depth_slots), reversed(depth_parents)):
        size.index_add_(1, parents, size[:, slots])
    # sort the slots by (parent, arc, -slot) with stable sorts, least significant key first
    before = torch.zeros(n, S, dtype=torch.long, device=dev)
    if S > 1 and n > 0:
        perm = torch.arange(S - 1, 0, -1, device=dev).expand(n, -1)  # (n, S-1) slots, higher first
        perm = perm.gather(1, arc.gather(1, perm).argsort(dim=1, stable=True))
        perm = perm.gather(1, slot_parent[perm].argsort(dim=1, stable=True))
        # every row now lists the same parents in the same order: one group of siblings per parent
        sorted_parent = slot_parent[perm[0]]
        group_start = torch.searchsorted(sorted_parent, sorted_parent)
        sz = size.gather(1, perm)
        preceding = sz.cumsum(1) - sz
        before.scatter_(1, perm, preceding - preceding[:, group_start])  # sizes of earlier siblings
    # pre-order position: right after the parent and the subtrees of the earlier siblings
    pos = torch.zeros(n, S, dtype=torch.long, device=dev)
    for slots, parents in zip(depth_slots, depth_parents):
        pos[:, slots] = pos[:, parents] + 1 + before[:, slots]
    counts = keep.sum(1)
    offset = torch.cat([counts.new_zeros(1), counts.cumsum(0)[:-1]])
    flat_kept = keep.reshape(-1).nonzero()[:, 0]
    packed = (offset[:, None] + pos).reshape(-1)[flat_kept]
    order = torch.empty_like(flat_kept)
    order[packed] = flat_kept
    parent_pos = torch.where(slot_parent >= 0, pos[:, slot_parent.clamp(min=0)], -1)  # (n, S)
    return order, parent_pos.reshape(-1)[order], counts


def _steps(q: Tensor, seg: Tensor) -> Tensor:
    """Steps ``q |q| / M = q sqrt(seg / M)`` of the inverse SRVF, given the segment lengths ``seg = |q|^2 / M``:
    ``(R, M, d)``. The square root is guarded so null segments give zero gradients."""
    M = q.shape[1]
    nonzero = seg > 0
    factor = torch.where(nonzero, (torch.where(nonzero, seg, 1) / M).sqrt(), 0)
    return q * factor.unsqueeze(-1)


def _curve_points(steps: Tensor, ends: Tensor, rows: Tensor, lo: Tensor, frac: Tensor) -> Tensor:
    """Points ``(m, p, d)`` of polylines from the origin given by their segments ``steps (R, M, d)`` and segment
    ends ``ends (R, M, d)``: on polyline ``rows (m, 1)``, segment ``lo (m, p)`` at fraction ``frac (m, p)`` of it."""
    m, p = lo.shape
    M, d = steps.shape[1:]
    idx = (rows * M + lo).reshape(-1)
    end = ends.reshape(-1, d).index_select(0, idx)
    step = steps.reshape(-1, d).index_select(0, idx)
    return end.addcmul_(step, (frac - 1).reshape(-1, 1)).reshape(m, p, d)


def _points_at(curves: Tensor, rows: Tensor, s: Tensor) -> Tensor:
    """``interpolate_curve(curves[rows], s)`` without copying the curves: ``curves (K, T, d)``, ``rows, s (m,)`` ->
    ``(m, d)``."""
    K, T, d = curves.shape
    x = s.clamp(0, 1) * (T - 1)
    lo = x.detach().floor().clamp(max=T - 2).long()
    flat = curves.reshape(K * T, d)
    a = flat.index_select(0, rows * T + lo)
    b = flat.index_select(0, rows * T + lo + 1)
    return a + (x - lo.to(x.dtype))[:, None] * (b - a)


def _arc_length_grid(seg: Tensor) -> tuple[Tensor, Tensor]:
    """Where the uniform arc-length grid of ``T = M + 1`` points falls on polylines with segment lengths
    ``seg (K, M)``: segment ``lo (K, T)`` and fraction ``frac (K, T)`` along it. A zero-length polyline gives its
    first point ``T`` times."""
    K, M = seg.shape
    T = M + 1
    cum = torch.cat([torch.zeros_like(seg[:, :1]), seg.cumsum(1)], dim=1)  # (K, T)
    target = torch.linspace(0, 1, T, dtype=seg.dtype, device=seg.device) * cum[:, -1:]  # (K, T)
    lo = torch.searchsorted(cum.detach(), target.detach(), right=True).clamp(1, T - 1) - 1
    c_lo, width = cum.gather(1, lo), seg.gather(1, lo)
    frac = torch.where(width > 0, (target - c_lo) / torch.where(width > 0, width, 1), 0).clamp(0, 1)
    return lo, frac
