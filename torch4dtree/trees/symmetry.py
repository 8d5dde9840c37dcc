"""Symmetric registration: each pair is solved in one canonical direction, the other direction is its inverse.

The solver alone is not symmetric (the DP warps the moving branch on the reference's grid, the position term is
measured after the moving tree's warp, children refits and rotation starts act on the moving tree): solving the
smaller tree onto the larger and inverting makes ``A -> B`` and ``B -> A`` one correspondence (docs/method.md §3).
"""

from __future__ import annotations

import hashlib

import numpy as np
import torch

from ..curves.warps import invert_warp
from .prepare import PreparedTree
from .solver import Candidate

__all__ = ["inverse_config", "solve_reversed"]


def _size_key(tree: PreparedTree) -> tuple[float, int, bytes]:
    """Orders trees independently of argument order: total length, branch count, then the SRVFs' bytes."""
    return float((tree.sqrt_len ** 2).sum()), len(tree.parent), hashlib.sha1(tree.q.numpy().tobytes()).digest()


def solve_reversed(mov: PreparedTree, ref: PreparedTree) -> bool:
    """Whether a symmetric registration of ``mov`` onto ``ref`` solves ``ref`` onto ``mov`` and inverts it.

    The smaller tree (by :func:`_size_key`) is always the one registered onto the larger: frames are chained in
    that direction, which keeps their identities best. The inverted direction's distance is slightly above a
    one-way solve of it (docs/experiments.md).
    """
    lm, lr = float((mov.sqrt_len ** 2).sum()), float((ref.sqrt_len ** 2).sum())
    if lm != lr:  # the hash is only needed for exact ties
        return lm > lr
    return _size_key(mov) >= _size_key(ref)


def inverse_config(cfg: Candidate, n_moving: int) -> Candidate:
    """The registration of the other tree (``n_moving`` branches) from ``cfg`` (reference onto moving): matches
    transposed, every matched warp inverted, branches matched to null keep the identity, rotation transposed; the
    energy is kept."""
    T = cfg.gamma.shape[1]
    gamma = np.tile(np.linspace(0.0, 1.0, T), (n_moving, 1))
    match = {a: b for b, a in cfg.match.items()}
    if match:
        src, dst = list(match.values()), list(match.keys())
        gamma[dst] = invert_warp(torch.from_numpy(cfg.gamma[src])).numpy()
    return Candidate(cfg.energy, match, gamma, cfg.O.T.contiguous())

