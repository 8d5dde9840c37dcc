"""Run the heavy work elsewhere: executors (inline, local processes, Dask), tasks, all-pairs tiles."""

from .executors import (
    DISTRIBUTED_HINT,
    DaskExecutor,
    InlineExecutor,
    check_executor,
    local_executor,
    make_executor,
    single_thread,
)
from .tasks import IN_FLIGHT, move, run_tasks
from .tiles import PAIR_CHUNK, TILE, TileRecordError, pair_matrix, run_pieces, tile_blocks, tiled_matrix

__all__ = [
    "DISTRIBUTED_HINT", "IN_FLIGHT", "PAIR_CHUNK", "TILE", "DaskExecutor", "InlineExecutor", "TileRecordError",
    "check_executor", "local_executor", "make_executor", "move", "pair_matrix", "run_pieces", "run_tasks",
    "single_thread", "tile_blocks", "tiled_matrix",
]
