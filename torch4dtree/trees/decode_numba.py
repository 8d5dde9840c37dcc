"""Compiled geometry of :func:`torch4dtree.trees.aligned.rows_to_trees` (numba, CPU, float64, no autograd).

Decoding a batch of trees ends with, per kept branch in packed depth-first order: integrate its SRVF from its start
(the root, or its parent's curve at ``s``), resample it uniformly in arc length, and snap its first point back onto
its (resampled) parent. In torch that is a dozen passes over ``(K, T, d)`` tensors (gathers, cumulative sums,
``searchsorted``), memory traffic that dominated a decoded 4D geodesic. Here it takes three passes:

1. :func:`integrate_rows`: every SRVF row, once, to its segment lengths and its curve from the origin. The SRVFs
   come in the factored form of :class:`~torch4dtree.trees.aligned.SlotRows` (row ``r`` is
   ``mean[slot[r]] + c[r] @ comp[slot[r]]``, a PCA decode) and are computed row by row, never stored.
2. :func:`place_branches`: each kept branch resampled from its row's curve, and where it starts on its parent's
   curve (both relative to their own origins);
3. then, in packed order (parents first): the starts added and each child snapped onto its resampled parent.

The first two passes treat rows and branches independently, so threads could share them; they run on the calling
thread, which is faster for the sizes of a decoded 4D geodesic (docs/experiments.md).

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

__all__ = ["HAVE_NUMBA", "depth_first_order", "integrate_rows", "place_branches", "warm_up"]


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
    def _nb_integrate(c: np.ndarray, slot: np.ndarray, mean: np.ndarray, comp: np.ndarray, seg: np.ndarray,
                      raw: np.ndarray) -> None:
        """Every row ``r``: ``seg[r] (M,) = |q_r|^2 / M`` and ``raw[r] (M + 1, d)``, the curve of ``q_r`` from the
        origin (steps ``q |q| / M = q sqrt(seg) / sqrt(M)``)."""
        R, M = seg.shape
        d = raw.shape[2]
        q = np.empty(mean.shape[1])
        inv_sqrt_m = 1.0 / math.sqrt(M)
        for r in range(R):
            _nb_row(c, slot, mean, comp, r, q)
            for e in range(d):
                raw[r, 0, e] = 0.0
            for m in range(M):
                acc = 0.0
                for e in range(d):
                    acc += q[m * d + e] * q[m * d + e]
                sm = acc / M
                seg[r, m] = sm
                f = math.sqrt(sm) * inv_sqrt_m
                for e in range(d):
                    raw[r, m + 1, e] = raw[r, m, e] + q[m * d + e] * f

    @numba.njit(cache=True, boundscheck=False)
    def _nb_resample(seg: np.ndarray, raw: np.ndarray, rows: np.ndarray, gp: np.ndarray, sc: np.ndarray,
                     offset: np.ndarray, pts: np.ndarray) -> None:
        """Every branch ``i``: ``pts[i] (T, d)``, row ``rows[i]``'s curve resampled uniformly in
        arc length, and ``offset[i] (d,)``, the point at parameter ``sc[i]`` of its parent's (``gp[i]``) curve
        before resampling (zero for a main branch, ``gp[i] == i``); both relative to their curve's origin."""
        K = rows.shape[0]
        M = seg.shape[1]
        d = raw.shape[2]
        T = M + 1
        cum = np.empty(T)
        for i in range(K):
            r = rows[i]
            p = gp[i]
            if p == i:
                for e in range(d):
                    offset[i, e] = 0.0
            else:  # interpolate_curve on the parent's curve
                pr = rows[p]
                x = min(max(sc[i], 0.0), 1.0) * M
                lo = min(int(math.floor(x)), M - 1)
                fr = x - lo
                for e in range(d):
                    offset[i, e] = raw[pr, lo, e] + fr * (raw[pr, lo + 1, e] - raw[pr, lo, e])
            cum[0] = 0.0
            for m in range(M):
                cum[m + 1] = cum[m] + seg[r, m]
            # uniform in arc length (searchsorted right, clamped to [1, T-1]: a zero-length curve gives its start)
            stride = cum[M] / (T - 1)
            hi = 1
            for j in range(T):
                target = stride * j
                while hi < T - 1 and cum[hi] <= target:
                    hi += 1
                lo = hi - 1
                width = seg[r, lo]
                fr = (target - cum[lo]) / width if width > 0 else 0.0
                fr = min(max(fr, 0.0), 1.0)
                for e in range(d):
                    pts[i, j, e] = raw[r, lo, e] + fr * (raw[r, lo + 1, e] - raw[r, lo, e])

    @numba.njit(cache=True, boundscheck=False)
    def _nb_depth_first(keep: np.ndarray, arc: np.ndarray, slot_parent: np.ndarray, order: np.ndarray,
                        parent: np.ndarray) -> None:
        """Packed pre-order of every tree's kept slots (``keep (n, S)``), siblings by increasing ``arc (n, S)``,
        ties to the higher slot: ``order (N,)`` flat ``tree * S + slot``, ``parent (N,)`` the parent's position
        within its tree (``-1`` for the main branch). ``slot_parent (S,)`` lists parents before children."""
        n, S = keep.shape
        by_slot_desc = np.arange(S - 1, 0, -1)
        pos = np.empty(S, dtype=np.int64)
        first = np.empty(S + 1, dtype=np.int64)
        child = np.empty(max(S - 1, 1), dtype=np.int64)
        stack = np.empty(S, dtype=np.int64)
        k = 0
        for t in range(n):
            # siblings in order: slots high to low, stably sorted by arc, then grouped by parent (counting sort)
            sibs = by_slot_desc[np.argsort(arc[t, by_slot_desc], kind="mergesort")]
            first[:] = 0
            for c in sibs:
                if keep[t, c]:
                    first[slot_parent[c] + 1] += 1
            for j in range(S):
                first[j + 1] += first[j]
            fill = first[:S].copy()
            for c in sibs:
                if keep[t, c]:
                    child[fill[slot_parent[c]]] = c
                    fill[slot_parent[c]] += 1
            # pre-order walk from the main branch: push children last-first so the first is taken next
            top = 0
            stack[0] = 0
            base = k
            while top >= 0:
                v = stack[top]
                top -= 1
                pos[v] = k - base
                order[k] = t * S + v
                parent[k] = -1 if v == 0 else pos[slot_parent[v]]
                k += 1
                for h in range(first[v + 1] - 1, first[v] - 1, -1):
                    top += 1
                    stack[top] = child[h]

    @numba.njit(cache=True, boundscheck=False)
    def _nb_starts(gp: np.ndarray, offset: np.ndarray, start: np.ndarray) -> None:
        """In packed order (parents first): a side branch ``i`` starts at its parent's start plus ``offset[i]``
        (``start (K, d)`` is overwritten; a main branch, ``gp[i] == i``, keeps its own)."""
        for i in range(gp.shape[0]):
            p = gp[i]
            if p != i:
                for e in range(start.shape[1]):
                    start[i, e] = start[p, e] + offset[i, e]

    @numba.njit(cache=True, boundscheck=False)
    def _nb_snap(gp: np.ndarray, s_out: np.ndarray, pts: np.ndarray) -> None:
        """In packed order: each side branch's first point onto arc-length fraction ``s_out[i]`` of its resampled
        parent (resampling moves the parent's curve by chord effects)."""
        T, d = pts.shape[1], pts.shape[2]
        for i in range(gp.shape[0]):
            p = gp[i]
            if p != i:
                x = s_out[i] * (T - 1)
                lo = min(int(math.floor(x)), T - 2)
                fr = x - lo
                for e in range(d):
                    pts[i, 0, e] = pts[p, lo, e] + fr * (pts[p, lo + 1, e] - pts[p, lo, e])


