"""Reading and writing trees: SWC, the reference ``.mat`` trees, dataset folders, checkpoints."""

from .dataset import (
    DatasetError,
    LoadedSequence,
    LoadOptions,
    read_dataset,
    read_sequence,
    read_tree,
    sequence_folders,
    time_from_name,
    write_sequence,
)
from .files import write_bytes_safely, write_text_safely
from .mat import MatTreeError, read_mat_tree
from .rooting import ROOTS, choose_root, reroot, stem_base
from .swc import Skeleton, SWCError, read_swc, read_swc_skeleton, write_swc

__all__ = [
    "ROOTS", "DatasetError", "LoadOptions", "LoadedSequence", "MatTreeError", "SWCError", "Skeleton", "choose_root",
    "read_dataset", "read_mat_tree", "read_sequence", "read_swc", "read_swc_skeleton", "read_tree", "reroot",
    "sequence_folders", "stem_base", "time_from_name", "write_bytes_safely", "write_sequence", "write_swc",
    "write_text_safely",
]
