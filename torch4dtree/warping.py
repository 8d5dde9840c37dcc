"""Elastic registration of curves: batched dynamic-programming warps and rotations.

All discrete choices minimise exactly the discrete energy of ``curves.py``::

    E(gamma, O) = || q1 - O warp_srvf(q2, gamma) ||^2

(``q1`` the reference SRVF, ``q2`` the moving one, both ``(B, M, d)`` piecewise constant on the
``T = M + 1`` grid points). The DP lattice has nodes ``(i, j)`` meaning ``gamma(s_i) = s_j``;
an edge ``(i - a, j - b) -> (i, j)`` uses a coprime step ``(a, b)`` and makes ``gamma`` linear
between its ends, so the warped curve's nodes inside the edge are ``beta2`` at the fractional
grid positions ``j - b + r b / a``. The identity warp is a lattice path (steps ``(1, 1)``), so a
full DP never does worse than the identity; banded / coarse-to-fine searches keep the best of
their result and the warp they started from, so they never do worse either.

Two interchangeable backends compute the same DP: a numba kernel (CPU default, parallel over
pairs) and a vectorised torch one (row by row over the lattice; any device).
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

from .curves import interpolate_curve, inverse_srvf, srvf, srvf_sq_distance, uniform_grid, warp_curve, warp_srvf
from .rotation import check_rotation_mode, optimal_rotation

try:  # numba is optional: without it the torch backend is used everywhere
    import numba

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover - exercised only without numba
    numba = None
    HAVE_NUMBA = False

__all__ = [
    "CurveRegistration",
    "DPWarp",
    "compose_warps",
    "dp_warp",
    "elastic_distance",
    "identity_warp",
    "invert_warp",
    "neighbourhood_steps",
    "random_warp",
    "register_curves",
    "warp_energy",
]


# ----------------------------------------------------------------------------- warp utilities


def identity_warp(B: int, T: int, like: Tensor | None = None) -> Tensor:
    """The identity warp ``linspace(0, 1, T)`` repeated, ``(B, T)``."""
    like = torch.empty(0, dtype=torch.float64) if like is None else like
    return uniform_grid(T, like).expand(B, T).clone()


def random_warp(B: int, T: int, generator: torch.Generator | None = None, strength: float = 1.0,
                modes: int = 4, dtype: torch.dtype = torch.float64, device: torch.device | str = "cpu") -> Tensor:
    """Smooth random warps ``(B, T)``: monotone, ``gamma(0) = 0``, ``gamma(1) = 1``.

    ``gamma' ∝ exp(f)`` with ``f`` a random combination of ``modes`` cosines whose amplitudes
    decay like ``1/k``; ``strength`` scales ``f`` (0 gives the identity).
    """
    if T < 2:
        raise ValueError(f"a warp needs at least 2 grid points, got T={T}")
    coef = torch.randn(B, modes, generator=generator, dtype=dtype) / torch.arange(1, modes + 1, dtype=dtype)
    mid = (torch.arange(T - 1, dtype=dtype) + 0.5) / (T - 1)
    f = strength * coef @ torch.cos(math.pi * torch.arange(1, modes + 1, dtype=dtype)[:, None] * mid)
    inc = torch.exp(f - f.amax(-1, keepdim=True))
    gamma = torch.cat([torch.zeros(B, 1, dtype=dtype), inc.cumsum(-1)], -1)
    gamma = gamma / gamma[:, -1:]
    gamma[:, -1] = 1.0
    return gamma.to(device)


def invert_warp(gamma: Tensor) -> Tensor:
    """``gamma^{-1}`` on the grid, ``(..., T) -> (..., T)`` (piecewise-linear inverse)."""
    shape, T = gamma.shape, gamma.shape[-1]
    g = gamma.reshape(-1, T).contiguous()
    s = uniform_grid(T, g).expand_as(g).contiguous()
    hi = torch.searchsorted(g, s, right=True).clamp(1, T - 1)
    lo = hi - 1
    g_lo, g_hi = g.gather(1, lo), g.gather(1, hi)
    width = g_hi - g_lo
    frac = torch.where(width > 0, (s - g_lo) / torch.where(width > 0, width, 1), 0).clamp(0, 1)
    inv = (lo.to(g.dtype) + frac) / (T - 1)
    inv[:, 0], inv[:, -1] = 0.0, 1.0
    return inv.reshape(shape)


def compose_warps(gamma1: Tensor, gamma2: Tensor) -> Tensor:
    """``gamma1 o gamma2`` on the grid: ``(..., T) x (..., T) -> (..., T)``.

    ``warp_curve(warp_curve(beta, gamma1), gamma2) ~ warp_curve(beta, compose_warps(gamma1, gamma2))``.
    """
    return interpolate_curve(gamma1.unsqueeze(-1), gamma2)[..., 0]


def warp_energy(q1: Tensor, q2: Tensor, gamma: Tensor, rotation: Tensor | None = None) -> Tensor:
    """The discrete energy ``||q1 - O warp_srvf(q2, gamma)||^2``. ``(B,M,d),(B,M,d),(B,M+1),(B,d,d) -> (B,)``."""
    q2w = warp_srvf(q2, gamma)
    if rotation is not None:
        q2w = q2w @ rotation.transpose(-1, -2)
    return srvf_sq_distance(q1, q2w)


# ----------------------------------------------------------------------------- DP lattice


@lru_cache(maxsize=None)
def neighbourhood_steps(n: int) -> tuple[tuple[int, int], ...]:
    """All coprime steps ``(a, b)`` with ``1 <= a, b <= n`` (``n = 6``: the 23 steps of the reference)."""
    if n < 1:
        raise ValueError(f"neighbourhood must be >= 1, got {n}")
    steps = [(a, b) for a in range(1, n + 1) for b in range(1, n + 1) if math.gcd(a, b) == 1]
    # (1, 1) first: on exact ties the DP keeps the first step, which favours the identity
    return tuple(sorted(steps, key=lambda ab: (ab != (1, 1), max(ab), ab)))


def _reachable_band(M: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Columns ``[lo_i, hi_i]`` of the lattice reachable from (0,0) and reaching (M,M) with slopes in [1/n, n]."""
    i = np.arange(M + 1)
    lo = np.maximum(-(-i // n), M - n * (M - i))
    hi = np.minimum(n * i, M - (-(-(M - i) // n)))
    return lo.astype(np.int64), hi.astype(np.int64)


def _band_around(center: Tensor, M: int, n: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Band of half-width ``width`` (in rows and columns) around warps ``center (B, M+1)``.

    Row ``i`` gets columns ``[M gamma(s_{i-w}) - w, M gamma(s_{i+w}) + w]``, cut to the reachable set.
    """
    g = center.detach().to("cpu", torch.float64).numpy() * M
    idx = np.arange(M + 1)
    lo = np.floor(g[:, np.clip(idx - width, 0, M)] + 1e-9) - width
    hi = np.ceil(g[:, np.clip(idx + width, 0, M)] - 1e-9) + width
    rlo, rhi = _reachable_band(M, n)
    lo = np.maximum(lo.astype(np.int64), rlo)
    hi = np.minimum(hi.astype(np.int64), rhi)
    return np.ascontiguousarray(lo), np.ascontiguousarray(np.maximum(hi, lo))


def _step_arrays(n: int) -> tuple[np.ndarray, np.ndarray]:
    steps = neighbourhood_steps(n)
    return np.array([a for a, _ in steps], np.int64), np.array([b for _, b in steps], np.int64)


# ----------------------------------------------------------------------------- numba backend

if HAVE_NUMBA:

    @numba.njit(cache=True, fastmath=False, boundscheck=False)
    def _nb_point(beta: np.ndarray, x: float, M: int, out: np.ndarray) -> None:
        """``beta`` at fractional node index ``x`` (same formula as curves.interpolate_curve)."""
        fl = int(math.floor(x))
        if fl > M - 1:
            fl = M - 1
        if fl < 0:
            fl = 0
        fr = x - fl
        for c in range(beta.shape[1]):
            out[c] = beta[fl, c] + fr * (beta[fl + 1, c] - beta[fl, c])

    @numba.njit(cache=True, boundscheck=False)
    def _nb_dp_one(q1: np.ndarray, beta2: np.ndarray, A: np.ndarray, Bs: np.ndarray, lo: np.ndarray,
                   hi: np.ndarray, gamma: np.ndarray) -> float:
        """DP for one pair; writes ``gamma (M+1,)`` and returns the energy (inf if the band has no path)."""
        M, d = q1.shape
        S = A.shape[0]
        off = np.zeros(S + 1, np.int64)
        for s in range(S):
            off[s + 1] = off[s] + A[s]
        # tables: 2/M * warped SRVF of every sub-segment r of every edge type, and 1/M * sum_r |v_r|
        QW = np.zeros((off[S], d, M + 1))
        SS = np.zeros((S, M + 1))
        p0 = np.empty(d)
        p1 = np.empty(d)
        v = np.empty(d)
        for s in range(S):
            a = A[s]
            b = Bs[s]
            for lcol in range(M + 1 - b):
                _nb_point(beta2, float(lcol), M, p0)
                tot = 0.0
                for r in range(a):
                    _nb_point(beta2, lcol + (r + 1) * b / a, M, p1)
                    nv2 = 0.0
                    for c in range(d):
                        v[c] = (p1[c] - p0[c]) * M
                        nv2 += v[c] * v[c]
                    nv = math.sqrt(nv2)
                    if nv > 0:
                        sc = 2.0 / (M * math.sqrt(nv))
                        for c in range(d):
                            QW[off[s] + r, c, lcol] = v[c] * sc
                    tot += nv
                    for c in range(d):
                        p0[c] = p1[c]
                SS[s, lcol] = tot / M
        E = np.full((M + 1, M + 1), np.inf)
        arg = np.zeros((M + 1, M + 1), np.int8)
        E[0, 0] = 0.0
        tmp = np.empty(M + 1)
        for i in range(1, M + 1):
            jl = lo[i]
            jh = hi[i]
            for s in range(S):
                a = A[s]
                b = Bs[s]
                k = i - a
                if k < 0:
                    continue
                j0 = max(jl, b)
                if j0 > jh:
                    continue
                for j in range(j0, jh + 1):
                    tmp[j] = SS[s, j - b]
                for r in range(a):
                    for c in range(d):
                        w = q1[k + r, c]
                        row = QW[off[s] + r, c]
                        for j in range(j0, jh + 1):
                            tmp[j] -= w * row[j - b]
                Ek = E[k]
                Ei = E[i]
                for j in range(j0, jh + 1):
                    cand = Ek[j - b] + tmp[j]
                    if cand < Ei[j]:
                        Ei[j] = cand
                        arg[i, j] = s
        if not E[M, M] < np.inf:
            for m in range(M + 1):
                gamma[m] = m / M
            return np.inf
        i = M
        j = M
        gamma[M] = 1.0
        while i > 0:
            s = arg[i, j]
            a = A[s]
            b = Bs[s]
            k = i - a
            lcol = j - b
            for r in range(a):
                gamma[k + r] = (lcol + r * b / a) / M
            i = k
            j = lcol
        q1sq = 0.0
        for m in range(M):
            for c in range(d):
                q1sq += q1[m, c] * q1[m, c]
        return E[M, M] + q1sq / M

    @numba.njit(cache=True, parallel=True, boundscheck=False)
    def _nb_dp_batch(q1: np.ndarray, beta2: np.ndarray, A: np.ndarray, Bs: np.ndarray, lo: np.ndarray,
                     hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        Bn, M, _ = q1.shape
        energy = np.empty(Bn)
        gamma = np.empty((Bn, M + 1))
        for p in numba.prange(Bn):
            energy[p] = _nb_dp_one(q1[p], beta2[p], A, Bs, lo[p], hi[p], gamma[p])
        return energy, gamma


def _dp_numba(q1: Tensor, q2: Tensor, n: int, lo: np.ndarray, hi: np.ndarray) -> tuple[Tensor, Tensor]:
    A, Bs = _step_arrays(n)
    q1n = q1.detach().to("cpu", torch.float64).contiguous().numpy()
    beta2 = inverse_srvf(q2.detach().to("cpu", torch.float64)).contiguous().numpy()
    energy, gamma = _nb_dp_batch(q1n, beta2, A, Bs, lo, hi)
    return torch.from_numpy(energy), torch.from_numpy(gamma)


# ----------------------------------------------------------------------------- torch backend


def _dp_torch(q1: Tensor, q2: Tensor, n: int, lo: np.ndarray, hi: np.ndarray) -> tuple[Tensor, Tensor]:
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
    for s, (a, b) in enumerate(steps):
        groups.setdefault(a, []).append(s)
    for a, idx in groups.items():
        qws, sss = [], []
        for s in idx:
            b = steps[s][1]
            L = M + 1 - b
            x = torch.arange(L, device=dev, dtype=dt)[None, :] + torch.arange(a + 1, device=dev, dtype=dt)[:, None] * (b / a)
            fl = x.floor().clamp(0, M - 1).long()
            fr = (x - fl.to(dt)).unsqueeze(-1)
            P0 = beta2[:, fl.reshape(-1)].reshape(B, a + 1, L, d)
            P1 = beta2[:, (fl + 1).reshape(-1)].reshape(B, a + 1, L, d)
            P = P0 + fr * (P1 - P0)
            v = torch.diff(P, dim=1) * M  # (B, a, L, d)
            nv = v.norm(dim=-1)
            qw = torch.where(nv.unsqueeze(-1) > 0, v / nv.clamp_min(1e-300).sqrt().unsqueeze(-1), 0) * (2.0 / M)
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
            shifted = torch.stack(
                [torch.cat([inf.expand(B, steps[s][1]), Ek[:, : M + 1 - steps[s][1]]], 1) for s in idx], 1)
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


# ----------------------------------------------------------------------------- DP driver


class DPWarp(NamedTuple):
    """Result of :func:`dp_warp`: ``gamma (B, M+1)`` and ``energy (B,) = ||q1 - warp_srvf(q2, gamma)||^2``."""

    gamma: Tensor
    energy: Tensor


def _resample_srvf(q: Tensor, M: int) -> Tensor:
    """SRVF of the curve of ``q`` resampled (linearly in the parameter) to ``M`` segments."""
    if q.shape[-2] == M:
        return q
    beta = inverse_srvf(q)
    return srvf(interpolate_curve(beta, uniform_grid(M + 1, q).expand(*q.shape[:-2], M + 1)))


def _pick_backend(backend: str, x: Tensor) -> str:
    if backend not in ("auto", "numba", "torch"):
        raise ValueError(f"unknown backend {backend!r}; expected 'auto', 'numba' or 'torch'")
    if backend == "auto":
        return "numba" if HAVE_NUMBA and x.device.type == "cpu" else "torch"
    if backend == "numba" and not HAVE_NUMBA:
        raise ValueError("backend='numba' needs the numba package")
    return backend


def _run_dp(q1: Tensor, q2: Tensor, n: int, lo: np.ndarray, hi: np.ndarray, backend: str) -> tuple[Tensor, Tensor]:
    if backend == "numba":
        energy, gamma = _dp_numba(q1, q2, n, lo, hi)
        return energy.to(q1.device, q1.dtype), gamma.to(q1.device, q1.dtype)
    return _dp_torch(q1, q2, n, lo, hi)


def _check_srvf_pair(q1: Tensor, q2: Tensor) -> None:
    if q1.dim() != 3 or q2.dim() != 3:
        raise ValueError(f"expected SRVFs of shape (B, M, d), got {tuple(q1.shape)} and {tuple(q2.shape)}")
    if q1.shape[0] != q2.shape[0] or q1.shape[2] != q2.shape[2]:
        raise ValueError(f"batch sizes / dimensions differ: {tuple(q1.shape)} vs {tuple(q2.shape)}")
    if q1.shape[1] < 1 or q2.shape[1] < 1:
        raise ValueError("curves need at least 2 points (1 SRVF segment)")
    if not (torch.isfinite(q1).all() and torch.isfinite(q2).all()):
        raise ValueError("SRVFs contain NaN or inf")


@torch.no_grad()
def dp_warp(q1: Tensor, q2: Tensor, neighbourhood: int = 6, band: int | None = 6, coarse: int | None = 32,
            init: Tensor | None = None, backend: str = "auto") -> DPWarp:
    """Optimal warps of ``q2`` onto ``q1`` by dynamic programming (no rotation).

    Args:
        q1: ``(B, M, d)`` reference SRVFs (or ``(M, d)`` for one pair).
        q2: ``(B, M2, d)`` moving SRVFs; resampled to ``M`` segments when ``M2 != M``.
        neighbourhood: allowed steps are the coprime ``(a, b)`` with ``1 <= a, b <= neighbourhood``.
        band: half-width (in grid cells) of the band searched around a first guess; ``None`` searches
            the whole lattice (exact DP optimum over all lattice warps).
        coarse: with a band and no ``init``, the first guess is the DP on a grid of about
            ``coarse`` segments (recursively coarse-to-fine); ``None`` uses the identity warp.
        init: ``(B, M+1)`` first-guess warps to search around (with ``band``).
        backend: ``"numba"`` (CPU), ``"torch"`` (any device) or ``"auto"``.

    Returns:
        ``DPWarp(gamma (B, M+1), energy (B,))`` with ``energy = ||q1 - warp_srvf(q2, gamma)||^2``
        never above that of the identity warp (nor of ``init``).
    """
    single = q1.dim() == 2
    if single:
        q1, q2 = q1.unsqueeze(0), q2.unsqueeze(0)
    _check_srvf_pair(q1, q2)
    q2 = _resample_srvf(q2.to(q1.dtype), q1.shape[1])
    be = _pick_backend(backend, q1)
    gamma, energy = _dp_search(q1, q2, neighbourhood, band, coarse, init, be)
    if single:
        gamma, energy = gamma[0], energy[0]
    return DPWarp(gamma, energy)


def _dp_search(q1: Tensor, q2: Tensor, n: int, band: int | None, coarse: int | None, init: Tensor | None,
               backend: str) -> tuple[Tensor, Tensor]:
    """Full, banded or coarse-to-fine DP, then keep the best of it, the identity and ``init``."""
    B, M, _ = q1.shape
    if band is None or (init is None and coarse is not None and M <= coarse):
        lo, hi = _reachable_band(M, n)
        energy, gamma = _run_dp(q1, q2, n, np.tile(lo, (B, 1)), np.tile(hi, (B, 1)), backend)
        return gamma, energy
    if init is None and coarse is not None:
        Mc = max(coarse, (M + 1) // 2)
        if Mc >= M:
            Mc = M // 2
        gc, _ = _dp_search(_resample_srvf(q1, Mc), _resample_srvf(q2, Mc), n, band, coarse, None, backend)
        center = interpolate_curve(gc.unsqueeze(-1), uniform_grid(M + 1, q1).expand(B, M + 1))[..., 0]
    else:
        center = identity_warp(B, M + 1, q1) if init is None else init
    lo, hi = _band_around(center, M, n, band)
    energy, gamma = _run_dp(q1, q2, n, lo, hi, backend)
    # guard: the band may miss the identity (or have no path); keep whichever is best
    cands = [identity_warp(B, M + 1, q1)] + ([init.to(q1.dtype)] if init is not None else [])
    for g in cands:
        e = warp_energy(q1, q2, g)
        better = e < energy
        if bool(better.any()):
            gamma = torch.where(better.unsqueeze(-1), g, gamma)
            energy = torch.where(better, e, energy)
    return gamma, energy
