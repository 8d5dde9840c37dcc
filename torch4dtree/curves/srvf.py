"""Curves and their square-root velocity functions (SRVFs), batched over any leading dims.

Discretisation (used everywhere in the package):

* A curve is a polyline of ``T`` points sampled on the uniform parameter grid
  ``s_k = k / (T - 1)``, shape ``(..., T, d)``.
* Its SRVF is **piecewise constant**: one value per segment, shape ``(..., T - 1, d)``:
  ``q_k = v_k / sqrt(|v_k|)`` with ``v_k = (beta_{k+1} - beta_k) (T - 1)``.
* The L2 inner product of SRVFs is ``<q1, q2> = sum_k q1_k . q2_k / (T - 1)``.

With these choices the relations of docs/method.md §3 hold exactly, not only up to quadrature error:
``||q||^2`` is the polyline length and ``inverse_srvf(srvf(beta), beta[..., 0, :]) == beta``.
A warp ``gamma`` is a monotone map of ``[0, 1]`` given by its values on the ``T`` grid points,
shape ``(..., T)``; it acts on a curve by resampling ``beta(gamma(s_k))`` (linear
interpolation along the parameter) and on an SRVF through its curve.
"""

from __future__ import annotations

import torch
from torch import Tensor


def _safe_sq_norm(v: Tensor) -> tuple[Tensor, Tensor]:
    """Squared norm over the last dim, and a mask of nonzero entries (NaN-free gradients)."""
    sq = (v * v).sum(-1)
    nonzero = sq > 0
    return torch.where(nonzero, sq, torch.ones_like(sq)), nonzero


def srvf(beta: Tensor) -> Tensor:
    """SRVF of polylines. ``beta (..., T, d) -> q (..., T-1, d)``; ``q = 0`` where the speed is 0.

    Example:
        >>> import torch
        >>> t = torch.linspace(0, 1, 5, dtype=torch.float64)[:, None]
        >>> line = torch.cat([3 * t, 4 * t, 0 * t], dim=1)  # a straight segment of length 5
        >>> q = srvf(line)
        >>> q.shape, float(srvf_sq_norm(q))  # M = T - 1 segments; ||q||^2 is the length
        (torch.Size([4, 3]), 5.0)
    """
    if beta.shape[-2] < 2:
        raise ValueError(f"a curve needs at least 2 points, got shape {tuple(beta.shape)}")
    v = torch.diff(beta, dim=-2) * (beta.shape[-2] - 1)
    sq, nonzero = _safe_sq_norm(v)
    return torch.where(nonzero.unsqueeze(-1), v * sq.pow(-0.25).unsqueeze(-1), torch.zeros_like(v))


def inverse_srvf(q: Tensor, start: Tensor | None = None) -> Tensor:
    """Curve from its SRVF. ``q (..., M, d)``, ``start (..., d)`` or None (origin) ``-> (..., M+1, d)``.

    Example:
        >>> import torch
        >>> t = torch.linspace(0, 1, 5, dtype=torch.float64)[:, None]
        >>> line = torch.cat([3 * t, 4 * t, 0 * t], dim=1)  # a straight segment of length 5
        >>> inverse_srvf(srvf(line))[-1]
        tensor([3., 4., 0.], dtype=torch.float64)
    """
    sq, nonzero = _safe_sq_norm(q)
    speed = torch.where(nonzero, sq.sqrt(), torch.zeros_like(sq))
    steps = q * speed.unsqueeze(-1) / q.shape[-2]
    zero = torch.zeros_like(steps[..., :1, :])
    beta = torch.cat([zero, steps.cumsum(-2)], dim=-2)
    return beta if start is None else beta + start.unsqueeze(-2)


def curve_length(beta: Tensor) -> Tensor:
    """Polyline length. ``(..., T, d) -> (...)``.

    Example:
        >>> import torch
        >>> t = torch.linspace(0, 1, 5, dtype=torch.float64)[:, None]
        >>> line = torch.cat([3 * t, 4 * t, 0 * t], dim=1)  # a straight segment of length 5
        >>> float(curve_length(line))
        5.0
    """
    sq, nonzero = _safe_sq_norm(torch.diff(beta, dim=-2))
    return torch.where(nonzero, sq.sqrt(), torch.zeros_like(sq)).sum(-1)


def srvf_inner(q1: Tensor, q2: Tensor) -> Tensor:
    """L2 inner product of piecewise-constant SRVFs. ``(..., M, d) x (..., M, d) -> (...)``."""
    return (q1 * q2).sum((-1, -2)) / q1.shape[-2]


def srvf_sq_norm(q: Tensor) -> Tensor:
    """Squared L2 norm of an SRVF (= the length of its curve). ``(..., M, d) -> (...)``."""
    return srvf_inner(q, q)


def srvf_sq_distance(q1: Tensor, q2: Tensor) -> Tensor:
    """Squared L2 distance of SRVFs. ``(..., M, d) x (..., M, d) -> (...)``."""
    return srvf_sq_norm(q1 - q2)


def uniform_grid(T: int, like: Tensor) -> Tensor:
    """The parameter grid ``linspace(0, 1, T)`` with the dtype and device of ``like``."""
    return torch.linspace(0.0, 1.0, T, dtype=like.dtype, device=like.device)


