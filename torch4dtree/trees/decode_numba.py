"""Compiled geometry of :func:`torch4dtree.trees.aligned.rows_to_trees` (numba, CPU, float64, no autograd).

Decoding a batch of trees ends with, per kept branch in packed depth-first order: integrate its SRVF from its start
(the root, or its parent's curve at ``s``), resample it uniformly in arc length, and snap its first point back onto
its (resampled) parent. In torch that is a dozen passes over ``(K, T, d)`` tensors (gathers, cumulative sums,
``searchsorted``), memory traffic that dominated a decoded 4D geodesic; this kernel does it in one pass per branch.
Parents come before their children in the packed order, so one loop over the branches sees every parent finished.
The torch code in ``aligned.py`` stays the differentiable path (and the reference the tests compare this with).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

try:  # numba is optional: without it the torch path is used
    import numba

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover - exercised only without numba
    numba = None
    HAVE_NUMBA = False

__all__ = ["HAVE_NUMBA", "place_branches", "segments", "warm_up"]


if HAVE_NUMBA:

    @numba.njit(cache=True, boundscheck=False)
    def _nb_segments(q: np.ndarray, seg: np.ndarray) -> None:
        """``seg (R, M) = |q|^2 / M`` of ``q (R, M, d)`` (torch reduces a last dim of 3 slowly, and via a temporary)."""
        R, M, d = q.shape
        for r in range(R):
            for m in range(M):
                acc = 0.0
                for c in range(d):
                    acc += q[r, m, c] * q[r, m, c]
                seg[r, m] = acc / M

    @numba.njit(cache=True, boundscheck=False)
    def _nb_place(q: np.ndarray, seg: np.ndarray, rows: np.ndarray, gp: np.ndarray, sc: np.ndarray,
                  s_out: np.ndarray, start: np.ndarray, pts: np.ndarray) -> None:
        """Fill ``pts (K, T, d)``; ``start (K, d)`` is overwritten (children's starts).

        ``q (R, M, d)``, ``seg (R, M)`` SRVFs and segment lengths; branch ``i`` uses row ``rows[i]``, hangs on
        packed branch ``gp[i]`` (itself for a main branch, which starts at ``start[i]``) at parameter ``sc[i]``
        of the parent's curve before resampling, and is snapped to arc-length fraction ``s_out[i]`` of the
        resampled parent.
        """
        K = rows.shape[0]
        M = q.shape[1]
        d = q.shape[2]
        T = M + 1
        # children of every branch (counting sort by parent): a branch places its children's starts while its
        # own curve before resampling is at hand, so no (K, T, d) scratch is needed
        first = np.zeros(K + 1, dtype=np.int64)
        for i in range(K):
            if gp[i] != i:
                first[gp[i] + 1] += 1
        for i in range(K):
            first[i + 1] += first[i]
        fill = first[:K].copy()
        child = np.empty(max(first[K], 1), dtype=np.int64)
        for i in range(K):
            if gp[i] != i:
                child[fill[gp[i]]] = i
                fill[gp[i]] += 1
        raw = np.empty((T, d))
        cum = np.empty(T)
        inv_sqrt_m = 1.0 / math.sqrt(M)
        for i in range(K):
            r = rows[i]
            p = gp[i]
            # inverse SRVF from the start: steps q |q| / M = q sqrt(seg) / sqrt(M)
            for c in range(d):
                raw[0, c] = start[i, c]
            cum[0] = 0.0
            for m in range(M):
                sm = seg[r, m]
                f = math.sqrt(sm) * inv_sqrt_m if sm > 0 else 0.0
                cum[m + 1] = cum[m] + sm
                for c in range(d):
                    raw[m + 1, c] = raw[m, c] + q[r, m, c] * f
            for e in range(first[i], first[i + 1]):  # children start on this curve at sc (interpolate_curve)
                ch = child[e]
                x = min(max(sc[ch], 0.0), 1.0) * M
                lo = min(int(math.floor(x)), M - 1)
                fr = x - lo
                for c in range(d):
                    start[ch, c] = raw[lo, c] + fr * (raw[lo + 1, c] - raw[lo, c])
            # uniform in arc length (searchsorted right, clamped to [1, T-1]: a zero-length curve gives its start)
            step = cum[M] / (T - 1)
            hi = 1
            for j in range(T):
                target = step * j
                while hi < T - 1 and cum[hi] <= target:
                    hi += 1
                lo = hi - 1
                width = seg[r, lo]
                fr = (target - cum[lo]) / width if width > 0 else 0.0
                fr = min(max(fr, 0.0), 1.0)
                for c in range(d):
                    pts[i, j, c] = raw[lo, c] + fr * (raw[lo + 1, c] - raw[lo, c])
            if p != i:  # back onto the resampled parent (resampling moves it by chord effects)
                x = s_out[i] * (T - 1)
                lo = min(int(math.floor(x)), T - 2)
                fr = x - lo
                for c in range(d):
                    pts[i, 0, c] = pts[p, lo, c] + fr * (pts[p, lo + 1, c] - pts[p, lo, c])


def segments(q: Tensor) -> Tensor:
    """``|q|^2 / M`` of SRVFs ``q (R, M, d)`` (float64, CPU, no gradients): ``(R, M)``."""
    seg = torch.empty(q.shape[:2], dtype=q.dtype)
    _nb_segments(q.detach().contiguous().numpy(), seg.numpy())
    return seg


def place_branches(q: Tensor, seg: Tensor, rows: Tensor, gp: Tensor, sc: Tensor, s_out: Tensor,
                   start: Tensor) -> Tensor:
    """The kernel on torch tensors (float64, CPU, no gradients): shapes as in :func:`_nb_place`; returns ``pts``."""
    K, T, d = rows.shape[0], q.shape[1] + 1, q.shape[2]
    pts = torch.empty(K, T, d, dtype=q.dtype)
    arr = [x.detach().contiguous().numpy() for x in (q, seg, rows, gp, sc, s_out)]
    _nb_place(*arr, start.detach().clone().numpy(), pts.numpy())
    return pts


def warm_up() -> None:
    """Load the kernels from numba's disk cache, or compile them (seconds, once after installing or updating)."""
    if HAVE_NUMBA:
        q = torch.zeros(2, 2, 3, dtype=torch.float64)
        s = torch.zeros(2, dtype=torch.float64)
        place_branches(q, segments(q), torch.arange(2), torch.zeros(2, dtype=torch.long), s, s, q[:, 0])
