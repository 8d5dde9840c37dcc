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
from functools import cache
from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

from .curves import (
    interpolate_curve,
    inverse_srvf,
    srvf,
    srvf_sq_distance,
    uniform_grid,
    warp_curve,
    warp_srvf,
)
from .rotation import axis_rotation, check_rotation_mode, optimal_rotation
from .warp_refinement import gauss_newton_torch

try:  # numba is optional: without it the torch backend is used everywhere
    import numba

    from .warp_refinement import _nb_gauss_newton

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
                modes: int = 4, dtype: torch.dtype = torch.float64,
                device: torch.device | str = "cpu") -> Tensor:
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
    """Discrete energy ``||q1 - O warp_srvf(q2, gamma)||^2``. ``(B,M,d),(B,M,d),(B,M+1),(B,d,d) -> (B,)``."""
    q2w = warp_srvf(q2, gamma)
    if rotation is not None:
        q2w = q2w @ rotation.transpose(-1, -2)
    return srvf_sq_distance(q1, q2w)


# ----------------------------------------------------------------------------- DP lattice


@cache
def neighbourhood_steps(n: int) -> tuple[tuple[int, int], ...]:
    """All coprime steps ``(a, b)`` with ``1 <= a, b <= n`` (``n = 6``: the 23 steps of the reference)."""
    if n < 1:
        raise ValueError(f"neighbourhood must be >= 1, got {n}")
    steps = [(a, b) for a in range(1, n + 1) for b in range(1, n + 1) if math.gcd(a, b) == 1]
    # (1, 1) first: on exact ties the DP keeps the first step, which favours the identity
    return tuple(sorted(steps, key=lambda ab: (ab != (1, 1), max(ab), ab)))


