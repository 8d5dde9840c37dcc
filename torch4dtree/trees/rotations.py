"""The global rotation of a registration: starting rotations, their ranking, and the alternation of
(warps + matchings, rotation) until the energy stops decreasing (docs/method.md §3).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import Tensor

from ..curves.register import register_curves
from ..curves.rotation import axis_rotation, kabsch, vertical_rotation
from ..curves.srvf import srvf_sq_norm, warp_srvf
from .aligned import Lambdas, slot_weights
from .prepare import PreparedTree
from .solver import Candidate, rotate_rows, solve

__all__ = ["KEEP_STARTS", "RANK_T", "STOP_START_RATIO", "initial_rotations", "rank_starts", "rotation_update",
           "search_rotations"]

# points per branch of the curves on which rotation starts are ranked (ranking only compares starts; DP cost ~ T^2)
RANK_T = 24
# a rotation start whose energy is this many times the best start's of the same pair is dropped
STOP_START_RATIO = 1.5
# ... and at most this many starts per pair keep alternating after the first round
KEEP_STARTS = 2
# absolute slack on that comparison, so that a start tied with a zero-energy best one is not dropped
ENERGY_SLACK = 1e-12


def rotation_update(mov: PreparedTree, ref: PreparedTree, cfg: Candidate, lambdas: Lambdas, rotation: str,
                    up: Tensor) -> tuple[Tensor, float]:
    """``(O (d, d), energy)``: the best rotation for ``cfg``'s fixed matches and warps (weighted Kabsch over all
    matched branches for ``"so3"``, about ``up (3,)`` for ``"vertical"``) and the energy with it."""
    a_idx = list(cfg.match.keys())
    b_idx = [cfg.match[a] for a in a_idx]
    w = slot_weights(torch.tensor([mov.depth[a] for a in a_idx]), lambdas)[0]
    qw = warp_srvf(mov.q[a_idx], torch.from_numpy(cfg.gamma[a_idx]))
    qr = ref.q[b_idx]
    M = qr.shape[1]
    A = (w[:, None, None, None] * qr.unsqueeze(-1) * qw.unsqueeze(-2)).sum((0, 1)) / M  # elementwise: see rotate_rows
    O = kabsch(A[None])[0] if rotation == "so3" else vertical_rotation(A[None], up)[0]

    def matched_energy(R: Tensor) -> float:
        return float((w * srvf_sq_norm(qr - rotate_rows(qw, R))).sum())

    return O, cfg.energy - matched_energy(cfg.O) + matched_energy(O)


def initial_rotations(mov: PreparedTree, ref: PreparedTree, rotation: str, up: Tensor, n_starts: int,
                      dp_opts: dict) -> list[Tensor]:
    """Starting rotations ``(d, d)``: the identity, the main branches' registration, and that one spun about an
    axis (``up`` for ``"vertical"``, the reference main branch's chord for ``"so3"``) ``n_starts - 1`` times
    evenly over a full turn. Only ``[identity]`` for ``rotation="none"``."""
    d = mov.q.shape[-1]
    eye = torch.eye(d, dtype=torch.float64)
    if rotation == "none":
        return [eye]
    opts = {k: v for k, v in dp_opts.items() if k in ("neighbourhood", "band", "coarse", "refine")}
    reg = register_curves(mov.q[0], ref.q[0], rotation=rotation, srvf_input=True, up=up, **opts)
    starts = [eye, reg.rotation.to(torch.float64)]
    if d == 3 and n_starts > 1:
        if rotation == "vertical":
            axis = up
        else:  # spin about the reference main branch's chord, the direction least fixed by it
            chord = (ref.q[0] * ref.q[0].norm(dim=-1, keepdim=True)).sum(0)
            axis = chord if bool(chord.norm() > 0) else up
        angles = torch.arange(1, n_starts, dtype=torch.float64) * (2 * math.pi / n_starts)
        spins = axis_rotation(axis.to(torch.float64), angles)
        starts += [R @ starts[1] for R in spins]
    return starts


def rank_starts(movs: Sequence[PreparedTree], refs: Sequence[PreparedTree], jobs: list[tuple[int, int, Tensor]],
                lambdas: Sequence[Lambdas], dp_opts: dict, prune: bool, rotation: str, up: Tensor,
                positions: str = "warped", order_tol: float | None = None) -> list[tuple[int, int, Tensor]]:
    """The ``KEEP_STARTS`` best starting rotations of each pair, ranked on the top two layers only
    (one rotation update each): the full recursion then runs for those alone."""
    configs = solve(movs, refs, jobs, lambdas, dp_opts, prune, max_depth=1, positions=positions,
                    order_tol=order_tol)
    scored = []
    for (m, r, _), cfg in zip(jobs, configs):
        O_new, e_new = rotation_update(movs[m], refs[r], cfg, lambdas[m], rotation, up)
        scored.append((min(e_new, cfg.energy), m, r, O_new if e_new < cfg.energy else cfg.O))
    kept: dict[int, int] = {}
    out = []
    for _, m, r, O in sorted(scored, key=lambda x: x[0]):
        if kept.get(m, 0) < KEEP_STARTS:
            kept[m] = kept.get(m, 0) + 1
            out.append((m, r, O))
    return out


def search_rotations(movs: Sequence[PreparedTree], refs: Sequence[PreparedTree], jobs: list[tuple[int, int, Tensor]],
                     lambdas: Sequence[Lambdas], dp_opts: dict, prune: bool, rotation: str, up: Tensor,
                     max_iters: int, tol: float, positions: str = "warped", order_tol: float | None = None
                     ) -> list[Candidate]:
    """The best :class:`Candidate` of each problem ``m`` (registering ``movs[m]`` onto ``refs[m]``).

    Every job ``(m, m, O)`` (at least one per problem) alternates :func:`solve` with :func:`rotation_update` for at
    most ``max_iters`` rounds, until its energy decreases by less than ``tol`` relatively; starts far behind
    their problem's best (``STOP_START_RATIO``) stop, and at most ``KEEP_STARTS`` per problem go on.
    """
    best: list[Candidate | None] = [None] * len(movs)
    last = [math.inf] * len(jobs)
    for _ in range(max(max_iters, 1)):
        configs = solve(movs, refs, jobs, lambdas, dp_opts, prune, positions=positions, order_tol=order_tol)
        nxt, nlast = [], []
        for (m, _, _), cfg, prev in zip(jobs, configs, last):
            cur = best[m]
            if cur is None or cfg.energy < cur.energy:
                cur = best[m] = cfg
            if rotation == "none":
                continue
            O_new, e_new = rotation_update(movs[m], refs[m], cfg, lambdas[m], rotation, up)
            if e_new < cur.energy:
                cur = best[m] = Candidate(e_new, cfg.match, cfg.gamma, O_new)
            e = min(e_new, cfg.energy)
            # a start far behind the best one of its pair will not catch up: stop it
            if e > STOP_START_RATIO * cur.energy + ENERGY_SLACK:
                continue
            if not math.isfinite(prev) or e < prev - tol * prev:
                nxt.append((m, m, O_new))
                nlast.append(e)
        # only the KEEP_STARTS most promising starts of each pair keep alternating
        kept: dict[int, int] = {}
        sel: list[int] = []
        for i in sorted(range(len(nxt)), key=lambda i: nlast[i]):
            if kept.get(nxt[i][0], 0) < KEEP_STARTS:
                kept[nxt[i][0]] = kept.get(nxt[i][0], 0) + 1
                sel.append(i)
        sel.sort()
        nxt, nlast = [nxt[i] for i in sel], [nlast[i] for i in sel]
        if not nxt:
            break
        jobs, last = nxt, nlast
    missing = [m for m, cfg in enumerate(best) if cfg is None]
    if missing:
        raise ValueError(f"problems {missing} have no rotation start: every problem needs at least one job")
    return [cfg for cfg in best if cfg is not None]
