"""torch4dtree: statistical analysis and generation of 4D tree-shaped structures in PyTorch."""

from .curves import curve_length, inverse_srvf, srvf, srvf_inner, srvf_sq_norm, warp_curve, warp_srvf
from .structures import TreeError, Trees, TreeSequence

__version__ = "0.1.0"

__all__ = [
    "TreeError", "TreeSequence", "Trees", "curve_length", "inverse_srvf", "srvf", "srvf_inner",
    "srvf_sq_norm", "warp_curve", "warp_srvf",
]