def _reachable_band(M: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Columns ``[lo_i, hi_i]`` of lattice nodes on some path (0,0) -> (M,M) with slopes in [1/n, n]."""
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

    @numba.njit(cache=True, boundscheck=False)
    def _nb_tables(beta2t: np.ndarray, A: np.ndarray, Bs: np.ndarray, off: np.ndarray,
                   QW: np.ndarray, SS: np.ndarray) -> None:
        """Edge tables of one pair. ``beta2t (d, M+1)`` (transposed so loops over columns vectorise).

        ``QW[off_s + r, c, l] = 2/M`` times the warped SRVF of sub-segment ``r`` of an edge of step ``s``
        starting at column ``l``; ``SS[s, l] = 1/M sum_r |v_r|`` (its squared norm).
        """
        d, M1 = beta2t.shape
        M = M1 - 1
        S = A.shape[0]
        P0 = np.empty((d, M1))
        P1 = np.empty((d, M1))
        nv = np.empty(M1)
        for s in range(S):
            a = A[s]
            b = Bs[s]
            L = M1 - b
            for t in range(L):
                SS[s, t] = 0.0
            for c in range(d):
                for t in range(L):
                    P0[c, t] = beta2t[c, t]
            for r in range(a):
                # node r+1 of the edge sits at column l + f + fr (f, fr independent of l)
                f = ((r + 1) * b) // a
                fr = (((r + 1) * b) % a) / a
                if f >= M:  # only the last column: clamp like curves.interpolate_curve
                    f = M - 1
                    fr = 1.0
                for c in range(d):
                    for t in range(L):
                        if t + f < M:
                            P1[c, t] = beta2t[c, t + f] + fr * (beta2t[c, t + f + 1] - beta2t[c, t + f])
                        else:
                            P1[c, t] = beta2t[c, M]
                for t in range(L):
                    nv[t] = 0.0
                for c in range(d):
                    for t in range(L):
                        dv = (P1[c, t] - P0[c, t]) * M
                        P0[c, t] = dv
                        nv[t] += dv * dv
                for t in range(L):
                    n1 = math.sqrt(nv[t])
                    SS[s, t] += n1 / M
                    nv[t] = 2.0 / (M * math.sqrt(n1)) if n1 > 0 else 0.0
                for c in range(d):
                    row = QW[off[s] + r, c]
                    for t in range(L):
                        row[t] = P0[c, t] * nv[t]
                        P0[c, t] = P1[c, t]

    @numba.njit(cache=True, boundscheck=False)
    def _nb_make_tables(beta2: np.ndarray, A: np.ndarray,
                        Bs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Edge tables ``(QW, SS, off)`` of the moving curve ``beta2 (M+1, d)`` (see ``_nb_tables``)."""
        M = beta2.shape[0] - 1
        d = beta2.shape[1]
        S = A.shape[0]
        off = np.zeros(S + 1, np.int64)
        for s in range(S):
            off[s + 1] = off[s] + A[s]
        QW = np.zeros((off[S], d, M + 1))
        SS = np.zeros((S, M + 1))
        _nb_tables(np.ascontiguousarray(beta2.T), A, Bs, off, QW, SS)
        return QW, SS, off

    @numba.njit(cache=True, boundscheck=False)
    def _nb_dp_one(q1: np.ndarray, beta2: np.ndarray, A: np.ndarray, Bs: np.ndarray, lo: np.ndarray,
                   hi: np.ndarray, gamma: np.ndarray) -> float:
        """DP for one pair; writes ``gamma (M+1,)`` and returns the energy (inf if the band has no path)."""
        QW, SS, off = _nb_make_tables(beta2, A, Bs)
        return _nb_dp_tab(q1, QW, SS, off, A, Bs, lo, hi, gamma)

    @numba.njit(cache=True, boundscheck=False)
    def _nb_dp_tab(q1: np.ndarray, QW: np.ndarray, SS: np.ndarray, off: np.ndarray, A: np.ndarray,
                   Bs: np.ndarray, lo: np.ndarray, hi: np.ndarray, gamma: np.ndarray) -> float:
        """The DP proper, given the moving curve's edge tables; rows ``i`` restricted to ``[lo_i, hi_i]``."""
        M, d = q1.shape
        S = A.shape[0]
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
                nj = jh + 1 - j0
                # contiguous views indexed from 0 so the inner loops vectorise (no wraparound checks)
                tv = tmp[:nj]
                sv = SS[s, j0 - b : jh + 1 - b]
                for t in range(nj):
                    tv[t] = sv[t]
                if d == 3:  # the common case: one pass per sub-segment (same arithmetic order)
                    for r in range(a):
                        w0 = q1[k + r, 0]
                        w1 = q1[k + r, 1]
                        w2 = q1[k + r, 2]
                        r0 = QW[off[s] + r, 0, j0 - b : jh + 1 - b]
                        r1 = QW[off[s] + r, 1, j0 - b : jh + 1 - b]
                        r2 = QW[off[s] + r, 2, j0 - b : jh + 1 - b]
                        for t in range(nj):
                            tv[t] = tv[t] - w0 * r0[t] - w1 * r1[t] - w2 * r2[t]
                else:
                    for r in range(a):
                        for c in range(d):
                            w = q1[k + r, c]
                            rv = QW[off[s] + r, c, j0 - b : jh + 1 - b]
                            for t in range(nj):
                                tv[t] -= w * rv[t]
                ev = E[k, j0 - b : jh + 1 - b]
                ei = E[i, j0 : jh + 1]
                av = arg[i, j0 : jh + 1]
                for t in range(nj):
                    cand = ev[t] + tv[t]
                    if cand < ei[t]:
                        ei[t] = cand
                        av[t] = s
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

    @numba.njit(cache=True, boundscheck=False)
    def _nb_inverse_srvf(q: np.ndarray, beta: np.ndarray) -> None:
        """``beta (M+1, d)`` from ``q (M, d)``, starting at the origin (as curves.inverse_srvf)."""
        M, d = q.shape
        for c in range(d):
            beta[0, c] = 0.0
        for m in range(M):
            nq = 0.0
            for c in range(d):
                nq += q[m, c] * q[m, c]
            sp = math.sqrt(nq) / M
            for c in range(d):
                beta[m + 1, c] = beta[m, c] + q[m, c] * sp

    @numba.njit(cache=True, boundscheck=False)
    def _nb_srvf(beta: np.ndarray, q: np.ndarray) -> None:
        """``q (T-1, d)`` of ``beta (T, d)`` (as curves.srvf)."""
        M = beta.shape[0] - 1
        d = beta.shape[1]
        for m in range(M):
            nv = 0.0
            for c in range(d):
                v = (beta[m + 1, c] - beta[m, c]) * M
                q[m, c] = v
                nv += v * v
            sc = 1.0 / math.sqrt(math.sqrt(nv)) if nv > 0 else 0.0
            for c in range(d):
                q[m, c] *= sc

    @numba.njit(cache=True, boundscheck=False)
    def _nb_interp(beta: np.ndarray, svals: np.ndarray, out: np.ndarray) -> None:
        """``beta (T, d)`` at parameters ``svals (n,)`` (as curves.interpolate_curve)."""
        T, d = beta.shape
        for m in range(svals.shape[0]):
            x = min(max(svals[m], 0.0), 1.0) * (T - 1)
            fl = min((math.floor(x)), T - 2)
            fr = x - fl
            for c in range(d):
                out[m, c] = beta[fl, c] + fr * (beta[fl + 1, c] - beta[fl, c])

    @numba.njit(cache=True, boundscheck=False)
    def _nb_resample(beta: np.ndarray, T: int) -> np.ndarray:
        out = np.empty((T, beta.shape[1]))
        _nb_interp(beta, np.linspace(0.0, 1.0, T), out)
        return out

    @numba.njit(cache=True, boundscheck=False)
    def _nb_energy(q1: np.ndarray, beta2: np.ndarray, gamma: np.ndarray, O: np.ndarray) -> float:
        """``||q1 - O warp_srvf(q2, gamma)||^2`` with ``beta2`` the curve of ``q2``."""
        M, d = q1.shape
        bw = np.empty((M + 1, d))
        _nb_interp(beta2, gamma, bw)
        qw = np.empty((M, d))
        _nb_srvf(bw, qw)
        e = 0.0
        for m in range(M):
            for c in range(d):
                x = q1[m, c]
                for c2 in range(d):
                    x -= O[c, c2] * qw[m, c2]
                e += x * x
        return e / M

    @numba.njit(cache=True, boundscheck=False)
    def _nb_kabsch3(A: np.ndarray) -> np.ndarray:
        """Proper rotation ``O (3, 3)`` maximising ``tr(O A^T)`` (Horn's quaternion method: the top
        eigenvector of a symmetric 4 x 4 matrix by cyclic Jacobi). The same optimum as the SVD route,
        without a LAPACK call and its copies."""
        N = np.empty((4, 4))
        sxx, sxy, sxz = A[0, 0], A[1, 0], A[2, 0]
        syx, syy, syz = A[0, 1], A[1, 1], A[2, 1]
        szx, szy, szz = A[0, 2], A[1, 2], A[2, 2]
        N[0, 0], N[0, 1], N[0, 2], N[0, 3] = sxx + syy + szz, syz - szy, szx - sxz, sxy - syx
        N[1, 1], N[1, 2], N[1, 3] = sxx - syy - szz, sxy + syx, szx + sxz
        N[2, 2], N[2, 3] = -sxx + syy - szz, syz + szy
        N[3, 3] = -sxx - syy + szz
        for i in range(4):
            for j in range(i):
                N[i, j] = N[j, i]
        V = np.eye(4)
        for _ in range(50):
            off = 0.0
            scale = 0.0
            for i in range(4):
                scale += N[i, i] * N[i, i]
                for j in range(i + 1, 4):
                    off += N[i, j] * N[i, j]
            if off <= 1e-32 * scale or off == 0.0:
                break
            for p in range(3):
                for q in range(p + 1, 4):
                    apq = N[p, q]
                    if apq == 0.0:
                        continue
                    theta = (N[q, q] - N[p, p]) / (2.0 * apq)
                    t = (1.0 if theta >= 0 else -1.0) / (abs(theta) + math.sqrt(theta * theta + 1.0))
                    c = 1.0 / math.sqrt(t * t + 1.0)
                    sn = t * c
                    for k in range(4):  # N <- N J (columns p, q)
                        akp = N[k, p]
                        akq = N[k, q]
                        N[k, p] = c * akp - sn * akq
                        N[k, q] = sn * akp + c * akq
                    for k in range(4):  # N <- J^T N (rows p, q)
                        apk = N[p, k]
                        aqk = N[q, k]
                        N[p, k] = c * apk - sn * aqk
                        N[q, k] = sn * apk + c * aqk
                    for k in range(4):
                        vkp = V[k, p]
                        vkq = V[k, q]
                        V[k, p] = c * vkp - sn * vkq
                        V[k, q] = sn * vkp + c * vkq
        best = 0
        for i in range(1, 4):
            if N[i, i] > N[best, best]:
                best = i
        w, x, y, z = V[0, best], V[1, best], V[2, best], V[3, best]
        nq = w * w + x * x + y * y + z * z
        w, x, y, z = w / math.sqrt(nq), x / math.sqrt(nq), y / math.sqrt(nq), z / math.sqrt(nq)
        O = np.empty((3, 3))
        O[0, 0] = w * w + x * x - y * y - z * z
        O[0, 1] = 2.0 * (x * y - w * z)
        O[0, 2] = 2.0 * (x * z + w * y)
        O[1, 0] = 2.0 * (x * y + w * z)
        O[1, 1] = w * w - x * x + y * y - z * z
        O[1, 2] = 2.0 * (y * z - w * x)
        O[2, 0] = 2.0 * (x * z - w * y)
        O[2, 1] = 2.0 * (y * z + w * x)
        O[2, 2] = w * w - x * x - y * y + z * z
        return O

    @numba.njit(cache=True, boundscheck=False)
    def _nb_rotation(q1: np.ndarray, beta2: np.ndarray, gamma: np.ndarray, mode: int,
                     up: np.ndarray) -> np.ndarray:
        """Optimal rotation (1 vertical, 2 so3) of ``warp_srvf(q2, gamma)`` onto ``q1`` (see rotation.py)."""
        M, d = q1.shape
        bw = np.empty((M + 1, d))
        _nb_interp(beta2, gamma, bw)
        qw = np.empty((M, d))
        _nb_srvf(bw, qw)
        A = np.zeros((d, d))
        for m in range(M):
            for i in range(d):
                for j in range(d):
                    A[i, j] += q1[m, i] * qw[m, j]
        for i in range(d):
            for j in range(d):
                A[i, j] /= M
        if mode == 2 and d == 3:
            return _nb_kabsch3(A)
        if mode == 2:
            U, _, Vt = np.linalg.svd(A)
            O = U @ Vt
            if np.linalg.det(O) < 0:
                U[:, d - 1] = -U[:, d - 1]
                O = U @ Vt
            return O
        u = up / math.sqrt((up * up).sum())
        K = np.zeros((3, 3))
        K[0, 1], K[0, 2], K[1, 2] = -u[2], u[1], -u[0]
        K[1, 0], K[2, 0], K[2, 1] = u[2], -u[1], u[0]
        uu = np.outer(u, u)
        c = A[0, 0] + A[1, 1] + A[2, 2] - u @ A @ u
        sn = (K * A).sum()
        th = math.atan2(sn, c)
        return uu + math.cos(th) * (np.eye(3) - uu) + math.sin(th) * K

    @numba.njit(cache=True, boundscheck=False)
    def _nb_band(center: np.ndarray, M: int, n: int, w: int, lo: np.ndarray, hi: np.ndarray) -> None:
        """Same band as ``_band_around`` for one warp ``center (M+1,)``."""
        for i in range(M + 1):
            g0 = center[max(i - w, 0)] * M
            g1 = center[min(i + w, M)] * M
            rlo = max(-(-i // n), M - n * (M - i))
            rhi = min(n * i, M - (-(-(M - i) // n)))
            lo[i] = max((math.floor(g0 + 1e-9)) - w, rlo)
            hi[i] = max(min((math.ceil(g1 - 1e-9)) + w, rhi), lo[i])

    @numba.njit(cache=True, boundscheck=False)
    def _nb_inverse_from(q: np.ndarray) -> np.ndarray:
        beta = np.empty((q.shape[0] + 1, q.shape[1]))
        _nb_inverse_srvf(q, beta)
        return beta

    @numba.njit(cache=True, boundscheck=False)
    def _nb_dp_search(q1: np.ndarray, QW: np.ndarray, SS: np.ndarray, off: np.ndarray, A: np.ndarray,
                      Bs: np.ndarray, n: int, band: int, init: np.ndarray, gamma: np.ndarray) -> float:
        """Full DP (``band < 0`` or no ``init``) or DP in a band around ``init (M+1,)``."""
        M = q1.shape[0]
        lo = np.empty(M + 1, np.int64)
        hi = np.empty(M + 1, np.int64)
        if band < 0 or init.shape[0] != M + 1:
            for i in range(M + 1):
                lo[i] = max(-(-i // n), M - n * (M - i))
                hi[i] = min(n * i, M - (-(-(M - i) // n)))
        else:
            _nb_band(init, M, n, band, lo, hi)
        return _nb_dp_tab(q1, QW, SS, off, A, Bs, lo, hi, gamma)

    @numba.njit(cache=True, boundscheck=False)
    def _nb_alternate(q1: np.ndarray, beta2: np.ndarray, QW: np.ndarray, SS: np.ndarray, off: np.ndarray,
                      A: np.ndarray, Bs: np.ndarray, n: int, band: int, mode: int, up: np.ndarray, max_iters: int,
                      tol: float, refine: int, O0: np.ndarray, init: np.ndarray, gamma: np.ndarray,
                      O: np.ndarray) -> float:
        """Alternate DP warps and optimal rotations on one grid, from rotation ``O0`` (and warp ``init``).

        Writes the best ``gamma`` and ``O`` seen and returns their energy. The DP runs on ``(q1 O, q2)``
        (the same energy as ``(q1, O q2)``) so the tables of ``q2`` (``_nb_make_tables``) are built once
        per grid and shared by all rounds and starts.
        """
        M, d = q1.shape
        eye = np.eye(d)
        best = np.inf
        Ocur = O0.copy()
        prev = init
        g = np.empty(M + 1)
        q1r = np.empty((M, d))
        last = np.inf
        for _ in range(max(max_iters, 1)):
            for m in range(M):
                for c in range(d):
                    x = 0.0
                    for c2 in range(d):
                        x += q1[m, c2] * Ocur[c2, c]
                    q1r[m, c] = x
            e = _nb_dp_search(q1r, QW, SS, off, A, Bs, n, band, prev, g)
            if refine > 0:
                if prev.shape[0] == M + 1 and _nb_energy(q1r, beta2, prev, eye) < e:
                    g[:] = prev  # the band search lost to the warp it started from
                _nb_gauss_newton(q1r, beta2, g, refine)
                e = _nb_energy(q1r, beta2, g, eye)
            if e < best:
                best = e
                gamma[:] = g
                O[:, :] = Ocur
            if mode == 0:
                break
            Onew = _nb_rotation(q1, beta2, g, mode, up)
            e2 = _nb_energy(q1, beta2, g, Onew)
            if e2 < best:
                best = e2
                gamma[:] = g
                O[:, :] = Onew
            if not last - e2 > tol * e2:  # relative decrease (last = inf on the first round)
                break
            last = e2
            Ocur = Onew
            prev = g.copy()
        return best

    @numba.njit(cache=True, boundscheck=False)
    def _nb_start_rotation(O: np.ndarray, mode: int, up: np.ndarray, k: int, starts: int) -> np.ndarray:
        """Start ``k`` of ``starts``: ``O`` itself, the identity, then ``O`` turned about ``up`` (vertical)
        or by a flip of two axes (so3: half-turns about the coordinate axes)."""
        d = O.shape[0]
        if k == 0:
            return O.copy()
        if k == 1:  # no rotation: the DP runs first (Kabsch at the identity warp can be biased)
            return np.eye(d)
        k -= 1
        starts -= 1
        if mode == 1:
            th = 2.0 * math.pi * k / starts
            u = up / math.sqrt((up * up).sum())
            K = np.zeros((3, 3))
            K[0, 1], K[0, 2], K[1, 2] = -u[2], u[1], -u[0]
            K[1, 0], K[2, 0], K[2, 1] = u[2], -u[1], u[0]
            uu = np.outer(u, u)
            return O @ (uu + math.cos(th) * (np.eye(3) - uu) + math.sin(th) * K)
        F = np.eye(d)
        i = (k - 1) % d
        F[i, i] = -1.0
        F[(i + 1) % d, (i + 1) % d] = -1.0
        return O @ F

    @numba.njit(cache=True, boundscheck=False)
    def _nb_register_one(q1: np.ndarray, q2: np.ndarray, A: np.ndarray, Bs: np.ndarray, Af: np.ndarray,
                         Bf: np.ndarray, cfg: np.ndarray, up: np.ndarray, tol: float, gamma: np.ndarray,
                         O: np.ndarray) -> tuple[float, float]:
        """Coarse-to-fine registration of one pair; returns (energy, identity energy).

        ``cfg = [n, band, coarse, mode, max_iters, refine, starts, n_fine, fine_iters]``. The coarsest grid
        (at most ``coarse`` segments, full DP with steps ``A, Bs``) runs the rotation / warp alternation
        from ``starts`` initial rotations for up to ``max_iters`` rounds; each finer grid (up to 3 times
        as fine) continues from the best for up to ``fine_iters`` rounds in a band (steps ``Af, Bf``);
        the local refinement runs on the finest grid only. The identity (warp, rotation) is the first
        candidate, so the energy never exceeds the identity's.
        """
        n, band, coarse, mode, max_iters, refine, starts, nf, fine_iters = (
            cfg[0], cfg[1], cfg[2], cfg[3], cfg[4], cfg[5], cfg[6], cfg[7], cfg[8])
        M, d = q1.shape
        beta1 = _nb_inverse_from(q1)
        beta2 = _nb_inverse_from(q2)
        eye = np.eye(d)
        ident = np.linspace(0.0, 1.0, M + 1)
        e_before = _nb_energy(q1, beta2, ident, eye)
        best = e_before
        gamma[:] = ident
        O[:, :] = eye
        sizes = np.empty(64, np.int64)
        L = 1
        sizes[0] = M
        if band >= 0:
            while sizes[L - 1] > coarse and L < 64:
                cur = sizes[L - 1]
                sizes[L] = min(max(coarse // 2, -(-cur // 3)), cur - 1)
                L += 1
        Ocur = eye.copy() if mode == 0 else _nb_rotation(q1, beta2, ident, mode, up)
        gcur = np.empty(0)
        for lev in range(L - 1, -1, -1):
            ML = sizes[lev]
            if ML == M:
                q1L = q1
                b2L = beta2
            else:
                q1L = np.empty((ML, d))
                _nb_srvf(_nb_resample(beta1, ML + 1), q1L)
                b2L = _nb_resample(beta2, ML + 1)
            init = np.empty(0)
            if gcur.shape[0] > 0:
                init = np.empty(ML + 1)
                _nb_interp(gcur.reshape(-1, 1), np.linspace(0.0, 1.0, ML + 1), init.reshape(-1, 1))
            gL = np.empty(ML + 1)
            OL = np.empty((d, d))
            top = lev == L - 1
            nst = starts if (top and mode != 0) else 1
            eL = np.inf
            gk = np.empty(ML + 1)
            Ok = np.empty((d, d))
            AL = A if top else Af
            BL = Bs if top else Bf
            QW, SS, off = _nb_make_tables(b2L, AL, BL)
            for k in range(max(nst, 1)):
                O0 = _nb_start_rotation(Ocur, mode, up, k, nst)
                ek = _nb_alternate(q1L, b2L, QW, SS, off, AL, BL, n if top else nf, band, mode, up,
                                   max_iters if top else fine_iters, tol, refine if lev == 0 else 0, O0, init,
                                   gk, Ok)
                if ek < eL:
                    eL = ek
                    gL[:] = gk
                    OL[:, :] = Ok
            gcur = gL
            Ocur = OL
            if lev == 0 and eL < best:
                best = eL
                gamma[:] = gL
                O[:, :] = OL
        return best, e_before

    @numba.njit(cache=True, parallel=True, boundscheck=False)
    def _nb_register_batch(q1: np.ndarray, q2: np.ndarray, A: np.ndarray, Bs: np.ndarray, Af: np.ndarray,
                           Bf: np.ndarray, cfg: np.ndarray, up: np.ndarray,
                           tol: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        Bn, M, d = q1.shape
        energy = np.empty(Bn)
        before = np.empty(Bn)
        gamma = np.empty((Bn, M + 1))
        O = np.empty((Bn, d, d))
        for p in numba.prange(Bn):
            energy[p], before[p] = _nb_register_one(q1[p], q2[p], A, Bs, Af, Bf, cfg, up, tol, gamma[p], O[p])
        return energy, before, gamma, O

    @numba.njit(cache=True, boundscheck=False)
    def _nb_register_serial(q1: np.ndarray, q2: np.ndarray, A: np.ndarray, Bs: np.ndarray, Af: np.ndarray,
                            Bf: np.ndarray, cfg: np.ndarray, up: np.ndarray,
                            tol: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        Bn, M, d = q1.shape
        energy = np.empty(Bn)
        before = np.empty(Bn)
        gamma = np.empty((Bn, M + 1))
        O = np.empty((Bn, d, d))
        for p in range(Bn):
            energy[p], before[p] = _nb_register_one(q1[p], q2[p], A, Bs, Af, Bf, cfg, up, tol, gamma[p], O[p])
        return energy, before, gamma, O

    @numba.njit(cache=True, boundscheck=False)
    def _nb_curves_one(mov: np.ndarray, ref: np.ndarray, srvf_input: bool, A: np.ndarray, Bs: np.ndarray,
                       Af: np.ndarray, Bf: np.ndarray, cfg: np.ndarray, up: np.ndarray, tol: float,
                       gamma: np.ndarray, O: np.ndarray, registered: np.ndarray,
                       q_reg: np.ndarray) -> tuple[float, float]:
        """The whole of ``register_curves`` for one pair without gradients: input prep (inverse SRVF,
        resampling, SRVFs), ``_nb_register_one`` and the registered curve; returns (energy, identity energy).

        ``mov (T2, d)``, ``ref (T, d)`` are curves (SRVFs ``(T2-1, d)``, ``(T-1, d)`` if ``srvf_input``).
        """
        if srvf_input:
            beta_r = _nb_inverse_from(ref)
            beta_m = _nb_inverse_from(mov)
        else:
            beta_r = ref
            beta_m = mov
        T, d = beta_r.shape
        if beta_m.shape[0] != T:
            beta_m = _nb_resample(beta_m, T)
        q_ref = np.empty((T - 1, d))
        q_mov = np.empty((T - 1, d))
        _nb_srvf(beta_r, q_ref)
        _nb_srvf(beta_m, q_mov)
        _, before = _nb_register_one(q_ref, q_mov, A, Bs, Af, Bf, cfg, up, tol, gamma, O)
        bw = np.empty((T, d))
        _nb_interp(beta_m, gamma, bw)
        for m in range(T):
            for c in range(d):
                x = 0.0
                for c2 in range(d):
                    x += bw[m, c2] * O[c, c2]
                registered[m, c] = x
        for m in range(T - 1, -1, -1):
            for c in range(d):
                registered[m, c] = registered[m, c] - registered[0, c] + beta_r[0, c]
        _nb_srvf(registered, q_reg)
        e = 0.0
        for m in range(T - 1):
            for c in range(d):
                x = q_ref[m, c] - q_reg[m, c]
                e += x * x
        return e / (T - 1), before

    @numba.njit(cache=True, parallel=True, boundscheck=False)
    def _nb_curves_batch(mov: np.ndarray, ref: np.ndarray, srvf_input: bool, A: np.ndarray, Bs: np.ndarray,
                         Af: np.ndarray, Bf: np.ndarray, cfg: np.ndarray, up: np.ndarray, tol: float,
                         chunks: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                                  np.ndarray]:
        """``_nb_curves_one`` over a batch, split into ``chunks`` interleaved chunks run in parallel."""
        Bn = ref.shape[0]
        T = ref.shape[1] + (1 if srvf_input else 0)
        d = ref.shape[2]
        energy = np.empty(Bn)
        before = np.empty(Bn)
        gamma = np.empty((Bn, T))
        O = np.empty((Bn, d, d))
        registered = np.empty((Bn, T, d))
        q_reg = np.empty((Bn, T - 1, d))
        nch = max(min(chunks, Bn), 1)
        for ch in numba.prange(nch):
            for p in range(ch, Bn, nch):  # interleaved: neighbouring pairs often cost alike
                energy[p], before[p] = _nb_curves_one(mov[p], ref[p], srvf_input, A, Bs, Af, Bf, cfg, up, tol,
                                                      gamma[p], O[p], registered[p], q_reg[p])
        return energy, before, gamma, O, registered, q_reg

    @numba.njit(cache=True, parallel=True, boundscheck=False)
    def _nb_dp_batch(q1: np.ndarray, beta2: np.ndarray, A: np.ndarray, Bs: np.ndarray, lo: np.ndarray,
                     hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        Bn, M, _ = q1.shape
        energy = np.empty(Bn)
        gamma = np.empty((Bn, M + 1))
        for p in numba.prange(Bn):
            energy[p] = _nb_dp_one(q1[p], beta2[p], A, Bs, lo[p], hi[p], gamma[p])
        return energy, gamma

    @numba.njit(cache=True, boundscheck=False)
    def _nb_dp_serial(q1: np.ndarray, beta2: np.ndarray, A: np.ndarray, Bs: np.ndarray, lo: np.ndarray,
                      hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        Bn, M, _ = q1.shape
        energy = np.empty(Bn)
        gamma = np.empty((Bn, M + 1))
        for p in range(Bn):
            energy[p] = _nb_dp_one(q1[p], beta2[p], A, Bs, lo[p], hi[p], gamma[p])
        return energy, gamma


# below this many pairs a parallel launch costs more than it saves (and stalls on a busy machine)
PARALLEL_MIN_PAIRS = 8


def _dp_numba(q1: Tensor, q2: Tensor, n: int, lo: np.ndarray, hi: np.ndarray) -> tuple[Tensor, Tensor]:
    A, Bs = _step_arrays(n)
    q1n = q1.detach().to("cpu", torch.float64).contiguous().numpy()
    beta2 = inverse_srvf(q2.detach().to("cpu", torch.float64)).contiguous().numpy()
    kernel = _nb_dp_batch if len(q1n) >= PARALLEL_MIN_PAIRS and numba.get_num_threads() > 1 else _nb_dp_serial
    energy, gamma = kernel(q1n, beta2, A, Bs, lo, hi)
    return torch.from_numpy(energy), torch.from_numpy(gamma)


# ----------------------------------------------------------------------------- torch backend


def _shift_right(x: Tensor, b: int, fill: Tensor) -> Tensor:
    """``y[:, j] = x[:, j - b]`` (``fill`` where ``j < b``). ``(B, n) -> (B, n)``."""
    n = x.shape[1]
    if b >= n:
        return fill.expand_as(x)
    return torch.cat([fill.expand(x.shape[0], b), x[:, : n - b]], 1)


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
            qw = torch.where(nv.unsqueeze(-1) > 0, v / nv.clamp_min(1e-300).sqrt().unsqueeze(-1), 0)
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


# ----------------------------------------------------------------------------- DP driver


class DPWarp(NamedTuple):
    """Result of :func:`dp_warp`: ``gamma (B, M+1)`` and ``energy (B,) = ||q1 - warp_srvf(q2, gamma)||^2``."""

    gamma: Tensor
    energy: Tensor


class CurveRegistration(NamedTuple):
    """Result of :func:`register_curves` (``B`` pairs, ``T`` points, dimension ``d``).

    * ``gamma (B, T)``: warp of the moving curve, ``registered = O moving(gamma(s))``.
    * ``rotation (B, d, d)``: ``O``, acting on row vectors as ``x @ O.T``.
    * ``distance (B,)``: ``sqrt(energy)``, differentiable in the inputs given ``gamma`` and ``O``.
    * ``energy (B,)``: ``||q_ref - O warp_srvf(q_mov, gamma)||^2`` (no scale normalisation).
    * ``energy_before (B,)``: the same with the identity warp and rotation.
    * ``registered (B, T, d)``: the moving curve rotated, reparameterised and translated to start at
      the reference's first point; ``q_registered (B, T-1, d)`` its SRVF.
    """

    gamma: Tensor
    rotation: Tensor
    distance: Tensor
    energy: Tensor
    energy_before: Tensor
    registered: Tensor
    q_registered: Tensor


def _resample_srvf(q: Tensor, M: int) -> Tensor:
    """SRVF of the curve of ``q`` resampled (linearly in the parameter) to ``M`` segments."""
    if q.shape[-2] == M:
        return q
    return srvf(_resample_curve(inverse_srvf(q), M + 1))


def _resample_curve(beta: Tensor, T: int) -> Tensor:
    if beta.shape[-2] == T:
        return beta
    return interpolate_curve(beta, uniform_grid(T, beta).expand(*beta.shape[:-2], T))


def _pick_backend(backend: str, x: Tensor) -> str:
    if backend not in ("auto", "numba", "torch"):
        raise ValueError(f"unknown backend {backend!r}; expected 'auto', 'numba' or 'torch'")
    if backend == "auto":
        return "numba" if HAVE_NUMBA and x.device.type == "cpu" else "torch"
    if backend == "numba" and not HAVE_NUMBA:
        raise ValueError("backend='numba' needs the numba package")
    return backend


def _run_dp(q1: Tensor, q2: Tensor, n: int, lo: np.ndarray, hi: np.ndarray,
            backend: str) -> tuple[Tensor, Tensor]:
    """One DP over the lattice restricted to columns ``[lo, hi] (B, M+1)`` per row. ``-> energy, gamma``."""
    if backend == "numba":
        energy, gamma = _dp_numba(q1, q2, n, lo, hi)
        return energy.to(q1.device, q1.dtype), gamma.to(q1.device, q1.dtype)
    return _dp_torch(q1, q2, n, lo, hi)


def _dp_search(q1: Tensor, q2: Tensor, n: int, band: int | None, init: Tensor | None,
               backend: str) -> tuple[Tensor, Tensor]:
    """Full DP (``band=None`` or no ``init``) or DP in a band around ``init (B, M+1)``. ``-> gamma, E``."""
    B, M, _ = q1.shape
    if band is None or init is None:
        lo, hi = _reachable_band(M, n)
        lo, hi = np.tile(lo, (B, 1)), np.tile(hi, (B, 1))
    else:
        lo, hi = _band_around(init, M, n, band)
    energy, gamma = _run_dp(q1, q2, n, lo, hi, backend)
    return gamma, energy


def _grid_sizes(M: int, band: int | None, coarse: int | None) -> list[int]:
    """Grids of the coarse-to-fine search, finest first (as in ``_nb_register_one``)."""
    sizes = [M]
    if band is not None and coarse is not None:
        while sizes[-1] > coarse and len(sizes) < 64:
            cur = sizes[-1]
            sizes.append(min(max(coarse // 2, -(-cur // 3)), cur - 1))
    return sizes


class _Settings(NamedTuple):
    """Search settings shared by both backends (see :func:`register_curves`)."""

    neighbourhood: int
    band: int | None
    coarse: int | None
    band_neighbourhood: int
    max_iters: int
    fine_iters: int
    tol: float
    refine: int
    starts: int


_MODES = {"none": 0, "vertical": 1, "so3": 2}


def _start_rotation(O: Tensor, rotation: str, up: Tensor, k: int, starts: int) -> Tensor:
    """Torch twin of ``_nb_start_rotation``."""
    d = O.shape[-1]
    if k == 0:
        return O.clone()
    if k == 1:
        return torch.eye(d, dtype=O.dtype, device=O.device).expand_as(O).clone()
    k, starts = k - 1, starts - 1
    if rotation == "vertical":
        th = torch.full(O.shape[:1], 2.0 * math.pi * k / starts, dtype=O.dtype, device=O.device)
        return O @ axis_rotation(up.to(O.dtype), th)
    F = torch.eye(d, dtype=O.dtype, device=O.device)
    i = (k - 1) % d
    F[i, i] = -1.0
    F[(i + 1) % d, (i + 1) % d] = -1.0
    return O @ F


def _alternate_torch(q1: Tensor, q2: Tensor, n: int, band: int | None, rotation: str, up: Tensor,
                     max_iters: int, tol: float, refine: int, O0: Tensor,
                     init: Tensor | None) -> tuple[Tensor, Tensor, Tensor]:
    """Batched torch twin of ``_nb_alternate``. ``-> energy (B,), gamma (B, M+1), O (B, d, d)``."""
    B, M, d = q1.shape
    beta2 = inverse_srvf(q2)
    best = torch.full((B,), float("inf"), dtype=q1.dtype, device=q1.device)
    gamma = identity_warp(B, M + 1, q1)
    O = O0.clone()
    Ocur, prev = O0, init
    last = torch.full_like(best, float("inf"))
    active = torch.ones(B, dtype=torch.bool, device=q1.device)

    def keep(e: Tensor, g: Tensor, R: Tensor) -> None:
        nonlocal best, gamma, O
        better = active & (e < best)
        best = torch.where(better, e, best)
        gamma = torch.where(better[:, None], g, gamma)
        O = torch.where(better[:, None, None], R, O)

    for _ in range(max(max_iters, 1)):
        q1r = q1 @ Ocur
        g, e = _dp_search(q1r, q2, n, band, prev, "torch")
        if refine > 0:
            if prev is not None:
                g = torch.where((warp_energy(q1r, q2, prev) < e)[:, None], prev, g)
            g = gauss_newton_torch(q1r, beta2, g, refine)
            e = warp_energy(q1r, q2, g)
        keep(e, g, Ocur)
        if rotation == "none":
            break
        Onew = optimal_rotation(q1, warp_srvf(q2, g), rotation, up)
        e2 = warp_energy(q1, q2, g, Onew)
        keep(e2, g, Onew)
        active = active & (last - e2 > tol * e2)
        if not bool(active.any()):
            break
        last = torch.where(active, e2, last)
        Ocur = torch.where(active[:, None, None], Onew, Ocur)
        prev = g if prev is None else torch.where(active[:, None], g, prev)
    return best, gamma, O


def _register_torch(q1: Tensor, q2: Tensor, rotation: str, up: Tensor,
                    cfg: _Settings) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Batched torch twin of ``_nb_register_one``. ``-> energy, energy_before, gamma, O``."""
    B, M, d = q1.shape
    ident = identity_warp(B, M + 1, q1)
    eye = torch.eye(d, dtype=q1.dtype, device=q1.device).expand(B, d, d).clone()
    before = warp_energy(q1, q2, ident)
    beta1, beta2 = inverse_srvf(q1), inverse_srvf(q2)
    Ocur = eye if rotation == "none" else optimal_rotation(q1, q2, rotation, up)
    gcur: Tensor | None = None
    sizes = _grid_sizes(M, cfg.band, cfg.coarse)
    eL = before
    for lev in range(len(sizes) - 1, -1, -1):
        ML = sizes[lev]
        q1L = q1 if ML == M else srvf(_resample_curve(beta1, ML + 1))
        q2L = q2 if ML == M else srvf(_resample_curve(beta2, ML + 1))
        init = None if gcur is None else _resample_curve(gcur.unsqueeze(-1), ML + 1)[..., 0]
        top = lev == len(sizes) - 1
        nst = cfg.starts if (top and rotation != "none") else 1
        eL = torch.full((B,), float("inf"), dtype=q1.dtype, device=q1.device)
        gL, OL = identity_warp(B, ML + 1, q1), eye.clone()
        for k in range(max(nst, 1)):
            O0 = _start_rotation(Ocur, rotation, up, k, nst)
            ek, gk, Ok = _alternate_torch(q1L, q2L, cfg.neighbourhood if top else cfg.band_neighbourhood,
                                          cfg.band, rotation, up, cfg.max_iters if top else cfg.fine_iters,
                                          cfg.tol, cfg.refine if lev == 0 else 0, O0, init)
            better = ek < eL
            eL = torch.where(better, ek, eL)
            gL = torch.where(better[:, None], gk, gL)
            OL = torch.where(better[:, None, None], Ok, OL)
        gcur, Ocur = gL, OL
    better = eL < before
    energy = torch.where(better, eL, before)
    gamma = torch.where(better[:, None], gcur, ident)
    O = torch.where(better[:, None, None], Ocur, eye)
    return energy, before, gamma, O


def _register_numba(q1: Tensor, q2: Tensor, rotation: str, up: Tensor,
                    cfg: _Settings) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    A, Bs = _step_arrays(cfg.neighbourhood)
    Af, Bf = _step_arrays(cfg.band_neighbourhood)
    ints = np.array([cfg.neighbourhood, -1 if cfg.band is None else cfg.band,
                     1 << 30 if cfg.coarse is None else cfg.coarse, _MODES[rotation], cfg.max_iters,
                     cfg.refine, cfg.starts, cfg.band_neighbourhood, cfg.fine_iters], np.int64)
    q1n = q1.detach().to("cpu", torch.float64).contiguous().numpy()
    q2n = q2.detach().to("cpu", torch.float64).contiguous().numpy()
    upn = up.detach().to("cpu", torch.float64).contiguous().numpy()
    kernel = _nb_register_batch if len(q1n) >= PARALLEL_MIN_PAIRS and numba.get_num_threads() > 1 \
        else _nb_register_serial
    out = kernel(q1n, q2n, A, Bs, Af, Bf, ints, upn, float(cfg.tol))
    return tuple(torch.from_numpy(x).to(q1.device, q1.dtype) for x in out)  # type: ignore[return-value]


def _register_curves_numba(moving: Tensor, reference: Tensor, srvf_input: bool, rotation: str, up: Tensor,
                           cfg: _Settings) -> CurveRegistration:
    """``register_curves`` without gradients in one numba call (input prep and outputs included)."""
    A, Bs = _step_arrays(cfg.neighbourhood)
    Af, Bf = _step_arrays(cfg.band_neighbourhood)
    ints = np.array([cfg.neighbourhood, -1 if cfg.band is None else cfg.band,
                     1 << 30 if cfg.coarse is None else cfg.coarse, _MODES[rotation], cfg.max_iters,
                     cfg.refine, cfg.starts, cfg.band_neighbourhood, cfg.fine_iters], np.int64)
    mov = moving.detach().to("cpu", torch.float64).contiguous().numpy()
    ref = reference.detach().to("cpu", torch.float64).contiguous().numpy()
    upn = up.detach().to("cpu", torch.float64).contiguous().numpy()
    chunks = numba.get_num_threads() if len(ref) >= PARALLEL_MIN_PAIRS else 1
    energy, before, gamma, O, reg, q_reg = _nb_curves_batch(mov, ref, srvf_input, A, Bs, Af, Bf, ints, upn,
                                                            float(cfg.tol), chunks)
    distance = np.sqrt(np.maximum(energy, 0.0))
    dt, dev = reference.dtype, reference.device
    return CurveRegistration(*(torch.from_numpy(x).to(dev, dt)
                               for x in (gamma, O, distance, energy, before, reg, q_reg)))


def _check_inputs(moving: Tensor, reference: Tensor, min_points: int,
                  what: str) -> tuple[Tensor, Tensor, bool]:
    """Validate a pair of batched (or single) inputs; returns them batched and whether they were single."""
    if not isinstance(moving, Tensor) or not isinstance(reference, Tensor):
        raise TypeError("moving and reference must be torch tensors")
    if moving.dim() != reference.dim() or moving.dim() not in (2, 3):
        raise ValueError(f"expected {what} of shape (B, T, d) or (T, d), got {tuple(moving.shape)} "
                         f"and {tuple(reference.shape)}")
    single = moving.dim() == 2
    if single:
        moving, reference = moving.unsqueeze(0), reference.unsqueeze(0)
    if moving.shape[0] != reference.shape[0]:
        raise ValueError(f"batch sizes differ: {moving.shape[0]} vs {reference.shape[0]}")
    if moving.shape[2] != reference.shape[2]:
        raise ValueError(f"dimensions differ: d={moving.shape[2]} vs d={reference.shape[2]}")
    if min(moving.shape[1], reference.shape[1]) < min_points:
        raise ValueError(f"{what} need at least {min_points} sample(s) along the curve, got "
                         f"{moving.shape[1]} and {reference.shape[1]}")
    if not moving.is_floating_point() or not reference.is_floating_point():
        raise ValueError("inputs must be floating point tensors")
    if not (torch.isfinite(moving).all() and torch.isfinite(reference).all()):
        raise ValueError(f"{what} contain NaN or inf")
    if moving.device != reference.device:
        raise ValueError(f"inputs are on different devices: {moving.device} vs {reference.device}")
    return moving, reference.to(moving.dtype), single


def _settings(neighbourhood: int, band: int | None, coarse: int | None, band_neighbourhood: int | None,
              max_iters: int, fine_iters: int, tol: float, refine: int, starts: int) -> _Settings:
    for name, v, low in (("neighbourhood", neighbourhood, 1), ("max_iters", max_iters, 1),
                         ("fine_iters", fine_iters, 1), ("refine", refine, 0), ("starts", starts, 1)):
        if not isinstance(v, int) or v < low:
            raise ValueError(f"{name} must be an integer >= {low}, got {v!r}")
    if band is not None and (not isinstance(band, int) or band < 1):
        raise ValueError(f"band must be None or an integer >= 1, got {band!r}")
    if coarse is not None and (not isinstance(coarse, int) or coarse < 2):
        raise ValueError(f"coarse must be None or an integer >= 2, got {coarse!r}")
    nf = neighbourhood if band_neighbourhood is None else band_neighbourhood
    if not isinstance(nf, int) or nf < 1:
        raise ValueError(f"band_neighbourhood must be None or an integer >= 1, got {band_neighbourhood!r}")
    return _Settings(neighbourhood, band, coarse, nf, max_iters, fine_iters, float(tol), refine, starts)


def dp_warp(q1: Tensor, q2: Tensor, neighbourhood: int = 6, band: int | None = 4, coarse: int | None = 16,
            band_neighbourhood: int | None = 5, refine: int = 0, backend: str = "auto") -> DPWarp:
    """Optimal warps of ``q2`` onto ``q1`` by dynamic programming (no rotation).

    Args:
        q1: ``(B, M, d)`` reference SRVFs (or ``(M, d)`` for one pair).
        q2: ``(B, M2, d)`` moving SRVFs; resampled (through their curves) to ``M`` segments if ``M2 != M``.
        neighbourhood: allowed steps are the coprime ``(a, b)`` with ``1 <= a, b <= neighbourhood``.
        band: with ``M > coarse``, the DP first runs on a grid of about ``M / 3`` segments (recursively
            until at most ``coarse``), then on the fine grid only within ``band`` cells of the coarse
            warp. ``None``: one DP over the whole lattice (its exact optimum over all lattice warps).
        band_neighbourhood: steps of the banded (finer) DPs (``None``: ``neighbourhood``). The
            defaults (6 on the coarse grid, 5 in a band of 4 cells) are a speed / accuracy trade-off
            measured in benchmarks/README.md; ``band=None`` gives the exact lattice optimum.
        refine: iterations of a damped Gauss-Newton refinement that moves the warp's nodes off the
            lattice (0 = pure DP; ``torch4dtree.warp_refinement``); it only accepts steps that lower
            the energy and keeps the warp strictly monotone.
        backend: ``"numba"`` (CPU), ``"torch"`` (any device) or ``"auto"`` (numba for CPU tensors).

    Returns:
        ``DPWarp(gamma (B, M+1), energy (B,))`` with ``energy = ||q1 - warp_srvf(q2, gamma)||^2``,
        never above the identity warp's energy.
    """
    q2, q1, single = _check_inputs(q2, q1, 1, "SRVFs")
    cfg = _settings(neighbourhood, band, coarse, band_neighbourhood, 1, 1, 0.0, refine, 1)
    q2 = _resample_srvf(q2, q1.shape[1])
    be = _pick_backend(backend, q1)
    up = torch.tensor([0.0, 0.0, 1.0], dtype=q1.dtype, device=q1.device)
    fn = _register_numba if be == "numba" else _register_torch
    with torch.no_grad():
        energy, _, gamma, _ = fn(q1.detach(), q2.detach(), "none", up, cfg)
    if single:
        gamma, energy = gamma[0], energy[0]
    return DPWarp(gamma, energy)


def register_curves(moving: Tensor, reference: Tensor, rotation: str = "none", srvf_input: bool = False,
                    neighbourhood: int = 3, band: int | None = 4, coarse: int | None = 16,
                    band_neighbourhood: int | None = 4,
                    up: Tensor | tuple[float, float, float] | None = None, max_iters: int = 6,
                    fine_iters: int = 1, tol: float = 1e-6, refine: int = 4, starts: int | None = None,
                    backend: str = "auto") -> CurveRegistration:
    """Elastic registration of ``moving`` onto ``reference``: ``min_{gamma,O} ||q_ref - O (q_mov o gamma)||``.

    Args:
        moving: ``(B, T2, d)`` curves (``(B, T2-1, d)`` SRVFs if ``srvf_input``), or one pair unbatched.
        reference: ``(B, T, d)`` curves (or SRVFs). ``moving`` is resampled to ``T`` points if needed
            (linearly in its parameter).
        rotation: ``"none"``, ``"vertical"`` (about ``up``, default z; d = 3) or ``"so3"``.
        srvf_input: inputs are SRVFs (curves then start at the origin).
        neighbourhood, band, coarse, band_neighbourhood, refine, backend: DP settings, see :func:`dp_warp`.
            The defaults here (slopes up to 3 on the coarsest grid, where the rotation / warp alternation
            runs, and up to 4 in the bands of the finer grids) are faster than :func:`dp_warp`'s 6 / 5 and
            about as good: 1.75x less CPU, mean energies -7 % to +12 % (mostly within +-3 %) on random,
            helix and Pheno4D pairs at T = 50, 100, 200 (benchmarks/README.md). Steep slopes on the coarse
            grid let the alternation settle on degenerate warps; the finer grids and the refinement then
            recover fine detail. With ``band=None`` (one grid) ``neighbourhood`` is the only lattice:
            raise it for strongly non-uniform warps.
        up: the vertical axis for ``rotation="vertical"``.
        max_iters: rounds of (DP warp, optimal rotation) on the coarsest grid (with a rotation, that
            grid has at least ``4 d`` segments); ``fine_iters`` on finer
            grids. Rounds stop early when the energy decreases by less than ``tol`` relatively.
        starts: initial rotations tried on the coarsest grid (the Kabsch rotation at the identity warp,
            the identity, then that Kabsch rotation turned by half-turns about the axes (so3) or by
            turns about ``up`` (vertical)); the best is kept. Default 5 with a rotation (one start
            gets stuck in a wrong basin now and then, e.g. 180 degrees off), 1 without.

    Returns:
        :class:`CurveRegistration`. Warps and rotations are found without gradients; ``distance``,
        ``registered`` and ``q_registered`` are differentiable in the inputs given them.
    """
    if srvf_input:
        moving, reference, single = _check_inputs(moving, reference, 1, "SRVFs")
    else:
        moving, reference, single = _check_inputs(moving, reference, 2, "curves")
    check_rotation_mode(rotation, moving.shape[-1])
    if starts is None:
        starts = 1 if rotation == "none" else 5
    if coarse is not None and rotation != "none":
        # a rotation of R^d is poorly determined by a very coarse curve in high dimension
        coarse = max(coarse, 4 * moving.shape[-1])
    cfg = _settings(neighbourhood, band, coarse, band_neighbourhood, max_iters, fine_iters, tol, refine,
                    starts)
    up_t = torch.as_tensor((0.0, 0.0, 1.0) if up is None else up, dtype=reference.dtype, device=reference.device)
    if up_t.shape != (3,) or not bool(up_t.norm() > 0):
        raise ValueError(f"up must be a nonzero 3-vector, got {up}")
    be = _pick_backend(backend, reference)
    if be == "numba" and not (torch.is_grad_enabled() and (moving.requires_grad or reference.requires_grad)):
        # no gradient wanted: the whole registration (input prep and outputs too) in one numba call
        out = _register_curves_numba(moving, reference, srvf_input, rotation, up_t, cfg)
        return CurveRegistration(*(x[0] for x in out)) if single else out
    beta_m, beta_r = (inverse_srvf(moving), inverse_srvf(reference)) if srvf_input else (moving, reference)
    T = beta_r.shape[1]
    beta_m = _resample_curve(beta_m, T)
    q_ref, q_mov = srvf(beta_r), srvf(beta_m)
    fn = _register_numba if be == "numba" else _register_torch
    with torch.no_grad():
        _, before, gamma, O = fn(q_ref.detach(), q_mov.detach(), rotation, up_t, cfg)
    registered = warp_curve(beta_m, gamma) @ O.transpose(-1, -2)
    registered = registered - registered[:, :1] + beta_r[:, :1]
    q_reg = srvf(registered)
    energy = srvf_sq_distance(q_ref, q_reg)
    distance = torch.where(energy > 0, energy.clamp_min(1e-300).sqrt(), torch.zeros_like(energy))
    out = CurveRegistration(gamma, O, distance, energy, before.to(energy.dtype), registered, q_reg)
    if single:
        out = CurveRegistration(*(x[0] for x in out))
    return out


def elastic_distance(moving: Tensor, reference: Tensor, **kwargs: object) -> Tensor:
    """Elastic distance ``(B,)`` (or a scalar for one pair): ``register_curves(...).distance``."""
    return register_curves(moving, reference, **kwargs).distance  # type: ignore[arg-type]
