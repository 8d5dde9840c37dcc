"""Karcher mean of 3D trees (docs/method.md §4, paper §4.1): register every tree onto the mean, average, repeat.

The mean lives in a **slot layout** (``S`` slots, parents first, depth-first with children by ``s``). One
iteration:

1. decode the mean exactly (each slot integrated from its SRVF, starting on its parent at its ``s``; no
   arc-length resampling, so the reference's SRVFT *is* the mean's) and register every tree onto it with
   one batched :func:`~torch4dtree.trees.register_to_reference` call;
2. **union layout**: the mean's slots, then one new slot per tree branch that matched nothing (a child of
   the slot its parent went to), null in every other tree;
3. average the registered SRVFTs: ``q`` over all trees (a null branch is ``q = 0``), ``s`` over the trees
   that have the branch (a null partner's ``s`` costs nothing, docs/method.md §3), roots over all trees;
4. **prune** the slots whose average branch length over the trees (a null branch counts 0) is below
   ``prune_length`` times the average main-branch length, with their descendants, and put the rest in
   canonical order. (Not the length of the mean branch: for a branch that ``k`` of ``n`` trees share it is
   ``(k/n)^2 L``, so as ``n`` grows every new slot, which holds one tree's branch, would be pruned before the
   others could join it.)

**The energy** ``E = sum_i d^2(tree_i, mean)`` **never increases** between iterations: each tree also keeps
its previous correspondence (the union row, restricted to the kept slots, its other branches unmatched) as
a candidate registration onto the new mean, and the better of it and the fresh registration counts. The
average minimises the union-layout energy, which is at most the previous one; pruning a slot the previous
mean already had could raise it, so if it would, only new slots are pruned in that iteration.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import torch
from torch import Tensor

from ..curves.srvf import interpolate_curve, inverse_srvf, srvf, srvf_sq_norm
from ..settings import ROTATIONS, RegistrationSettings, check_choice, check_lambdas
from ..trees.aligned import AlignedTrees, Lambdas, slot_weights
from ..trees.registration import RELATIVE_LP_SCALE, TreeRegistration
from ..trees.structures import Trees
from .fitted import FittedModule, NotFittedError

__all__ = ["KarcherMean", "MeanRegistration", "SlotLimitError"]

# default pruning threshold, as a fraction of the mean's main-branch length (see KarcherMean)
DEFAULT_PRUNE = 0.01
# slots shorter than this fraction of the main branch are null whatever prune_length says
NULL_FRACTION = 1e-9
# the medoid rule ranks its candidates on branches resampled to this many points
MEDOID_T = 24


class SlotLimitError(ValueError):
    """The mean's slot layout would exceed ``max_slots``."""


class MeanRegistration(NamedTuple):
    """Trees registered onto a fitted mean, written in the mean's layout (``n`` trees, ``S`` slots).

    * ``aligned``: :class:`AlignedTrees` ``(n, S)``: slot ``j`` holds the branch matched to the mean's slot
      ``j`` (null where none did; its ``s`` is then the mean's); ``source`` gives the branch index.
    * ``distance``: ``(n,)`` registered distance of each tree to the mean, unmatched branches included.
    * ``dropped``: per tree, the branches (indices within the tree) that matched no slot of the mean and are
      therefore not in ``aligned``.
    * ``dropped_sq_norm``: ``(n,)`` what they cost: ``distance^2 = |f(aligned_i) - f(mean)|^2 + dropped_sq_norm``
      with ``f`` = :meth:`AlignedTrees.features` (s terms only where both trees have the branch).
    """

    aligned: AlignedTrees
    distance: Tensor
    dropped: list[list[int]]
    dropped_sq_norm: Tensor


# ----------------------------------------------------------------------------- internal forms (float64, CPU)


@dataclass
class _Mean:
    """A mean tree in its slot layout: ``q (S, M, d)``, ``s (S,)``, ``root (d,)``, ``parent (S,)`` long."""

    q: Tensor
    s: Tensor
    root: Tensor
    parent: Tensor

    @property
    def num_slots(self) -> int:
        return self.q.shape[0]


