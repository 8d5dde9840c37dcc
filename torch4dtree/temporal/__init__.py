"""4D trees (docs/method.md §5): within-sequence registration, trajectories in R^k, temporal registration, 4D geodesics.

* :mod:`.within` registers every frame onto the next and writes a sequence in one slot layout
  (:class:`AlignedSequence`, one identity and one parameterisation per slot);
* :mod:`.trajectory` resamples per-frame coordinates on a common time grid and maps trajectories to
  their SRVFs and back;
* :mod:`.registration` finds optimal time warps between trajectories (batched DP) and 4D geodesics;
* :mod:`.spatiotemporal` registers two 4D trees in space and time (:func:`register4d`).
"""

from .registration import (
                           TemporalRegistration,
                           geodesic4d,
                           register_trajectories,
                           time_warp_trajectory,
                           trajectory_distance,
)
from .spatiotemporal import SpatiotemporalRegistration, combine_sequences, register4d, representative_tree
from .trajectory import Trajectory, fine_size, resample_trajectory, trajectory_from_srvf, trajectory_srvf
from .within import AlignedSequence, IdentityAccuracy, identity_accuracy, register_sequence

__all__ = [
    "AlignedSequence", "IdentityAccuracy", "SpatiotemporalRegistration", "TemporalRegistration", "Trajectory",
    "combine_sequences", "fine_size", "geodesic4d", "identity_accuracy", "register4d", "register_sequence",
    "register_trajectories", "representative_tree", "resample_trajectory", "time_warp_trajectory",
    "trajectory_distance", "trajectory_from_srvf", "trajectory_srvf",
]
