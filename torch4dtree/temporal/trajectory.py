"""Trajectories in R^k (docs/method.md §5): a 4D tree as a curve of shape coordinates over normalised time.

A trajectory is ``alpha (..., n_t, k)``: the shape coordinates (e.g. tree-PCA coefficients) of a 4D
tree at ``n_t`` equally spaced normalised times ``linspace(0, 1, n_t)``. Its SRVF representation is
``(alpha(0), q)`` with ``q (..., n_t - 1, k)`` the piecewise-constant SRVF of :mod:`torch4dtree.curves.srvf`,
so ``trajectory_from_srvf(*trajectory_srvf(alpha)) == alpha`` exactly.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from ..curves.srvf import inverse_srvf, srvf

__all__ = ["OVERSAMPLE", "Trajectory", "fine_size", "resample_trajectory", "trajectory_from_srvf", "trajectory_srvf"]

# samples per time step of a moving trajectory handed to register_trajectories (fine_size): on Pheno4D warped
# copies (.mat, n_t = 32) the drop in distance is 98.1 / 96.4 % with 2, 100.0 / 99.9 % with 8 (maize / tomato)
OVERSAMPLE = 8
MAX_OVERSAMPLE = 64  # fine_size's cap when frames are packed closer than two fine steps


class Trajectory(NamedTuple):
    """A trajectory in SRVF form: ``start (..., k)`` = ``alpha(0)`` and ``q (..., n_t - 1, k)``."""

    start: Tensor
    q: Tensor


def resample_trajectory(coeffs: Tensor, times: Tensor, n_t: int = 32) -> Tensor:
    """Linear interpolation of per-frame coordinates at ``n_t`` equally spaced normalised times.

    Args:
        coeffs: ``(n_frames, k)`` or ``(B, n_frames, k)`` coordinates of each frame.
        times: ``(n_frames,)`` or ``(B, n_frames)`` strictly increasing acquisition times (any unit,
            any spacing: missing days are simply absent frames). Each sequence's times are mapped
            affinely onto ``[0, 1]`` (first frame 0, last frame 1). ``(n_frames,)`` times are shared
            by every sequence of a batch.
        n_t: number of output samples (at least 2).

    Returns:
        ``(n_t, k)`` or ``(B, n_t, k)``: the piecewise-linear trajectory through the frames evaluated at
        ``linspace(0, 1, n_t)``. Differentiable in ``coeffs``.

    Example:
        >>> coeffs = torch.tensor([[0.0, 0.0], [1.0, 2.0], [2.0, 2.0]], dtype=torch.float64)
        >>> resample_trajectory(coeffs, torch.tensor([0.0, 1.0, 4.0]), n_t=5)[:, 0].tolist()
        [0.0, 1.0, 1.3333333333333333, 1.6666666666666665, 2.0]
    """
    if not isinstance(n_t, int) or n_t < 2:
        raise ValueError(f"n_t must be an integer >= 2, got {n_t!r}")
    if coeffs.dim() not in (2, 3):
        raise ValueError(f"coeffs must be (n_frames, k) or (B, n_frames, k), got {tuple(coeffs.shape)}")
    if not coeffs.is_floating_point():
        raise ValueError("coeffs must be a floating point tensor")
    single = coeffs.dim() == 2
    c = coeffs.unsqueeze(0) if single else coeffs
    B, n, _ = c.shape
    t = torch.as_tensor(times, device=c.device).to(c.dtype)
    if t.dim() == 1:
        t = t.expand(B, -1)
    if t.shape != (B, n):
        raise ValueError(f"times must have shape ({n},) or ({B}, {n}) to match coeffs {tuple(coeffs.shape)}, "
                         f"got {tuple(torch.as_tensor(times).shape)}")
    if n < 2:
        raise ValueError(f"a trajectory needs at least 2 frames, got {n}")
    if not bool(torch.isfinite(t).all()) or not bool((torch.diff(t, dim=1) > 0).all()):
        raise ValueError("times must be finite and strictly increasing within each sequence")
    tn = (t - t[:, :1]) / (t[:, -1:] - t[:, :1])  # (B, n) in [0, 1]
    grid = torch.linspace(0.0, 1.0, n_t, dtype=c.dtype, device=c.device).expand(B, n_t).contiguous()
    # segment [tn_lo, tn_hi] holding each grid time; the last grid time falls in the last segment
    hi = torch.searchsorted(tn.contiguous(), grid, right=True).clamp(1, n - 1)
    lo = hi - 1
    t_lo, t_hi = tn.gather(1, lo), tn.gather(1, hi)
    frac = ((grid - t_lo) / (t_hi - t_lo)).clamp(0.0, 1.0).unsqueeze(-1)
    k = c.shape[-1]
    a = c.gather(1, lo.unsqueeze(-1).expand(B, n_t, k))
    b = c.gather(1, hi.unsqueeze(-1).expand(B, n_t, k))
    out = a + frac * (b - a)
    return out[0] if single else out


def fine_size(n_t: int, times: Tensor | None = None, oversample: int = OVERSAMPLE,
              max_oversample: int = MAX_OVERSAMPLE) -> int:
    """Samples of a trajectory ``F`` times finer than the ``n_t`` grid (``linspace(0, 1, n_t)`` among them).

    ``resample_trajectory(coeffs, times, fine_size(n_t, times))`` is the moving trajectory that
    :func:`~torch4dtree.temporal.register_trajectories` can time-warp without cutting the corners its frames make
    between the ``n_t`` grid times. ``F = oversample``, doubled (up to ``max_oversample``) while two of ``times``
    (normalised to ``[0, 1]``) are closer than two fine steps: the fine polyline must hold every frame's corner.

    Example:
        >>> fine_size(32)
        249
    """
    if not isinstance(n_t, int) or n_t < 2:
        raise ValueError(f"n_t must be an integer >= 2, got {n_t!r}")
    if not isinstance(oversample, int) or oversample < 1:
        raise ValueError(f"oversample must be an integer >= 1, got {oversample!r}")
    F = oversample
    if times is not None and times.shape[-1] > 1:
        t = torch.as_tensor(times, dtype=torch.float64)
        t = (t - t[..., :1]) / (t[..., -1:] - t[..., :1])
        gap = float(torch.diff(t, dim=-1).min())
        while F < max_oversample and gap * F * (n_t - 1) < 2:
            F *= 2
    return F * (n_t - 1) + 1


def trajectory_srvf(alpha: Tensor) -> Trajectory:
    """``alpha (..., n_t, k) -> Trajectory(start (..., k), q (..., n_t - 1, k))`` (any ``k``, any leading dims).

    Example:
        >>> alpha = torch.rand(2, 8, 3, dtype=torch.float64)
        >>> start, q = trajectory_srvf(alpha)
        >>> torch.allclose(trajectory_from_srvf(start, q), alpha)
        True
    """
    if alpha.dim() < 2 or alpha.shape[-2] < 2:
        raise ValueError(f"a trajectory must be (..., n_t >= 2, k), got {tuple(alpha.shape)}")
    return Trajectory(alpha[..., 0, :], srvf(alpha))


def trajectory_from_srvf(start: Tensor, q: Tensor) -> Tensor:
    """Inverse of :func:`trajectory_srvf`: ``start (..., k)``, ``q (..., n_t - 1, k) -> alpha (..., n_t, k)``."""
    if q.dim() < 2 or start.shape != q.shape[:-2] + q.shape[-1:]:
        raise ValueError(f"start must be (..., k) and q (..., n_t - 1, k) with the same leading dims and k, "
                         f"got {tuple(start.shape)} and {tuple(q.shape)}")
    return inverse_srvf(q, start)
