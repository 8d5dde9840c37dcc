"""Spatiotemporal registration of two 4D trees (docs/method.md §5, paper §4.2) and their 4D geodesic.

The pipeline, for 4D trees ``A`` (reference) and ``B`` (moving):

1. **Within-sequence registration** (:func:`register_sequence`): each 4D tree's frames in one slot layout, a slot
   being one branch identity over the whole sequence.
2. **Cross-sequence spatial registration**: ``B``'s representative tree (every slot's branch from the latest
   frame holding it, in the sequence's own parameterisation) is registered onto ``A``'s (with the cross-sequence
   settings, :class:`~torch4dtree.settings.CrossSettings`). The correspondence,
   warps and rotation found are applied to *every* frame of ``B``, so identities stay consistent over time; both
   4D trees are written into one union layout (``A``'s slots, then ``B``'s unmatched ones). The correspondence
   and warps are chosen on one tree while the 4D distance runs over all times, so three candidates are scored
   by the 4D distance and the smallest is kept (``spatial_candidate``): the registration as found
   (``"registered"``), its correspondence with identity warps (``"correspondence"``: a warp fitted to a
   branch's latest shape can misfit its younger frames), and the index-order correspondence (``"index_order"``:
   ``B``'s slots matched to ``A``'s by order of ``s``, identity warps; the distance *before* registration is
   this one's, so the spatial stage never ends above it). Where neither registered
   candidate beats index order, the representatives are registered again with a wider rotation search
   (``CrossSettings.fallback_rotation``, default ``"vertical"``) and its two candidates
   (``"registered_vertical"``, ``"correspondence_vertical"``) join.
   Each registration's correspondence is also *completed* by the index order where the two agree
   (:func:`completed_matches`: pairs of slots both left unmatched under matched parents, in order and by place;
   ``"completed"``, identity warps): a registration with a large ``lp`` leaves organs at different nodes and spurs
   unmatched, which the 4D distance (the space's ``lp``) pays for in full, so without it the index order could beat
   the registration's organs on distance alone. Last, the registration's correspondences (found and completed) are
   tried again with the warps that minimise the 4D distance itself (:func:`fourd_warps`, one elastic matching per
   slot over all times at once; ``"correspondence_4d"``, ``"completed_4d"``...), and, where still no registered
   candidate beats index order, the index order too (``"index_order_4d"``): where the index order is already the
   best correspondence (sequences chained by node rank), the spatial stage still lowers the distance through the
   branches' parameterisations.
3. **Tree space**: PCA of all frames' weighted SRVFT features (all components by default, so coefficient
   distances are exactly tree distances); each 4D tree becomes a trajectory in ``R^k``, resampled at ``n_t``
   equally spaced normalised times between its actual frame times.
4. **Temporal registration** (:func:`register_trajectories`): the time warp of ``B``'s trajectory onto ``A``'s, with
   a penalty on warping (``time_weight``: two plants are not time warps of each other), and the 4D distance at it.
   ``B``'s trajectory is passed :func:`~.trajectory.fine_size` samples, so the warp moves ``B``'s frames (the corners
   of its trajectory), not only its ``n_t`` samples.

The three distances reported are the same 4D distance, ``sqrt(||alpha_A(0) - alpha_B(0)||^2 + ||q_A - q_B||^2)``
with ``q`` the SRVF of the trajectory: before any registration (``B``'s slots matched to ``A``'s in index order,
identity warps and rotation), after the spatial registration, and after the temporal one.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from concurrent.futures import Executor
from functools import partial
from typing import NamedTuple

import torch
from torch import Tensor

from ..curves.register import dp_warp
from ..curves.srvf import interpolate_curve, inverse_srvf, srvf, warp_srvf
from ..curves.warps import compose_warps
from ..parallel import run_tasks
from ..settings import (
    DEFAULT_NT,
    ROTATIONS,
    TIME_WEIGHT,
    CrossSettings,
    RegistrationSettings,
    TemporalSettings,
    check_at_least,
    check_choice,
    check_lambdas,
)
from ..space.pca import TreePCA
from ..trees.aligned import AlignedTrees, slot_weights
from ..trees.registration import effective_lambdas, index_order_matches
from ..trees.structures import Trees, TreeSequence
from .registration import TemporalRegistration, geodesic4d, trajectory_distance
from .trajectory import fine_size, resample_trajectory, trajectory_srvf
from .within import AlignedSequence, inverse_at, register_sequence

__all__ = ["SpatiotemporalRegistration", "bounded_slots", "combine_many", "combine_sequences", "completed_matches",
           "fourd_warps", "gap_pairs", "grow_union", "layout_trajectories", "open_slots", "place_sequence",
           "place_targets", "register4d", "representative_tree", "slot_masses", "union_subset"]



def representative_tree(seq: AlignedSequence) -> Trees:
    """``seq``'s representative tree (:meth:`AlignedSequence.representative`)."""
    return seq.representative()


