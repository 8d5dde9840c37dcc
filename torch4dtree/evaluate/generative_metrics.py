"""The generative section's ground metric and set metrics (docs/method.md §7): distances between 4D plants written
as trajectories in one layout, and MMD / COV / 1-NNA / novelty from them.

**Ground metric.** The distance of two trajectories ``(n_t, k)`` (coordinates in which Euclidean distances are the
layout's tree distances, on the normalised time grid) is the **4D distance after temporal registration**
(:func:`~torch4dtree.temporal.register_trajectories`, batched): both directions are registered and the smaller
distance kept (each is an upper bound of the same quotient distance; the minimum is tighter and symmetric).

**Metrics** (``S`` samples, ``R`` references, ``d`` the ground metric): MMD ``= mean_r min_s d(r, s)`` (lower is
better: every real plant has a close sample); COV ``= |{argmin_r d(s, r)}| / |R|`` in ``[0, 1]`` (higher is better:
samples spread over the real plants); 1-NNA = the leave-one-out accuracy of the 1-nearest-neighbour classifier of
``S u R`` into "sample" / "real" in ``[0, 1]`` (50 % ideal: indistinguishable; 100 %: separable; near 0 %: each
sample sits on a real plant - memorisation of the evaluated set), with its accuracy on each set: where the real
plants are farther from each other than from the mean, a collapsed generator reaches 50 % as samples 100 % / real
0 %. ``novelty``: the share of samples closer to a training plant than the median nearest-neighbour distance
between training plants divided by 4.
"""

from __future__ import annotations

import math
from concurrent.futures import Executor

import torch
from torch import Tensor

from ..parallel import pair_matrix
from ..temporal.registration import register_trajectories

__all__ = ["CHUNK", "NOVELTY_DIVISOR", "PAIR_VALUES", "distance4d", "distance_matrix", "novelty", "pair_span",
           "pairs_per_call", "set_metrics", "within_draw"]

CHUNK = 2048  # pairs per task of distance_matrix, and per registration call at most
# a registration call keeps a (k, k) rotation per registered pair (both directions): calls hold at most this many
# of those values (128 MB), whatever the coordinates' dimension k (the layout's extension can reach hundreds)
PAIR_VALUES = 1 << 24
NOVELTY_DIVISOR = 4.0


