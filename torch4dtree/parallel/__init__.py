"""Run the heavy work elsewhere: executors (inline, local processes, Dask), tasks, all-pairs tiles."""

from .executors import (
    DISTRIBUTED_HINT,
    DaskExecutor,
    InlineExecutor,
    RayExecutor,
    check_executor,
    local_executor,
    make_executor,
    single_thread,
)
from .tasks import IN_FLIGHT, move, run_tasks
from .tiles import (
    MIN_BLOCKS,
    PAIR_CHUNK,
    TILE,
    TileRecordError,
    default_tile,
    pair_matrix,
    run_pieces,
    tile_blocks,
    tiled_matrix,
)

__all__ = [
    "DISTRIBUTED_HINT", "IN_FLIGHT", "MIN_BLOCKS", "PAIR_CHUNK", "TILE", "DaskExecutor", "InlineExecutor",
    "RayExecutor", "TileRecordError", "check_executor", "default_tile", "local_executor", "make_executor", "move",
    "pair_matrix", "run_pieces", "run_tasks", "single_thread", "tile_blocks", "tiled_matrix",
]