def depth_first_order(keep: Tensor, arc: Tensor, slot_parent: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """:func:`~torch4dtree.trees.aligned._depth_first_order` on the CPU (the same outputs): ``order (N,)``,
    ``parent (N,)``, ``counts (n,)``."""
    counts = keep.sum(1)
    N = int(counts.sum())
    order = torch.empty(N, dtype=torch.long)
    parent = torch.empty(N, dtype=torch.long)
    _nb_depth_first(keep.contiguous().numpy(), arc.detach().to(torch.float64).contiguous().numpy(),
                    slot_parent.contiguous().numpy(), order.numpy(), parent.numpy())
    return order, parent, counts


def _arrays(rows: SlotRows) -> list[np.ndarray]:
    """``c, slot, mean, comp`` of ``rows`` as numpy arrays (``slot`` None: row ``r`` is ``mean[r]``)."""
    slot = torch.arange(len(rows.c)) if rows.slot is None else rows.slot
    return [x.detach().contiguous().numpy() for x in (rows.c, slot, rows.mean, rows.comp)]


def integrate_rows(rows: SlotRows, M: int, d: int) -> tuple[Tensor, np.ndarray]:
    """Segment lengths ``seg (R, M) = |q|^2 / M`` of the SRVF rows and their curves from the origin
    ``(R, M + 1, d)`` (numpy, for :func:`place_branches`). Float64, CPU, no gradients."""
    R = len(rows.c)
    seg = torch.empty(R, M, dtype=rows.mean.dtype)
    raw = np.empty((R, M + 1, d))
    _nb_integrate(*_arrays(rows), seg.numpy(), raw)
    return seg, raw


def place_branches(raw: np.ndarray, seg: Tensor, order: Tensor, gp: Tensor, sc: Tensor, s_out: Tensor,
                   start: Tensor) -> Tensor:
    """The branches' points ``(K, M + 1, d)`` in packed order (float64, CPU, no gradients).

    Branch ``i`` is SRVF row ``order[i]`` (its curve from the origin ``raw`` and segment lengths ``seg (R, M)``,
    from :func:`integrate_rows`); it hangs on packed branch ``gp[i]`` (itself for a main branch, which starts at
    ``start[i]``, ``start (K, d)``) at parameter ``sc[i]`` of the parent's curve before resampling, and is snapped
    to arc-length fraction ``s_out[i]`` of the resampled parent. Parents come before their children.
    """
    K, M, d = order.shape[0], seg.shape[1], start.shape[1]
    pts = torch.empty(K, M + 1, d, dtype=seg.dtype)
    offset = np.empty((K, d))
    seg_n, order_n, gp_n, sc_n, s_out_n = [x.detach().contiguous().numpy() for x in (seg, order, gp, sc, s_out)]
    out = pts.numpy()
    _nb_resample(seg_n, raw, order_n, gp_n, sc_n, offset, out)
    starts = start.detach().clone()
    _nb_starts(gp_n, offset, starts.numpy())
    pts += starts[:, None]  # torch: numba's loop over a runtime d = 3 does not vectorise
    _nb_snap(gp_n, s_out_n, out)
    return pts


def warm_up() -> None:
    """Load the kernels from numba's disk cache, or compile them (seconds, once after installing or updating)."""
    from .aligned import SlotRows

    if HAVE_NUMBA:
        rows = SlotRows.of(torch.zeros(2, 2, 3, dtype=torch.float64))
        s = torch.zeros(2, dtype=torch.float64)
        seg, raw = integrate_rows(rows, 2, 3)
        place_branches(raw, seg, torch.arange(2), torch.zeros(2, dtype=torch.long), s, s,
                       torch.zeros(2, 3, dtype=torch.float64))
        depth_first_order(torch.ones(1, 2, dtype=torch.bool), torch.zeros(1, 2, dtype=torch.float64),
                          torch.tensor([-1, 0]))
