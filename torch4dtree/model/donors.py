"""The donor kernel of the organ model (docs/method.md §5, generative models): which training plants a generated
plant draws its organs from, by Gaussian kernel weights near its latent, and how wide that kernel must be for a
sample to draw on several plants rather than copy one.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

__all__ = ["BANDWIDTH_STEPS", "FLAT_FEATURE", "MAX_BANDWIDTH", "MIN_DONORS", "effective_donors", "latent_weights",
           "pick_donors", "widened_bandwidth"]

# a latent feature with no spread (every training plant alike) is measured in these units instead of by its zero
# standard deviation
FLAT_FEATURE = 1e-9
# the latent kernel keeps at least this many effective donors (Kish's ``1 / sum w^2``) at the training plants' own
# latents, on average (OrganModel.donor_bandwidth): with few training plants a fixed width puts most of the weight on
# the plant the latent was drawn around, and samples copy it whole. Three: populations of 20 plants keep 3.8-4.1 at
# the default width, so it widens only for fewer plants (about 15 or less)
MIN_DONORS = 3.0
# the widest kernel the search for MIN_DONORS tries, in standard deviations of the latent (its weights are then
# nearly uniform over any population's latents, whose features lie within a few standard deviations)
MAX_BANDWIDTH = 8.0
# bisection steps of that search (the width to 2**-20 of the search's log range)
BANDWIDTH_STEPS = 20


def latent_weights(summary: Tensor, latent: Tensor, bandwidth: float) -> Tensor:
    """``summary (P, F)`` the training plants' latents, ``latent (..., F)`` -> ``(..., P)`` Gaussian kernel weights
    (sum 1; uniform where every weight underflows) of width ``bandwidth`` in standard deviations of ``summary``'s
    features (a constant feature counts as one of width :data:`FLAT_FEATURE`).

    Example:
        >>> w = latent_weights(torch.tensor([[0.0], [2.0]]).double(), torch.tensor([[0.0], [1.0]]).double(), 1.0)
        >>> w.round(decimals=2).tolist()
        [[0.73, 0.27], [0.5, 0.5]]
    """
    scale = summary.std(0).clamp_min(FLAT_FEATURE)
    d2 = ((latent[..., None, :] - summary) / scale).square().sum(-1)
    w = torch.exp(-0.5 * d2 / bandwidth ** 2)
    total = w.sum(-1, keepdim=True)
    return torch.where(total > 0, w / total.clamp_min(torch.finfo(w.dtype).tiny), 1.0 / w.shape[-1])


def effective_donors(summary: Tensor, bandwidth: float) -> Tensor:
    """The mean over the training plants ``summary (P, F)`` of the effective number of plants (Kish's
    ``1 / sum_j w_j^2``, between 1 and ``P``) among the kernel weights (:func:`latent_weights`) at each one's own
    latent: how many plants a sample drawn around that plant takes its organs from.

    Example:
        >>> summary = torch.tensor([[0.0], [1.0], [2.0]])
        >>> round(float(effective_donors(summary, 0.01)), 2), round(float(effective_donors(summary, 100.0)), 2)
        (1.0, 3.0)
    """
    w = latent_weights(summary, summary, bandwidth)
    return (1.0 / w.square().sum(-1)).mean()


def pick_donors(weights: Tensor, u: Tensor) -> Tensor:
    """``weights (B, P) >= 0`` (each row with a positive one), uniforms ``u (B,)`` in ``[0, 1)`` -> ``(B,)`` one index
    per row drawn in proportion to its weights (inverse CDF: one uniform a draw, so draws batch over rows).

    Example:
        >>> pick_donors(torch.tensor([[0.0, 1.0, 3.0], [1.0, 0.0, 0.0]]), torch.tensor([0.3, 0.9])).tolist()
        [2, 0]
    """
    cdf = weights.cumsum(-1)
    return torch.searchsorted(cdf, u[:, None] * cdf[:, -1:], right=True).reshape(-1).clamp(max=weights.shape[-1] - 1)


def widened_bandwidth(summary: Tensor, least: float) -> float:
    """The least kernel width, at or above ``least`` (standard deviations), whose weights at the training plants'
    own latents ``summary (P, F)`` keep on average :data:`MIN_DONORS` effective donors (:func:`effective_donors`;
    :data:`MAX_BANDWIDTH` when no width up to it does): on tens of plants ``least`` already does and stays, on a few
    the kernel widens so samples mix plants instead of copying one.

    Example:
        >>> summary = torch.tensor([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
        >>> round(widened_bandwidth(summary, 0.1), 2), widened_bandwidth(summary, 5.0)
        (1.34, 5.0)
    """
    lo, hi = least, max(least, MAX_BANDWIDTH)
    if float(effective_donors(summary, lo)) >= MIN_DONORS:
        return lo
    if float(effective_donors(summary, hi)) < MIN_DONORS:
        return hi
    for _ in range(BANDWIDTH_STEPS):  # geometric bisection: the donors grow with the width
        mid = math.sqrt(lo * hi)
        lo, hi = (lo, mid) if float(effective_donors(summary, mid)) >= MIN_DONORS else (mid, hi)
    return hi