def place_sequence(mov: AlignedSequence, slot_of: Sequence[int], num_slots: int, gamma: Tensor,
                   rotation: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """All frames of ``mov`` written into a layout of ``num_slots`` slots, ``mov`` slot ``k`` going to ``slot_of[k]``.

    Args:
        slot_of: ``S_mov`` target slots (distinct where ``>= 0``; a parent's target is the parent of its child's
            target); a negative target leaves that slot out (a slot the layout dropped, :func:`bounded_slots`).
        gamma: ``(S_mov, T)`` warp of each ``mov`` slot (applied to every frame's branch in that slot).
        rotation: ``(d, d)`` applied to ``mov``'s SRVFs (row vectors, ``x @ R.T``).

    Returns:
        ``q (n, num_slots, M, d)``, ``s (n, num_slots)`` (0 in slots ``mov`` does not reach), ``present`` and
        ``source`` (``mov``'s own slot, ``-1`` elsewhere) ``(n, num_slots)``.
    """
    ma = mov.aligned
    n_m, S_m, M, d = ma.q.shape
    dev, dt = ma.q.device, ma.q.dtype
    mov_parent = ma.slot_parent.tolist()
    q = torch.zeros(n_m, num_slots, M, d, dtype=dt, device=dev)
    s = torch.zeros(n_m, num_slots, dtype=dt, device=dev)
    present = torch.zeros(n_m, num_slots, dtype=torch.bool, device=dev)
    source = torch.full((n_m, num_slots), -1, dtype=torch.long, device=dev)
    g = gamma.to(device=dev, dtype=dt)
    R = rotation.to(device=dev, dtype=dt)
    kept = [k for k, t in enumerate(slot_of) if t >= 0]
    idx = torch.as_tensor([slot_of[k] for k in kept], dtype=torch.long, device=dev)
    src = torch.as_tensor(kept, dtype=torch.long, device=dev)
    qm = warp_srvf(ma.q[:, src].reshape(n_m * len(kept), M, d), g[src].repeat(n_m, 1)).reshape(
        n_m, len(kept), M, d) @ R.T
    q[:, idx] = qm * ma.present[:, src, None, None]
    # a child's parameter moves with its parent's warp
    sm = ma.s.clone()
    if S_m > 1:  # every frame's child slots at once: (n_m * (S_m - 1),) parameters through their parents' warps
        parents = torch.as_tensor(mov_parent[1:], dtype=torch.long, device=dev)
        warps = g[parents].repeat(n_m, 1)
        sm[:, 1:] = inverse_at(warps, ma.s[:, 1:].reshape(-1)).reshape(n_m, S_m - 1)
    s[:, idx] = sm[:, src]
    present[:, idx] = ma.present[:, src]
    source[:, idx] = src
    return q, s, present, source


def slot_masses(mov: AlignedSequence, targets: Sequence[int], slot_depth: Sequence[int],
                lambdas: tuple[float, float, float]) -> dict[int, float]:
    """What each of ``mov``'s slots carries of the training norm: ``{target slot: sum over frames of
    w_q(depth) ||q||^2}`` (the squared weighted length, the ``q`` part of the features' squared norm; the warps and
    the rotation keep it), with ``w_q`` of the target slot's depth in the layout. Negative targets are left out.
    What :func:`bounded_slots` ranks the slots by."""
    q = mov.aligned.q
    per = (q.square().sum((-1, -2)) * mov.aligned.present).sum(0) / q.shape[2]  # (S_mov,)
    depth = torch.as_tensor([slot_depth[t] for t in targets if t >= 0], dtype=torch.long)
    w_q = slot_weights(depth, lambdas)[0].tolist()
    mine = [(k, t) for k, t in enumerate(targets) if t >= 0]
    return {t: w * float(per[k]) for (k, t), w in zip(mine, w_q)}


def bounded_slots(mass: Sequence[float], slot_parent: Sequence[int], max_slots: int) -> list[int]:
    """The ``max_slots`` slots (ascending) carrying the most of ``mass``, closed under parents: a slot ranks by the
    largest mass in its subtree (itself or a descendant), ties by index, so a parent always ranks before its
    children and a kept slot's parent is kept. Slots are in parents-first order (``slot_parent[u] < u``).

    Example:
        >>> bounded_slots([5.0, 1.0, 0.5, 3.0], [-1, 0, 1, 0], 3)
        [0, 1, 3]
        >>> bounded_slots([5.0, 0.1, 4.0], [-1, 0, 1], 2)
        [0, 1]
    """
    prio = [float(m) for m in mass]
    for u in range(len(prio) - 1, 0, -1):
        p = slot_parent[u]
        if p >= 0:
            prio[p] = max(prio[p], prio[u])
    order = sorted(range(len(prio)), key=lambda u: (-prio[u], u))
    return sorted(order[:max_slots])


def open_slots(mov: AlignedSequence, match: Sequence[tuple[int, int]], slot_parent: list[int],
               slot_depth: list[int]) -> list[int]:
    """The union-layout slot of each of ``mov``'s slots; each unmatched one opens a new slot (appended, in ``mov``'s
    slot order, child of its parent's slot), ``slot_parent`` / ``slot_depth`` growing in place.

    ``match``: ``[(mov slot, union slot), ...]``, to any slot already in ``slot_parent`` (also one opened by an
    earlier moving sequence). The one rule :func:`combine_many` and :func:`grow_union` share, so slot indices agree.
    """
    slot_of = dict(match)
    mov_parent = mov.aligned.slot_parent.tolist()
    for k in range(len(mov_parent)):  # parents first, so a parent's slot exists
        if k not in slot_of:
            slot_of[k] = len(slot_parent)
            parent = slot_of[mov_parent[k]] if mov_parent[k] >= 0 else -1
            slot_parent.append(parent)
            slot_depth.append(slot_depth[parent] + 1)
    return [slot_of[k] for k in range(len(mov_parent))]


def grow_union(union: Trees, mov: AlignedSequence, targets: Sequence[int], slot_parent: Sequence[int],
               gamma: Tensor, rotation: Tensor) -> Trees:
    """``union`` (a one-tree representative, ``label`` = slot) with a branch for every slot ``mov`` opened.

    Args:
        targets: union slot of each ``mov`` slot (:func:`open_slots`); slots past ``union``'s are new.
        slot_parent: the union layout's parents, new slots included.
        gamma, rotation: ``mov``'s registration onto ``union`` (as in :func:`place_sequence`).

    A new slot's branch is ``mov``'s, as its representative has it (latest frame holding it), warped and rotated
    into the union's coordinates by :func:`place_sequence`, hung on its parent's union branch at the warped ``s``.
    """
    S_u, S = union.points.shape[0], len(slot_parent)
    if S == S_u:
        return union
    q, s, present, _ = place_sequence(mov, targets, S, gamma, rotation)
    n = q.shape[0]
    frame = torch.arange(n, device=q.device)[:, None].expand(n, S)
    latest = torch.where(present, frame, -1).amax(0)
    curves = list(union.points.to(q.dtype).unbind(0))
    s_new = []
    for u in range(S_u, S):
        j = int(latest[u])
        start = interpolate_curve(curves[slot_parent[u]][None], s[j, u].reshape(1, 1))[0, 0]
        curves.append(inverse_srvf(q[j, u], start))
        s_new.append(s[j, u].clamp(0, 1))
    dev = union.points.device
    return Trees(torch.stack(curves), torch.as_tensor(list(slot_parent), dtype=torch.long, device=dev),
                 torch.cat([union.s.to(q.dtype), torch.stack(s_new)]), torch.tensor([S], device=dev),
                 torch.arange(S, device=dev))


def union_subset(union: Trees, kept: Sequence[int], parent: Sequence[int]) -> Trees:
    """The one-tree union representative ``union`` (``label`` = slot) with only the slots ``kept`` (ascending,
    closed under parents), renumbered ``0..len(kept) - 1``; ``parent``: the kept slots' parents, renumbered."""
    dev = union.points.device
    idx = torch.as_tensor(list(kept), dtype=torch.long, device=dev)
    S = len(kept)
    return Trees(union.points[idx], torch.as_tensor(list(parent), dtype=torch.long, device=dev), union.s[idx],
                 torch.tensor([S], device=dev), torch.arange(S, device=dev))


def combine_many(ref: AlignedSequence, movs: Sequence[AlignedSequence], matches: Sequence[Sequence[tuple[int, int]]],
                 gammas: Sequence[Tensor], rotations: Sequence[Tensor],
                 lambdas: tuple[float, float, float]) -> AlignedTrees:
    """All frames of ``ref`` then of every ``movs[i]`` in one union layout, given a correspondence of each onto ``ref``.

    Args:
        matches: per moving sequence, ``[(mov slot, union slot), ...]`` (a partial matching that maps parents to
            parents): a union slot is one of ``ref``'s or one opened by an earlier moving sequence (slots open in
            the order of :func:`open_slots`, as :func:`grow_union` builds a union representative).
        gammas: per moving sequence, ``(S_mov, T)`` warp of each of its slots.
        rotations: per moving sequence, ``(d, d)`` applied to its SRVFs (row vectors, ``x @ R.T``).
        lambdas: metric weights of the returned layout.

    Returns:
        :class:`AlignedTrees` of ``len(ref) + sum(len(m))`` trees: ``ref``'s slots first (same order), then, for each
        moving sequence in turn, a slot for every one of its unmatched slots (child of its parent's slot).
        ``source`` is the sequence's own slot.
    """
    if not (len(movs) == len(matches) == len(gammas) == len(rotations)):
        raise ValueError(f"one matching, warp and rotation per moving sequence: got {len(movs)} sequences, "
                         f"{len(matches)} matchings, {len(gammas)} warps, {len(rotations)} rotations")
    ra = ref.aligned
    slot_parent, slot_depth = ra.slot_parent.tolist(), ra.slot_depth.tolist()
    targets = [open_slots(mov, match, slot_parent, slot_depth) for mov, match in zip(movs, matches)]
    return place_targets(ref, list(range(ra.q.shape[1])), movs, targets, slot_parent, slot_depth, gammas, rotations,
                         lambdas)


def place_targets(ref: AlignedSequence, ref_targets: Sequence[int], movs: Sequence[AlignedSequence],
                  targets: Sequence[Sequence[int]], slot_parent: Sequence[int], slot_depth: Sequence[int],
                  gammas: Sequence[Tensor], rotations: Sequence[Tensor],
                  lambdas: tuple[float, float, float]) -> AlignedTrees:
    """All frames of ``ref`` then of every ``movs[i]`` in the layout ``slot_parent`` / ``slot_depth``, each sequence's
    slot ``k`` going to its ``targets[k]`` (negative: left out, :func:`place_sequence`); ``ref`` unwarped and
    unrotated (its own ``q`` and ``s`` exactly), the others with their ``gammas`` and ``rotations``.

    Returns:
        :class:`AlignedTrees` of ``len(ref) + sum(len(m))`` trees (``source``: the sequence's own slot). Memory:
        the layout once, ``frames x slots x M x d`` values (filled sequence by sequence).
    """
    ra = ref.aligned
    S = len(slot_parent)
    n_r = ra.q.shape[0]
    dev = ra.q.device
    ident = torch.eye(ra.q.shape[3], dtype=ra.q.dtype, device=dev)
    grid = torch.linspace(0, 1, ra.T, dtype=ra.q.dtype, device=dev).expand(ra.q.shape[1], -1)
    seqs = [(ref, ref_targets, grid, ident)] + list(zip(movs, targets, gammas, rotations))
    counts = [len(m) for m, *_ in seqs]
    n = sum(counts)
    _, _, M, d = ra.q.shape
    q = ra.q.new_zeros(n, S, M, d)
    s = ra.s.new_zeros(n, S)
    present = torch.zeros(n, S, dtype=torch.bool, device=dev)
    source = torch.full((n, S), -1, dtype=torch.long, device=dev)
    at = 0
    for (m, t, g, R), c in zip(seqs, counts):
        q[at:at + c], s[at:at + c], present[at:at + c], source[at:at + c] = place_sequence(m, t, S, g, R)
        at += c
    kept = [k for k, t in enumerate(ref_targets) if t >= 0]
    idx = torch.as_tensor([ref_targets[k] for k in kept], dtype=torch.long, device=dev)
    src = torch.as_tensor(kept, dtype=torch.long, device=dev)
    s[:n_r, idx] = ra.s[:, src]  # the reference's own parameters, exactly (no warp round trip)
    q[:n_r, idx] = ra.q[:, src]
    root = torch.cat([ra.root] + [m.aligned.root for m in movs])
    return AlignedTrees(q, s, present, root, torch.tensor(list(slot_parent), device=dev),
                        torch.tensor(list(slot_depth), device=dev), source, lambdas)


def combine_sequences(ref: AlignedSequence, mov: AlignedSequence, matches: Sequence[tuple[int, int]],
                      gamma: Tensor, rotation: Tensor, lambdas: tuple[float, float, float]) -> AlignedTrees:
    """All frames of ``ref`` then ``mov`` in one union layout (:func:`combine_many` with one moving sequence).

    Args:
        matches: ``[(mov slot, ref slot), ...]`` (a partial matching that maps parents to parents).
        gamma: ``(S_mov, T)`` warp of each ``mov`` slot (applied to every frame's branch in that slot).
        rotation: ``(d, d)`` applied to ``mov``'s SRVFs (row vectors, ``x @ R.T``).
        lambdas: metric weights of the returned layout.

    Returns:
        :class:`AlignedTrees` of ``len(ref) + len(mov)`` trees: ``ref``'s slots first (same order), then a slot
        for every unmatched ``mov`` slot (child of its parent's slot). ``source`` is the sequence's own slot.
    """
    return combine_many(ref, [mov], [matches], [gamma], [rotation], lambdas)


class SpatiotemporalRegistration(NamedTuple):
    """Result of :func:`register4d` (``k`` PCA components, ``n_t`` common times).

    * ``distance_before`` / ``distance_after_spatial`` / ``distance_after_temporal``: floats, the 4D distance
      (module doc) before registration, after the spatial and after the temporal registration.
    * ``warp (n_t,)``: the time warp ``xi`` of ``B`` (``B`` at ``xi(t)`` matches ``A`` at ``t``), on
      ``times (n_t,) = linspace(0, 1, n_t)``.
    * ``alpha_ref``, ``alpha_mov``, ``alpha_mov_registered``: ``(n_t, k)`` trajectories in the tree space.
    * ``alpha_mov_fine``: ``B``'s trajectory as the temporal registration saw it, ``(fine_size(n_t, B's times), k)``
      (``alpha_mov`` is every ``F``-th sample of it); ``None``: ``alpha_mov``.
    * ``pca``: the fitted :class:`TreePCA` (decodes coefficients to trees in the common layout).
    * ``layout``: every frame of both 4D trees in the common layout (:class:`AlignedTrees`, ``A``'s frames first).
    * ``sequences``: the two within-sequence registrations; ``matches``: ``[(B slot, A slot)]``.
    * ``temporal``: the :class:`TemporalRegistration`; ``time_span_ref``: ``(t_first, t_last)`` of ``A``.
    * ``seconds``: wall time per stage.
    * ``kept_index_order``: the index-order correspondence was kept (``spatial_candidate == "index_order"``).
    * ``spatial_candidate``: which candidate of the spatial stage was kept (module doc): ``"registered"``,
      ``"correspondence"``, ``"index_order"`` or, from the fallback search, ``"registered_vertical"`` /
      ``"correspondence_vertical"``; with the 4D-distance warps, the same name and ``"_4d"``.
    * ``cross_registration``: the cross-sequence registration's settings, ``{"positions", "lambdas", "order_tol"}``
      (the effective weights it used).
    """

    distance_before: float
    distance_after_spatial: float
    distance_after_temporal: float
    warp: Tensor
    times: Tensor
    alpha_ref: Tensor
    alpha_mov: Tensor
    alpha_mov_registered: Tensor
    pca: TreePCA
    layout: AlignedTrees
    sequences: tuple[AlignedSequence, AlignedSequence]
    matches: list[tuple[int, int]]
    temporal: TemporalRegistration
    time_span_ref: tuple[float, float]
    seconds: dict[str, float]
    kept_index_order: bool = False
    spatial_candidate: str = "registered"
    alpha_mov_fine: Tensor | None = None
    cross_registration: dict | None = None

    def geodesic(self, steps: int = 5) -> list[TreeSequence]:
        """The 4D geodesic from ``A`` to ``B`` (after spatiotemporal registration) as ``steps`` 4D trees.

        Each is decoded at the ``n_t`` common times (in ``A``'s time units); branches keep their slot as ``label``.
        """
        path = geodesic4d(*trajectory_srvf(self.alpha_ref), *trajectory_srvf(self.alpha_mov_registered), steps)
        return self._decode(path)

    def _decode(self, alphas: Tensor) -> list[TreeSequence]:
        """``alphas (m, n_t, k)`` -> ``m`` 4D trees, decoded in one batch of ``m * n_t`` trees."""
        t0, t1 = self.time_span_ref
        times = (t0 + self.times.to(torch.float64) * (t1 - t0)).to(self.pca.mean.dtype)
        m, n_t = alphas.shape[:2]
        trees = self.pca.decode(alphas)
        return [TreeSequence(trees[i * n_t:(i + 1) * n_t], times) for i in range(m)]

    def decoded(self) -> tuple[TreeSequence, TreeSequence, TreeSequence]:
        """``A``, ``B`` and ``B`` time-warped onto ``A``, decoded from their trajectories on the common times."""
        a, b, b_reg = self._decode(torch.stack([self.alpha_ref, self.alpha_mov, self.alpha_mov_registered]))
        return a, b, b_reg


class _Candidate(NamedTuple):
    """A candidate of register4d's spatial stage: ``B``'s slots matched to ``A``'s (``matches``), warped
    (``gamma (S_B, T)``) and rotated, the union ``layout`` they give and its 4D ``distance``."""

    name: str
    matches: list[tuple[int, int]]
    layout: AlignedTrees
    distance: float
    gamma: Tensor
    rotation: Tensor


def _split_trajectories(coeffs: Tensor, n_ref: int, ref_times: Tensor, mov_times: Tensor, n_t: int,
                        mov_samples: int | None = None) -> tuple[Tensor, Tensor]:
    """Frame coefficients (``A``'s frames first) -> ``alpha_ref (n_t, k)``, ``alpha_mov (mov_samples, k)``."""
    alpha_ref = resample_trajectory(coeffs[:n_ref], ref_times.to(coeffs.dtype), n_t)
    alpha_mov = resample_trajectory(coeffs[n_ref:], mov_times.to(coeffs.dtype), mov_samples or n_t)
    return alpha_ref, alpha_mov


def layout_trajectories(layout: AlignedTrees, n_ref: int, ref_times: Tensor, mov_times: Tensor, n_t: int,
                  n_components: int | None, mov_samples: int | None = None) -> tuple[TreePCA, Tensor, Tensor]:
    """PCA of ``layout`` and the trajectories ``alpha_ref (n_t, k)``, ``alpha_mov (mov_samples, k)`` (default
    ``n_t``; :func:`~.trajectory.fine_size` for the temporal registration)."""
    n = layout.num_trees
    k = n - 1 if n_components is None else n_components
    pca = TreePCA(n_components=min(k, n - 1)).fit(layout)
    return pca, *_split_trajectories(pca.transform(layout), n_ref, ref_times, mov_times, n_t, mov_samples)


def _candidate_distance(layout: AlignedTrees, n_ref: int, ref_times: Tensor, mov_times: Tensor, n_t: int,
                        n_components: int | None, mov_samples: int) -> float:
    """The 4D distance (identity time warp) of a spatial candidate's layout, as :func:`layout_trajectories` gives
    it.

    With all components (the default) the coefficients are the centred features in an orthonormal basis of their
    span, and the 4D distance only sees Euclidean geometry, so any such basis gives it: a QR factorisation
    ``Xc^T = Q R`` gives the coefficients ``R^T`` to full precision, cheaper than the PCA's SVD (one tree PCA is
    fitted, for the candidate kept, instead of three).
    """
    if n_components is not None:
        _, a, b = layout_trajectories(layout, n_ref, ref_times, mov_times, n_t, n_components, mov_samples)
    else:
        X = layout.features().detach()
        coeffs = torch.linalg.qr((X - X.mean(0)).T)[1].T
        a, b = _split_trajectories(coeffs, n_ref, ref_times, mov_times, n_t, mov_samples)
    return float(trajectory_distance(a, b))


def fourd_warps(layout: AlignedTrees, n_ref: int, ref_times: Tensor, mov_times: Tensor, n_t: int,
                matches: Sequence[tuple[int, int]], gamma: Tensor) -> Tensor:
    """The warp of each matched ``B`` slot that best aligns it with its ``A`` slot *over the whole 4D distance*.

    A slot's warp acts on all of ``B``'s frames as a linear isometry ``W`` of the slot's features (``q -> (q o g)
    sqrt(g')``), so ``W`` commutes with the trajectory's time derivative and keeps its norm: ``B``'s trajectory SRVF
    becomes ``W q_B`` and its start point ``W alpha_B(0)``. The 4D distance at the identity time warp,
    ``|alpha_A(0) - W alpha_B(0)|^2 + ||q_A - W q_B||^2``, then splits into one elastic matching per slot of the
    functions ``[alpha(0), q(t_1), ..., q(t_{n_t - 1})]`` stacked as channels (``R^{M x n_t d}``), which the DP
    engine solves exactly on its lattice (:func:`~torch4dtree.curves.register.dp_warp`, never worse than the
    identity). Children's parameters (the ``s`` features) move with their parents' warps and are left out of the
    objective; the candidate is scored on the full distance.

    Args:
        layout: both sequences in the union layout with ``gamma`` applied (``A``'s ``n_ref`` frames first).
        matches: ``[(B slot, A slot)]``; ``gamma``: ``(S_B, T)`` the warps ``layout`` was built with.

    Returns:
        ``(S_B, T)``: ``gamma`` composed with the new warp on every matched slot.
    """
    m = list(matches)
    if not m:
        return gamma
    X = layout.features().detach()
    _, S, M, d = layout.q.shape
    parts = []
    for x, t in ((X[:n_ref], ref_times), (X[n_ref:], mov_times)):
        alpha = resample_trajectory(x, t.to(x.dtype), n_t)
        q = srvf(alpha) / (n_t - 1) ** 0.5  # (n_t - 1, F): the 4D distance's weight per time step
        parts.append(torch.cat([alpha[:1], q])[:, : S * M * d].reshape(n_t, S, M, d))
    a_slots = torch.tensor([a for _, a in m], device=X.device)
    # (P, M, n_t d): each slot's stacked channels (the slot's constant feature weight scales both sides alike)
    f_a, f_b = (p[:, a_slots].permute(1, 2, 0, 3).reshape(len(m), M, n_t * d) for p in parts)
    g = dp_warp(f_a, f_b).gamma.to(gamma.dtype)
    out = gamma.clone()
    b_slots = torch.tensor([b for b, _ in m], device=gamma.device)
    # layout's slot = beta_B o gamma; the new warp acts after it: beta_B o gamma o g
    out[b_slots] = compose_warps(gamma[b_slots], g)
    return out


def gap_pairs(free_mov: Sequence[int], free_ref: Sequence[int], s_mov: Sequence[float], s_ref: Sequence[float]
              ) -> list[tuple[int, int]]:
    """The children of one gap (:func:`completed_matches`) paired in their order along the parents:
    ``min(len(free_mov), len(free_ref))`` pairs, the longer side's extras chosen to minimise the summed squared
    difference of the pairs' places ``s`` (ties: extras at the top, as the index order leaves them).

    Why: the lowest of one side's children is not the lowest's partner where the other side has a child below them
    (a spur, an organ the registration left out): pairing from the bottom would shift every pair above by one.

    Args:
        free_mov, free_ref: the gap's children of each tree, in their order along the parents.
        s_mov, s_ref: every branch's place on its parent.

    Returns:
        ``[(moving branch, reference branch), ...]`` in order.

    Example (B's two children sit by A's upper two; the index order would pair B's lowest with A's lowest):
        >>> gap_pairs([5, 6], [1, 2, 3], [0.0] * 5 + [0.55, 0.75], [0.0, 0.33, 0.55, 0.73])
        [(5, 2), (6, 3)]
    """
    swap = len(free_mov) > len(free_ref)
    short, long_ = (free_ref, free_mov) if swap else (free_mov, free_ref)
    s_short, s_long = (s_ref, s_mov) if swap else (s_mov, s_ref)
    n, m = len(short), len(long_)

    def cost(i: int, j: int) -> float:
        return (float(s_short[short[i]]) - float(s_long[long_[j]])) ** 2

    # best[i][j]: the first i of the short side paired within the first j of the long side
    best = [[0.0] * (m + 1)] + [[math.inf] * (m + 1) for _ in range(n)]
    for i in range(1, n + 1):
        for j in range(i, m + 1):
            best[i][j] = min(best[i][j - 1], best[i - 1][j - 1] + cost(i - 1, j - 1))
    pairs = []
    i, j = n, m
    while i > 0:
        if j > i and best[i][j - 1] <= best[i - 1][j - 1] + cost(i - 1, j - 1):
            j -= 1  # the long side's child j - 1 left out
        else:
            pairs.append((short[i - 1], long_[j - 1]) if not swap else (long_[j - 1], short[i - 1]))
            i, j = i - 1, j - 1
    return pairs[::-1]


def completed_matches(matches: Sequence[tuple[int, int]], parent_mov: Sequence[int], parent_ref: Sequence[int],
                      s_mov: Sequence[float], s_ref: Sequence[float]) -> list[tuple[int, int]]:
    """``matches`` completed in index order between its pairs: under every matched pair of parents, the children
    both trees leave unmatched between two consecutive matched siblings (below the first, above the last) are paired
    in their order along the parents (:func:`gap_pairs`: where one side has more, those whose places fit worst are
    left out), parents first, so that added pairs keep their order with the matched siblings.

    Args:
        matches: ``[(moving branch, reference branch), ...]``, a partial matching mapping parents to parents.
        parent_mov, parent_ref: every branch's parent (``-1``: the main branch) in the moving / reference tree.
        s_mov, s_ref: every branch's place on its parent.

    Returns:
        ``matches`` and the added pairs, sorted by moving branch. Why: a registration with a large ``lp`` leaves
        organs at different nodes (and spurs) unmatched, which the 4D distance (the space's ``lp``) would rather pair;
        completed, the registration's own pairs can still beat the index order there (module doc).

    Example (stems with three children; the middle ones matched, then B's lowest to A's highest: nothing pairs
    across it):
        >>> s = [0.0, 0.2, 0.5, 0.8]
        >>> completed_matches([(0, 0), (2, 2)], [-1, 0, 0, 0], [-1, 0, 0, 0], s, s)
        [(0, 0), (1, 1), (2, 2), (3, 3)]
        >>> completed_matches([(0, 0), (1, 3)], [-1, 0, 0, 0], [-1, 0, 0, 0], s, s)
        [(0, 0), (1, 3)]
    """
    out = dict(matches)
    kids_mov: dict[int, list[int]] = {}
    kids_ref: dict[int, list[int]] = {}
    for kids, parent, s in ((kids_mov, parent_mov, s_mov), (kids_ref, parent_ref, s_ref)):
        for c, p in enumerate(parent):
            if p >= 0:
                kids.setdefault(p, []).append(c)
        for v in kids.values():
            v.sort(key=lambda c: s[c])
    pending = sorted(out.items())
    while pending:
        pb, pa = pending.pop(0)
        km, kr = kids_mov.get(pb, []), kids_ref.get(pa, [])
        taken = set(out.values())
        # the matched siblings in B's order cut both child lists into gaps; each gap paired in order
        cuts = [(km.index(b), kr.index(a)) for b, a in sorted(out.items(), key=lambda x: s_mov[x[0]])
                if parent_mov[b] == pb and b in km and a in kr]
        lo_m = lo_r = 0
        for hi_m, hi_r in [*cuts, (len(km), len(kr))]:
            free_m = [b for b in km[lo_m:hi_m] if b not in out]
            free_r = [a for a in kr[lo_r:hi_r] if a not in taken]
            for b, a in gap_pairs(free_m, free_r, s_mov, s_ref):
                out[b] = a
                taken.add(a)
                pending.append((b, a))
            lo_m, lo_r = hi_m + 1, max(lo_r, hi_r + 1)
    return sorted(out.items())


def register4d(reference: TreeSequence | AlignedSequence, moving: TreeSequence | AlignedSequence,
               lambdas: Sequence[float] = (1.0, 1.0, 1.0), rotation: str = "none", n_t: int = DEFAULT_NT,
               n_components: int | None = None, progress: bool = False, time_weight: float = TIME_WEIGHT,
               registration: RegistrationSettings | None = None, cross: CrossSettings | None = None,
               temporal: TemporalSettings | None = None, executor: Executor | None = None
               ) -> SpatiotemporalRegistration:
    """Register the 4D tree ``moving`` (``B``) onto ``reference`` (``A``) in space and time (module doc).

    Args:
        reference, moving: 4D trees (frames in time order, irregular times and missing days allowed), or their
            within-sequence registrations (:func:`register_sequence`) to reuse.
        lambdas: ``(lm, ls, lp)`` of the cross-sequence registration and of the 4D distance; ``lp`` is relative to
            ``A``'s main-branch length (as in :func:`torch4dtree.trees.register_to_reference`). A
            :class:`TreeSequence` is registered within itself with :func:`register_sequence`'s own weights.
        rotation: global rotation of ``B`` onto ``A`` (:data:`~torch4dtree.settings.ROTATIONS`).
        n_t: common time samples of the trajectories (finer than the frame count).
        n_components: PCA components; default all (``frames - 1``), so nothing of the shapes is lost.
        progress: progress bars for the within-sequence registrations.
        time_weight: the temporal registration's penalty on warping (:func:`register_trajectories`; two plants are
            not time warps of each other); ``0``: the warp minimising the 4D distance.
        registration: how every tree registration searches (within- and cross-sequence); default
            :class:`~torch4dtree.settings.RegistrationSettings`'s.
        cross: the cross-sequence registration's children's positions, relative ``lp``, order tolerance and
            fallback rotation (:class:`~torch4dtree.settings.CrossSettings`); the within-sequence registrations
            keep :func:`register_sequence`'s own, the 4D distance keeps ``lambdas``.
        temporal: the time-warp DP (:class:`~torch4dtree.settings.TemporalSettings`).
        executor: runs the within-sequence registrations of the two 4D trees there, one task each
            (:mod:`torch4dtree.parallel`; no progress bars then); the result does not depend on it.

    Returns:
        :class:`SpatiotemporalRegistration`.

    Example:
        >>> from torch4dtree.data import synthetic_plant
        >>> a = synthetic_plant("maize", 0, n_frames=3, T=8).sequence
        >>> b = synthetic_plant("maize", 1, n_frames=3, T=8).sequence
        >>> r = register4d(a, b, n_t=4)
        >>> bool(r.distance_after_temporal <= r.distance_before)
        True
    """
    check_lambdas(lambdas)
    check_choice("rotation", rotation, ROTATIONS)
    n_t = check_at_least("n_t", n_t, 2)
    search = registration or RegistrationSettings()
    cross = cross or CrossSettings()
    temporal = temporal or TemporalSettings()
    seconds: dict[str, float] = {}
    t0 = time.perf_counter()
    # one metric for the whole 4D space: lp relative to the reference's last frame (or its representative)
    ref_tree = representative_tree(reference) if isinstance(reference, AlignedSequence) else None
    if isinstance(reference, TreeSequence):
        ref_tree = reference.frames[len(reference) - 1]
    if ref_tree is None:
        raise TypeError(f"expected a TreeSequence or an AlignedSequence, got {type(reference).__name__}")
    lam = effective_lambdas(lambdas, ref_tree)
    lam_reg = lam if cross.lp is None else effective_lambdas((*lambdas[:2], cross.lp), ref_tree)
    seqs: list[AlignedSequence | TreeSequence] = []
    for x in (reference, moving):
        if isinstance(x, TreeSequence) and len(x) < 2:
            raise ValueError(f"{x.name or 'a 4D tree'} has {len(x)} frame(s); a 4D tree needs at least 2")
        if not isinstance(x, (AlignedSequence, TreeSequence)):
            raise TypeError(f"expected a TreeSequence or an AlignedSequence, got {type(x).__name__}")
        seqs.append(x)
    # identities over time with register_sequence's own weights (as Population does); lam from here on
    todo = [i for i, x in enumerate(seqs) if isinstance(x, TreeSequence)]
    if executor is None:
        for i in todo:
            seqs[i] = register_sequence(seqs[i].to(torch.float64), progress=progress, registration=search)
    else:
        within = partial(register_sequence, progress=False, registration=search)
        done = run_tasks(within, [(seqs[i].to(torch.float64),) for i in todo], executor,
                         seqs[todo[0]].frames.points.device if todo else None)
        for i, a in zip(todo, done):
            seqs[i] = a
    A, B = seqs
    seconds["within_sequence"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    rep_a, rep_b = representative_tree(A), representative_tree(B)
    ident = torch.linspace(0, 1, rep_b.T, dtype=torch.float64).expand(rep_b.points.shape[0], -1)
    eye = torch.eye(rep_b.dim, dtype=torch.float64)
    n_ref = len(A)
    # B's trajectory finer than n_t, so the temporal registration warps its frames, not its n_t samples
    fine = fine_size(n_t, B.times)

    def score(name: str, m: Sequence[tuple[int, int]], g: Tensor, R: Tensor) -> _Candidate:
        layout = combine_sequences(A, B, m, g, R, lam)
        return _Candidate(name, list(m), layout,
                          _candidate_distance(layout, n_ref, A.times, B.times, n_t, n_components, fine), g, R)

    parents = set(B.aligned.slot_parent.tolist())

    def with_4d_warps(c: _Candidate) -> _Candidate:
        g4 = fourd_warps(c.layout, n_ref, A.times, B.times, n_t, c.matches, c.gamma)
        options = [score(f"{c.name}_4d", c.matches, g4, c.rotation)]
        # the warps leave the children's places (s features) out: warping a parent moves them, which can cost more
        # than the warp gains, so the same warps on childless slots only are scored too
        childless = [b for b, _ in c.matches if b not in parents]
        if 0 < len(childless) < len(c.matches):
            leaves = c.gamma.clone()
            leaves[childless] = g4[childless]
            options.append(score(f"{c.name}_4d", c.matches, leaves, c.rotation))
        return min(options, key=lambda x: x.distance)

    # index order first: the distance before registration is its
    index_matches = index_order_matches(rep_b, rep_a)
    candidates = [score("index_order", index_matches, ident, eye)]
    searches = [rotation]
    fallback = cross.fallback_rotation
    if fallback is not None and fallback != rotation and not (fallback == "vertical" and rep_b.dim != 3):
        searches.append(fallback)
    for k, rot in enumerate(searches):
        if k and min(c.distance for c in candidates[1:]) < candidates[0].distance:
            break  # the fallback search only runs where the first did not beat index order
        # one way (symmetric=False), as the weights are A's: B's representative onto A's
        reg = search.register(rep_b, rep_a, lam_reg, rot, positions=cross.positions, order_tol=cross.order_tol,
                              lp_relative=False, symmetric=False)[0]
        R = reg.rotation.to(torch.float64)
        suffix = "" if k == 0 else f"_{rot}"
        candidates += [score(f"registered{suffix}", reg.matches, reg.gamma.to(torch.float64), R),
                       score(f"correspondence{suffix}", reg.matches, ident, R)]
        filled = completed_matches(reg.matches, rep_b.parent.tolist(), rep_a.parent.tolist(), rep_b.s.tolist(),
                                   rep_a.s.tolist())
        if len(filled) > len(reg.matches):
            candidates.append(score(f"completed{suffix}", filled, ident, R))
    # the registration's correspondences (found and completed) again with the warps that minimise the 4D distance
    # itself (fourd_warps); the index order's only where no registered candidate beats it: where one does, the
    # registration's correspondence is the organs' (synthetic bean: an index order with 4D warps can edge below it,
    # 85 % of the slots the same organ instead of 96 %)
    d_before = candidates[0].distance
    candidates += [with_4d_warps(c) for c in candidates if c.name.startswith(("correspondence", "completed"))]
    if min(c.distance for c in candidates[1:]) >= d_before:
        candidates.append(with_4d_warps(candidates[0]))
    seconds["cross_sequence"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    # ties go to the registrations (in search order), index order last
    spatial_candidate, matches, after = min(candidates[1:] + candidates[:1], key=lambda c: c.distance)[:3]
    pca, alpha_a, alpha_b = layout_trajectories(after, n_ref, A.times, B.times, n_t, n_components, fine)
    seconds["tree_space"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    time_reg = temporal.register(alpha_a, alpha_b, time_weight=time_weight)
    d_spatial = float(time_reg.distance_before)
    seconds["temporal"] = time.perf_counter() - t0
    times = torch.linspace(0, 1, n_t, dtype=alpha_a.dtype)
    span = (float(A.times[0]), float(A.times[-1]))
    alpha_b_grid = alpha_b[::(fine - 1) // (n_t - 1)]
    return SpatiotemporalRegistration(
        d_before, d_spatial, float(time_reg.distance), time_reg.warp, times, alpha_a, alpha_b_grid,
        time_reg.registered, pca, after, (A, B), matches, time_reg, span, seconds,
        spatial_candidate == "index_order", spatial_candidate, alpha_b,
        {"positions": cross.positions, "lambdas": tuple(lam_reg), "order_tol": cross.order_tol})

