"""Tiny example inputs for the docstring examples and first experiments: a helix arc and a pair of two-branch trees."""

from __future__ import annotations

import torch
from torch import Tensor

from ..trees.structures import Trees

__all__ = ["helix_arc", "helix_pair", "leaf_pair"]


def helix_arc(n: int = 16, dtype: torch.dtype = torch.float64) -> Tensor:
    """``n`` points ``(n, 3)`` on a helix arc of about 2.2 units, from ``(1, 0, 0)``.

    Example:
        >>> helix_arc(16).shape
        torch.Size([16, 3])
    """
    s = torch.linspace(0, 1, n, dtype=dtype)
    return torch.stack([torch.cos(2 * s), torch.sin(2 * s), s], dim=1)


def helix_pair(n: int = 16, strength: float = 0.5, seed: int = 0, dtype: torch.dtype = torch.float64
               ) -> tuple[Tensor, Tensor]:
    """A helix arc ``(n, 3)`` and the same arc reparameterised by a random warp of ``strength`` (``(x, y)``).

    Example:
        >>> x, y = helix_pair(16)
        >>> bool(torch.allclose(x[[0, -1]], y[[0, -1]]))  # same ends, points moved along the curve
        True
    """
    from ..curves import random_warp, warp_curve

    x = helix_arc(n, dtype)
    gamma = random_warp(1, n, generator=torch.Generator().manual_seed(seed), strength=strength)[0].to(dtype)
    return x, warp_curve(x, gamma)


def leaf_pair(T: int = 8, dtype: torch.dtype = torch.float64) -> tuple[Trees, Trees]:
    """Two trees of two branches each: a unit stem along ``z`` with a straight leaf at half height, and the same stem
    with a bent leaf a little higher (``(tree, other)``, each a :class:`Trees` of one tree).

    Example:
        >>> tree, other = leaf_pair()
        >>> tree.num_branches.tolist(), other.points.shape
        ([2], torch.Size([2, 8, 3]))
    """
    t = torch.linspace(0, 1, T, dtype=dtype)[:, None]
    zero = torch.zeros_like(t)
    stem = torch.cat([zero, zero, t], dim=1)
    leaf = torch.cat([t, zero, 0.5 + zero], dim=1)
    bent = torch.cat([t, 0.3 * t ** 2, 0.6 + zero], dim=1)
    tree, other = (Trees.from_branches([[stem, b]], [[-1, 0]], T=T, dtype=dtype) for b in (leaf, bent))
    return tree, other
