"""Warps of [0, 1] on a grid: identity, random, inverse, composition, energy, and the DP lattice's steps."""

from __future__ import annotations

import math
from functools import cache

import numpy as np
import torch
from torch import Tensor

from .srvf import interpolate_curve, srvf_sq_distance, uniform_grid, warp_srvf

# a warp value within rounding of a grid line counts as on it when a band is cut to whole cells
GRID_SNAP = 1e-9

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


def reachable_band(M: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Columns ``[lo_i, hi_i]`` of lattice nodes on some path (0,0) -> (M,M) with slopes in [1/n, n]."""
    i = np.arange(M + 1)
    lo = np.maximum(-(-i // n), M - n * (M - i))
    hi = np.minimum(n * i, M - (-(-(M - i) // n)))
    return lo.astype(np.int64), hi.astype(np.int64)


def band_around(center: Tensor, M: int, n: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Band of half-width ``width`` (in rows and columns) around warps ``center (B, M+1)``.

    Row ``i`` gets columns ``[M gamma(s_{i-w}) - w, M gamma(s_{i+w}) + w]``, cut to the reachable set.
    """
    g = center.detach().to("cpu", torch.float64).numpy() * M
    idx = np.arange(M + 1)
    lo = np.floor(g[:, np.clip(idx - width, 0, M)] + GRID_SNAP) - width
    hi = np.ceil(g[:, np.clip(idx + width, 0, M)] - GRID_SNAP) + width
    rlo, rhi = reachable_band(M, n)
    lo = np.maximum(lo.astype(np.int64), rlo)
    hi = np.minimum(hi.astype(np.int64), rhi)
    return np.ascontiguousarray(lo), np.ascontiguousarray(np.maximum(hi, lo))


def step_arrays(n: int) -> tuple[np.ndarray, np.ndarray]:
    steps = neighbourhood_steps(n)
    return np.array([a for a, _ in steps], np.int64), np.array([b for _, b in steps], np.int64)


# ----------------------------------------------------------------------------- numba backend
