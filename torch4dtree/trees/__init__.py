"""Trees: ragged batches (`Trees`, `TreeSequence`), skeleton graphs to branch hierarchies, SRVF trees in a
common slot layout (`AlignedTrees`), elastic registration of trees, geodesics and point correspondences."""

from ..settings import DEFAULT_T
from .aligned import AlignedTrees, Lambdas
from .correspondence import CycleConsistency, cycle_consistency, map_points
from .geodesic import geodesic
from .registration import (
    TreeRegistration,
    index_order_matches,
    pairwise_distances,
    register_to_reference,
    register_trees,
)
from .structures import TreeError, Trees, TreeSequence

__all__ = [
    "DEFAULT_T", "AlignedTrees", "CycleConsistency", "Lambdas", "TreeError", "TreeRegistration", "TreeSequence",
    "Trees", "cycle_consistency", "geodesic", "index_order_matches", "map_points", "pairwise_distances",
    "register_to_reference", "register_trees",
]
