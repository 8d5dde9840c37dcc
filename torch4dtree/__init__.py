"""torch4dtree: statistical analysis and generation of 4D tree-shaped structures in PyTorch."""

from .aligned import AlignedTrees
from .correspondence import cycle_consistency
from .curves import curve_length, inverse_srvf, srvf, srvf_inner, srvf_sq_norm, warp_curve, warp_srvf
from .geodesic import geodesic
from .registration import pairwise_distances, register_to_reference, register_trees
from .structures import TreeError, Trees, TreeSequence
from .warping import dp_warp, elastic_distance, register_curves

__version__ = "0.1.0"

__all__ = [
    "AlignedTrees", "TreeError", "TreeSequence", "Trees", "curve_length", "cycle_consistency", "dp_warp",
    "elastic_distance", "geodesic", "inverse_srvf", "pairwise_distances", "register_curves", "register_to_reference",
    "register_trees", "srvf", "srvf_inner", "srvf_sq_norm", "warp_curve", "warp_srvf",
]
