"""Geodesics between registered 3D trees (docs/method.md §3): straight lines in the common slot layout.

After registration both trees live in one :class:`AlignedTrees` layout where the metric is a
weighted L2 norm, so the geodesic is ``(1 - t) Q_moving* + t Q_reference`` (SRVFs, bifurcation
parameters and the root position interpolated linearly), decoded with the inverse SRVF, each
child starting on its parent's curve at its interpolated ``s``.
"""

from __future__ import annotations

import torch
from torch import Tensor

from .aligned import AlignedTrees
from .registration import TreeRegistration
from .structures import Trees

__all__ = ["geodesic", "geodesic_aligned", "geodesic_times"]


def geodesic_times(n_steps: int, dtype: torch.dtype = torch.float64) -> Tensor:
    """``linspace(0, 1, n_steps)``; ``n_steps >= 2`` so the path holds both ends."""
    if n_steps < 2:
        raise ValueError(f"a geodesic needs n_steps >= 2, got {n_steps}")
    return torch.linspace(0.0, 1.0, n_steps, dtype=dtype)


def geodesic_aligned(registration: TreeRegistration | AlignedTrees, n_steps: int = 5) -> AlignedTrees:
    """The geodesic in the common layout: ``n_steps`` trees from the registered moving tree (``t = 0``)
    to the reference (``t = 1``). Accepts a :class:`TreeRegistration` or a 2-tree :class:`AlignedTrees`."""
    aligned = registration.aligned if isinstance(registration, TreeRegistration) else registration
    if aligned.num_trees != 2:
        raise ValueError(f"a geodesic needs 2 aligned trees, got {aligned.num_trees}")
    return aligned[0].lerp(aligned[1], geodesic_times(n_steps, aligned.q.dtype))


def geodesic(registration: TreeRegistration | AlignedTrees, n_steps: int = 5, eps: float = 1e-6) -> Trees:
    """Decoded geodesic: ``n_steps`` trees in path order (registered moving first, reference last).

    Branches shorter than ``eps`` (null slots, or branches that have just appeared) are dropped;
    each tree's branch ``label`` is its slot index, so a branch keeps its identity along the path.
    The path's length is ``registration.distance`` (constant speed in the metric).

    Example:
        >>> import torch
        >>> from torch4dtree.trees import register_trees
        >>> from torch4dtree.data.examples import leaf_pair
        >>> tree, other = leaf_pair(T=8)  # a stem with a straight leaf, and with a bent one
        >>> path = geodesic(register_trees(other, tree), n_steps=3)  # other, the midpoint, tree
        >>> path.num_trees, path.num_branches.tolist()
        (3, [2, 2, 2])
    """
    return geodesic_aligned(registration, n_steps).to_trees(eps)
