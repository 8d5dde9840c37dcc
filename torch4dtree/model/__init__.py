"""The generative models of 4D trees (docs/method.md §5): the paper's :class:`FourDTreeModel` (4D mean and modes, the
truncated-Gaussian sampler, forecasting), the organ-by-organ :class:`OrganModel` (with :func:`forecast_organs` and
its stated :func:`forecast_distribution`), and their checkpoints (``save_model`` / ``load``)."""

from ..settings import OrganSettings
from .checkpoint import CheckpointError, load, save_model
from .fourd import Forecast, FourDTreeModel, ModelOutput, Score, sequence_validity
from .organ_forecast import ForecastDistribution, forecast_distribution, forecast_organs, forecast_point, seen_slots
from .organs import OrganModel, OrganModelError
from .sampler import TruncatedNormalSampler, truncated_normal_variance
from .trajectory import TrajectoryMean, TrajectoryPCA, flatten_srvf, unflatten_srvf

__all__ = [
    "CheckpointError", "Forecast", "ForecastDistribution", "FourDTreeModel", "ModelOutput", "OrganModel",
    "OrganModelError", "OrganSettings", "Score", "TrajectoryMean", "TrajectoryPCA", "TruncatedNormalSampler",
    "flatten_srvf", "forecast_distribution", "forecast_organs", "forecast_point", "load", "save_model", "seen_slots",
    "sequence_validity", "truncated_normal_variance", "unflatten_srvf",
]
