"""torch4dtree: statistical analysis and generation of 4D tree-shaped structures in PyTorch."""

from .curves import (
    curve_length,
    dp_warp,
    elastic_distance,
    inverse_srvf,
    register_curves,
    srvf,
    srvf_inner,
    srvf_sq_norm,
    warp_curve,
    warp_srvf,
)
from .trees import (
    AlignedTrees,
    TreeError,
    Trees,
    TreeSequence,
    cycle_consistency,
    geodesic,
    pairwise_distances,
    register_to_reference,
    register_trees,
)

__version__ = "0.1.0"

__all__ = [
    "AlignedTrees", "TreeError", "TreeSequence", "Trees", "curve_length", "cycle_consistency", "dp_warp",
    "elastic_distance", "geodesic", "inverse_srvf", "pairwise_distances", "register_curves", "register_to_reference",
    "register_trees", "srvf", "srvf_inner", "srvf_sq_norm", "warp_curve", "warp_srvf",
]
