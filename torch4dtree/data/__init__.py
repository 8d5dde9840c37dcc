"""Synthetic growing plants with ground truth: the package's embedded default data (see :mod:`.synthetic`)."""

from .synthetic import (
    KINDS,
    SyntheticPlant,
    default_times,
    evaluate_warp,
    label_layer,
    label_parts,
    plant_seed,
    relative_warp,
    sample_growth_warp,
    synthetic_dataset,
    synthetic_plant,
)
from .writing import LABEL_SCHEME, read_ground_truth, run_synth, write_dataset

__all__ = [
    "KINDS", "LABEL_SCHEME", "SyntheticPlant", "default_times", "evaluate_warp", "label_layer", "label_parts",
    "plant_seed", "read_ground_truth", "relative_warp", "run_synth", "sample_growth_warp", "synthetic_dataset",
    "synthetic_plant", "write_dataset",
]