@dataclass
class _Registered:
    """One tree registered onto a mean: the mean's ``S`` slots first, then slots for its unmatched branches.

    ``q (S', M, d)``, ``s``, ``present``, ``source`` ``(S',)``, ``parent (S',)`` (the first ``S`` are the mean's),
    ``root (d,)``, ``sq_dist`` its squared distance to the mean.
    """

    q: Tensor
    s: Tensor
    present: Tensor
    source: Tensor
    parent: Tensor
    root: Tensor
    sq_dist: float


@dataclass
class _Union:
    """``n`` registered trees in the union layout of ``U`` slots (the mean's ``S`` first)."""

    q: Tensor  # (n, U, M, d)
    s: Tensor  # (n, U)
    present: Tensor  # (n, U)
    source: Tensor  # (n, U)
    parent: Tensor  # (U,)
    root: Tensor  # (n, d)


@dataclass
class _Carry:
    """What the previous iteration offers each tree: its union row mapped onto the new mean's slots."""

    union: _Union
    keep_map: Tensor  # (U,) new slot of each union slot, -1 if pruned
    inv: Tensor  # (S_new,) union slot of each new slot
    sq_dist: Tensor  # (n,) squared distance of each union row to the new mean


def _slot_depth(parent: Tensor) -> Tensor:
    """``(S,)`` layer of each slot from ``parent (S,)`` (parents first)."""
    par = parent.tolist()
    depth = [0] * len(par)
    for k in range(1, len(par)):
        depth[k] = depth[par[k]] + 1
    return torch.tensor(depth, dtype=torch.long)


def _canonical_order(parent: Sequence[int], s: Sequence[float], slots: Sequence[int]) -> list[int]:
    """The given slots (ancestor-closed, containing 0) depth-first, children by increasing ``s``."""
    children: dict[int, list[int]] = {k: [] for k in slots}
    for k in slots:
        if k != 0:
            children[parent[k]].append(k)
    order: list[int] = []
    stack = [0]
    while stack:
        k = stack.pop()
        order.append(k)
        stack.extend(sorted(children[k], key=lambda c: (s[c], c), reverse=True))
    return order


def _close_down(keep: Tensor, parent: Tensor) -> Tensor:
    """Drop the descendants of dropped slots (``keep (U,)`` bool, parents first); slot 0 stays."""
    out = keep.tolist()
    par = parent.tolist()
    out[0] = True
    for k in range(1, len(out)):
        out[k] = out[k] and out[par[k]]
    return torch.tensor(out, dtype=torch.bool)


def _close_up(keep: Tensor, parent: Tensor) -> Tensor:
    """Add the ancestors of kept slots."""
    out = keep.tolist()
    par = parent.tolist()
    out[0] = True
    for k in range(len(out) - 1, 0, -1):
        if out[k]:
            out[par[k]] = True
    return torch.tensor(out, dtype=torch.bool)


def _subset(mean: _Mean, order: Sequence[int]) -> _Mean:
    """The mean restricted to ``order`` (ancestor-closed, parents first), renumbered."""
    idx = torch.tensor(order, dtype=torch.long)
    new = torch.full((mean.num_slots,), -1, dtype=torch.long)
    new[idx] = torch.arange(len(order))
    par = mean.parent[idx]
    parent = torch.where(par >= 0, new[par.clamp(min=0)], par)
    s = mean.s[idx].clone()
    s[0] = 0.0
    return _Mean(mean.q[idx], s, mean.root, parent)


def _prune_threshold(lengths: Tensor, prune: float) -> float:
    return max(prune, NULL_FRACTION) * float(lengths[0])


def _tree_mean(tree: Trees, prune: float) -> _Mean:
    """One tree as a mean: its SRVFT in canonical slot order, short branches pruned."""
    pts = tree.points.detach().cpu().to(torch.float64)
    mean = _Mean(srvf(pts), tree.s.detach().cpu().to(torch.float64), pts[0, 0], tree.parent.cpu())
    lengths = srvf_sq_norm(mean.q)
    keep = _close_down(lengths > _prune_threshold(lengths, prune), mean.parent)
    slots = keep.nonzero()[:, 0].tolist()
    return _subset(mean, _canonical_order(mean.parent.tolist(), mean.s.tolist(), slots))


