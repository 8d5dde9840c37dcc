"""All-pairs matrices in tiles: bounded tasks on any executor, an on-disk matrix that an interrupted run resumes.

An ``(n, m)`` matrix is cut into ``tile x tile`` blocks (``TILE = 64``: 4,096 pairs a task amortise the scheduling
and a worker holds only ``2 x tile`` items); a symmetric matrix (``m = n``, zero diagonal) computes only the blocks
on and above the diagonal, each pair ``i < j`` once, and mirrors them. Every pair is computed by the same function
whatever tile it falls in, so the matrix does not depend on the tiling or the executor (the batched registrations
give each pair the same bits whatever batch it shares: ``tests/parallel``).

With ``path`` (a folder) the matrix is ``distances.npy`` (a memory map, so it may exceed the RAM), ``tiles.json``
says what it is (shape, tile, the caller's fingerprint of the inputs and settings), and ``done.npy`` marks the
finished blocks; a block is marked (written to a temporary file, then renamed: atomic) only after its values are
flushed to the matrix. Run again on the same folder with the same inputs, only unfinished blocks are computed.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from concurrent.futures import Executor
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from .tasks import run_tasks

__all__ = ["TILE", "TileRecordError", "pair_matrix", "tile_blocks", "tiled_matrix"]

TILE = 64
MATRIX, RECORD, DONE = "distances.npy", "tiles.json", "done.npy"


class TileRecordError(ValueError):
    """A tile folder that cannot be resumed: unreadable, or written for other inputs, settings or tiles."""


def tile_blocks(n: int, m: int, tile: int, symmetric: bool) -> list[tuple[int, int]]:
    """The ``(block row, block column)`` of every tile to compute, row-major; ``symmetric``: those on and above
    the diagonal only.

    Example:
        >>> tile_blocks(3, 3, 2, symmetric=True)
        [(0, 0), (0, 1), (1, 1)]
    """
    if tile < 1:
        raise ValueError(f"tile must be at least 1, got {tile}")
    nb, mb = -(-n // tile), -(-m // tile)
    return [(a, b) for a in range(nb) for b in range(mb) if not symmetric or b >= a]


def _open(path: Path, shape: tuple[int, int], tile: int, fingerprint: str) -> tuple[np.ndarray, np.ndarray]:
    """The matrix memory map and the done-blocks grid of a tile folder, created or checked for resuming."""
    record = {"shape": list(shape), "tile": tile, "fingerprint": fingerprint}
    blocks = (-(-shape[0] // tile), -(-shape[1] // tile))
    meta = path / RECORD
    if meta.exists():
        try:
            found = json.loads(meta.read_text())
            done = np.load(path / DONE)
            matrix = np.lib.format.open_memmap(path / MATRIX, mode="r+")
        except (OSError, ValueError) as e:
            raise TileRecordError(f"{path}: unreadable tile record ({e}); delete the folder to start over") from e
        if found != record:
            raise TileRecordError(f"{path}: its tiles are of other inputs or settings ({found} != {record}); use "
                                  "another folder or delete it")
        if done.shape != blocks or matrix.shape != shape or matrix.dtype != np.float64:
            raise TileRecordError(f"{path}: corrupt tile record (done {done.shape}, matrix {matrix.shape} "
                                  f"{matrix.dtype}); delete the folder to start over")
        return matrix, done.astype(bool)
    path.mkdir(parents=True, exist_ok=True)
    matrix = np.lib.format.open_memmap(path / MATRIX, mode="w+", dtype=np.float64, shape=shape)
    done = np.zeros(blocks, dtype=bool)
    _save_done(path, done)
    tmp = meta.with_suffix(".tmp")
    tmp.write_text(json.dumps(record))
    os.replace(tmp, meta)
    return matrix, done


def _save_done(path: Path, done: np.ndarray) -> None:
    """Write the done-blocks grid atomically (temporary file, then rename)."""
    tmp = path / "done.tmp.npy"
    np.save(tmp, done)
    os.replace(tmp, path / DONE)


def tiled_matrix(shape: tuple[int, int], task: Callable[[int, int, int, int], tuple[Callable[..., Any], tuple]],
                 symmetric: bool, tile: int = TILE, executor: Executor | None = None, path: str | Path | None = None,
                 fingerprint: str = "", on_tile: Callable[[int, int, int], None] | None = None) -> np.ndarray:
    """The ``shape`` float64 matrix computed block by block (module doc).

    ``task(i0, i1, j0, j1)`` returns ``(fn, args)``: ``fn(*args)`` (top-level, run on ``executor``) gives the block
    ``[i0:i1, j0:j1]`` as an array; in a ``symmetric`` matrix only its entries above the diagonal are kept.
    ``path``: resumable folder (module doc), checked against ``fingerprint`` (a string identifying the inputs and
    settings). ``on_tile(block_row, block_col, pairs)`` is called after each block is stored (progress; raising
    there interrupts the run, which resumes later). Returns the matrix (a memory map of the folder with ``path``).

    Example:
        >>> def add(i0: int, i1: int, j0: int, j1: int) -> tuple:
        ...     return np.add.outer, (np.arange(i0, i1, dtype=float), np.arange(j0, j1, dtype=float))
        >>> tiled_matrix((3, 3), add, symmetric=True, tile=2).tolist()
        [[0.0, 1.0, 2.0], [1.0, 0.0, 3.0], [2.0, 3.0, 0.0]]
    """
    n, m = shape
    if symmetric and n != m:
        raise ValueError(f"a symmetric matrix is square, got {shape}")
    blocks = tile_blocks(n, m, tile, symmetric)
    if path is None:
        matrix, done = np.zeros(shape, dtype=np.float64), np.zeros((-(-n // tile), -(-m // tile)), dtype=bool)
    else:
        path = Path(path)
        matrix, done = _open(path, (n, m), tile, fingerprint)
    todo = [(a, b) for a, b in blocks if not done[a, b]]
    tasks = []
    for a, b in todo:
        fn, args = task(a * tile, min(n, (a + 1) * tile), b * tile, min(m, (b + 1) * tile))
        tasks.append((fn, args))

    def store(k: int, values: Any) -> None:  # noqa: ANN401 - an array or tensor
        a, b = todo[k]
        i0, j0 = a * tile, b * tile
        block = np.asarray(values, dtype=np.float64)
        i1, j1 = i0 + block.shape[0], j0 + block.shape[1]
        if symmetric:
            keep = np.arange(i0, i1)[:, None] < np.arange(j0, j1)[None, :]
            block = np.where(keep, block, 0.0)
            if a == b:
                block = block + block.T
            else:
                matrix[j0:j1, i0:i1] = block.T
        matrix[i0:i1, j0:j1] = block
        pairs = int(keep.sum()) if symmetric else block.size
        if path is not None:
            matrix.flush()
            done[a, b] = True
            _save_done(path, done)
        if on_tile is not None:
            on_tile(a, b, pairs)

    run_tasks(_call, tasks, executor, done=store)
    return matrix


def _call(fn: Callable[..., Any], args: tuple) -> Any:  # noqa: ANN401
    """Worker side of a block: ``fn(*args)``."""
    return fn(*args)


def _pairs_block(fn: Callable[[Tensor, Tensor], Tensor], a: Tensor, b: Tensor) -> Tensor:
    """Block of ``fn`` over every pair of rows of ``a`` and ``b``: ``(len(a), len(b))``."""
    i, j = torch.meshgrid(torch.arange(a.shape[0]), torch.arange(b.shape[0]), indexing="ij")
    return fn(a[i.reshape(-1)], b[j.reshape(-1)]).reshape(a.shape[0], b.shape[0]).detach().cpu()


def pair_matrix(fn: Callable[[Tensor, Tensor], Tensor], x: Tensor, y: Tensor | None = None, tile: int = TILE,
                executor: Executor | None = None, path: str | Path | None = None, fingerprint: str = "") -> Tensor:
    """``(n, m)`` float64 ``fn`` between the rows of ``x (n, ...)`` and ``y (m, ...)`` in tiles (module doc);
    ``y=None``: the symmetric matrix of ``x`` (pairs ``i < j`` once, zero diagonal). ``fn(a, b) -> (P,)`` maps
    ``P`` pairs of rows to their values (top-level, so it pickles for ``executor``). Returned on ``x``'s device.

    Example:
        >>> def gap(a: Tensor, b: Tensor) -> Tensor:
        ...     return (a - b).norm(dim=-1)
        >>> pair_matrix(gap, torch.tensor([[0.0], [3.0], [4.0]])).tolist()
        [[0.0, 3.0, 4.0], [3.0, 0.0, 1.0], [4.0, 1.0, 0.0]]
    """
    symmetric = y is None
    other = x if y is None else y

    def task(i0: int, i1: int, j0: int, j1: int) -> tuple:
        rows, cols = x[i0:i1], other[j0:j1]
        if symmetric and i0 == j0:  # the diagonal block: each pair i < j once
            return _upper_block, (fn, rows)
        return _pairs_block, (fn, rows, cols)

    out = tiled_matrix((x.shape[0], other.shape[0]), task, symmetric, tile, executor, path, fingerprint)
    return torch.from_numpy(np.array(out)).to(x.device)


def _upper_block(fn: Callable[[Tensor, Tensor], Tensor], a: Tensor) -> Tensor:
    """Diagonal block of a symmetric matrix: ``fn`` over the pairs ``i < j`` of rows of ``a`` (zeros elsewhere)."""
    n = a.shape[0]
    i, j = torch.triu_indices(n, n, 1)
    out = torch.zeros(n, n, dtype=torch.float64)
    out[i, j] = fn(a[i], a[j]).detach().cpu().to(torch.float64)
    return out
