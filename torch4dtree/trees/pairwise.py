"""All-pairs tree-shape distances, row by row, inline or on an executor (docs/method.md §3)."""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from concurrent.futures import Executor

import torch
from torch import Tensor

from .structures import Trees

__all__ = ["MIN_PAIRS_PER_PROCESS", "pairwise_distances"]

# a spawned worker pays seconds of start-up (torch import, numba cache load): a default pool gets at least this many
# pairs per process, and smaller jobs run inline
MIN_PAIRS_PER_PROCESS = 32


def _single_thread() -> None:
    """Pool initializer: one thread per process (the processes are the parallelism)."""
    torch.set_num_threads(1)
    try:
        import numba

        numba.set_num_threads(1)
    except (ImportError, ValueError):  # pragma: no cover - numba missing or already single-threaded
        pass


def _row(task: tuple[Sequence[Trees], dict]) -> list[float]:
    """Distances from the first tree of ``task[0]`` (reference) to the others (moving), with settings ``task[1]``."""
    from .registration import register_to_reference  # here: registration re-exports this module's function

    trees, kwargs = task
    if len(trees) < 2:
        return []
    res = register_to_reference(Trees.cat(list(trees[1:])), trees[0], **kwargs)
    return [float(r.distance) for r in res]


def pairwise_distances(trees: Trees, processes: int | None = None, progress: bool = True,
                       executor: Executor | None = None, **kwargs: object) -> Tensor:
    """All-pairs tree-shape distances ``(n, n)`` float64 (symmetric, zero diagonal) of the ``n`` trees of ``trees``.

    Tree ``j > i`` is registered onto tree ``i`` (one batched
    :func:`~torch4dtree.trees.registration.register_to_reference` per row; ``kwargs`` are
    its settings). Rows run on ``executor`` if given (anything with ``map``, e.g. a
    :class:`~concurrent.futures.ProcessPoolExecutor`); otherwise on a local process pool of ``processes`` workers
    (default: the CPU count), or inline where that is 1 or gives fewer than ``MIN_PAIRS_PER_PROCESS`` pairs per
    process. The result does not depend on where the rows run. ``progress`` shows a tqdm bar.

    Example:
        >>> import torch
        >>> t = torch.linspace(0, 1, 8, dtype=torch.float64)[:, None]
        >>> def stem(bend: float) -> Trees:
        ...     points = torch.cat([bend * t ** 2, 0 * t, t], dim=1)[None]
        ...     return Trees.from_branches([[points[0]]], [[-1]], T=8, dtype=torch.float64)
        >>> D = pairwise_distances(Trees.cat([stem(0.0), stem(0.5), stem(1.0)]), progress=False)
        >>> D.shape, bool((D == D.T).all()), D.diagonal().tolist()
        (torch.Size([3, 3]), True, [0.0, 0.0, 0.0])
    """
    from tqdm.auto import tqdm

    n = trees.num_trees
    split = trees.split()
    out = torch.zeros(n, n, dtype=torch.float64)
    tasks = [(split[i:], dict(kwargs)) for i in range(n - 1)]
    bar = tqdm(total=n * (n - 1) // 2, disable=not progress, desc="pairwise distances", unit="pair")

    def fill(rows: Iterable[list[float]]) -> None:
        for i, vals in enumerate(rows):
            for k, v in enumerate(vals):
                out[i, i + 1 + k] = out[i + 1 + k, i] = v
            bar.update(len(vals))

    if executor is not None:
        fill(executor.map(_row, tasks))
    else:
        procs = processes if processes is not None else (os.cpu_count() or 1)
        procs = max(1, min(procs, n * (n - 1) // 2 // MIN_PAIRS_PER_PROCESS))
        if procs == 1:
            fill(map(_row, tasks))
        else:
            import multiprocessing as mp
            from concurrent.futures import ProcessPoolExecutor

            # spawn: forking after torch / numba threads started is unsafe
            with ProcessPoolExecutor(procs, mp_context=mp.get_context("spawn"), initializer=_single_thread) as pool:
                fill(pool.map(_row, tasks))
    bar.close()
    return out
