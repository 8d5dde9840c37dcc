"""The population tree space (docs/method.md §5): ``N`` 4D trees in one slot layout, a tree PCA, trajectories.

:func:`fit_population` runs, for ``N`` 4D trees:

1. **within-sequence registration** of each (:func:`register_sequence` with its own weights, which favour
   identities between consecutive frames); the space itself has one metric (``lp``
   relative to the median last-frame main-branch length, so it does not depend on which plant is the reference);
2. **the reference**: the medoid of the representatives (:func:`representative_tree`) among
   ``medoid_candidates`` candidates, chosen by an order-independent rule (the candidates are the
   representatives at evenly spaced ranks of total length, ties by name; the one with the smallest sum of
   squared registered distances of all representatives onto it wins);
3. **cross-sequence registration** onto a growing **union representative** and the **union layout** of all frames
   (:func:`place_targets`). The union representative starts as the reference's; the other representatives are
   registered onto it one by one, in the order of their registered distance to the reference (ties by name, so the
   result does not depend on the input order): a branch matched to a union slot goes there, also to a slot an
   earlier plant opened, and an unmatched one opens a slot whose branch joins the union representative
   (:func:`grow_union`). So a branch the reference lacks opens one slot that later plants can share, not one slot
   per plant. These registrations use the cross-sequence settings (:class:`~torch4dtree.settings.CrossSettings`:
   node ranks on every axis, lp 100 relative, organs kept in their order along the parent by default); the layout
   keeps the space's metric. Until a slot is opened, the batched registrations onto the reference are reused; the later
   ones are one call per plant. The layout keeps at most ``max_slots`` slots: each slot carries the squared
   weighted length of the training branches placed in it, and when the union has grown past ``SLOT_SLACK``
   times the bound (and once at the end) only the ``max_slots`` slots carrying the most are kept, closed under
   parents (:func:`bounded_slots`); branches in dropped slots leave the layout (their share is reported);
4. a :class:`TreePCA` on all frames, and each 4D tree's **trajectory** ``(n_t, k)`` on the normalised time grid
   ``linspace(0, 1, n_t)`` between its first and last frame (its ``time_spans`` give data units back).

:class:`Population` is an ``nn.Module`` holding what is needed to put a *new* 4D tree into the fitted space
(:meth:`Population.transform`): the union representative (its branch points, one per layout slot), the tree PCA,
the settings. The registration's matches are completed by place (:func:`completed_matches`: children it left
unmatched under a matched parent take that slot's free child slots, in order between the matched siblings); a new
tree's branches that still match no slot cannot be written in the layout and are dropped (their cost is reported).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from concurrent.futures import Executor
from functools import partial
from typing import Any, NamedTuple

import torch
from torch import Tensor

from ..parallel import move, run_tasks
from ..settings import (
    DEFAULT_MAX_SLOTS,
    DEFAULT_NT,
    ROTATIONS,
    CrossSettings,
    RegistrationSettings,
    check_at_least,
    check_choice,
    check_lambdas,
)
from ..space.fitted import FittedModule, NotFittedError
from ..space.pca import TreePCA
from ..trees.aligned import AlignedTrees, slot_weights
from ..trees.prepare import RankedTree, prepare_tree
from ..trees.registration import RELATIVE_LP_SCALE, TreeRegistration
from ..trees.structures import Trees, TreeSequence
from .spatiotemporal import (
    bounded_slots,
    completed_matches,
    grow_union,
    open_slots,
    place_sequence,
    place_targets,
    representative_tree,
    slot_masses,
    union_subset,
)
from .trajectory import resample_trajectory
from .within import AlignedSequence, register_sequence

__all__ = ["Population", "SequenceEncoding", "UnionLayout", "cross_registration", "fit_population",
           "transform_sequence"]

# the union layout grows to this many times max_slots before it is cut back to max_slots: a slot a plant opens
# gathers the norm of the plants after it before it is ranked (the registrations' cost stays bounded by it)
SLOT_SLACK = 2


class SequenceEncoding(NamedTuple):
    """One 4D tree written in a fitted :class:`Population` (``n`` frames, ``k`` components, ``S`` slots).

    * ``trajectory (n_t, k)``: tree-PCA coefficients on the normalised time grid.
    * ``frame_coefficients (n, k)``: per frame; ``times (n,)`` their data times.
    * ``aligned``: the frames in the population layout (:class:`AlignedTrees` of ``n`` trees).
    * ``dropped_sq_norm (n,)``: squared weighted length of each frame's branches outside the layout.
    """

    trajectory: Tensor
    frame_coefficients: Tensor
    times: Tensor
    aligned: AlignedTrees
    dropped_sq_norm: Tensor


class UnionLayout(NamedTuple):
    """The union layout of :meth:`Population.fit` (``N`` plants, ``S`` slots).

    * ``movs``: the moving plants in union order; ``union``: the union representative (one tree, ``S`` branches),
      a :class:`RankedTree` with node ranks (``rank``, ``nodes`` positions).
    * ``regs``: each plant's registration onto the union representative as it was at its turn.
    * ``targets``: per plant (the reference first, then ``movs``), the layout slot of each of its slots (``-1``:
      dropped by the bound).
    * ``slot_parent``, ``slot_depth``: the layout (``S`` each); ``opened``: slots opened in all (before the bound).
    * ``dropped_share``: share of the training frames' squared weighted length in the dropped slots.
    """

    movs: list[int]
    union: Trees
    regs: list[Any]
    targets: list[list[int]]
    slot_parent: list[int]
    slot_depth: list[int]
    opened: int
    dropped_share: float


def cross_registration(trees: Trees, reference: Trees, lam: tuple[float, float, float], rotation: str,
                       registration: RegistrationSettings, cross: CrossSettings) -> list[TreeRegistration]:
    """A cross-sequence registration of ``trees`` onto ``reference`` with weights ``lam`` (effective), one way
    (``symmetric=False``: no inverted solutions, as every use of a layout's registrations). A task: top-level,
    picklable."""
    return registration.register(trees, reference, lam, rotation, positions=cross.positions,
                                 order_tol=cross.order_tol, lp_relative=False, symmetric=False)


def own_ranks(tree: Trees, positions: str) -> list[float] | None:
    """``tree``'s children's node ranks on its own branches (``positions`` ``"rank"`` or ``"nodes"``), ``None`` for
    the other positions (which do not count a parent's other children)."""
    if positions not in ("rank", "nodes"):
        return None
    return prepare_tree(tree, (1.0, 1.0, 1.0), positions).s.tolist()


def ranked(union: Trees, ranks: Sequence[float] | None, positions: str) -> Trees:
    """The one-tree ``union`` compared with the node ``ranks`` its branches had on the plants they came from
    (:class:`RankedTree`; docs/method.md §3), or as it is where ``ranks`` is ``None``."""
    if ranks is None:
        return union
    return RankedTree(union.points, union.parent, union.s, union.num_branches, union.label,
                      torch.as_tensor(list(ranks), dtype=torch.float64, device=union.points.device), positions)


def transform_sequence(population: Population, sequence: TreeSequence) -> SequenceEncoding:
    """``population.transform(sequence)`` (a task: top-level, picklable)."""
    return population.transform(sequence)


class Population(FittedModule):
    """``N`` 4D trees in one tree space (module doc). Fit with :meth:`fit` or :func:`fit_population`.

    Args:
        lambdas: ``(lm, ls, lp)``; ``lp`` relative to the plants' size (module doc, step 1).
        rotation: ``"none"``, ``"vertical"`` or ``"so3"`` (cross-sequence registration; within a sequence the
            frames share the scanner's frame, so none is used there).
        n_t: common time samples of the trajectories.
        n_components: tree-PCA components (default: the smallest number explaining ``variance``).
        variance: share of the frames' variance the tree PCA keeps when ``n_components`` is None.
        medoid_candidates: how many representatives compete for the reference (each costs one batched
            registration of all ``N``).
        registration: how the tree registrations search (within- and cross-sequence).
        cross: the cross-sequence registrations' (medoid, union, :meth:`transform`) children's positions, relative
            ``lp`` (``None``: ``lambdas[2]``; the space's metric keeps ``lambdas``) and ``order_tol``, as in
            :func:`~torch4dtree.temporal.register4d` (its ``fallback_rotation`` is register4d's only). Within a
            sequence, :func:`register_sequence` keeps its own.
        max_slots: the union layout's slot bound (``None``: unbounded): the slots carrying the most of the training
            frames' squared weighted length are kept, the rarest dropped (module doc, step 3; the dropped share is
            ``report_["dropped_share"]``). It bounds the features (``frames x slots``) and the registrations onto
            the union representative whatever the number of plants.

    Fitted buffers: ``ref_points (S, T, d)``, ``ref_parent (S,)``, ``ref_s (S,)`` (the union representative,
    module doc step 3: one branch per layout slot, in slot order), ``ref_ranks (S,)`` (its branches' node ranks on
    the plants they came from, what a plant registered onto it is compared with; empty unless ``cross.positions``
    is ``"rank"`` or ``"nodes"``), ``trajectories (N, n_t, k)``,
    ``time_spans (N, 2)`` (first and last frame time of each training 4D tree); the tree PCA is the submodule
    ``pca``. ``lambdas_`` (the effective weights), ``cross_lambdas_`` (the cross registrations' effective weights),
    ``names_``, ``report_`` travel in the extra state.

    Example:
        >>> from torch4dtree.data import synthetic_plant
        >>> plants = [synthetic_plant("maize", i, n_frames=3, T=8).sequence for i in range(2)]
        >>> pop = Population(n_t=4, medoid_candidates=1).fit(plants)
        >>> pop.trajectories.shape[:2]
        torch.Size([2, 4])
    """

    _fitted_buffers = ("ref_points", "ref_parent", "ref_s", "ref_ranks", "trajectories", "time_spans")

    def __init__(self, lambdas: Sequence[float] = (1.0, 1.0, 1.0), rotation: str = "none", n_t: int = DEFAULT_NT,
                 n_components: int | None = None, variance: float = 0.99, medoid_candidates: int = 3,
                 registration: RegistrationSettings | None = None, cross: CrossSettings | None = None,
                 max_slots: int | None = DEFAULT_MAX_SLOTS) -> None:
        super().__init__()
        check_choice("rotation", rotation, ROTATIONS)
        self.max_slots = None if max_slots is None else check_at_least("max_slots", max_slots, 1)
        self.lambdas = check_lambdas(lambdas)
        self.rotation, self.n_t = rotation, check_at_least("n_t", n_t, 2)
        self.medoid_candidates = check_at_least("medoid_candidates", medoid_candidates, 1)
        for name, value, kind in (("registration", registration, RegistrationSettings),
                                  ("cross", cross, CrossSettings)):
            if value is not None and not isinstance(value, kind):
                raise TypeError(f"{name} must be a {kind.__name__}, got {type(value).__name__}")
        self.registration = registration or RegistrationSettings()
        self.cross = cross or CrossSettings()
        self.lambdas_ = self.cross_lambdas_ = self.lambdas
        self.names_: list[str] = []
        self.report_: dict[str, Any] = {}
        self.pca = TreePCA(n_components=n_components, variance=variance)
        self.register_buffer("ref_points", torch.zeros(0, 0, 0))
        self.register_buffer("ref_parent", torch.zeros(0, dtype=torch.long))
        self.register_buffer("ref_s", torch.zeros(0))
        self.register_buffer("ref_ranks", torch.zeros(0))
        self.register_buffer("trajectories", torch.zeros(0, 0, 0))
        self.register_buffer("time_spans", torch.zeros(0, 2))
        self.layout_: AlignedTrees | None = None  # the training frames (not saved)
        self.sequences_: list[AlignedSequence] = []

    def get_extra_state(self) -> dict[str, Any]:
        return {"version": 1, "lambdas": list(self.lambdas), "rotation": self.rotation, "n_t": self.n_t,
                "medoid_candidates": self.medoid_candidates, "registration": self.registration.to_dict(),
                "lambdas_": list(self.lambdas_), "names": list(self.names_), "report": self.report_,
                "positions": self.cross.positions, "cross_lp": self.cross.lp, "cross_order_tol": self.cross.order_tol,
                "cross_lambdas_": list(self.cross_lambdas_), "max_slots": self.max_slots}

    def set_extra_state(self, state: dict[str, Any]) -> None:
        if not isinstance(state, dict) or state.get("version") != 1:
            raise ValueError("not a Population state (missing or unknown version)")
        self.lambdas, self.rotation, self.n_t = check_lambdas(state["lambdas"]), state["rotation"], state["n_t"]
        self.medoid_candidates = state["medoid_candidates"]
        self.registration = RegistrationSettings.from_dict(state["registration"])
        self.lambdas_ = check_lambdas(state["lambdas_"])
        # a state without the cross settings was fitted with warped positions, the space's lp, children in any order
        self.cross = CrossSettings(state.get("positions", "warped"), state.get("cross_lp"),
                                   state.get("cross_order_tol"), self.cross.fallback_rotation)
        self.cross_lambdas_ = check_lambdas(state.get("cross_lambdas_", state["lambdas_"]))
        self.names_, self.report_ = list(state["names"]), dict(state["report"])
        self.max_slots = state.get("max_slots")  # a state without it was fitted unbounded

    def _load_from_state_dict(self, state_dict: dict[str, Any], prefix: str, *args: Any, **kwargs: Any) -> None:
        # a state without ranks compares the union representative with the ranks counted on it
        state_dict.setdefault(prefix + "ref_ranks", torch.zeros(0))
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    @property
    def is_fitted(self) -> bool:
        return self.trajectories.shape[0] > 0

    def _register_cross(self, trees: Trees, reference: Trees, lam: tuple[float, float, float]
                        ) -> list[TreeRegistration]:
        """:func:`cross_registration` with this population's settings."""
        return cross_registration(trees, reference, lam, self.rotation, self.registration, self.cross)

    @property
    def k(self) -> int:
        return self.pca.n_components_

    def _check_fitted(self) -> None:
        if not self.is_fitted:
            raise NotFittedError("Population is not fitted: call fit() or load_state_dict() first")

    def reference_tree(self) -> Trees:
        """The union representative (module doc, step 3) as a one-tree :class:`Trees` (float64; ``label`` = slot), a
        :class:`RankedTree` with ``ref_ranks`` where the population has them."""
        S = self.ref_parent.shape[0]
        dev = self.ref_points.device
        tree = Trees(self.ref_points.to(torch.float64), self.ref_parent.clone(), self.ref_s.to(torch.float64),
                     torch.tensor([S], device=dev), torch.arange(S, device=dev))
        return ranked(tree, self.ref_ranks.tolist() if self.ref_ranks.numel() == S else None, self.cross.positions)

    # ------------------------------------------------------------------------ fit
    def fit(self, sequences: Sequence[TreeSequence], progress: bool = False, executor: Executor | None = None
            ) -> Population:
        """Fit on ``N >= 2`` 4D trees (each with at least 2 frames). Returns ``self``; timings in ``report_``.

        ``executor``: runs the within-sequence registrations (one task a plant) and the reference's candidates
        (one task each) there (:mod:`torch4dtree.parallel`); the union layout grows plant by plant on the driver.
        The result does not depend on it."""
        seqs = list(sequences)
        if len(seqs) < 2:
            raise ValueError(f"a population needs at least 2 4D trees, got {len(seqs)}")
        for i, s in enumerate(seqs):
            if not isinstance(s, TreeSequence):
                raise TypeError(f"sequence {i} is a {type(s).__name__}, not a TreeSequence")
            if len(s) < 2:
                raise ValueError(f"{s.name or f'sequence {i}'} has {len(s)} frame(s); a 4D tree needs at least 2")
        seqs = [s.to(torch.float64) for s in seqs]
        seconds: dict[str, float] = {}
        t0 = time.perf_counter()
        lengths = torch.stack([s.frames[len(s) - 1].branch_lengths()[0] for s in seqs])
        lm, ls, lp = self.lambdas
        lam = (lm, ls, lp * RELATIVE_LP_SCALE * float(lengths.median()))
        # the cross registrations' weights (the layout keeps lam)
        self.cross_lambdas_ = lam if self.cross.lp is None else \
            (lm, ls, self.cross.lp * RELATIVE_LP_SCALE * float(lengths.median()))
        from tqdm.auto import tqdm

        # identities over time with register_sequence's own weights (lp relative to each frame pair: a plant's
        # young frames need it); the space's metric ``lam`` applies from the union layout on
        device = seqs[0].frames.points.device
        with tqdm(total=len(seqs), disable=not progress, desc="within-sequence registration", unit="plant") as bar:
            within = partial(register_sequence, progress=False, registration=self.registration)
            aseqs = run_tasks(within, [(s,) for s in seqs], executor, device, lambda i, r: bar.update())
        seconds["within_sequence"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        reps = [representative_tree(a) for a in aseqs]
        names = [s.name or f"plant_{i}" for i, s in enumerate(seqs)]
        ref, regs = self._medoid(reps, names, self.cross_lambdas_, progress, executor)
        movs, union, regs, targets, slot_parent, slot_depth, opened, dropped = self._union(
            aseqs, reps, names, ref, regs, self.cross_lambdas_, lam, progress)
        seconds["cross_sequence"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        layout = place_targets(aseqs[ref], targets[0], [aseqs[i] for i in movs], targets[1:], slot_parent,
                               slot_depth, [regs[i].gamma.to(torch.float64) for i in movs],
                               [regs[i].rotation.to(torch.float64) for i in movs], lam)
        order = [ref] + movs
        counts = [len(aseqs[i]) for i in order]
        coeffs = self.pca.fit_transform(layout)
        pieces = coeffs.split(counts)
        trajs = torch.empty(len(seqs), self.n_t, coeffs.shape[1], dtype=coeffs.dtype)
        for i, c in zip(order, pieces):
            trajs[i] = resample_trajectory(c, seqs[i].times.to(c.dtype), self.n_t)
        seconds["tree_space"] = time.perf_counter() - t0
        # the layout in the input order of the sequences (the reference's frames were first)
        starts = torch.tensor([0] + counts).cumsum(0).tolist()
        where = {i: list(range(starts[j], starts[j + 1])) for j, i in enumerate(order)}
        self.layout_ = layout[[r for i in range(len(seqs)) for r in where[i]]]
        self.sequences_ = aseqs
        spans = torch.tensor([[float(s.times[0]), float(s.times[-1])] for s in seqs], dtype=torch.float64)
        self.lambdas_, self.names_ = lam, names
        self.report_ = {
            "reference": names[ref], "slots": layout.num_slots, "reference_slots": reps[ref].points.shape[0],
            "max_slots": self.max_slots, "slots_opened": opened, "dropped_share": dropped,
            "frames": int(sum(counts)), "components": self.pca.n_components_,
            "variance_explained": float(self.pca.explained_variance_ratio.sum()),
            "within_sequence_distance_mean": float(torch.cat([a.distances for a in aseqs]).mean()),
            # each plant's registration the layout used: onto the union representative as it was at its turn
            "cross_distance_before": [float(r.distance_before) for r in regs],
            "cross_distance_after": [float(r.distance) for r in regs], "seconds": seconds,
            "cross_registration": {"positions": self.cross.positions, "lambdas": list(self.cross_lambdas_),
                                   "order_tol": self.cross.order_tol},
        }
        ranks = union.ranks if isinstance(union, RankedTree) else torch.zeros(0)
        self._set_fitted(ref_points=union.points, ref_parent=union.parent, ref_s=union.s, ref_ranks=ranks,
                         trajectories=trajs, time_spans=spans)
        return self

    def _medoid(self, reps: list[Trees], names: list[str], lam: tuple[float, float, float], progress: bool,
                executor: Executor | None = None) -> tuple[int, list[Any]]:
        """Index of the reference and the registrations of every representative onto it (module doc, step 2)."""
        total = [float(r.total_length()[0]) for r in reps]
        ranked = sorted(range(len(reps)), key=lambda i: (total[i], names[i]))
        m = min(self.medoid_candidates, len(reps))
        cands = sorted({ranked[round(j * (len(reps) - 1) / max(m - 1, 1))] for j in range(m)}) if m > 1 else \
            [ranked[(len(reps) - 1) // 2]]
        batch = Trees.cat(reps)
        from tqdm.auto import tqdm

        tasks = [(batch, reps[c], lam, self.rotation, self.registration, self.cross) for c in cands]
        with tqdm(total=len(cands), disable=not progress, desc="choosing the reference", unit="candidate") as bar:
            found = run_tasks(cross_registration, tasks, executor, batch.points.device, lambda i, r: bar.update())
        scored = [(sum(float(r.distance) ** 2 for r in regs), names[c], c, regs) for c, regs in zip(cands, found)]
        best = min(scored, key=lambda x: x[:2])
        return best[2], best[3]

    def _union(self, aseqs: list[AlignedSequence], reps: list[Trees], names: list[str], ref: int, regs: list[Any],
               lam: tuple[float, float, float], space: tuple[float, float, float], progress: bool) -> UnionLayout:
        """The union layout (module doc, step 3): the moving plants in union order, each plant's registration onto
        the union representative as it was at its turn, and the layout's slots, bounded by ``max_slots``.

        Order: registered distance to the reference, ties by name (input-order independent). A registration onto
        the reference stays valid while no plant has opened a slot, so only later plants are registered again.
        Bound: each slot carries the training frames' squared weighted length placed in it (:func:`slot_masses`,
        weights of the space's metric ``space``); once the union has more than ``SLOT_SLACK * max_slots`` slots it
        keeps the ``max_slots`` that carry the most (:func:`bounded_slots`), and once more at the end, so the union
        representative every plant is registered onto stays under ``SLOT_SLACK * max_slots`` slots.
        """
        movs = sorted((i for i in range(len(reps)) if i != ref), key=lambda i: (float(regs[i].distance), names[i]))
        union = reps[ref]
        # the union representative's node ranks: each branch's on the plant it came from (:func:`ranked`)
        ranks = own_ranks(union, self.cross.positions)
        slot_parent = aseqs[ref].aligned.slot_parent.tolist()
        slot_depth = aseqs[ref].aligned.slot_depth.tolist()
        targets = {ref: list(range(len(slot_parent)))}
        mass = [0.0] * len(slot_parent)
        for t, m in slot_masses(aseqs[ref], targets[ref], slot_depth, space).items():
            mass[t] += m
        opened, dropped = len(slot_parent), 0.0
        regs = list(regs)
        cap = None if self.max_slots is None else SLOT_SLACK * self.max_slots
        from tqdm.auto import tqdm

        def bound(keep_at_most: int) -> None:
            nonlocal union, slot_parent, slot_depth, mass, dropped, ranks
            kept = bounded_slots(mass, slot_parent, keep_at_most)
            new = [-1] * len(slot_parent)
            for j, u in enumerate(kept):
                new[u] = j
            dropped += sum(m for u, m in enumerate(mass) if new[u] < 0)
            parent = [new[slot_parent[u]] if slot_parent[u] >= 0 else -1 for u in kept]
            union = union_subset(union, kept, parent)
            ranks = None if ranks is None else [ranks[u] for u in kept]
            slot_parent, slot_depth, mass = parent, [slot_depth[u] for u in kept], [mass[u] for u in kept]
            for i in targets:
                targets[i] = [new[t] if t >= 0 else -1 for t in targets[i]]

        grown = False
        for i in tqdm(movs, disable=not progress, desc="union layout", unit="plant"):
            if grown:
                regs[i] = self._register_cross(reps[i], ranked(union, ranks, self.cross.positions), lam)[0]
            gamma, rot = regs[i].gamma.to(torch.float64), regs[i].rotation.to(torch.float64)
            S_u = len(slot_parent)
            targets[i] = open_slots(aseqs[i], regs[i].matches, slot_parent, slot_depth)
            union = grow_union(union, aseqs[i], targets[i], slot_parent, gamma, rot)
            if ranks is not None and len(slot_parent) > S_u:
                mine, opener = own_ranks(reps[i], self.cross.positions), {u: k for k, u in enumerate(targets[i])}
                ranks = ranks + [mine[opener[u]] for u in range(S_u, len(slot_parent))]
            grown |= len(slot_parent) > S_u
            opened += len(slot_parent) - S_u
            mass += [0.0] * (len(slot_parent) - S_u)
            for t, m in slot_masses(aseqs[i], targets[i], slot_depth, space).items():
                mass[t] += m
            if cap is not None and len(slot_parent) > cap:
                bound(self.max_slots)
        if self.max_slots is not None and len(slot_parent) > self.max_slots:
            bound(self.max_slots)
        total = sum(mass) + dropped
        return UnionLayout(movs, ranked(union, ranks, self.cross.positions), regs, [targets[i] for i in [ref] + movs],
                           slot_parent, slot_depth, opened,
                           dropped / total if total > 0 else 0.0)

    # ------------------------------------------------------------------------ transform
    def portable(self) -> Population:
        """A copy on the CPU holding only the fitted state (what a checkpoint holds, not the training layout):
        what is shipped to workers to write new plants in the space (:meth:`transform_many`)."""
        self._check_fitted()
        copy = Population(cross=self.cross, max_slots=self.max_slots)
        copy.load_state_dict(move(self.state_dict(), "cpu"))
        return copy

    def transform_many(self, sequences: Sequence[TreeSequence], executor: Executor | None = None
                       ) -> list[SequenceEncoding]:
        """:meth:`transform` of every 4D tree of ``sequences``; on ``executor`` one task a plant, :meth:`portable`
        packed once (:func:`~torch4dtree.parallel.run_tasks`' ``shared``; results on this population's device, equal
        to :meth:`transform`'s).

        Example:
            >>> from torch4dtree.data import synthetic_plant
            >>> plants = [synthetic_plant("maize", i, n_frames=3, T=8).sequence for i in range(2)]
            >>> pop = Population(n_t=4, medoid_candidates=1).fit(plants)
            >>> [e.trajectory.shape[0] for e in pop.transform_many(plants)]
            [4, 4]
        """
        seqs = list(sequences)
        if executor is None:
            return [self.transform(s) for s in seqs]
        return run_tasks(transform_sequence, [(s,) for s in seqs], executor, self.ref_points.device,
                         shared=self.portable())

    def transform(self, sequence: TreeSequence, aligned: AlignedSequence | None = None) -> SequenceEncoding:
        """Write a new 4D tree into the fitted space (module doc): within-sequence registration, registration of
        its representative onto the union representative, its frames in the layout, their coefficients and
        trajectory.

        ``aligned``: its within-sequence registration, if already computed. A single frame is allowed (its
        trajectory is then constant).
        """
        self._check_fitted()
        if not isinstance(sequence, TreeSequence):
            raise TypeError(f"expected a TreeSequence, got {type(sequence).__name__}")
        seq = sequence.to(device=self.ref_points.device, dtype=torch.float64)
        T = self.ref_points.shape[1]
        if seq.frames.T != T:  # frames read at another resolution than the fit's: the layout's slots have T points
            if aligned is not None:
                raise ValueError(f"aligned has {seq.frames.T} points per branch, the fitted layout {T}: "
                                 f"register the sequence resampled to T = {T}")
            seq = TreeSequence(seq.frames.resample(T), seq.times, seq.name)
        if aligned is None:
            aligned = register_sequence(seq, registration=self.registration)  # as in fit
        rep = representative_tree(aligned)
        ref = self.reference_tree()
        reg = self._register_cross(rep, ref, self.cross_lambdas_)[0]
        S_r = ref.points.shape[0]
        # children the registration left unmatched under a matched parent take its slot's free child slots in their
        # order between the matched siblings, by place (as register4d completes its matches)
        matched = dict(completed_matches(reg.matches, rep.parent.tolist(), ref.parent.tolist(), rep.s.tolist(),
                                         ref.s.tolist()))
        S_m = aligned.num_slots
        # unmatched slots go to scratch slots past the layout, then are cut off (and their cost reported)
        slot_of, extra = [], S_r
        for k in range(S_m):
            if k in matched:
                slot_of.append(matched[k])
            else:
                slot_of.append(extra)
                extra += 1
        q, s, present, _ = place_sequence(aligned, slot_of, extra, reg.gamma.to(torch.float64),
                                          reg.rotation.to(torch.float64))
        S = self.pca.num_slots
        n, _, M, d = q.shape
        # what the branches outside the layout cost (weights of their own depth in the new tree)
        w_mov = slot_weights(aligned.aligned.slot_depth, self.lambdas_)[0].to(q)
        cut = torch.tensor([slot_of[k] >= S_r for k in range(S_m)], device=q.device)
        idx = torch.as_tensor(slot_of, device=q.device)
        dropped = (w_mov * cut * q[:, idx].square().sum((-1, -2)) / M).sum(1)
        qf = q.new_zeros(n, S, M, d)
        sf = s.new_zeros(n, S)
        pf = present.new_zeros(n, S)
        qf[:, :S_r], sf[:, :S_r], pf[:, :S_r] = q[:, :S_r], s[:, :S_r], present[:, :S_r]
        source = torch.full((n, S), -1, dtype=torch.long, device=qf.device)
        layout = AlignedTrees(qf, sf, pf, aligned.aligned.root, self.pca.slot_parent, self.pca.slot_depth, source,
                              self.pca.lambdas)
        coeffs = self.pca.transform(layout)
        if n >= 2:
            traj = resample_trajectory(coeffs, seq.times.to(coeffs.dtype), self.n_t)
        else:
            traj = coeffs.expand(self.n_t, -1).clone()
        return SequenceEncoding(traj, coeffs, seq.times, layout, dropped)


def fit_population(sequences: Sequence[TreeSequence], lambdas: Sequence[float] = (1.0, 1.0, 1.0),
                   rotation: str = "none", n_t: int = DEFAULT_NT, variance: float = 0.99,
                   n_components: int | None = None, progress: bool = False, medoid_candidates: int = 3,
                   registration: RegistrationSettings | None = None, cross: CrossSettings | None = None,
                   executor: Executor | None = None, max_slots: int | None = DEFAULT_MAX_SLOTS) -> Population:
    """``N`` 4D trees in one tree space (module doc): ``Population(...).fit(sequences)``.

    Example:
        >>> from torch4dtree.data import synthetic_plant
        >>> plants = [synthetic_plant("maize", i, n_frames=3, T=8).sequence for i in range(2)]
        >>> fit_population(plants, n_t=4, medoid_candidates=1).trajectories.shape[:2]
        torch.Size([2, 4])
    """
    return Population(lambdas, rotation, n_t, n_components, variance, medoid_candidates, registration,
                      cross, max_slots).fit(sequences, progress, executor)
