"""Compiled geometry of :func:`torch4dtree.trees.aligned.rows_to_trees` (numba, CPU, float64, no autograd).

Decoding a batch of trees ends with, per kept branch in packed depth-first order: integrate its SRVF from its start
(the root, or its parent's curve at ``s``), resample it uniformly in arc length, and snap its first point back onto
its (resampled) parent. In torch that is a dozen passes over ``(K, T, d)`` tensors (gathers, cumulative sums,
``searchsorted``), memory traffic that dominated a decoded 4D geodesic; this kernel does it in one pass per branch.
Parents come before their children in the packed order, so one loop over the branches sees every parent finished.
The SRVFs come in the factored form of :class:`~torch4dtree.trees.aligned.SlotRows` (row ``r`` is
``mean[slot[r]] + c[r] @ comp[slot[r]]``, a PCA decode) and are computed row by row where needed, never stored: a
``(R, M, d)`` buffer is memory traffic and fresh pages (costly on a virtual machine) for values used twice.
The torch code in ``aligned.py`` stays the differentiable path (and the reference the tests compare this with).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import torch
from torch import Tensor

if TYPE_CHECKING:
    from .aligned import SlotRows

try:  # numba is optional: without it the torch path is used
    import numba

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover - exercised only without numba
    numba = None
    HAVE_NUMBA = False

__all__ = ["HAVE_NUMBA", "place_branches", "segments", "warm_up"]


if HAVE_NUMBA:

    @numba.njit(cache=True, boundscheck=False)
    def _nb_row(c: np.ndarray, slot: np.ndarray, mean: np.ndarray, comp: np.ndarray, r: int, buf: np.ndarray) -> None:
        """SRVF row ``r`` (flat, ``(M*d,)``) into ``buf``: ``mean[slot[r]] + c[r] @ comp[slot[r]]``."""
        j = slot[r]
        MD = mean.shape[1]
        for f in range(MD):
            buf[f] = mean[j, f]
        for a in range(c.shape[1]):
            ca = c[r, a]
            for f in range(MD):  # contiguous: vectorised
                buf[f] += ca * comp[j, a, f]

    @numba.njit(cache=True, boundscheck=False)
    def _nb_segments(c: np.ndarray, slot: np.ndarray, mean: np.ndarray, comp: np.ndarray, seg: np.ndarray) -> None:
        """``seg (R, M) = |q_r|^2 / M`` of every SRVF row (the factored rows of :func:`_nb_row`)."""
        R, M = seg.shape
        d = mean.shape[1] // M
        buf = np.empty(mean.shape[1])
        for r in range(R):
            _nb_row(c, slot, mean, comp, r, buf)
            for m in range(M):
                acc = 0.0
                for e in range(d):
                    acc += buf[m * d + e] * buf[m * d + e]
                seg[r, m] = acc / M

    @numba.njit(cache=True, boundscheck=False)
    def _nb_place(c: np.ndarray, slot: np.ndarray, mean: np.ndarray, comp: np.ndarray, seg: np.ndarray,
                  rows: np.ndarray, gp: np.ndarray, sc: np.ndarray, s_out: np.ndarray, start: np.ndarray,
                  pts: np.ndarray) -> None:
        """Fill ``pts (K, T, d)``; ``start (K, d)`` is overwritten (children's starts).

        ``c, slot, mean, comp``: the SRVF rows (:func:`_nb_row`), ``seg (R, M)`` their segment lengths; branch ``i``
        uses row ``rows[i]``, hangs on packed branch ``gp[i]`` (itself for a main branch, which starts at
        ``start[i]``) at parameter ``sc[i]`` of the parent's curve before resampling, and is snapped to arc-length
        fraction ``s_out[i]`` of the resampled parent.
        """
        K = rows.shape[0]
        M = seg.shape[1]
        d = mean.shape[1] // M
        T = M + 1
        q = np.empty(M * d)
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
            _nb_row(c, slot, mean, comp, r, q)
            # inverse SRVF from the start: steps q |q| / M = q sqrt(seg) / sqrt(M)
            for e in range(d):
                raw[0, e] = start[i, e]
            cum[0] = 0.0
            for m in range(M):
                sm = seg[r, m]
                f = math.sqrt(sm) * inv_sqrt_m if sm > 0 else 0.0
                cum[m + 1] = cum[m] + sm
                for e in range(d):
                    raw[m + 1, e] = raw[m, e] + q[m * d + e] * f
            for h in range(first[i], first[i + 1]):  # children start on this curve at sc (interpolate_curve)
                ch = child[h]
                x = min(max(sc[ch], 0.0), 1.0) * M
                lo = min(int(math.floor(x)), M - 1)
                fr = x - lo
                for e in range(d):
                    start[ch, e] = raw[lo, e] + fr * (raw[lo + 1, e] - raw[lo, e])
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
                for e in range(d):
                    pts[i, j, e] = raw[lo, e] + fr * (raw[lo + 1, e] - raw[lo, e])
            if p != i:  # back onto the resampled parent (resampling moves it by chord effects)
                x = s_out[i] * (T - 1)
                lo = min(int(math.floor(x)), T - 2)
                fr = x - lo
                for e in range(d):
                    pts[i, 0, e] = pts[p, lo, e] + fr * (pts[p, lo + 1, e] - pts[p, lo, e])


def _arrays(rows: SlotRows) -> list[np.ndarray]:
    """``c, slot, mean, comp`` of ``rows`` as numpy arrays (``slot`` None: row ``r`` is ``mean[r]``)."""
    slot = torch.arange(len(rows.c)) if rows.slot is None else rows.slot
    return [x.detach().contiguous().numpy() for x in (rows.c, slot, rows.mean, rows.comp)]


def segments(rows: SlotRows, M: int) -> Tensor:
    """``|q|^2 / M`` of the SRVF rows (float64, CPU, no gradients): ``(R, M)``."""
    seg = torch.empty(len(rows.c), M, dtype=rows.mean.dtype)
    _nb_segments(*_arrays(rows), seg.numpy())
    return seg


def place_branches(rows: SlotRows, seg: Tensor, order: Tensor, gp: Tensor, sc: Tensor, s_out: Tensor,
                   start: Tensor) -> Tensor:
    """The kernel on torch tensors (float64, CPU, no gradients): shapes as in :func:`_nb_place` (``order`` is its
    ``rows``); returns ``pts (K, M + 1, d)``."""
    K, M, d = order.shape[0], seg.shape[1], start.shape[1]
    pts = torch.empty(K, M + 1, d, dtype=seg.dtype)
    arr = [x.detach().contiguous().numpy() for x in (seg, order, gp, sc, s_out)]
    _nb_place(*_arrays(rows), *arr, start.detach().clone().numpy(), pts.numpy())
    return pts


def warm_up() -> None:
    """Load the kernels from numba's disk cache, or compile them (seconds, once after installing or updating)."""
    from .aligned import SlotRows

    if HAVE_NUMBA:
        rows = SlotRows.of(torch.zeros(2, 2, 3, dtype=torch.float64))
        s = torch.zeros(2, dtype=torch.float64)
        place_branches(rows, segments(rows, 2), torch.arange(2), torch.zeros(2, dtype=torch.long), s, s,
                       torch.zeros(2, 3, dtype=torch.float64))
