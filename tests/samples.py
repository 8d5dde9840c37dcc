"""Test inputs shared by the test folders: random curves, warps from lattice paths, random plant-like trees and
transformed copies with their ground truth (importable from any test: tests/ is on the path via conftest.py)."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import torch

from torch4dtree.curves import curve_length, random_warp, warp_curve
from torch4dtree.curves.rotation import axis_rotation, random_rotation
from torch4dtree.trees.structures import Trees

T = 24  # points per branch of the random trees


# ----------------------------------------------------------------------------- curves


def smooth_curves(B: int, T: int, d: int = 3, seed: int = 0, modes: int = 5,
                  dtype: torch.dtype = torch.float64) -> torch.Tensor:
    """Smooth random curves of unit length ``(B, T, d)`` (random Fourier modes with decaying amplitudes)."""
    g = torch.Generator().manual_seed(seed)
    s = torch.linspace(0, 1, T, dtype=torch.float64)
    k = torch.arange(1, modes + 1, dtype=torch.float64)
    c = torch.randn(B, modes, d, generator=g, dtype=torch.float64) / k[:, None]
    ph = torch.rand(B, modes, d, generator=g, dtype=torch.float64) * 2 * math.pi
    x = torch.einsum("bkd,bkdt->btd", c, torch.sin(math.pi * k[None, :, None, None] * s + ph[..., None]))
    return (x / curve_length(x)[:, None, None]).to(dtype)


def rough_curves(B: int, T: int, d: int = 3, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.randn(B, T, d, generator=g, dtype=torch.float64).cumsum(1) / T


def path_to_warp(path: list[tuple[int, int]], M: int) -> torch.Tensor:
    gamma = torch.zeros(M + 1, dtype=torch.float64)
    for (k, l), (i, j) in zip(path[:-1], path[1:], strict=True):
        for m in range(k, i + 1):
            gamma[m] = (l + (m - k) * (j - l) / (i - k)) / M
    return gamma


# ----------------------------------------------------------------------------- trees


def _curve(rng, n, length, start, direction):
    d = np.asarray(direction, float)
    d /= np.linalg.norm(d)
    bend = rng.normal(scale=0.5, size=(2, 3))
    t = np.linspace(0, 1, n)[:, None]
    pts = t * d + t**2 * bend[0] * 0.4 + np.sin(np.pi * t) * bend[1] * 0.3
    return pts / np.linalg.norm(np.diff(pts, axis=0), axis=1).sum() * length + start


def random_tree(rng, n_side=(3, 5), depth=3, T=T, extra=None):
    """A plant-like random tree, labels 0..N-1 in generation order; ``extra`` = (s, length) adds one branch."""
    main = _curve(rng, 40, 30.0, np.zeros(3), [0, 0, 1])
    br, par, lengths, frontier = [main], [-1], [30.0], [0]
    for lev in range(depth - 1):
        new = []
        for b in frontier:
            k = int(rng.integers(n_side[0], n_side[1] + 1)) if lev == 0 else int(rng.integers(0, 3))
            for s in np.sort(rng.uniform(0.1, 0.9, size=k)):
                p = br[b]
                frac = np.concatenate([[0], np.linalg.norm(np.diff(p, axis=0), axis=1).cumsum()]) / lengths[b]
                ang = rng.uniform(0, 2 * math.pi)
                length = lengths[b] * rng.uniform(0.25, 0.5)
                br.append(_curve(rng, 25, length, p[int(np.searchsorted(frac, s))], [math.cos(ang), math.sin(ang),
                                                                                      rng.uniform(0.2, 1.0)]))
                par.append(b)
                lengths.append(length)
                new.append(len(br) - 1)
        frontier = new
    if extra is not None:
        s, length = extra
        k = int(s * (len(main) - 1))
        br.append(_curve(np.random.default_rng(99), 25, length, main[k], [-1.0, 0.3, 0.5]))
        par.append(0)
    return Trees.from_branches([br], [par], T=T, labels=[list(range(len(br)))], dtype=torch.float64)


def _restore_order(points, parent, s, label):
    """Depth-first order with children sorted by ``s`` (the Trees convention), from any parent-first order.

    Returns the tree and ``order`` (new branch ``k`` is old branch ``order[k]``)."""
    N = len(parent)
    children = [[] for _ in range(N)]
    for i, p in enumerate(parent):
        if p >= 0:
            children[p].append(i)
    order, stack = [], [0]
    while stack:
        k = stack.pop()
        order.append(k)
        stack.extend(sorted(children[k], key=lambda c: -float(s[c])))
    new = {k: i for i, k in enumerate(order)}
    tree = Trees(points[order], torch.tensor([-1 if parent[k] < 0 else new[parent[k]] for k in order]),
                 s[order], torch.tensor([N]), label[order])
    return tree, order


class CopyTruth(NamedTuple):
    """Ground truth of :func:`transformed_copy_truth`: copy branch ``k`` is ``O (tree branch order[k] o
    warps[order[k]] - root) + root + shift``."""

    order: list
    warps: torch.Tensor  # (N, T), indexed by the original branch
    rotation: torch.Tensor  # (3, 3)
    shift: torch.Tensor  # (3,)


def transformed_copy_truth(tree, gen, rotation="none", strength=0.8, angle=None):
    """The same tree rotated about its root, translated, every branch reparameterised (children moved
    with their parent's warp, so their order along the parent may change), stored in a new order;
    returns the copy and its :class:`CopyTruth`. ``angle``: the vertical rotation (random if None)."""
    N, Tn, _ = tree.points.shape
    g = random_warp(N, Tn, generator=gen, strength=strength)
    pts = warp_curve(tree.points, g)
    grid = np.linspace(0, 1, Tn)
    s = tree.s.clone()
    parent = tree.parent.tolist()
    for i, p in enumerate(parent):
        if p >= 0:
            s[i] = float(np.interp(float(tree.s[i]), g[p].numpy(), grid))
    if rotation == "so3":
        O = random_rotation(1, 3, generator=gen)[0]
    elif rotation == "vertical":
        th = torch.rand(1, generator=gen, dtype=torch.float64) * 2 * math.pi if angle is None else torch.tensor([angle])
        O = axis_rotation(torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64), th.double())[0]
    else:
        O = torch.eye(3, dtype=torch.float64)
    root = tree.points[0, 0]
    shift = torch.tensor([1.0, -2.0, 0.5], dtype=torch.float64)
    pts = (pts - root) @ O.T + root + shift
    # the warps move children along their parents, so re-sorting by s permutes the side subtrees
    # (the labels keep the ground truth)
    copy, order = _restore_order(pts, parent, s, tree.label)
    return copy, CopyTruth(order, g, O, shift)


def transformed_copy(tree, gen, rotation="none", strength=0.8, angle=2.0):
    """:func:`transformed_copy_truth` without the truth (a fixed vertical angle unless ``angle=None``)."""
    return transformed_copy_truth(tree, gen, rotation, strength, angle)[0]
