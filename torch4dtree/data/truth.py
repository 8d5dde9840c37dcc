"""Scoring branch identities against the synthetic plants' organ ground truth.

A registration matches branches of a moving tree to branches of a reference tree; each branch
carries the label of its majority organ (see :mod:`.synthetic` and :mod:`.labels`). Because the hierarchy rule
decides which skeleton paths become branches, a label may label several branches of one tree
or none, so the scores are stated over matched pairs and over labels, not over branches:

* **precision**: of the matched pairs whose two labels are both valid (not in ``ignore``), the
  share whose labels are equal;
* **recall**: of the valid labels present in both trees, the share for which some branch with
  that label in the moving tree is matched to some branch with that label in the reference.

Spurs (:data:`~.labels.SPUR_LABEL`) and unknown labels (``-1``) are ignored by default.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from .labels import SPUR_LABEL

if TYPE_CHECKING:
    from ..trees.registration import TreeRegistration
    from ..trees.structures import Trees
    from .synthetic import SyntheticPlant

DEFAULT_IGNORE = (SPUR_LABEL, -1)


class IdentityScores(NamedTuple):
    """Result of :func:`identity_scores` (``nan`` when a denominator is 0)."""

    precision: float  # equal-label share of the matched pairs with two valid labels
    recall: float  # share of the valid labels common to both trees whose branches were matched together
    n_matched: int  # matched pairs with two valid labels (precision's denominator)
    n_common: int  # valid labels present in both trees (recall's denominator)


def identity_scores(
    matches: Sequence[tuple[int, int]],
    labels_moving: Sequence[int],
    labels_reference: Sequence[int],
    ignore: Collection[int] = DEFAULT_IGNORE,
) -> IdentityScores:
    """Precision and recall of branch matches against per-branch labels (module doc).

    Args:
        matches: ``[(moving branch, reference branch), ...]`` indices into the label lists (as
            :attr:`~torch4dtree.trees.registration.TreeRegistration.matches` gives for single trees).
        labels_moving / labels_reference: the label of every branch of each tree.
        ignore: labels that are not organs (spurs, unknown).

    Example (the registration swapped leaves 3 and 4):
        >>> identity_scores([(0, 0), (1, 2), (2, 1)], [0, 3, 4], [0, 3, 4])
        IdentityScores(precision=0.3333333333333333, recall=0.3333333333333333, n_matched=3, n_common=3)
    """
    lm, lr = [int(x) for x in labels_moving], [int(x) for x in labels_reference]
    skip = {int(x) for x in ignore}
    for i, j in matches:
        if not (0 <= i < len(lm) and 0 <= j < len(lr)):
            raise IndexError(f"match ({i}, {j}) is outside the trees ({len(lm)} and {len(lr)} branches)")
    valid = [(lm[i], lr[j]) for i, j in matches if lm[i] not in skip and lr[j] not in skip]
    correct = {a for a, b in valid if a == b}
    common = (set(lm) & set(lr)) - skip
    precision = sum(a == b for a, b in valid) / len(valid) if valid else float("nan")
    recall = len(correct & common) / len(common) if common else float("nan")
    return IdentityScores(precision, recall, len(valid), len(common))


def score_registration(
    registration: TreeRegistration, moving: Trees, reference: Trees, ignore: Collection[int] = DEFAULT_IGNORE,
) -> IdentityScores:
    """:func:`identity_scores` of a registration of two single trees, from their ``label`` attributes.

    Example:
        >>> import numpy as np
        >>> from torch4dtree import Trees
        >>> stem, leaf = np.array([[0.0, 0, 0], [0, 0, 10]]), np.array([[0.0, 0, 5], [4, 0, 8]])
        >>> tree = Trees.from_branches([[stem, leaf]], [[-1, 0]], T=8, labels=[[0, 3]])
        >>> from torch4dtree.trees.registration import register_trees
        >>> score_registration(register_trees(tree, tree), tree, tree)
        IdentityScores(precision=1.0, recall=1.0, n_matched=2, n_common=2)
    """
    if moving.num_trees != 1 or reference.num_trees != 1:
        raise ValueError(f"score_registration takes single trees, got {moving.num_trees} and {reference.num_trees}")
    return identity_scores(registration.matches, moving.label.tolist(), reference.label.tolist(), ignore)


def longest_path_organ(xyz: np.ndarray, parent: np.ndarray, organ: np.ndarray) -> int:
    """The organ at the end of a skeleton's longest root-to-leaf path (what the longest-path rule makes
    the main branch run into); ``0`` when it is the stem's own tip.

    Computed here from the skeleton alone, independently of the package's hierarchy rules.

    Example (a stem of 10 mm with a 12 mm leaf, label 3, at 5 mm):
        >>> xyz = np.array([[0.0, 0, 0], [0, 0, 5], [0, 0, 10], [12, 0, 5]])
        >>> longest_path_organ(xyz, np.array([-1, 0, 1, 1]), np.array([0, 0, 0, 3]))
        3
    """
    xyz, parent = np.asarray(xyz, dtype=np.float64), np.asarray(parent, dtype=np.int64)
    n = len(parent)
    children: list[list[int]] = [[] for _ in range(n)]
    for v, p in enumerate(parent.tolist()):
        if p >= 0:
            children[p].append(v)
    order = [int(np.nonzero(parent < 0)[0][0])]
    for v in order:  # breadth-first, grows while iterating
        order.extend(children[v])
    dist = np.zeros(n)
    for v in order[1:]:
        dist[v] = dist[parent[v]] + float(np.linalg.norm(xyz[v] - xyz[parent[v]]))
    return int(organ[int(np.argmax(dist))])


def main_branch_organs(plant: SyntheticPlant) -> list[int]:
    """Per frame, the organ at the tip of the main branch of the plant's derived tree (any hierarchy rule).

    The main branch ends at a skeleton node (resampling keeps end points): the organ of the node
    nearest its last point.

    Example:
        >>> from torch4dtree.data import synthetic_plant
        >>> organs = main_branch_organs(synthetic_plant("tomato", seed=0, n_frames=2, T=8))
        >>> len(organs)
        2
    """
    f = plant.sequence.frames
    tips = f.points[f.parent == -1, -1].detach().double().cpu().numpy()
    out = []
    for (xyz, _, organ), tip in zip(plant.skeletons, tips):
        out.append(int(organ[int(np.argmin(((xyz - tip) ** 2).sum(1)))]))
    return out

