"""Off-lattice refinement of DP warps by damped Gauss-Newton (Levenberg-Marquardt).

A DP warp only takes values on its lattice. The discrete energy of ``curves.py`` is a sum of
squares over segments, ``E(x) = 1/M sum_m |r_m|^2`` with ``r_m = q1_m - u(v_m)``,
``v_m = M (beta2(x_{m+1}) - beta2(x_m))`` and ``u(v) = v / sqrt|v|``, where ``x = gamma`` on the
grid. Each residual depends on two neighbouring warp nodes only, so the Gauss-Newton matrix
``J^T J`` is tridiagonal and one step costs O(M) (a Thomas solve). Steps are damped
(Marquardt: ``J^T J + lam diag(J^T J)``), shortened so that no gap between nodes shrinks by more
than 90 % (the warp stays strictly monotone, ends fixed) and kept only when the energy drops,
so the energy never increases.

``beta2`` is a polyline, so ``beta2(x)`` has a kink at every grid point, and DP warps put their nodes
exactly there: a one-sided slope there would pick a side by rounding. The Jacobian therefore uses a
continuous slope (segment slopes interpolated linearly between segment midpoints, the tangent of
the smooth curve the polyline samples) while the residuals and the acceptance test use the exact
polyline, so the energy is still the exact discrete one.

Gauss-Newton reaches lower energies than a node-by-node coordinate search at a fraction of its cost
(docs/experiments.md). The numba kernel and the batched torch twin do the same arithmetic.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

try:  # numba is optional: without it the torch twin is used
    import numba

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover - exercised only without numba
    numba = None
    HAVE_NUMBA = False

# Levenberg-Marquardt damping: start, factor on success, factor on failure, failures per iteration
LM_START = 1e-3
LM_DOWN = 1.0 / 3.0
LM_UP = 8.0
LM_TRIES = 4
# fraction of each gap between warp nodes a step may use up (keeps the warp strictly monotone)
MAX_GAP_USE = 0.9
# an iteration that lowers the energy by less than this (relatively) ends the refinement
MIN_DECREASE = 1e-12
# the damping never falls below this after successes (a pure Gauss-Newton step on a flat direction is unbounded)
LM_MIN = 1e-12
# floor of a pivot of the tridiagonal solve: a node the energy does not depend on gets a finite step
MIN_DIAG = 1e-300

if HAVE_NUMBA:

    @numba.njit(cache=True, boundscheck=False)
    def _nb_residuals(q1: np.ndarray, beta2: np.ndarray, x: np.ndarray, R: np.ndarray, J0: np.ndarray,
                      J1: np.ndarray, P: np.ndarray, D: np.ndarray) -> float:
        """Residuals ``R (M, d)`` at warp nodes ``x (M+1,)``, their derivatives in the segment's first
        (``J0``) and last (``J1``) node; returns ``sum_m |r_m|^2``. ``P, D (M+1, d)`` are scratch."""
        M, d = q1.shape
        M2 = beta2.shape[0] - 1
        for k in range(M + 1):
            y = min(max(x[k], 0.0), 1.0) * M2
            f = min(math.floor(y), M2 - 1)
            t = y - f
            # the slope: segment slopes interpolated between segment midpoints (see _smooth_slope)
            u = min(max(y - 0.5, 0.0), M2 - 1.0)
            h = min(math.floor(u), max(M2 - 2, 0))
            w = u - h
            h1 = min(h + 1, M2 - 1)
            for c in range(d):
                P[k, c] = beta2[f, c] + t * (beta2[f + 1, c] - beta2[f, c])
                s0 = beta2[h + 1, c] - beta2[h, c]
                s1 = beta2[h1 + 1, c] - beta2[h1, c]
                D[k, c] = (s0 + w * (s1 - s0)) * (M * M2)  # d v / d x, with v = M (beta2(x') - beta2(x))
        e = 0.0
        for m in range(M):
            nv = 0.0
            for c in range(d):
                v = (P[m + 1, c] - P[m, c]) * M
                R[m, c] = v  # v for now
                nv += v * v
            if nv > 0:
                s = 1.0 / math.sqrt(math.sqrt(nv))
                w0 = 0.0
                w1 = 0.0
                for c in range(d):
                    w0 += R[m, c] * D[m, c]
                    w1 += R[m, c] * D[m + 1, c]
                w0 *= 0.5 / nv
                w1 *= 0.5 / nv
                for c in range(d):  # d u / d v = (I - v v^T / (2 |v|^2)) / sqrt|v|, r = q1 - u
                    v = R[m, c]
                    J0[m, c] = s * (D[m, c] - v * w0)
                    J1[m, c] = -s * (D[m + 1, c] - v * w1)
                    R[m, c] = q1[m, c] - v * s
            else:
                for c in range(d):
                    R[m, c] = q1[m, c]
                    J0[m, c] = 0.0
                    J1[m, c] = 0.0
            for c in range(d):
                e += R[m, c] * R[m, c]
        return e

    @numba.njit(cache=True, boundscheck=False)
    def nb_gauss_newton(q1: np.ndarray, beta2: np.ndarray, gamma: np.ndarray, iters: int) -> None:
        """Refine the interior nodes of ``gamma (M+1,)`` in place (see the module docstring)."""
        M, d = q1.shape
        if M < 2 or iters <= 0:
            return
        R, J0, J1 = np.empty((M, d)), np.empty((M, d)), np.empty((M, d))
        Rn, J0n, J1n = np.empty((M, d)), np.empty((M, d)), np.empty((M, d))
        P, D = np.empty((M + 1, d)), np.empty((M + 1, d))
        g, hd, ho = np.zeros(M + 1), np.zeros(M + 1), np.zeros(M + 1)
        cc, dd, dx, xn = np.zeros(M + 1), np.zeros(M + 1), np.zeros(M + 1), np.empty(M + 1)
        e = _nb_residuals(q1, beta2, gamma, R, J0, J1, P, D)
        lam = LM_START
        for _ in range(iters):
            for k in range(1, M):  # gradient / 2 and the tridiagonal J^T J of the interior nodes
                gk = 0.0
                hk = 0.0
                ok = 0.0
                for c in range(d):
                    gk += R[k - 1, c] * J1[k - 1, c] + R[k, c] * J0[k, c]
                    hk += J1[k - 1, c] * J1[k - 1, c] + J0[k, c] * J0[k, c]
                    ok += J0[k, c] * J1[k, c]
                g[k] = gk
                hd[k] = hk
                ho[k] = ok  # coupling of nodes k and k + 1 (unused for k = M - 1)
            e_old = e
            for _t in range(LM_TRIES):
                for k in range(1, M):  # Thomas algorithm on (H + lam diag H) dx = -g
                    diag = hd[k] * (1.0 + lam)
                    rhs = -g[k]
                    if k > 1:
                        diag -= ho[k - 1] * cc[k - 1]
                        rhs -= ho[k - 1] * dd[k - 1]
                    if not diag > MIN_DIAG:
                        diag = MIN_DIAG
                    cc[k] = ho[k] / diag if k < M - 1 else 0.0
                    dd[k] = rhs / diag
                dx[M - 1] = dd[M - 1]
                for k in range(M - 2, 0, -1):
                    dx[k] = dd[k] - cc[k] * dx[k + 1]
                alpha = 1.0
                for k in range(M):
                    shrink = dx[k] - dx[k + 1]
                    if shrink > 0:
                        lim = MAX_GAP_USE * (gamma[k + 1] - gamma[k]) / shrink
                        if lim < alpha:
                            alpha = lim
                xn[0] = gamma[0]
                xn[M] = gamma[M]
                for k in range(1, M):
                    xn[k] = gamma[k] + alpha * dx[k]
                en = _nb_residuals(q1, beta2, xn, Rn, J0n, J1n, P, D)
                if en < e:
                    gamma[:] = xn
                    e = en
                    R, Rn = Rn, R
                    J0, J0n = J0n, J0
                    J1, J1n = J1n, J1
                    lam = max(lam * LM_DOWN, LM_MIN)
                    break
                lam *= LM_UP
            if not e_old - e > MIN_DECREASE * e_old:
                break


    @numba.njit(cache=True, boundscheck=False)
    def nb_refine_finer(q1: np.ndarray, fine: np.ndarray, gamma: np.ndarray, iters: int, strides: np.ndarray,
                         finer: np.ndarray) -> None:
        """:func:`refine_on_finer` for a batch: ``q1 (B, M, d)``, ``fine (B, M2+1, d)``, ``gamma (B, M+1)`` and
        ``finer (B,)`` written in place."""
        B, M, d = q1.shape
        F = (fine.shape[1] - 1) // M
        R, J0, J1 = np.empty((M, d)), np.empty((M, d)), np.empty((M, d))
        P, D = np.empty((M + 1, d)), np.empty((M + 1, d))
        for b in range(B):
            g = gamma[b].copy()
            for s in strides:
                nb_gauss_newton(q1[b], np.ascontiguousarray(fine[b, ::s]), g, iters)
            e_start = _nb_residuals(q1[b], np.ascontiguousarray(fine[b, ::F]), gamma[b], R, J0, J1, P, D)
            e_fine = _nb_residuals(q1[b], fine[b], g, R, J0, J1, P, D)
            # the levels below the finest minimise other energies: the start read on fine is a candidate too
            e0 = _nb_residuals(q1[b], fine[b], gamma[b], R, J0, J1, P, D)
            if e0 < e_fine:
                g[:] = gamma[b]
                e_fine = e0
            finer[b] = e_fine < e_start
            if finer[b]:
                gamma[b, :] = g


def refinement_strides(factor: int) -> list[int]:
    """Subsampling strides of a polyline ``factor`` times finer than the warp's grid, coarse to fine: ``factor / 2^j``
    while it divides ``factor`` (each level's polyline has ``factor / stride`` segments per warp segment), then 1."""
    if not isinstance(factor, int) or factor < 1:
        raise ValueError(f"factor must be an integer >= 1, got {factor!r}")
    strides, f = [], 2
    while f < factor:
        if factor % f == 0:
            strides.append(factor // f)
        f *= 2
    return strides + [1]


def refine_on_finer(q1: Tensor, fine: Tensor, gamma: Tensor, iters: int, backend: str = "numba"
                    ) -> tuple[Tensor, Tensor]:
    """Refine warps ``gamma (B, M+1)`` of the polylines ``fine (B, F M + 1, d)`` onto SRVFs ``q1 (B, M, d)``.

    The moving curve is given ``F`` times finer than the warp's grid (every ``F``-th point on it), e.g. a
    trajectory through frames whose times fall between the grid's: its polyline on the grid (its samples) cuts
    those corners, the fine one nearly does not, and ``fine(gamma(s_i))`` can put them where ``q1`` has them.
    Gauss-Newton runs on ``fine`` subsampled ``F / 2, F / 4, ...`` times, then on ``fine`` itself
    (:func:`refinement_strides`; going straight to ``fine`` from a warp found on the samples can stop in a shallower
    minimum).

    Returns:
        ``(gamma, finer)``: ``finer (B,)`` where the warp read on ``fine`` (the refined one, or the start if that is
        lower) has a lower energy than the start read on the samples ``fine[:, ::F]``; there ``gamma`` is that warp,
        elsewhere the start. So the energy of the returned reading is never above the start's.
    """
    B, M, _ = q1.shape
    if (fine.shape[1] - 1) % M:
        raise ValueError(f"fine must have a multiple of {M} segments, got {fine.shape[1] - 1}")
    F = (fine.shape[1] - 1) // M
    strides = refinement_strides(F)
    if backend == "numba" and HAVE_NUMBA:
        out = gamma.detach().to("cpu", torch.float64).contiguous().numpy().copy()
        finer = np.zeros(B, np.bool_)
        nb_refine_finer(q1.detach().to("cpu", torch.float64).contiguous().numpy(),
                         fine.detach().to("cpu", torch.float64).contiguous().numpy(), out, int(iters),
                         np.asarray(strides, np.int64), finer)
        return torch.from_numpy(out).to(gamma.device, gamma.dtype), torch.from_numpy(finer).to(gamma.device)
    g = gamma
    for s in strides:
        g = gauss_newton_torch(q1, fine[:, ::s].contiguous(), g, iters)
    e0 = _residuals_torch(q1, fine, gamma)[0]
    e_fine = _residuals_torch(q1, fine, g)[0]
    g = torch.where((e0 < e_fine)[:, None], gamma, g)
    finer = torch.minimum(e0, e_fine) < _residuals_torch(q1, fine[:, ::F].contiguous(), gamma)[0]
    return torch.where(finer[:, None], g, gamma), finer


def _residuals_torch(q1: Tensor, beta2: Tensor, x: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Torch twin of ``_nb_residuals``: ``q1 (B, M, d)``, ``beta2 (B, M2+1, d)``, ``x (B, M+1)``
    ``-> e (B,), R, J0, J1 (B, M, d)``."""
    M, d = q1.shape[1], q1.shape[2]
    M2 = beta2.shape[1] - 1
    y = x.clamp(0.0, 1.0) * M2
    f = y.floor().clamp(max=M2 - 1)
    t = (y - f).unsqueeze(-1)
    idx = f.long().unsqueeze(-1).expand(*f.shape, d)
    b0 = torch.gather(beta2, 1, idx)
    P = b0 + t * (torch.gather(beta2, 1, idx + 1) - b0)
    u = (y - 0.5).clamp(0.0, M2 - 1.0)
    h = u.floor().clamp(max=max(M2 - 2, 0))
    w = (u - h).unsqueeze(-1)
    slopes = beta2[:, 1:] - beta2[:, :-1]
    hi = h.long().unsqueeze(-1).expand(*h.shape, d)
    s0 = torch.gather(slopes, 1, hi)
    s1 = torch.gather(slopes, 1, (hi + 1).clamp(max=M2 - 1))
    D = (s0 + w * (s1 - s0)) * (M * M2)
    v = (P[:, 1:] - P[:, :-1]) * M
    nv = (v * v).sum(-1, keepdim=True)
    pos = nv > 0
    nv_safe = torch.where(pos, nv, torch.ones_like(nv))
    s = torch.where(pos, 1.0 / nv_safe.sqrt().sqrt(), torch.zeros_like(nv))
    w0 = (v * D[:, :-1]).sum(-1, keepdim=True) * (0.5 / nv_safe)
    w1 = (v * D[:, 1:]).sum(-1, keepdim=True) * (0.5 / nv_safe)
    J0 = s * (D[:, :-1] - v * w0)
    J1 = -s * (D[:, 1:] - v * w1)
    R = q1 - v * s
    return (R * R).sum((-1, -2)), R, J0, J1


def gauss_newton_torch(q1: Tensor, beta2: Tensor, gamma: Tensor, iters: int) -> Tensor:
    """Batched torch twin of ``nb_gauss_newton``: refined copy of ``gamma (B, M+1)`` (any device)."""
    B, M, _ = q1.shape
    gamma = gamma.clone()
    if M < 2 or iters <= 0:
        return gamma
    e, R, J0, J1 = _residuals_torch(q1, beta2, gamma)
    lam = torch.full_like(e, LM_START)
    active = torch.ones(B, dtype=torch.bool, device=q1.device)
    zero = torch.zeros_like(e)
    for _ in range(iters):
        g = (R[:, :-1] * J1[:, :-1] + R[:, 1:] * J0[:, 1:]).sum(-1)  # (B, M-1): nodes 1..M-1
        hd = (J1[:, :-1] ** 2 + J0[:, 1:] ** 2).sum(-1)
        ho = (J0[:, 1:] * J1[:, 1:]).sum(-1)  # ho[:, k-1] couples nodes k and k + 1
        e_old = e
        pending = active.clone()
        for _t in range(LM_TRIES):
            cc, dd = [], []
            for k in range(M - 1):  # Thomas algorithm, as in the kernel
                diag = hd[:, k] * (1.0 + lam)
                rhs = -g[:, k]
                if k > 0:
                    diag = diag - ho[:, k - 1] * cc[k - 1]
                    rhs = rhs - ho[:, k - 1] * dd[k - 1]
                diag = torch.where(diag > MIN_DIAG, diag, torch.full_like(diag, MIN_DIAG))
                cc.append(ho[:, k] / diag if k < M - 2 else zero)
                dd.append(rhs / diag)
            dx = [dd[M - 2]]
            for k in range(M - 3, -1, -1):
                dx.append(dd[k] - cc[k] * dx[-1])
            step = torch.stack([zero, *dx[::-1], zero], 1)  # (B, M+1)
            shrink = step[:, :-1] - step[:, 1:]
            gap = MAX_GAP_USE * (gamma[:, 1:] - gamma[:, :-1])
            limits = torch.where(shrink > 0, gap / torch.where(shrink > 0, shrink, 1.0), 1.0)
            alpha = limits.min(1).values.clamp(max=1.0)
            xn = gamma + alpha[:, None] * step
            en, Rn, J0n, J1n = _residuals_torch(q1, beta2, xn)
            ok = pending & (en < e)
            gamma = torch.where(ok[:, None], xn, gamma)
            e = torch.where(ok, en, e)
            R, J0, J1 = (torch.where(ok[:, None, None], new, old) for new, old in ((Rn, R), (J0n, J0), (J1n, J1)))
            lam = torch.where(ok, (lam * LM_DOWN).clamp_min(LM_MIN), torch.where(pending, lam * LM_UP, lam))
            pending = pending & ~ok
            if not bool(pending.any()):
                break
        active = active & (e_old - e > MIN_DECREASE * e_old)
        if not bool(active.any()):
            break
    return gamma