def _decode(mean: _Mean) -> Trees:
    """The mean as a single ``Trees`` (float64) whose SRVFs and ``s`` are exactly the mean's; label = slot."""
    S, M, d = mean.q.shape
    depth = _slot_depth(mean.parent)
    pts = mean.q.new_zeros(S, M + 1, d)
    for lev in range(int(depth.max()) + 1):
        idx = (depth == lev).nonzero()[:, 0]
        if lev == 0:
            start = mean.root[None]
        else:
            start = interpolate_curve(pts[mean.parent[idx]], mean.s[idx, None])[:, 0]
        pts[idx] = inverse_srvf(mean.q[idx], start)
    return Trees(pts, mean.parent.clone(), mean.s.clamp(0, 1), torch.tensor([S]), torch.arange(S))


def _registered(reg: TreeRegistration) -> _Registered:
    """Row 0 of a registration's 2-tree layout (reference = a decoded mean, so its first slots are the mean's)."""
    a = reg.aligned
    return _Registered(a.q[0].detach().cpu(), a.s[0].detach().cpu(), a.present[0].cpu(), a.source[0].cpu(),
                       a.slot_parent.cpu(), a.root[0].detach().cpu(), float(reg.distance) ** 2)


def _union(forms: Sequence[_Registered], S: int) -> _Union:
    """Registered trees in one layout: the mean's ``S`` slots, then each tree's extra slots in turn."""
    n = len(forms)
    M, d = forms[0].q.shape[1:]
    parent = forms[0].parent[:S].tolist()
    rows: list[Tensor] = []
    for f in forms:
        off = len(parent)
        extra = f.parent[S:].tolist()
        rows.append(torch.cat([torch.arange(S), off + torch.arange(len(extra))]).long())
        parent += [p if p < S else off + p - S for p in extra]
    U = len(parent)
    q = torch.zeros(n, U, M, d, dtype=torch.float64)
    s = torch.zeros(n, U, dtype=torch.float64)
    present = torch.zeros(n, U, dtype=torch.bool)
    source = torch.full((n, U), -1, dtype=torch.long)
    for i, (f, idx) in enumerate(zip(forms, rows)):
        q[i, idx], s[i, idx], present[i, idx], source[i, idx] = f.q, f.s, f.present, f.source
    root = torch.stack([f.root for f in forms])
    return _Union(q, s, present, source, torch.tensor(parent, dtype=torch.long), root)


def _union_sq_dist(u: _Union, q: Tensor, s: Tensor, keep: Tensor, w_q: Tensor, w_s: Tensor) -> Tensor:
    """``(n,)`` squared distance of every union row to a mean ``q (U, M, d)``, ``s (U,)`` present on ``keep``.

    A slot where only one side has a branch costs its branch's weighted length (its ``s`` is free).
    """
    mq = q * keep[:, None, None]
    both = u.present & keep
    return (w_q * srvf_sq_norm(u.q - mq)).sum(1) + (w_s * both * (u.s - s).square()).sum(1)


def _carry(c: _Carry, i: int, mean: _Mean) -> _Registered:
    """Tree ``i``'s previous correspondence as a registration onto ``mean``: kept slots map to the new slots,
    its branches in pruned slots become unmatched (extra slots)."""
    u = c.union
    present = u.present[i, c.inv]
    s = torch.where(present, u.s[i, c.inv], mean.s)
    source = torch.where(present, u.source[i, c.inv], -1)
    keep_map = c.keep_map.tolist()
    uparent = u.parent.tolist()
    extras = [k for k in range(len(keep_map)) if keep_map[k] < 0 and bool(u.present[i, k])]
    local = {k: mean.num_slots + j for j, k in enumerate(extras)}
    par_e = [keep_map[uparent[k]] if keep_map[uparent[k]] >= 0 else local[uparent[k]] for k in extras]
    ex = torch.tensor(extras, dtype=torch.long)
    return _Registered(torch.cat([u.q[i, c.inv], u.q[i, ex]]), torch.cat([s, u.s[i, ex]]),
                       torch.cat([present, u.present[i, ex]]), torch.cat([source, u.source[i, ex]]),
                       torch.cat([mean.parent, torch.tensor(par_e, dtype=torch.long)]), u.root[i],
                       float(c.sq_dist[i]))