def pairs_per_call(k: int) -> int:
    """Pairs of trajectories in ``k`` coordinates registered per call: :data:`CHUNK`, fewer when their rotation
    buffers would exceed :data:`PAIR_VALUES` (memory; the distances do not depend on it).

    Example:
        >>> pairs_per_call(3), pairs_per_call(500)
        (2048, 33)
    """
    return max(1, min(CHUNK, PAIR_VALUES // (2 * k * k)))


def pair_span(x: Tensor, y: Tensor) -> tuple[Tensor, Tensor]:
    """Pairs of trajectories ``x, y (P, n_t, k)`` written in an orthonormal basis of each pair's ``2 n_t`` samples
    ``(P, n_t, m)``, ``m = 2 n_t``, when ``k > m`` (else unchanged): an isometry of every sample of the pair, so
    their start points, SRVFs and time warps keep their distances, while the registration's cost grows faster than
    ``k`` (the layout's extended coordinates reach hundreds).

    Example:
        >>> x, y = torch.randn(2, 3, 9, dtype=torch.float64), torch.randn(2, 3, 9, dtype=torch.float64)
        >>> xs, ys = pair_span(x, y)
        >>> xs.shape, bool(torch.allclose(torch.cdist(xs, ys), torch.cdist(x, y)))
        (torch.Size([2, 3, 6]), True)
    """
    m = x.shape[-2] + y.shape[-2]
    if x.shape[-1] <= m:
        return x, y
    basis = torch.linalg.qr(torch.cat([x, y], -2).transpose(-1, -2)).Q  # (P, k, m)
    return x @ basis, y @ basis


def distance4d(a: Tensor, b: Tensor) -> Tensor:
    """The ground metric (module doc) of pairs of trajectories ``a, b (P, n_t, k) -> (P,)``: 4D distance after
    temporal registration, the smaller of the two directions; each pair registered in its own span
    (:func:`pair_span`: the same distances up to rounding, at most 2.3e-5 relative on random trajectories with
    k = 634).

    Example:
        >>> a = torch.linspace(0, 1, 5, dtype=torch.float64)[None, :, None].expand(2, 5, 3)
        >>> distance4d(a, a).tolist()
        [0.0, 0.0]
    """
    if a.shape != b.shape:
        raise ValueError(f"trajectories must have one shape, got {tuple(a.shape)} and {tuple(b.shape)}")
    out = []
    step = pairs_per_call(min(a.shape[-1], 2 * a.shape[-2]))
    for i in range(0, a.shape[0], step):
        x, y = pair_span(a[i:i + step].detach(), b[i:i + step].detach())
        d = register_trajectories(torch.cat([x, y]), torch.cat([y, x])).distance  # both directions in one batch
        out.append(torch.minimum(d[:len(x)], d[len(x):]))
    return torch.cat(out) if out else a.new_zeros(0)


def distance_matrix(x: Tensor, y: Tensor | None = None, executor: Executor | None = None) -> Tensor:
    """``(n, m)`` ground distances between trajectories ``x (n, n_t, k)`` and ``y (m, n_t, k)``; ``y=None``: the
    symmetric matrix of ``x`` (each pair once, zero diagonal). ``executor``: pieces of ``CHUNK`` pairs run there
    (:func:`~torch4dtree.parallel.pair_matrix`), the same numbers as inline.

    Example:
        >>> x = torch.zeros(3, 5, 2, dtype=torch.float64)
        >>> distance_matrix(x).shape
        torch.Size([3, 3])
    """
    return pair_matrix(distance4d, x, y, chunk=CHUNK, executor=executor)


def set_metrics(d_ss: Tensor, d_sr: Tensor, d_rr: Tensor) -> dict[str, float]:
    """MMD, COV and 1-NNA (module doc) of samples ``S`` against references ``R`` from their distances:
    ``d_ss (S, S)``, ``d_sr (S, R)``, ``d_rr (R, R)``. Ties go to the lower index, samples before references.
    ``nna_samples`` / ``nna_real``: the classifier's accuracy on each set (1-NNA is their mean when ``S = R``): a
    collapsed generator gets 100 % / 0 % when the real plants are farther from each other than from its samples.

    Example:
        >>> s, r = torch.tensor([10.0, 11.0]), torch.tensor([0.0, 1.0])
        >>> set_metrics((s[:, None] - s).abs(), (s[:, None] - r).abs(), (r[:, None] - r).abs())["nna"]
        1.0
    """
    S, R = d_sr.shape
    if S == 0 or R == 0:
        raise ValueError(f"need samples and references, got {S} and {R}")
    mmd = float(d_sr.min(0).values.mean())
    cov = int(torch.unique(d_sr.argmin(1)).numel()) / R
    full = torch.cat([torch.cat([d_ss, d_sr], 1), torch.cat([d_sr.T, d_rr], 1)], 0).clone()
    full.fill_diagonal_(math.inf)  # leave-one-out
    is_real = torch.arange(S + R) >= S
    right = (is_real[full.argmin(1)] == is_real).double()
    return {"mmd": mmd, "cov": cov, "nna": float(right.mean()), "nna_samples": float(right[:S].mean()),
            "nna_real": float(right[S:].mean())}


def novelty(d_st: Tensor, d_tt: Tensor, divisor: float = NOVELTY_DIVISOR) -> dict[str, float]:
    """How far samples are from the training plants: ``d_st (S, N)`` sample-training and ``d_tt (N, N)``
    training-training distances. ``threshold`` = the median nearest-neighbour distance between training plants /
    ``divisor``; ``share_closer`` = the share of samples closer than it to some training plant.

    Example:
        >>> t, s = torch.tensor([0.0, 4.0, 10.0]), torch.tensor([0.5, 7.0])
        >>> novelty((s[:, None] - t).abs(), (t[:, None] - t).abs())["share_closer"]
        0.5
    """
    nn = d_tt + torch.diag(torch.full((d_tt.shape[0],), math.inf, dtype=d_tt.dtype))
    threshold = float(nn.min(1).values.median()) / divisor
    nearest = d_st.min(1).values
    return {"threshold": threshold, "share_closer": float((nearest < threshold).double().mean()),
            "nearest_min": float(nearest.min()), "nearest_median": float(nearest.median()),
            "training_nn_median": threshold * divisor}


def within_draw(pool: Tensor, idx: Tensor, known: Tensor | None = None) -> Tensor:
    """``(draws, h, h)`` ground distances between the samples of each draw ``idx (draws, h)`` of trajectories
    ``pool (P, n_t, k)`` (each distinct pool pair registered once). ``known``: the pool's ``(P, P)``
    :func:`distance_matrix` when already computed, read instead of registering the pairs again (the same numbers:
    a pair's distance does not depend on the batch it is registered in).

    Example:
        >>> pool = torch.arange(3, dtype=torch.float64)[:, None, None].expand(3, 4, 1)
        >>> within_draw(pool, torch.tensor([[0, 2]])).shape
        torch.Size([1, 2, 2])
    """
    D, h = idx.shape
    if known is not None:
        if known.shape != (pool.shape[0], pool.shape[0]):
            raise ValueError(f"known distances must be ({pool.shape[0]}, {pool.shape[0]}), got {tuple(known.shape)}")
        return known[idx[:, :, None], idx[:, None, :]].clone()
    out = pool.new_zeros(D, h, h)
    if h < 2:
        return out
    i, j = torch.triu_indices(h, h, 1)
    a, b = idx[:, i].reshape(-1), idx[:, j].reshape(-1)
    lo, hi = torch.minimum(a, b), torch.maximum(a, b)
    keys, inv = torch.unique(lo * pool.shape[0] + hi, return_inverse=True)
    p, q = keys // pool.shape[0], keys % pool.shape[0]
    d = pool.new_zeros(len(keys))  # a pool item drawn twice is at distance 0 from itself
    distinct = p != q
    d[distinct] = distance4d(pool[p[distinct]], pool[q[distinct]])
    vals = d[inv].reshape(D, -1)
    out[:, i, j], out[:, j, i] = vals, vals
    return out
