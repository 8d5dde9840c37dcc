"""torch4dtree: statistical analysis and generation of 4D tree-shaped structures in PyTorch.

The public names below are imported on first use (PEP 562), so that ``import torch4dtree.cli`` (the console
script, ``--help``) does not pay for importing torch, scipy and numba.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

_CURVES = ("curve_length", "dp_warp", "elastic_distance", "inverse_srvf", "register_curves", "srvf", "srvf_inner",
           "srvf_sq_norm", "warp_curve", "warp_srvf")
_TREES = ("AlignedTrees", "TreeError", "TreeSequence", "Trees", "cycle_consistency", "geodesic", "pairwise_distances",
          "register_to_reference", "register_trees")
_MODEL = ("FourDTreeModel", "OrganModel", "load")
_TEMPORAL = ("register4d",)
# public name -> the subpackage that defines it
_EXPORTS = {**dict.fromkeys(_CURVES, "curves"), **dict.fromkeys(_TREES, "trees"), **dict.fromkeys(_MODEL, "model"),
            **dict.fromkeys(_TEMPORAL, "temporal")}
# every subpackage and top-level module, reachable as ``torch4dtree.NAME`` after a bare ``import torch4dtree``
_SUBPACKAGES = ("bench", "cli", "config", "curves", "data", "evaluate", "io", "model", "render", "settings", "space",
                "temporal", "trees")

__all__ = [
    "AlignedTrees", "FourDTreeModel", "OrganModel", "TreeError", "TreeSequence", "Trees", "curve_length",
    "cycle_consistency", "dp_warp", "elastic_distance", "geodesic", "inverse_srvf", "load", "pairwise_distances",
    "register4d", "register_curves", "register_to_reference", "register_trees", "srvf", "srvf_inner", "srvf_sq_norm",
    "warp_curve", "warp_srvf",
]

if TYPE_CHECKING:  # what static tools see; at run time __getattr__ imports on demand
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
    from .model import FourDTreeModel, OrganModel, load
    from .temporal import register4d
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


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        value = getattr(importlib.import_module(f".{_EXPORTS[name]}", __name__), name)
        globals()[name] = value  # later lookups skip this function
        return value
    if name in _SUBPACKAGES:  # ``torch4dtree.curves.srvf`` after a bare ``import torch4dtree``
        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