# ----------------------------------------------------------------------------- the module


class KarcherMean(FittedModule):
    """Karcher mean of 3D trees in a growing slot layout (docs/method.md §4; the algorithm in the module doc).

    Args:
        lambdas: ``(lm, ls, lp)`` metric weights (docs/method.md §3).
        rotation: ``"none"``, ``"vertical"`` or ``"so3"`` (registration onto the mean).
        max_iters: at most this many rounds of registration onto a mean (the first is onto the initial one).
        tol: stop when the mean moved by less than ``tol`` relatively (``|f(new) - f(old)| / |f(old)|`` in the
            union layout) or the energy decreased by less than ``tol`` relatively.
        max_slots: cap on the mean's layout; exceeding it raises :class:`SlotLimitError` (raise the cap or
            ``prune_length``) instead of silently dropping branches.
        prune_length: slots whose average branch length over the trees is below this **fraction of the average
            main-branch length** are pruned with their descendants after each average (and the initial tree's
            shorter branches). The default 0.01, measured against no pruning: synthetic tomato (10 frames)
            41 slots instead of 58 for a 0.5% higher energy; Pheno4D tom_1 (9 days) 62 instead of 76, +0.15%
            (0.02: 29 and 50 slots, +2.1% and +0.6%; 0.05: 10 and 32 slots, +14% and +2.4%).
        init: ``"medoid"``: among ``medoid_subsample`` trees (evenly spaced ranks when sorted by total length,
            then branch count), the one with the smallest sum of squared registered distances of the subsample
            onto it (branches resampled to ``MEDOID_T`` points for this ranking); the result does not depend on
            the input order (ties aside). Or an ``int``: that tree.
        medoid_subsample: subsample size of the medoid rule (it costs ``m^2`` pair registrations).
        progress: a tqdm bar over the iterations.
        registration: how the registrations onto the mean search
            (:class:`~torch4dtree.settings.RegistrationSettings`; its ``max_iters`` / ``tol`` are the registration's
            own). They match children by the layout's own metric (``positions="warped"``), in any order.
        lp_relative: ``lp`` is relative to the trees' size (as in :func:`~torch4dtree.trees.register_to_reference`):
            ``fit`` multiplies it once by ``RELATIVE_LP_SCALE`` times the trees' median main-branch length (one metric
            for every round); afterwards ``lambdas`` holds the effective weights and ``lp_relative`` is False.

    Fitted buffers (float in the dtype of the fitted trees; ``.to()`` moves and casts them):
    ``mean_q (S, M, d)``, ``mean_s (S,)``, ``mean_root (d,)``, ``slot_parent (S,)``, ``slot_depth (S,)``.
    The settings, ``history``, ``n_iter_`` and ``converged_`` travel in the extra state, so a fresh
    ``KarcherMean().load_state_dict(sd)`` restores the fitted module exactly.

    After ``fit``: ``history`` is one dict per round of registration: ``energy`` (sum of squared distances to
    that round's mean), ``num_slots`` (its layout size), ``union_slots`` (the union layout built from that
    round, before pruning; 0 in the last round), ``rel_change`` (how far that mean moved from the previous
    one; NaN in round 0), ``kept_previous`` (trees whose previous correspondence beat their fresh registration)
    and ``seconds`` (wall time of the round, the initialisation included in round 0).
    ``n_iter_ = len(history)``, ``converged_`` whether ``tol`` was met before ``max_iters``, ``init_index_`` the
    tree the mean started from.

    Example:
        >>> from torch4dtree.data import synthetic_plant
        >>> trees = synthetic_plant("maize", 0, n_frames=3, T=8).sequence.frames
        >>> km = KarcherMean(max_iters=2, progress=False).fit(trees)
        >>> km.mean_tree().num_trees, km.transform(trees).distance.shape
        (1, torch.Size([3]))
    """

    _fitted_buffers = ("mean_q", "mean_s", "mean_root", "slot_parent", "slot_depth")

    def __init__(self, lambdas: Sequence[float] = (1.0, 1.0, 1.0), rotation: str = "none", max_iters: int = 20,
                 tol: float = 1e-4, max_slots: int = 512, prune_length: float = DEFAULT_PRUNE,
                 init: str | int = "medoid", medoid_subsample: int = 8, progress: bool = True,
                 registration: RegistrationSettings | None = None, lp_relative: bool = True) -> None:
        super().__init__()
        self.lambdas: Lambdas = check_lambdas(lambdas)
        self.lp_relative = bool(lp_relative)
        check_choice("rotation", rotation, ROTATIONS)
        if max_iters < 1 or not tol >= 0 or max_slots < 1 or not prune_length >= 0 or medoid_subsample < 1:
            raise ValueError(f"need max_iters >= 1, tol >= 0, max_slots >= 1, prune_length >= 0 and "
                             f"medoid_subsample >= 1; got {max_iters}, {tol}, {max_slots}, {prune_length}, "
                             f"{medoid_subsample}")
        if not (init == "medoid" or (isinstance(init, int) and not isinstance(init, bool))):
            raise ValueError(f"init must be 'medoid' or a tree index, got {init!r}")
        self.rotation, self.max_iters, self.tol, self.max_slots = rotation, int(max_iters), float(tol), int(max_slots)
        self.prune_length, self.init, self.medoid_subsample = float(prune_length), init, int(medoid_subsample)
        if registration is not None and not isinstance(registration, RegistrationSettings):
            raise TypeError(f"registration must be a RegistrationSettings, got {type(registration).__name__}")
        self.progress, self.registration = bool(progress), registration or RegistrationSettings()
        self.history: list[dict[str, float]] = []
        self.n_iter_ = 0
        self.converged_ = False
        self.init_index_ = -1
        self.register_buffer("mean_q", torch.zeros(0, 0, 0))
        self.register_buffer("mean_s", torch.zeros(0))
        self.register_buffer("mean_root", torch.zeros(0))
        self.register_buffer("slot_parent", torch.zeros(0, dtype=torch.long))
        self.register_buffer("slot_depth", torch.zeros(0, dtype=torch.long))

    # ------------------------------------------------------------------------ state
    def get_extra_state(self) -> dict[str, Any]:
        return {"version": 1, "lambdas": list(self.lambdas), "lp_relative": self.lp_relative,
                "rotation": self.rotation, "max_iters": self.max_iters,
                "tol": self.tol, "max_slots": self.max_slots, "prune_length": self.prune_length, "init": self.init,
                "medoid_subsample": self.medoid_subsample, "registration": self.registration.to_dict(),
                "history": [dict(h) for h in self.history], "n_iter": self.n_iter_, "converged": self.converged_,
                "init_index": self.init_index_}

    def set_extra_state(self, state: dict[str, Any]) -> None:
        if not isinstance(state, dict) or state.get("version") != 1:
            raise ValueError("not a KarcherMean state (missing or unknown version)")
        self.lambdas = check_lambdas(state["lambdas"])
        self.lp_relative = bool(state.get("lp_relative", False))
        self.rotation, self.max_iters, self.tol = state["rotation"], state["max_iters"], state["tol"]
        self.max_slots, self.prune_length, self.init = state["max_slots"], state["prune_length"], state["init"]
        self.medoid_subsample = state["medoid_subsample"]
        self.registration = RegistrationSettings.from_dict(state["registration"])
        self.history = [dict(h) for h in state["history"]]
        self.n_iter_, self.converged_, self.init_index_ = state["n_iter"], state["converged"], state["init_index"]

    @property
    def is_fitted(self) -> bool:
        return self.mean_q.shape[0] > 0

    @property
    def num_slots(self) -> int:
        """``S``, the size of the fitted mean's layout."""
        return self.mean_q.shape[0]

    def _check_fitted(self) -> None:
        if not self.is_fitted:
            raise NotFittedError("KarcherMean is not fitted: call fit() or load_state_dict() first")

    def _mean(self) -> _Mean:
        """The fitted mean in float64 on the CPU (where registration runs)."""
        self._check_fitted()
        f = {"dtype": torch.float64, "device": "cpu"}
        return _Mean(self.mean_q.to(**f), self.mean_s.to(**f), self.mean_root.to(**f), self.slot_parent.cpu())

    # ------------------------------------------------------------------------ fitted mean
    def mean_aligned(self) -> AlignedTrees:
        """The mean as a 1-tree :class:`AlignedTrees` in its own layout (buffers' dtype and device)."""
        self._check_fitted()
        S = self.num_slots
        dev = self.mean_q.device
        return AlignedTrees(self.mean_q[None], self.mean_s[None], torch.ones(1, S, dtype=torch.bool, device=dev),
                            self.mean_root[None], self.slot_parent, self.slot_depth,
                            torch.full((1, S), -1, dtype=torch.long, device=dev), self.lambdas)

    def mean_tree(self) -> Trees:
        """The mean decoded as a tree (branches resampled uniformly in arc length; ``label`` = slot index)."""
        return self.mean_aligned().to_trees()

    # ------------------------------------------------------------------------ fit / transform
    def fit(self, trees: Trees) -> KarcherMean:
        """Fit the mean of ``trees`` (``n >= 1`` trees). Returns ``self``."""
        self._fit(trees)
        return self

    def fit_transform(self, trees: Trees) -> MeanRegistration:
        """Fit, then the trees as registered onto the final mean in the last round (no extra registration)."""
        forms, mean = self._fit(trees)
        return self._result(forms, mean)

    def transform(self, trees: Trees) -> MeanRegistration:
        """Register ``trees`` onto the fitted mean (one batched call) and write them in the mean's layout.

        Branches that match no slot of the mean are dropped from the returned layout (listed in ``dropped``,
        their cost in ``dropped_sq_norm``), so every result shares the mean's fixed layout (what PCA needs).
        """
        _check_trees(trees)
        mean = self._mean()
        return self._result(self._register(trees.to("cpu"), mean), mean)

    def _result(self, forms: Sequence[_Registered], mean: _Mean) -> MeanRegistration:
        S = mean.num_slots
        depth = _slot_depth(mean.parent)
        aligned = AlignedTrees(torch.stack([f.q[:S] for f in forms]), torch.stack([f.s[:S] for f in forms]),
                               torch.stack([f.present[:S] for f in forms]), torch.stack([f.root for f in forms]),
                               mean.parent, depth, torch.stack([f.source[:S] for f in forms]), self.lambdas)
        dropped, dropped_sq = [], []
        for f in forms:
            w_q, _ = slot_weights(_slot_depth(f.parent)[S:], self.lambdas)
            dropped.append(f.source[S:].tolist())
            dropped_sq.append(float((w_q * srvf_sq_norm(f.q[S:])).sum()))
        dist = torch.tensor([math.sqrt(f.sq_dist) for f in forms], dtype=torch.float64)
        like = {"dtype": self.mean_q.dtype, "device": self.mean_q.device}
        return MeanRegistration(aligned.to(**like), dist.to(**like), dropped,
                                torch.tensor(dropped_sq, dtype=torch.float64).to(**like))

    def _register(self, trees: Trees, mean: _Mean) -> list[_Registered]:
        # one way (symmetric=False): the trees are aligned onto the mean; an inverted solution would only fit worse
        # warped positions: the registrations minimise the layout's own metric, which the mean averages
        regs = self.registration.register(trees, _decode(mean), self.lambdas, self.rotation, positions="warped",
                                          order_tol=None, lp_relative=False, symmetric=False)
        return [_registered(r) for r in regs]

    def _initial_mean(self, trees: Trees) -> tuple[_Mean, list[_Registered] | None]:
        """The starting mean, and the registrations of all trees onto it when the medoid rule computed them."""
        n = trees.num_trees
        if self.init != "medoid":
            i = int(self.init)
            if not -n <= i < n:
                raise ValueError(f"init={i} is not a tree index for {n} trees")
            self.init_index_ = i % n
            return self._capped(_tree_mean(trees[i], self.prune_length)), None
        total, count = trees.total_length().tolist(), trees.num_branches.tolist()
        ranked = sorted(range(n), key=lambda i: (total[i], count[i], i))
        m = min(self.medoid_subsample, n)
        sub = ranked if m == n else [ranked[round(j * (n - 1) / max(m - 1, 1))] for j in range(m)]
        # candidates are ranked on coarser curves (DP cost ~ T^2): the same medoid at T = 24 as at 64 on synthetic
        # tomato and maize and Pheno4D tomato, 2.3-2.9x faster
        coarse = trees.T > MEDOID_T
        ranking = trees.resample(MEDOID_T) if coarse else trees
        subtrees = ranking[sub]
        scored = []
        for c in sub:
            forms = self._register(subtrees, self._capped(_tree_mean(ranking[c], self.prune_length)))
            scored.append((sum(f.sq_dist for f in forms), c, forms))
        best = min(scored, key=lambda x: x[0])
        self.init_index_ = best[1]
        mean = self._capped(_tree_mean(trees[best[1]], self.prune_length))
        if m < n or coarse:
            return mean, None
        pos = {t: k for k, t in enumerate(sub)}  # every tree was registered onto this very mean: reuse
        return mean, [best[2][pos[i]] for i in range(n)]

    def _capped(self, mean: _Mean) -> _Mean:
        if mean.num_slots > self.max_slots:
            raise SlotLimitError(f"the mean needs {mean.num_slots} slots > max_slots={self.max_slots}: raise "
                                 f"max_slots or prune_length (now {self.prune_length} of the main branch)")
        return mean

    def _update(self, mean: _Mean, forms: Sequence[_Registered], energy: float) -> tuple[_Mean, _Carry, float, int]:
        """Average the registered trees in their union layout, prune, reorder.

        Returns the new mean, the previous correspondences carried onto it, the relative change of the mean
        and the union layout's size.
        """
        S = mean.num_slots
        u = _union(forms, S)
        U = u.parent.shape[0]
        w_q, w_s = slot_weights(_slot_depth(u.parent), self.lambdas)
        q = u.q.mean(0)
        count = u.present.sum(0)
        s = torch.where(count > 0, (u.s * u.present).sum(0) / count.clamp(min=1), 0.0).clamp(0, 1)
        # the average branch length over the trees (null = 0), not the length of the average branch: the latter
        # is (k/n)^2 L for a branch that k of n trees share, which would prune every new slot as n grows
        lengths = srvf_sq_norm(u.q).mean(0)
        keep = _close_down(lengths > _prune_threshold(lengths, self.prune_length), u.parent)
        sq = _union_sq_dist(u, q, s, keep, w_q, w_s)
        if float(sq.sum()) > energy * (1 + 1e-12):  # pruning an old slot raised the energy: prune new ones only
            old = (torch.arange(U) < S) & (lengths > 0)
            keep = _close_up(keep | old, u.parent)
            sq = _union_sq_dist(u, q, s, keep, w_q, w_s)
        if int(keep.sum()) > self.max_slots:
            raise SlotLimitError(f"the union layout keeps {int(keep.sum())} slots after pruning > max_slots="
                                 f"{self.max_slots}: raise max_slots or prune_length (now {self.prune_length} "
                                 f"of the main branch)")
        order = _canonical_order(u.parent.tolist(), s.tolist(), keep.nonzero()[:, 0].tolist())
        inv = torch.tensor(order, dtype=torch.long)
        full = _Mean(q, s, u.root.mean(0), u.parent)
        new = _subset(full, order)
        keep_map = torch.full((U,), -1, dtype=torch.long)
        keep_map[inv] = torch.arange(len(order))
        # how far the mean moved, in the union layout (s compared where both means have the branch)
        q_old = torch.cat([mean.q, q.new_zeros(U - S, *q.shape[1:])])
        s_old = torch.cat([mean.s, s.new_zeros(U - S)])
        both = (torch.arange(U) < S) & keep
        moved = (w_q * srvf_sq_norm(q_old - q * keep[:, None, None])).sum() + (w_s * both * (s_old - s).square()).sum()
        scale = (w_q[:S] * srvf_sq_norm(mean.q)).sum()
        change = math.sqrt(float(moved / scale)) if float(scale) > 0 else 0.0
        return new, _Carry(u, keep_map, inv, sq), change, U

    def _fit(self, trees: Trees) -> tuple[list[_Registered], _Mean]:
        from tqdm.auto import tqdm

        _check_trees(trees)
        dtype = trees.dtype
        trees = trees.to("cpu")  # the discrete solve runs on the CPU
        self.history, self.n_iter_, self.converged_ = [], 0, False
        bar = tqdm(total=self.max_iters, disable=not self.progress, desc="Karcher mean", unit="iter")
        start = time.perf_counter()
        if self.lp_relative:  # one metric for all rounds: lp relative to the trees' median main-branch length
            main = trees.branch_lengths()[trees.main_index]
            scale = RELATIVE_LP_SCALE * float(main.median())
            self.lambdas = (self.lambdas[0], self.lambdas[1], self.lambdas[2] * scale)
            self.lp_relative = False
        mean, forms = self._initial_mean(trees)
        carry: _Carry | None = None
        change = math.nan
        prev: float | None = None
        for it in range(self.max_iters):
            if forms is None:
                forms = self._register(trees, mean)
            kept = 0
            if carry is not None:  # keep the previous correspondence where it is the better registration
                better = (carry.sq_dist < torch.tensor([f.sq_dist for f in forms], dtype=torch.float64)).tolist()
                forms = [_carry(carry, i, mean) if b else f for i, (f, b) in enumerate(zip(forms, better))]
                kept = sum(better)
            energy = sum(f.sq_dist for f in forms)
            step = {"energy": energy, "num_slots": mean.num_slots, "union_slots": 0, "rel_change": change,
                    "kept_previous": kept}
            self.history.append(step)
            size = len(forms) * float((slot_weights(_slot_depth(mean.parent), self.lambdas)[0]
                                       * srvf_sq_norm(mean.q)).sum())
            exact = energy <= 1e-20 * size  # every tree is the mean (rounding aside)
            done = exact or (prev is not None and (change < self.tol or prev - energy <= self.tol * prev))
            if done or it == self.max_iters - 1:
                self.converged_ = done
                step["seconds"] = time.perf_counter() - start
                bar.update(1)
                break
            new, carry, change, step["union_slots"] = self._update(mean, forms, energy)
            step["seconds"] = time.perf_counter() - start
            start = time.perf_counter()
            bar.update(1)
            bar.set_postfix(energy=f"{energy:.4g}", slots=mean.num_slots)
            mean, forms, prev = new, None, energy
        bar.close()
        if forms is None:  # the loop's last round always registers (max_iters >= 1)
            raise RuntimeError("internal error: the Karcher mean ended without registrations")
        mean.root = torch.stack([f.root for f in forms]).mean(0)  # not in the metric: also when stopping at round 0
        self.n_iter_ = len(self.history)
        depth = _slot_depth(mean.parent)
        self._set_fitted(mean_q=mean.q.to(dtype), mean_s=mean.s.to(dtype), mean_root=mean.root.to(dtype),
                         slot_parent=mean.parent, slot_depth=depth)
        return forms, mean


def _check_trees(trees: Trees) -> None:
    if not isinstance(trees, Trees):
        raise TypeError(f"expected a Trees batch, got {type(trees).__name__}")
    if trees.num_trees < 1:
        raise ValueError("need at least one tree")
