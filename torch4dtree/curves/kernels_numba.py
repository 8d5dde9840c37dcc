"""The compiled kernels of the numba DP backend (CPU): DP tables and searches, the rotation / warp alternation, and
``nb_pairs``, the one entry point from Python (see :mod:`.dp_numba` for the driver and :mod:`.register` for the
energy and the lattice).

Compile time: numba links every callee into its caller and LLVM re-optimises the whole linked module at each level,
so the cold compile grows with the depth of the call chain. Functions with a single caller on the main chain
(``_nb_register_one``, ``_nb_alternate``, ``_nb_dp_search``) are therefore inlined at numba level
(``inline="always"``): same code and results, one level each less, a shorter cold compile (docs/experiments.md).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .refinement import nb_gauss_newton
from .warps import GRID_SNAP

__all__ = ["nb_dp_serial", "nb_pairs", "nb_warp_energies"]

# Jacobi sweeps stop when the off-diagonal mass is this share of the diagonal's (below double rounding)
JACOBI_TOL = 1e-32


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
        if off <= JACOBI_TOL * scale or off == 0.0:
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
    """Same band as ``band_around`` for one warp ``center (M+1,)``."""
    for i in range(M + 1):
        g0 = center[max(i - w, 0)] * M
        g1 = center[min(i + w, M)] * M
        rlo = max(-(-i // n), M - n * (M - i))
        rhi = min(n * i, M - (-(-(M - i) // n)))
        lo[i] = max((math.floor(g0 + GRID_SNAP)) - w, rlo)
        hi[i] = max(min((math.ceil(g1 - GRID_SNAP)) + w, rhi), lo[i])

@numba.njit(cache=True, boundscheck=False)
def _nb_inverse_from(q: np.ndarray) -> np.ndarray:
    beta = np.empty((q.shape[0] + 1, q.shape[1]))
    _nb_inverse_srvf(q, beta)
    return beta

@numba.njit(cache=True, boundscheck=False)
def nb_warp_energies(q1: np.ndarray, q2: np.ndarray, gammas: np.ndarray, out: np.ndarray) -> None:
    """``out[i] = ||q1 - warp_srvf(q2, gammas[i])||^2`` for warps ``gammas (n, M+1)`` of one SRVF pair."""
    beta2 = _nb_inverse_from(q2)
    eye = np.eye(q1.shape[1])
    for i in range(gammas.shape[0]):
        out[i] = _nb_energy(q1, beta2, gammas[i], eye)

@numba.njit(cache=True, boundscheck=False, inline="always")
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

@numba.njit(cache=True, boundscheck=False, inline="always")
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
            nb_gauss_newton(q1r, beta2, g, refine)
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

@numba.njit(cache=True, boundscheck=False, inline="always")
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

@numba.njit(cache=True, boundscheck=False)
def _nb_prepare(mov: np.ndarray, ref: np.ndarray,
                srvf_input: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``register_curves``' inputs of one pair: ``mov (T2, d)``, ``ref (T, d)`` curves (SRVFs ``(T2-1, d)``,
    ``(T-1, d)`` if ``srvf_input``) -> the curves ``beta_m`` (resampled to ``T`` points), ``beta_r`` and their
    SRVFs ``q_mov``, ``q_ref (T-1, d)``."""
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
    return beta_m, beta_r, q_mov, q_ref

@numba.njit(cache=True, boundscheck=False)
def _nb_finish(beta_m: np.ndarray, beta_r: np.ndarray, q_ref: np.ndarray, gamma: np.ndarray, O: np.ndarray,
               registered: np.ndarray, q_reg: np.ndarray) -> float:
    """``register_curves``' outputs of one pair: writes the registered curve ``(T, d)`` (warped, rotated,
    translated to start at the reference's first point) and its SRVF; returns its energy against ``q_ref``."""
    T, d = beta_r.shape
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
    return e / (T - 1)

@numba.njit(cache=True, nogil=True, boundscheck=False)
def nb_pairs(curves: bool, mov: np.ndarray, ref: np.ndarray, srvf_input: bool, A: np.ndarray, Bs: np.ndarray,
              Af: np.ndarray, Bf: np.ndarray, cfg: np.ndarray, up: np.ndarray, tol: float, start: int, step: int,
              energy: np.ndarray, before: np.ndarray, gamma: np.ndarray, O: np.ndarray, registered: np.ndarray,
              q_reg: np.ndarray) -> None:
    """Pairs ``start, start + step, ...`` of a batch, written into the output arrays (the one entry point
    from Python: one compiled signature serves every call, and ``nogil`` lets threads share a batch).

    ``curves``: the whole of ``register_curves`` without gradients (``mov (B, T2, d)``, ``ref (B, T, d)``
    curves or SRVFs; ``_nb_prepare``, ``_nb_register_one``, ``_nb_finish``; fills every output).
    Otherwise ``_nb_register_one`` on SRVFs ``q1 = ref``, ``q2 = mov``, both ``(B, M, d)``; fills
    ``energy``, ``before``, ``gamma (B, M+1)``, ``O``; ``registered`` and ``q_reg`` may then be empty.
    ``_nb_register_one`` has one call site, so it is compiled (and optimised) once.
    """
    for p in range(start, ref.shape[0], step):
        if curves:
            beta_m, beta_r, q_mov, q_ref = _nb_prepare(mov[p], ref[p], srvf_input)
        else:
            beta_m, beta_r, q_mov, q_ref = mov[p], ref[p], mov[p], ref[p]
        e, before[p] = _nb_register_one(q_ref, q_mov, A, Bs, Af, Bf, cfg, up, tol, gamma[p], O[p])
        if curves:
            e = _nb_finish(beta_m, beta_r, q_ref, gamma[p], O[p], registered[p], q_reg[p])
        energy[p] = e

@numba.njit(cache=True, boundscheck=False)
def nb_dp_serial(q1: np.ndarray, beta2: np.ndarray, A: np.ndarray, Bs: np.ndarray, lo: np.ndarray,
                  hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    Bn, M, _ = q1.shape
    energy = np.empty(Bn)
    gamma = np.empty((Bn, M + 1))
    for p in range(Bn):
        energy[p] = _nb_dp_one(q1[p], beta2[p], A, Bs, lo[p], hi[p], gamma[p])
    return energy, gamma
