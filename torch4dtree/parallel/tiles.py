"""All-pairs matrices in pieces: bounded tasks on any executor, an on-disk matrix that an interrupted run resumes.

Two ways to cut the pairs into tasks:

* :func:`tiled_matrix`: ``tile x tile`` blocks (``TILE = 64``: 4,096 pairs a task amortise the scheduling and a
  worker holds only ``2 x tile`` items; smaller tiles for small matrices, :func:`default_tile`); a symmetric
  matrix (zero diagonal) computes only the blocks on and above the diagonal, each pair ``i < j`` once, and mirrors
  them. For functions whose value of a pair does not depend on which pairs share its batch (the batched tree
  registrations: checked in ``tests/parallel``), the matrix is then that of the serial computation, whatever the
  tiling or executor.
* :func:`pair_matrix`: consecutive pieces of a fixed pair list (cheap pairs such as trajectories, whose batched
  solver may give a pair other last bits in another batch): the pieces are the serial computation's own batches.

With ``path`` (a folder) the matrix is ``distances.npy`` (a memory map, so it may exceed the RAM), ``tiles.json``
says what it is (shape, pieces, the caller's fingerprint of the inputs and settings), and ``done.npy`` flags the
finished pieces; a piece is flagged (written to a temporary file, then renamed: atomic) only after its values are
flushed to the matrix. Run again on the same folder with the same inputs, only unfinished pieces are computed.
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

__all__ = ["MIN_BLOCKS", "PAIR_CHUNK", "TILE", "TileRecordError", "default_tile", "pair_matrix", "run_pieces",
           "tile_blocks", "tiled_matrix"]

TILE = 64
# below 8 x TILE items a side, tiles shrink so a side still has this many blocks (36 tasks on and above the
# diagonal): a few workers stay busy on small matrices
MIN_BLOCKS = 8
PAIR_CHUNK = 2048  # pairs a task of pair_matrix (cheap pairs: trajectories)
MATRIX, RECORD, DONE = "distances.npy", "tiles.json", "done.npy"


class TileRecordError(ValueError):
    """A tile folder that cannot be resumed: unreadable, or written for other inputs, settings or tiles."""


def default_tile(n: int) -> int:
    """The tile size for ``n`` items a side: ``TILE``, or smaller so that a side has ``MIN_BLOCKS`` blocks.

    Example:
        >>> default_tile(30), default_tile(100), default_tile(10_000)
        (4, 13, 64)
    """
    return max(1, min(TILE, -(-n // MIN_BLOCKS)))


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


def _open(path: Path, shape: tuple[int, int], pieces: int, fingerprint: str) -> tuple[np.ndarray, np.ndarray]:
    """The matrix memory map and the done-pieces flags of a folder, created or checked for resuming."""
    record = {"shape": list(shape), "pieces": pieces, "fingerprint": fingerprint}
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
        if done.shape != (pieces,) or done.dtype != bool or matrix.shape != shape or matrix.dtype != np.float64:
            raise TileRecordError(f"{path}: corrupt tile record (done {done.shape} {done.dtype}, matrix "
                                  f"{matrix.shape} {matrix.dtype}); delete the folder to start over")
        return matrix, done
    path.mkdir(parents=True, exist_ok=True)
    matrix = np.lib.format.open_memmap(path / MATRIX, mode="w+", dtype=np.float64, shape=shape)
    done = np.zeros(pieces, dtype=bool)
    _save_done(path, done)
    tmp = path / "tiles.tmp.json"
    tmp.write_text(json.dumps(record))
    os.replace(tmp, meta)
    return matrix, done


def _save_done(path: Path, done: np.ndarray) -> None:
    """Write the done-pieces flags atomically (temporary file, then rename)."""
    tmp = path / "done.tmp.npy"
    np.save(tmp, done)
    os.replace(tmp, path / DONE)


def run_pieces(shape: tuple[int, int], count: int, task: Callable[[int], tuple[Callable[..., Any], tuple]],
               place: Callable[[np.ndarray, int, Any], int], executor: Executor | None = None,
               path: str | Path | None = None, fingerprint: str = "",
               on_piece: Callable[[int, int], None] | None = None) -> np.ndarray:
    """Fill a ``shape`` float64 matrix from ``count`` pieces (the engine of :func:`tiled_matrix` and
    :func:`pair_matrix`): piece ``k`` is the task ``fn(*args)`` of ``task(k) = (fn, args)`` (run on ``executor``),
    and ``place(matrix, k, values)`` writes its values and returns how many pairs it held. With ``path`` (module
    doc) the finished pieces are skipped and each new one is flushed, then marked. ``on_piece(k, pairs)`` is
    called after each piece is stored (progress; raising there interrupts the run, which resumes later)."""
    if path is None:
        matrix, done = np.zeros(shape, dtype=np.float64), np.zeros(count, dtype=bool)
    else:
        path = Path(path)
        matrix, done = _open(path, shape, count, fingerprint)
    todo = [k for k in range(count) if not done[k]]

    def store(t: int, values: Any) -> None:  # noqa: ANN401 - an array or tensor
        k = todo[t]
        pairs = place(matrix, k, values)
        if path is not None:
            matrix.flush()
            done[k] = True
            _save_done(path, done)
        if on_piece is not None:
            on_piece(k, pairs)

    run_tasks(_call, (task(k) for k in todo), executor, done=store, keep=False)
    return matrix


def tiled_matrix(shape: tuple[int, int], task: Callable[[int, int, int, int], tuple[Callable[..., Any], tuple]],
                 symmetric: bool, tile: int | None = None, executor: Executor | None = None,
                 path: str | Path | None = None,
                 fingerprint: str = "", on_tile: Callable[[int, int, int], None] | None = None) -> np.ndarray:
    """The ``shape`` float64 matrix computed block by block (module doc).

    ``task(i0, i1, j0, j1)`` returns ``(fn, args)``: ``fn(*args)`` (top-level, run on ``executor``) gives the block
    ``[i0:i1, j0:j1]`` as an array; in a ``symmetric`` matrix only its entries above the diagonal are kept.
    ``tile``: the block side (default :func:`default_tile` of the larger side).
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
    tile = default_tile(max(n, m)) if tile is None else tile
    blocks = tile_blocks(n, m, tile, symmetric)

    def bounds(k: int) -> tuple[int, int, int, int]:
        a, b = blocks[k]
        return a * tile, min(n, (a + 1) * tile), b * tile, min(m, (b + 1) * tile)

    def place(matrix: np.ndarray, k: int, values: Any) -> int:  # noqa: ANN401 - an array or tensor
        i0, i1, j0, j1 = bounds(k)
        block = np.asarray(values, dtype=np.float64)
        if block.shape != (i1 - i0, j1 - j0):
            raise ValueError(f"block {blocks[k]} has shape {block.shape}, expected {(i1 - i0, j1 - j0)}")
        if not symmetric:
            matrix[i0:i1, j0:j1] = block
            return block.size
        keep = np.arange(i0, i1)[:, None] < np.arange(j0, j1)[None, :]
        block = np.where(keep, block, 0.0)
        if i0 == j0:
            block = block + block.T
        else:
            matrix[j0:j1, i0:i1] = block.T
        matrix[i0:i1, j0:j1] = block
        return int(keep.sum())

    def progress(k: int, pairs: int) -> None:
        if on_tile is not None:
            on_tile(*blocks[k], pairs)

    return run_pieces(shape, len(blocks), lambda k: task(*bounds(k)), place, executor, path,
                      f"tiles {tile} {fingerprint}", progress)


