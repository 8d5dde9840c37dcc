"""All-pairs tree-shape distances in tiles, inline or on an executor, resumable on disk (docs/method.md §3)."""

from __future__ import annotations

import hashlib
import json
import os
from concurrent.futures import Executor
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ..parallel import TILE, check_executor, default_tile, local_executor, tiled_matrix
from .structures import Trees

__all__ = ["MIN_PAIRS_PER_PROCESS", "pairwise_distances", "trees_fingerprint"]

# a spawned worker pays seconds of start-up (torch import, numba cache load): a default pool gets at least this many
# pairs per process, and smaller jobs run inline
MIN_PAIRS_PER_PROCESS = 32


def tree_block(rows: Trees, cols: Trees, i0: int, j0: int, kwargs: dict) -> np.ndarray:
    """Distances of the pairs ``(i, j)``, ``i < j``, of a tile: ``rows`` are trees ``i0, i0 + 1, ...``, ``cols``
    trees ``j0, ...``; each row's later columns are registered onto it in one batched
    :func:`~torch4dtree.trees.registration.register_to_reference` (settings ``kwargs``). Returns
    ``(len(rows), len(cols))`` float64, zeros where ``i >= j``."""
    from .registration import register_to_reference  # here: registration re-exports this module's function

    rs, cs = rows.split(), cols.split()
    out = np.zeros((len(rs), len(cs)), dtype=np.float64)
    for a, ref in enumerate(rs):
        first = max(0, i0 + a + 1 - j0)
        if first >= len(cs):
            continue
        res = register_to_reference(Trees.cat(cs[first:]), ref, **kwargs)
        out[a, first:] = [float(r.distance) for r in res]
    return out


def trees_fingerprint(trees: Trees, kwargs: dict) -> str:
    """A digest of the trees' tensors and the registration settings: what a resumed tile folder must match.

    Example:
        >>> t = torch.linspace(0, 1, 4, dtype=torch.float64)[:, None]
        >>> stem = Trees.from_branches([[torch.cat([0 * t, 0 * t, t], 1)]], [[-1]], T=4, dtype=torch.float64)
        >>> trees_fingerprint(stem, {}) == trees_fingerprint(stem, {"rotation": "so3"})
        False
    """
    h = hashlib.sha256(json.dumps(kwargs, sort_keys=True, default=repr).encode())
    for name in ("points", "parent", "s", "num_branches", "label"):
        value = getattr(trees, name, None)
        if isinstance(value, Tensor):
            h.update(name.encode())
            h.update(value.detach().cpu().contiguous().numpy().tobytes())
    return h.hexdigest()


def pairwise_distances(trees: Trees, processes: int | None = None, progress: bool = True,
                       executor: Executor | None = None, tile: int | None = None, path: str | Path | None = None,
                       **kwargs: object) -> Tensor:
    """All-pairs tree-shape distances ``(n, n)`` float64 (symmetric, zero diagonal) of the ``n`` trees of ``trees``.

    Tree ``j > i`` is registered onto tree ``i`` (:func:`~torch4dtree.trees.registration.register_to_reference`,
    ``kwargs`` its settings), in ``tile x tile`` blocks of pairs (:mod:`torch4dtree.parallel.tiles`; default:
    ``TILE`` inline, where larger batches are faster, else :func:`~torch4dtree.parallel.default_tile`, smaller
    below 512 trees so that workers share the blocks; a run resumed from ``path`` needs the same tile), each a task
    on ``executor`` if given (any :class:`~concurrent.futures.Executor`, e.g.
    :func:`torch4dtree.parallel.make_executor`); otherwise on a local process pool of ``processes`` workers
    (default: the CPU count), or inline where that is 1 or gives fewer than ``MIN_PAIRS_PER_PROCESS`` pairs per
    process. ``path``: a folder holding the matrix on disk; a run interrupted there resumes without recomputing
    finished tiles. The result does not depend on where or in which tiles the pairs run. ``progress`` shows a
    tqdm bar.

    Example:
        >>> t = torch.linspace(0, 1, 8, dtype=torch.float64)[:, None]
        >>> def stem(bend: float) -> Trees:
        ...     points = torch.cat([bend * t ** 2, 0 * t, t], dim=1)[None]
        ...     return Trees.from_branches([[points[0]]], [[-1]], T=8, dtype=torch.float64)
        >>> D = pairwise_distances(Trees.cat([stem(0.0), stem(0.5), stem(1.0)]), progress=False)
        >>> D.shape, bool((D == D.T).all()), D.diagonal().tolist()
        (torch.Size([3, 3]), True, [0.0, 0.0, 0.0])
    """
    from tqdm.auto import tqdm

    executor = check_executor(executor)
    n = trees.num_trees
    split = trees.split()
    settings = dict(kwargs)
    bar = tqdm(total=n * (n - 1) // 2, disable=not progress, desc="pairwise distances", unit="pair")

    def task(i0: int, i1: int, j0: int, j1: int) -> tuple:
        return tree_block, (Trees.cat(split[i0:i1]), Trees.cat(split[j0:j1]), i0, j0, settings)

    def run(ex: Executor | None) -> np.ndarray:
        fingerprint = trees_fingerprint(trees, settings) if path is not None else ""
        side = tile if tile is not None else (TILE if ex is None else default_tile(n))
        return tiled_matrix((n, n), task, True, side, ex, path, fingerprint, lambda a, b, pairs: bar.update(pairs))

    if executor is None:
        procs = processes if processes is not None else (os.cpu_count() or 1)
        procs = max(1, min(procs, n * (n - 1) // 2 // MIN_PAIRS_PER_PROCESS))
        if procs > 1:
            with local_executor(procs) as pool:
                out = run(pool)
        else:
            out = run(None)
    else:
        out = run(executor)
    bar.close()
    return torch.from_numpy(np.array(out)).to(trees.points.device)
