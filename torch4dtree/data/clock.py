"""Time for the synthetic plants: a plant's biological clock (a random monotone warp) and its scanning days.

Every plant has a *biological clock* ``b = h(t)``, a monotone warp of its normalised calendar
time ``t in [0, 1]`` (``h(0) = 0``, ``h(1) = 1``); its growth is a deterministic function of
``b``, so the true temporal correspondence between two plants is ``h_2^{-1} o h_1``: the ground
truth of a temporal registration (docs/method.md §5).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

__all__ = ["default_times", "evaluate_warp", "sample_growth_warp"]


def sample_growth_warp(rng: np.random.Generator, grid_size: int = 101, strength: float = 1.0) -> tuple[
        np.ndarray, np.ndarray]:
    """A random smooth monotone warp ``h`` of ``[0, 1]`` with ``h(0) = 0``, ``h(1) = 1``.

    ``h`` is the normalised integral of a positive density ``exp(a (x - 1/2) + c sin(2 pi x + e))``:
    ``a > 0`` develops late, ``a < 0`` early. Returns ``(grid (G,), h (G,))``; between grid points
    ``h`` is linear (that piecewise-linear function IS the ground truth, see :func:`evaluate_warp`).

    Example:
        >>> grid, h = sample_growth_warp(np.random.default_rng(0), grid_size=5)
        >>> grid.tolist(), float(h[0]), float(h[-1]), bool((np.diff(h) > 0).all())
        ([0.0, 0.25, 0.5, 0.75, 1.0], 0.0, 1.0, True)
    """
    a = rng.uniform(-1.4, 1.4) * strength
    c = rng.uniform(-0.35, 0.35) * strength
    e = rng.uniform(0.0, 2 * math.pi)
    grid = np.linspace(0.0, 1.0, grid_size)
    fine = np.linspace(0.0, 1.0, 8 * (grid_size - 1) + 1)
    dens = np.exp(a * (fine - 0.5) + c * (np.sin(2 * math.pi * fine + e) - math.sin(e)))
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (dens[1:] + dens[:-1]))])
    h = np.interp(grid, fine, cum / cum[-1])
    h[0], h[-1] = 0.0, 1.0
    return grid, h


def evaluate_warp(grid: Tensor | np.ndarray, values: Tensor | np.ndarray, x: Tensor | np.ndarray | float) -> Tensor:
    """Evaluate a warp given on a grid (piecewise linear) at ``x`` (any shape) -> same shape, float64.

    Example:
        >>> evaluate_warp(np.array([0.0, 0.5, 1.0]), np.array([0.0, 0.2, 1.0]), np.array([0.25, 1.0])).tolist()
        [0.1, 1.0]
    """
    g = np.asarray(torch.as_tensor(grid).double().cpu())
    v = np.asarray(torch.as_tensor(values).double().cpu())
    xs = np.asarray(torch.as_tensor(x).double().cpu())
    return torch.from_numpy(np.asarray(np.interp(xs, g, v), dtype=np.float64).reshape(xs.shape))


def default_times(rng: np.random.Generator, n_frames: int) -> np.ndarray:
    """``(n_frames,)`` irregular acquisition days (gaps of 1 to 3 days, mostly 2, as in Pheno4D), from day 0.

    Example:
        >>> default_times(np.random.default_rng(0), 4).tolist()
        [0.0, 3.0, 5.0, 7.0]
    """
    gaps = rng.choice([1.0, 2.0, 2.0, 2.0, 3.0], size=max(n_frames - 1, 0))
    return np.concatenate([[0.0], np.cumsum(gaps)])