def _call(fn: Callable[..., Any], args: tuple) -> Any:  # noqa: ANN401
    """Worker side of a piece: ``fn(*args)``."""
    return fn(*args)


def pair_matrix(fn: Callable[[Tensor, Tensor], Tensor], x: Tensor, y: Tensor | None = None,
                chunk: int = PAIR_CHUNK, executor: Executor | None = None, path: str | Path | None = None,
                fingerprint: str = "") -> Tensor:
    """``(n, m)`` values of ``fn`` between the rows of ``x (n, ...)`` and ``y (m, ...)``; ``y=None``: the
    symmetric matrix of ``x`` (pairs ``i < j`` once, zero diagonal). ``fn(a, b) -> (P,)`` maps ``P`` pairs of rows
    to their values (top-level, so it pickles for ``executor``).

    The pairs, in row-major order (``torch.triu_indices`` order when symmetric), are cut into consecutive pieces of
    ``chunk`` pairs, one task each (``path``: resumable, as :func:`tiled_matrix`). Where ``fn`` is batched and its
    bits depend on which pairs share a batch, the result is still that of ``fn`` on the same consecutive pieces of
    the same pair list, whatever the executor. Returned in ``x``'s dtype and device.

    Example:
        >>> def gap(a: Tensor, b: Tensor) -> Tensor:
        ...     return (a - b).norm(dim=-1)
        >>> pair_matrix(gap, torch.tensor([[0.0], [3.0], [4.0]]), chunk=2).tolist()
        [[0.0, 3.0, 4.0], [3.0, 0.0, 1.0], [4.0, 1.0, 0.0]]
    """
    if chunk < 1:
        raise ValueError(f"chunk must be at least 1, got {chunk}")
    other = x if y is None else y
    n, m = x.shape[0], other.shape[0]
    if y is None:
        i, j = torch.triu_indices(n, n, 1)
    else:
        i, j = (g.reshape(-1) for g in torch.meshgrid(torch.arange(n), torch.arange(m), indexing="ij"))
    starts = list(range(0, i.numel(), chunk))
    pieces = [(i[a:a + chunk].numpy(), j[a:a + chunk].numpy()) for a in starts]

    def task(k: int) -> tuple:
        rows, cols = pieces[k]
        return _pairs, (fn, x[torch.from_numpy(rows)], other[torch.from_numpy(cols)])

    def place(matrix: np.ndarray, k: int, values: Any) -> int:  # noqa: ANN401 - a tensor
        rows, cols = pieces[k]
        v = np.asarray(values, dtype=np.float64)
        matrix[rows, cols] = v
        if y is None:
            matrix[cols, rows] = v
        return len(v)

    out = run_pieces((n, m), len(pieces), task, place, executor, path, f"pairs {chunk} {fingerprint}")
    return torch.from_numpy(np.array(out)).to(device=x.device, dtype=x.dtype)


def _pairs(fn: Callable[[Tensor, Tensor], Tensor], a: Tensor, b: Tensor) -> Tensor:
    """Worker side of :func:`pair_matrix`: ``fn(a, b)`` as float64 on the CPU."""
    return fn(a, b).detach().cpu().to(torch.float64)
