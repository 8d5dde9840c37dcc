"""Synthetic growing plants with organ ground truth: the package's embedded default data.

:mod:`.synthetic` generates plants (built by :mod:`.clock`, :mod:`.kinds`, :mod:`.plant_model`,
:mod:`.organ_curves`, :mod:`.scanning`; labels in :mod:`.labels`), :mod:`.writing` writes them as
dataset folders, :mod:`.truth` scores registrations against their labels, and :mod:`.dataset` is a
``torch.utils.data.Dataset`` over any dataset folder (imported on its own: it needs ``torch.utils.data``).
"""

from .examples import helix_arc, helix_pair, leaf_pair
from .synthetic import (
    KINDS,
    SHOOT_OFFSET,
    SPUR_LABEL,
    STEM_LABEL,
    SyntheticPlant,
    default_times,
    evaluate_warp,
    label_layer,
    label_organ,
    label_parts,
    parent_label,
    plant_seed,
    relative_warp,
    sample_growth_warp,
    synthetic_dataset,
    synthetic_plant,
)
from .truth import (
    IdentityScores,
    identity_scores,
    longest_path_organ,
    main_branch_organs,
    score_registration,
)
from .writing import LABEL_SCHEME, read_ground_truth, run_synth, write_dataset, write_skeleton_swc

__all__ = [
    "KINDS", "LABEL_SCHEME", "SHOOT_OFFSET", "SPUR_LABEL", "STEM_LABEL", "IdentityScores", "SyntheticPlant",
    "default_times", "evaluate_warp", "helix_arc", "helix_pair", "identity_scores", "label_layer", "label_organ",
    "label_parts", "leaf_pair", "longest_path_organ", "main_branch_organs", "parent_label", "plant_seed",
    "read_ground_truth", "relative_warp", "run_synth", "sample_growth_warp", "score_registration",
    "synthetic_dataset", "synthetic_plant", "write_dataset", "write_skeleton_swc",
]
