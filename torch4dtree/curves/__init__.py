"""Curves: SRVFs and their inverse, warps, rotations, and batched elastic registration (the DP engine).

* :mod:`.srvf` polylines, SRVFs, arc-length resampling; :mod:`.warps` warp utilities; :mod:`.rotation`
  closed-form rotations;
* :mod:`.dp_numba` / :mod:`.dp_torch` the two DP backends (numba kernels on the CPU, :mod:`.kernels_numba`,
  driven by :mod:`.dp_numba`; a vectorised torch twin for any device); :mod:`.refinement` the off-lattice
  Gauss-Newton warp refinement;
* :mod:`.register` the public ``dp_warp`` / ``register_curves`` / ``elastic_distance``.
"""

from .register import CurveRegistration, DPWarp, dp_warp, elastic_distance, register_curves
from .rotation import axis_rotation, kabsch, optimal_rotation, random_rotation, vertical_rotation
from .srvf import (
    curve_length,
    interpolate_curve,
    inverse_srvf,
    project_on_polyline,
    resample_polylines,
    srvf,
    srvf_inner,
    srvf_sq_distance,
    srvf_sq_norm,
    uniform_grid,
    warp_curve,
    warp_srvf,
)
from .warps import compose_warps, identity_warp, invert_warp, neighbourhood_steps, random_warp, warp_energy

__all__ = [
    "CurveRegistration", "DPWarp", "axis_rotation", "compose_warps", "curve_length", "dp_warp", "elastic_distance",
    "identity_warp", "interpolate_curve", "inverse_srvf", "invert_warp", "kabsch", "neighbourhood_steps",
    "optimal_rotation", "project_on_polyline", "random_rotation", "random_warp", "register_curves",
    "resample_polylines", "srvf", "srvf_inner", "srvf_sq_distance", "srvf_sq_norm", "uniform_grid", "vertical_rotation",
    "warp_curve", "warp_energy", "warp_srvf",
]
