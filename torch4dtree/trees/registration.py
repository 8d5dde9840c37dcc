"""Elastic registration of 3D trees: warps, partial branch correspondences, rotation (docs/method.md §3).

For a moving tree ``Q2`` and a reference ``Q1`` we minimise, over a global rotation ``O``, a warp of every branch
and a partial matching of side subtrees at every node,

    D(a, b) = lm ||q_b - O (q_a o gamma_ab)||^2 + min_matching [ sum_matched lp (s'_c - s_e)^2 + ls D(c, e)
                                                               + sum_unmatched ls ||Q||^2 ],

where ``s'_c`` is where child ``c`` sits on the warped parent (:mod:`.prepare`), ``||Q||^2`` the recursive norm
(the squared distance to the null tree, a null partner sitting at the same ``s``). As in the paper the warp of a
branch is chosen on the branch alone (DP), then the children's parameters move with it and their matching is one
assignment (:mod:`.matching`); matched children may refit their parent's warp (:mod:`.refit`). The solver
(:mod:`.solver`) batches every depth of every registration in flight into one DP call; the rotation alternates with
it from several starts (:mod:`.rotations`); each pair is solved in one canonical direction (:mod:`.symmetry`). The
result is never worse than the index-order solution (children matched by order of ``s``, identity warps and
rotation), which is kept when it is better.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

from ..curves.rotation import check_rotation_mode
from ..curves.srvf import srvf, warp_srvf
from ..settings import (
    DEFAULT_POSITIONS,
    ORDER_TOL,
    POSITIONS,
    RegistrationSettings,
    check_choice,
    check_lambdas,
)
from .aligned import AlignedTrees, Lambdas
from .pairwise import pairwise_distances
from .prepare import PreparedTree, child_positions, prepare_tree
from .rotations import KEEP_STARTS, RANK_T, initial_rotations, rank_starts, search_rotations
from .solver import Candidate, closest_positions, rotate_rows
from .structures import Trees
from .symmetry import inverse_config, solve_reversed

__all__ = [
    "DEFAULT_POSITIONS",
    "ORDER_TOL",
    "POSITIONS",
    "RELATIVE_LP_SCALE",
    "TreeRegistration",
    "check_lambdas",
    "effective_lambdas",
    "index_order_matches",
    "pairwise_distances",
    "register_to_reference",
    "register_trees",
]

# floor under a squared distance before its square root: the gradient stays finite at 0 (where 0 is returned)
MIN_SQ_DISTANCE = 1e-300


class TreeRegistration(NamedTuple):
    """Result of :func:`register_trees` (moving tree with ``Nm`` branches, ``T`` points per branch).

    * ``distance``: scalar, the registered distance ``||f(moving*) - f(reference)||`` (metric of docs/method.md §3,
      with the children's positions compared as the registration's ``positions`` says); differentiable in the input
      points given the discrete choices.
    * ``distance_before``: scalar, the index-order distance (children matched by order of ``s``, extra
      ones to null, identity warps and rotation).
    * ``rotation``: ``(d, d)`` acting on row vectors of the moving tree as ``x @ O.T`` (about its root).
    * ``gamma``: ``(Nm, T)`` warp of each moving branch (identity for branches matched to null).
    * ``matches``: ``[(moving branch, reference branch), ...]``, indices within each tree's packed
      branches (depth-first order), the main branches first.
    * ``unmatched_moving`` / ``unmatched_reference``: branches matched to a null branch.
    * ``aligned``: :class:`AlignedTrees` with 2 trees in one layout: ``[registered moving, reference]``
      (reference's slots first, in its packed order, then slots for the moving tree's unmatched branches); its
      ``s`` are bifurcation parameters whatever the ``positions`` compared (with ``"warped"``, ``distance`` is its
      features' distance).
    * ``used_index_order``: the index-order solution was better than the optimised one and was kept.

    """

    distance: Tensor
    distance_before: Tensor
    rotation: Tensor
    gamma: Tensor
    matches: list[tuple[int, int]]
    unmatched_moving: list[int]
    unmatched_reference: list[int]
    aligned: AlignedTrees
    used_index_order: bool



def _index_order_match(mov: PreparedTree, ref: PreparedTree) -> dict[int, int]:
    """``{moving branch: reference branch}``: the main branches, then children paired in order of ``s``."""
    match: dict[int, int] = {}
    stack = [(0, 0)]
    while stack:
        a, b = stack.pop()
        match[a] = b
        stack.extend(zip(mov.children[a], ref.children[b]))
    return match


def index_order_matches(moving: Trees, reference: Trees) -> list[tuple[int, int]]:
    """The index-order correspondence ``[(moving branch, reference branch), ...]``: children matched by order of
    ``s`` at every node, extras to null (the baseline a registration never ends worse than).

    Example:
        >>> import torch
        >>> t = torch.linspace(0, 1, 8, dtype=torch.float64)[:, None]
        >>> stem = torch.cat([0 * t, 0 * t, t], dim=1)
        >>> leaf = torch.cat([t, 0 * t, 0.5 + 0 * t], dim=1)
        >>> one = Trees.from_branches([[stem, leaf]], [[-1, 0]], T=8, dtype=torch.float64)
        >>> index_order_matches(one, Trees.from_branches([[stem]], [[-1]], T=8, dtype=torch.float64))
        [(0, 0)]
    """
    lam = (1.0, 1.0, 1.0)
    m = _index_order_match(prepare_tree(moving, lam), prepare_tree(reference, lam))
    return sorted(m.items())


def _build_aligned(mov: PreparedTree, ref: PreparedTree, match: dict[int, int], gamma: np.ndarray, O: Tensor,
                   lambdas: Lambdas, positions: str = "warped") -> tuple[AlignedTrees, Tensor]:
    """Write the registered moving tree and the reference in one layout (differentiable in the points).

    Returns the layout and the ``(2, S)`` positions the registration compared. The layout's ``s`` are always
    bifurcation parameters on the parents (a moving child at ``gamma^{-1}(s)`` of its matched parent's warp), so
    it decodes to the trees and its geodesic to trees in between. With ``"arclength"`` / ``"rank"`` positions the
    compared ones differ (arc lengths on the reference parent's scale, node ranks: :func:`child_positions`): the
    registered distance is the layout's with them in place of ``s`` (:func:`_pair_distance`); with ``"warped"``
    they are the layout's ``s``."""
    Nm, Nr = len(mov.parent), len(ref.parent)
    dtype = torch.float64
    pts_m = mov.points.to(dtype)
    dev = pts_m.device
    pts_r = ref.points.to(device=dev, dtype=dtype)
    T = pts_r.shape[1]
    grid = np.linspace(0.0, 1.0, T)
    slot_of = [-1] * Nm
    slot_parent = list(ref.parent)
    slot_depth = list(ref.depth)
    for a in range(Nm):  # parents before children, so a parent's slot exists
        if a in match:
            slot_of[a] = match[a]
        else:
            slot_of[a] = len(slot_parent)
            ps = slot_of[mov.parent[a]]
            slot_parent.append(ps)
            slot_depth.append(slot_depth[ps] + 1)
    S = len(slot_parent)
    g = torch.from_numpy(gamma).to(device=dev, dtype=dtype)
    qm = rotate_rows(warp_srvf(srvf(pts_m), g), O.to(device=dev, dtype=dtype))
    qr = srvf(pts_r)
    M, d = qr.shape[1:]
    # a child's parameter moves with its parent's warp (identity for unmatched parents: a null partner at the same s)
    s_m, cmp_m = np.zeros(Nm), np.zeros(Nm)
    for a in range(1, Nm):
        p = mov.parent[a]
        if p not in match:
            s_m[a], cmp_m[a] = mov.frac[a], mov.s[a]
        else:
            s_m[a] = np.interp(mov.frac[a], gamma[p], grid)
            cmp_m[a] = child_positions(mov, ref, p, match[p], [a], gamma[p], grid, positions)[0]
    if positions == "closest":  # the places the solver compared matched children at
        cmp_m = closest_positions(mov, ref, match, cmp_m)
    q = torch.zeros(2, S, M, d, dtype=dtype, device=dev)
    present = torch.zeros(2, S, dtype=torch.bool, device=dev)
    source = torch.full((2, S), -1, dtype=torch.long, device=dev)
    idx_m = torch.tensor(slot_of, dtype=torch.long, device=dev)
    ar_m, ar_r = torch.arange(Nm, device=dev), torch.arange(Nr, device=dev)
    q = q.index_put((torch.zeros(Nm, dtype=torch.long, device=dev), idx_m), qm)
    q = q.index_put((torch.ones(Nr, dtype=torch.long, device=dev), ar_r), qr)

    def slot_positions(s_ref: np.ndarray, s_mov: np.ndarray) -> Tensor:
        out = torch.zeros(2, S, dtype=dtype, device=dev)
        out[1, :Nr] = torch.from_numpy(s_ref).to(dev)
        out[0, :Nr] = out[1, :Nr]  # null partners sit at the same s
        out[0, idx_m] = torch.from_numpy(s_mov).to(dev)
        out[1, Nr:] = out[0, Nr:]
        return out

    s = slot_positions(ref.frac, s_m)
    compared = s if positions == "warped" else slot_positions(ref.s, cmp_m)
    present[0, idx_m] = True
    present[1, :Nr] = True
    source[0, idx_m] = ar_m
    source[1, :Nr] = ar_r
    root = torch.stack([pts_m[0, 0], pts_r[0, 0]])
    aligned = AlignedTrees(q, s, present, root, torch.tensor(slot_parent, device=dev),
                           torch.tensor(slot_depth, device=dev), source, tuple(float(x) for x in lambdas))
    return aligned, compared


def _pair_distance(aligned: AlignedTrees, positions: Tensor | None = None) -> Tensor:
    """The layout's distance between its two trees, with ``positions (2, S)`` in place of its ``s`` if given."""
    f = (aligned if positions is None else replace(aligned, s=positions)).features()
    e = (f[0] - f[1]).square().sum()
    return torch.where(e > 0, e.clamp_min(MIN_SQ_DISTANCE).sqrt(), torch.zeros_like(e))




# with lp_relative, lp = 1 weighs bifurcation positions like RELATIVE_LP_SCALE x the pair's main-branch length: the
# default keeps correspondences cycle-consistent (a larger scale keeps more identities between frames but pulls
# matches away from what a stem's weakly determined warp implies; docs/experiments.md)
RELATIVE_LP_SCALE = 0.1


def effective_lambdas(lambdas: Sequence[float], reference: Trees, moving: Trees | None = None) -> Lambdas:
    """``(lm, ls, lp * RELATIVE_LP_SCALE * L)``: the weights a registration of ``moving`` onto ``reference`` uses
    with ``lp_relative``.

    ``L = sqrt(L_moving * L_reference)``, the geometric mean of the two main-branch lengths (``L_reference`` without
    ``moving``): symmetric in the pair, so ``A -> B`` and ``B -> A`` minimise the same metric.

    Example:
        >>> import torch
        >>> t = torch.linspace(0, 1, 8, dtype=torch.float64)[:, None]
        >>> stem = Trees.from_branches([[torch.cat([0 * t, 0 * t, 2 * t], dim=1)]], [[-1]], T=8, dtype=torch.float64)
        >>> [round(x, 6) for x in effective_lambdas((1.0, 1.0, 1.0), stem)]
        [1.0, 1.0, 0.2]
    """
    lm, ls, lp = check_lambdas(lambdas)
    length = float(reference.branch_lengths()[0].detach())
    if moving is not None:
        length = math.sqrt(length * float(moving.branch_lengths()[0].detach()))
    return lm, ls, lp * RELATIVE_LP_SCALE * length


_SEARCH = RegistrationSettings()  # the search defaults, one source for this signature and the settings dataclass


def register_to_reference(trees: Trees, reference: Trees, lambdas: Sequence[float] = (1.0, 1.0, 1.0),
                          rotation: str = "none", up: Sequence[float] | Tensor | None = None,
                          n_starts: int = _SEARCH.n_starts, max_iters: int = _SEARCH.max_iters,
                          tol: float = _SEARCH.tol, neighbourhood: int = _SEARCH.neighbourhood,
                          band: int | None = _SEARCH.band, coarse: int | None = _SEARCH.coarse,
                          refine: int = _SEARCH.refine, prune: bool = _SEARCH.prune, lp_relative: bool = True,
                          positions: str = DEFAULT_POSITIONS, order_tol: float | None = None,
                          symmetric: bool = True) -> list[TreeRegistration]:
    """Register every tree of ``trees`` (moving) onto the single tree ``reference``, all at once
    (docs/method.md §3). Every depth of every registration (and every rotation start) shares one batched DP call.

    Args:
        trees: ``n`` moving trees (any numbers of branches, dimension ``d``); resampled to ``reference.T`` if needed.
        reference: one tree of dimension ``d``.
        lambdas: ``(lm, ls, lp)`` weights of the main-branch SRVF, the subtrees and the bifurcation positions.
        rotation: ``"none"``, ``"vertical"`` (about ``up``; 3D only) or ``"so3"`` (``settings.ROTATIONS``).
        up: ``(3,)`` vertical axis for ``"vertical"``; default z.
        n_starts: starting rotations spun evenly about the vertical (or the reference main branch) axis; they are
            ranked on the top two layers and the best ``KEEP_STARTS`` run in full. 12 (30 degrees apart) keeps
            plants with spiral leaves out of wrong local minima.
        max_iters: rounds of (warps + matchings, rotation) at most (10: the alternation settles within a few).
        tol: stop alternating when the energy decreases by less than this share (1e-3: a finer tolerance costs
            time for no visible change).
        neighbourhood: DP slopes, see :func:`torch4dtree.curves.dp_warp` (4: the fastest and most cycle-consistent
            at T = 64; 6 for strongly non-uniform warps).
        band: DP band of a coarse-to-fine search; ``None`` (default): the full lattice, its exact optimum.
        coarse: DP coarse grid size when ``band`` is set.
        refine: gradient refinement steps of each DP warp (0: refinement lowers each energy but makes the
            correspondences less cycle-consistent).
        prune: skip subtree pairs that provably cannot be matched (exact: does not change the result).
        lp_relative: the effective ``lp`` is ``lambdas[2] x RELATIVE_LP_SCALE x L`` (:func:`effective_lambdas`, one
            ``lp`` per pair, the same both ways): shape terms are lengths in the data's units while ``s`` is a
            fraction, so a fixed ``lp`` would weigh positions differently for every scale. ``False``: ``lambdas[2]``
            as it is. The weights used are in the results' ``aligned.lambdas``.
        positions: how a matched child's place on its parent is compared (``settings.POSITIONS``, :mod:`.prepare`).
            ``"rank"`` (default): a child of the main branch by its node rank, deeper ones by arc-length fraction;
            node k of a growing plant stays node k, so identities survive elongating stems. ``"warped"``: the
            child moves with its parent's warp, so the distance is the layout's own metric (what means and
            geodesics need). ``"arclength"``: its arc length from the parent's base in units of the reference
            parent's length. ``"nodes"``: node ranks on every branch, a side shoot half a node above the organs
            of its node (plants of one kind compared across plants, :mod:`.prepare`). Whatever ``positions``, the
            results' ``aligned`` holds bifurcation parameters, so it
            decodes and :func:`~torch4dtree.trees.geodesic` works; only with ``"warped"`` is ``distance`` the
            layout's (and the geodesic's) length.
        order_tol: ``None`` (default, the metric's own matching): each node's side subtrees are matched in any
            order. A number (e.g. ``settings.ORDER_TOL``): matched children keep their order along the parent,
            except siblings within ``order_tol`` of each other (one node), which may match in any order (frames of
            one growing plant, whose organs never pass each other; :func:`.matching.ordered_assignment`).
        symmetric: the answer does not depend on which tree is the reference: each pair is solved in one canonical
            direction (:mod:`.symmetry`) and the other direction is its inverse, so ``A -> B -> A`` returns every
            point to where it started. ``False``: solve the given direction (one-way uses: chaining a sequence,
            comparing candidates by their distances onto one tree, aligning trees onto a mean or a layout).

    Returns:
        One :class:`TreeRegistration` per moving tree, on the input's device and dtype.

    Example:
        >>> import torch
        >>> t = torch.linspace(0, 1, 8, dtype=torch.float64)[:, None]
        >>> stem = torch.cat([0 * t, 0 * t, t], dim=1)
        >>> leaf = torch.cat([t, 0 * t, 0.5 + 0 * t], dim=1)
        >>> plant = Trees.from_branches([[stem, leaf]], [[-1, 0]], T=8, dtype=torch.float64)
        >>> bare = Trees.from_branches([[stem]], [[-1]], T=8, dtype=torch.float64)
        >>> [r.matches for r in register_to_reference(Trees.cat([plant, bare]), plant)]
        [[(0, 0), (1, 1)], [(0, 0)]]
    """
    lam = check_lambdas(lambdas)
    check_rotation_mode(rotation, reference.dim)
    check_choice("positions", positions, POSITIONS)
    if order_tol is not None and not (math.isfinite(order_tol) and order_tol >= 0):
        raise ValueError(f"order_tol must be None or a finite number >= 0, got {order_tol}")
    if reference.num_trees != 1:
        raise ValueError(f"reference must be a single tree, got {reference.num_trees}")
    if trees.dim != reference.dim:
        raise ValueError(f"dimensions differ: {trees.dim} vs {reference.dim}")
    if trees.T != reference.T:
        trees = trees.resample(reference.T)
    singles = trees.split()
    # per moving tree: lp scaled by the pair (the DP warps, the norms and the rotation weights use lm and ls only)
    lams = [effective_lambdas(lam, reference, t) if lp_relative else lam for t in singles]
    up_t = torch.as_tensor((0.0, 0.0, 1.0) if up is None else up, dtype=torch.float64)
    dp_opts = {"neighbourhood": neighbourhood, "band": band, "coarse": coarse, "refine": refine}
    ref = prepare_tree(reference, lam, positions)
    movs = [prepare_tree(t, lt, positions) for t, lt in zip(singles, lams)]
    # the pair is solved in its canonical direction (the same whichever tree is given as the reference):
    # problem m registers svs[m] onto srs[m]; flipped ones are inverted at the end
    flip = [symmetric and solve_reversed(mv, ref) for mv in movs]
    svs = [prepare_tree(reference, lt, positions) if f else mv for mv, lt, f in zip(movs, lams, flip)]
    srs = [mv if f else ref for mv, f in zip(movs, flip)]
    with torch.no_grad():
        starts = [initial_rotations(sv, sr, rotation, up_t, n_starts, dp_opts) for sv, sr in zip(svs, srs)]
        jobs = [(m, m, O) for m, Os in enumerate(starts) for O in Os]
        if rotation != "none" and max(len(Os) for Os in starts) > KEEP_STARTS:
            if reference.T > RANK_T:  # ranking only compares starts: coarser curves do (DP cost ~ T^2)
                c_ref = reference.resample(RANK_T)
                c_movs = [prepare_tree(t, lt, positions) for t, lt in zip(trees.resample(RANK_T).split(), lams)]
                c_refm = [prepare_tree(c_ref, lt, positions) if f else None for lt, f in zip(lams, flip)]
                c_ref0 = prepare_tree(c_ref, lam, positions)
                jobs = rank_starts([cr if f else cm for cm, cr, f in zip(c_movs, c_refm, flip)],
                                   [cm if f else c_ref0 for cm, f in zip(c_movs, flip)], jobs, lams, dp_opts,
                                   prune, rotation, up_t, positions, order_tol)
            else:
                jobs = rank_starts(svs, srs, jobs, lams, dp_opts, prune, rotation, up_t, positions, order_tol)
            # the identity always runs in full, so a rotation search never ends worse than rotation="none"
            eye = torch.eye(reference.dim, dtype=torch.float64)
            kept_identity = {m for m, _, O in jobs if torch.equal(O, eye)}
            jobs += [(m, m, eye) for m in range(len(movs)) if m not in kept_identity]
        best = search_rotations(svs, srs, jobs, lams, dp_opts, prune, rotation, up_t, max_iters, tol, positions,
                                order_tol)
    # where the reference was registered onto a tree: the inverse correspondence, warps and rotation
    inverse = {m: inverse_config(cfg, len(movs[m].parent)) for m, cfg in enumerate(best) if flip[m]}
    out = []
    eye = torch.eye(reference.dim, dtype=torch.float64)
    for m, (mov, cfg, lam_m) in enumerate(zip(movs, best, lams)):
        cfg = inverse.get(m, cfg)
        aligned, compared = _build_aligned(mov, ref, cfg.match, cfg.gamma, cfg.O, lam_m, positions)
        dist = _pair_distance(aligned, compared)
        ident = np.tile(np.linspace(0.0, 1.0, reference.T), (len(mov.parent), 1))
        base_match = _index_order_match(mov, ref)
        base, base_compared = _build_aligned(mov, ref, base_match, ident, eye, lam_m, positions)
        dist_before = _pair_distance(base, base_compared)
        used_base = bool(dist_before < dist)
        # the index-order solution is a valid candidate: never return worse (kept over an inverted solution too,
        # the one place a symmetric registration can differ between the two argument orders)
        if used_base:
            cfg = Candidate(float(dist_before) ** 2, base_match, ident, eye)
            aligned, dist = base, dist_before
        matches = sorted(cfg.match.items())
        matched_ref = set(cfg.match.values())
        out.append(TreeRegistration(
            dist, dist_before, cfg.O.to(device=trees.device, dtype=trees.dtype),
            torch.from_numpy(cfg.gamma).to(device=trees.device, dtype=trees.dtype), matches,
            [a for a in range(len(mov.parent)) if a not in cfg.match],
            [b for b in range(len(ref.parent)) if b not in matched_ref], aligned, used_base,
        ))
    return out


def register_trees(moving: Trees, reference: Trees, lambdas: Sequence[float] = (1.0, 1.0, 1.0),
                   rotation: str = "none", order_tol: float | None = None, **kwargs: object) -> TreeRegistration:
    """Register one tree onto another (docs/method.md §3); ``kwargs``: the settings of
    :func:`register_to_reference`.

    ``order_tol``: ``None`` (default) any partial matching, the metric's own; :data:`ORDER_TOL`: matched children
    keep their order along their parents, siblings at one node excepted (:func:`.matching.ordered_assignment`), as
    organs of one plant do between snapshots. Ordered matching keeps a woody tree's spurs whose direction turns
    between snapshots with themselves (any matching gives them a neighbour of like direction), but leaves more length
    unmatched where children cross (docs/method.md §7: cycle consistency with null branches), so it is opt-in.

    Returns a :class:`TreeRegistration`; ``distance`` is the tree-shape distance (never above ``distance_before``,
    the index-order one).

    Example:
        >>> import torch
        >>> t = torch.linspace(0, 1, 8, dtype=torch.float64)[:, None]
        >>> stem, leaf, bent = (torch.cat(xyz, dim=1) for xyz in ((0 * t, 0 * t, t), (t, 0 * t, 0.5 + 0 * t),
        ...                                                       (t, 0.3 * t ** 2, 0.6 + 0 * t)))
        >>> tree, other = (Trees.from_branches([[stem, b]], [[-1, 0]], T=8, dtype=torch.float64) for b in (leaf, bent))
        >>> r = register_trees(other, tree)
        >>> r.matches, r.unmatched_moving, round(float(register_trees(tree, tree).distance), 6)
        ([(0, 0), (1, 1)], [], 0.0)
    """
    if moving.num_trees != 1:
        raise ValueError(f"moving must be a single tree, got {moving.num_trees}")
    return register_to_reference(moving, reference, lambdas, rotation, order_tol=order_tol,  # type: ignore[arg-type]
                                 **kwargs)[0]


