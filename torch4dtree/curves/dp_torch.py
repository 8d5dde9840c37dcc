"""The torch backend of the DP warp: vectorised over pairs, columns and steps (any device)."""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from .srvf import inverse_srvf, uniform_grid
from .warps import neighbourhood_steps

# floor under a segment's speed before its square root: a degenerate segment gives 0 (by the where), never nan
MIN_SPEED = 1e-300


def _shift_right(x: Tensor, b: int, fill: Tensor) -> Tensor:
    """``y[:, j] = x[:, j - b]`` (``fill`` where ``j < b``). ``(B, n) -> (B, n)``."""
    n = x.shape[1]
    if b >= n:
        return fill.expand_as(x)
    return torch.cat([fill.expand(x.shape[0], b), x[:, : n - b]], 1)


def banded_dp_torch(q1: Tensor, q2: Tensor, n: int, lo: np.ndarray, hi: np.ndarray) -> tuple[Tensor, Tensor]:
    """The same DP, vectorised over pairs, columns and steps; loops over lattice rows only."""
    B, M, d = q1.shape
    dev, dt = q1.device, q1.dtype
    q1 = q1.detach()
    beta2 = inverse_srvf(q2.detach())
    steps = neighbourhood_steps(n)
    S = len(steps)
    inf = torch.tensor(float("inf"), dtype=dt, device=dev)
    # per step, tables indexed by the destination column j = l + b (so a row update needs no gather)
    groups: dict[int, list[int]] = {}
    QWd: dict[int, Tensor] = {}
    SSd: dict[int, Tensor] = {}
    for s, (a, _) in enumerate(steps):
        groups.setdefault(a, []).append(s)
    for a, idx in groups.items():
        qws, sss = [], []
        for s in idx:
            b = steps[s][1]
            L = M + 1 - b
            if L <= 0:  # a step longer than the grid: never usable
                qws.append(torch.zeros(B, a, d, M + 1, dtype=dt, device=dev))
                sss.append(torch.full((B, M + 1), float("inf"), dtype=dt, device=dev))
                continue
            x = (torch.arange(L, device=dev, dtype=dt)[None, :]
                 + torch.arange(a + 1, device=dev, dtype=dt)[:, None] * (b / a))
            fl = x.floor().clamp(0, M - 1).long()
            fr = (x - fl.to(dt)).unsqueeze(-1)
            P0 = beta2[:, fl.reshape(-1)].reshape(B, a + 1, L, d)
            P1 = beta2[:, (fl + 1).reshape(-1)].reshape(B, a + 1, L, d)
            P = P0 + fr * (P1 - P0)
            v = torch.diff(P, dim=1) * M  # (B, a, L, d)
            nv = v.norm(dim=-1)
            qw = torch.where(nv.unsqueeze(-1) > 0, v / nv.clamp_min(MIN_SPEED).sqrt().unsqueeze(-1), 0)
            qw = qw * (2.0 / M)
            qwd = torch.zeros(B, a, d, M + 1, dtype=dt, device=dev)
            qwd[..., b:] = qw.permute(0, 1, 3, 2)
            ssd = torch.full((B, M + 1), float("inf"), dtype=dt, device=dev)
            ssd[:, b:] = nv.sum(1) / M
            qws.append(qwd)
            sss.append(ssd)
        QWd[a] = torch.stack(qws, 1)  # (B, n_a, a, d, M+1)
        SSd[a] = torch.stack(sss, 1)  # (B, n_a, M+1)
    lo_t = torch.from_numpy(lo).to(dev)
    hi_t = torch.from_numpy(hi).to(dev)
    cols = torch.arange(M + 1, device=dev)
    E = torch.full((B, M + 1, M + 1), float("inf"), dtype=dt, device=dev)
    E[:, 0, 0] = 0.0
    arg = torch.zeros(B, M + 1, M + 1, dtype=torch.long, device=dev)
    for i in range(1, M + 1):
        cand = torch.full((B, S, M + 1), float("inf"), dtype=dt, device=dev)
        for a, idx in groups.items():
            k = i - a
            if k < 0:
                continue
            cost = SSd[a] - torch.einsum("brc,bsrcj->bsj", q1[:, k:i], QWd[a])
            Ek = E[:, k]
            shifted = torch.stack([_shift_right(Ek, steps[s][1], inf) for s in idx], 1)
            cand[:, idx] = shifted + cost
        best, barg = cand.min(1)
        inside = (cols >= lo_t[:, i : i + 1]) & (cols <= hi_t[:, i : i + 1])
        E[:, i] = torch.where(inside, best, inf)
        arg[:, i] = barg
    A = torch.tensor([a for a, _ in steps], device=dev)
    Bst = torch.tensor([b for _, b in steps], device=dev)
    energy = E[:, M, M] + (q1 * q1).sum((-1, -2)) / M
    gamma = torch.empty(B, M + 1, dtype=dt, device=dev)
    gamma[:, M] = 1.0
    ii = torch.full((B,), M, device=dev, dtype=torch.long)
    jj = ii.clone()
    rows = torch.arange(B, device=dev)
    for _ in range(M):
        active = ii > 0
        if not bool(active.any()):
            break
        s = arg[rows, ii, jj]
        a, b = A[s], Bst[s]
        k, lcol = ii - a, jj - b
        af, bf, lf = a.to(dt), b.to(dt), lcol.to(dt)
        for r in range(n):
            ok = active & (r < a)
            m = torch.where(ok, k + r, M)
            gamma[rows, m] = torch.where(ok, (lf + r * bf / af) / M, gamma[rows, m])
        ii = torch.where(active, k, ii)
        jj = torch.where(active, lcol, jj)
    gamma[:, M] = 1.0
    bad = ~torch.isfinite(energy)
    if bool(bad.any()):
        gamma[bad] = uniform_grid(M + 1, gamma)
    return energy, gamma

