"""The generative model of 4D trees (docs/method.md §5): 4D mean and modes, the truncated-Gaussian sampler, forecasting,
the bundled :class:`FourDTreeModel` and its checkpoints (``load``)."""

from .checkpoint import CheckpointError, load, save_model
from .fourd import Forecast, FourDTreeModel, ModelOutput, Score, sequence_validity
from .sampler import TruncatedNormalSampler, truncated_normal_variance
from .trajectory import TrajectoryMean, TrajectoryPCA, flatten_srvf, unflatten_srvf

__all__ = [
    "CheckpointError", "Forecast", "FourDTreeModel", "ModelOutput", "Score", "TrajectoryMean", "TrajectoryPCA",
    "TruncatedNormalSampler", "flatten_srvf", "load", "save_model", "sequence_validity", "truncated_normal_variance",
    "unflatten_srvf",
]