def interpolate_curve(beta: Tensor, s: Tensor) -> Tensor:
    """Evaluate polylines at parameters. ``beta (..., T, d)``, ``s (..., n)`` in [0, 1] ``-> (..., n, d)``.

    The leading dims of ``s`` must match those of ``beta``; linear interpolation between grid points.
    """
    T = beta.shape[-2]
    x = s.clamp(0.0, 1.0) * (T - 1)
    lo = x.detach().floor().clamp(max=T - 2).long()
    frac = (x - lo.to(x.dtype)).unsqueeze(-1)
    idx = lo.unsqueeze(-1).expand(*lo.shape, beta.shape[-1])
    a = torch.gather(beta, -2, idx)
    b = torch.gather(beta, -2, idx + 1)
    return a + frac * (b - a)


def warp_curve(beta: Tensor, gamma: Tensor) -> Tensor:
    """Reparameterise curves: ``beta (..., T, d)``, ``gamma (..., T) -> beta(gamma(s_k)) (..., T, d)``.

    Example:
        >>> import torch
        >>> t = torch.linspace(0, 1, 5, dtype=torch.float64)[:, None]
        >>> line = torch.cat([3 * t, 4 * t, 0 * t], dim=1)  # a straight segment of length 5
        >>> gamma = torch.tensor([0.0, 0.1, 0.3, 0.6, 1.0], dtype=torch.float64)
        >>> warp_curve(line, gamma)[:, 0]
        tensor([0.0000, 0.3000, 0.9000, 1.8000, 3.0000], dtype=torch.float64)
    """
    return interpolate_curve(beta, gamma)


def warp_srvf(q: Tensor, gamma: Tensor) -> Tensor:
    """The warp action ``(q o gamma) sqrt(gamma')`` on SRVFs, ``q (..., M, d)``, ``gamma (..., M+1)``.

    Computed through the curve, so that it is exactly the SRVF of the resampled polyline.
    """
    return srvf(warp_curve(inverse_srvf(q), gamma))


def resample_polylines(points: Tensor, counts: Tensor, T: int) -> Tensor:
    """Resample ragged polylines uniformly in arc length.

    Args:
        points: ``(B, N, d)`` padded polylines; row ``b`` uses its first ``counts[b]`` points.
        counts: ``(B,)`` number of valid points per polyline, each at least 2.
        T: number of output points.

    Returns:
        ``(B, T, d)``: the points at arc-length fractions ``linspace(0, 1, T)`` of each polyline.
        A polyline of zero length gives ``T`` copies of its first point.
    """
    B, N, d = points.shape
    if B == 0:
        return points.new_zeros(0, T, d)
    if int(counts.min()) < 2:
        raise ValueError("every polyline needs at least 2 points")
    valid_seg = torch.arange(N - 1, device=points.device) < (counts - 1).unsqueeze(1)  # (B, N-1)
    seg = torch.diff(points, dim=1).norm(dim=-1) * valid_seg
    cum = torch.cat([seg.new_zeros(B, 1), seg.cumsum(1)], dim=1)  # (B, N)
    total = cum[:, -1:]
    target = torch.linspace(0, 1, T, dtype=points.dtype, device=points.device) * total  # (B, T)
    # index of the segment each target falls in; padding has cum == total so right-side search is safe
    hi = torch.searchsorted(cum.contiguous(), target.contiguous(), right=True).clamp(1, N - 1)
    hi = torch.minimum(hi, (counts - 1).unsqueeze(1))
    lo = hi - 1
    c_lo, c_hi = cum.gather(1, lo), cum.gather(1, hi)
    width = c_hi - c_lo
    frac = torch.where(width > 0, (target - c_lo) / torch.where(width > 0, width, 1), 0).clamp(0, 1)
    p_lo = points.gather(1, lo.unsqueeze(-1).expand(B, T, d))
    p_hi = points.gather(1, hi.unsqueeze(-1).expand(B, T, d))
    return p_lo + frac.unsqueeze(-1) * (p_hi - p_lo)


def project_on_polyline(beta: Tensor, x: Tensor) -> tuple[Tensor, Tensor]:
    """Closest point of each polyline to a point, as a curve parameter.

    Args:
        beta: ``(B, T, d)`` polylines on the uniform grid (for curves resampled uniformly in arc
            length, the parameter is the arc-length fraction).
        x: ``(B, d)`` points.

    Returns:
        ``s (B,)`` the parameter of the closest point (``interpolate_curve(beta, s)`` gives it back),
        ``dist (B,)`` the distance to it.
    """
    a, b = beta[:, :-1], beta[:, 1:]
    ab = b - a
    denom = (ab * ab).sum(-1)
    u = (((x.unsqueeze(1) - a) * ab).sum(-1) / torch.where(denom > 0, denom, 1)).clamp(0, 1)
    dist = (a + u.unsqueeze(-1) * ab - x.unsqueeze(1)).norm(dim=-1)  # (B, T-1)
    best = dist.argmin(1, keepdim=True)
    s = (best[:, 0] + u.gather(1, best)[:, 0]) / (beta.shape[1] - 1)
    return s, dist.gather(1, best)[:, 0]
