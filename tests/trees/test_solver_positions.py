"""``"closest"`` positions (``register_sequence``'s default): which places of a child the solver compares."""

from __future__ import annotations

import numpy as np
import torch

from torch4dtree import Trees, TreeSequence
from torch4dtree.data import synthetic_plant
from torch4dtree.temporal import identity_accuracy, register_sequence


def _stem(length: float, organs: list[tuple[float, int]]) -> Trees:
    """A vertical stem ``length`` mm long carrying like 20 mm organs ``(arc length from the base, label)``, each
    leaving it at 60 degrees the same way (only their places tell them apart); listed top-down (a registration's
    index-order fallback is then not the answer)."""
    t = np.linspace(0.0, 1.0, 40)[:, None]
    direction = np.array([np.sin(np.radians(60.0)), 0.0, np.cos(np.radians(60.0))])
    organs = sorted(organs, reverse=True)
    branches = [t * np.array([0.0, 0.0, length])]
    branches += [np.array([0.0, 0.0, arc]) + t * (20.0 if label != 21 or length > 100.0 else 1.0) * direction
                 for arc, label in organs]
    return Trees.from_branches([branches], [[-1] + [0] * len(organs)], T=32, dtype=torch.float64,
                               labels=[[1] + [label for _, label in organs]])


def _slot_organs(seq: TreeSequence) -> list[tuple[int | None, ...]]:
    """Every slot of ``register_sequence(seq)`` as its organ in each frame (``None`` where absent)."""
    ident = register_sequence(seq).identity.tolist()
    counts = seq.frames.num_branches.tolist()
    labels = seq.frames.label.tolist()
    starts = np.concatenate([[0], np.cumsum(counts)]).tolist()
    return sorted((tuple(None if ident[j][k] < 0 else labels[starts[j] + ident[j][k]] for j in range(len(counts)))
                   for k in range(len(ident[0]))), key=str)


def test_organs_keep_their_share_of_a_stem_that_elongates_throughout() -> None:
    """A stem elongates evenly by 1.25x while a 1 mm bud at its base becomes a 20 mm shoot: every organ above keeps
    its share of the stem, while its node rank rises by one and its height moves toward the next organ's. Node
    ranks and arc lengths alone shift every like organ by one place; the fractions keep each with itself."""
    organs = [(10.0, 21), (30.0, 22), (50.0, 23), (70.0, 24)]
    earlier = _stem(100.0, organs)
    later = _stem(125.0, [(1.25 * arc, label) for arc, label in organs])
    seq = TreeSequence(Trees.cat([earlier, later]), torch.tensor([0.0, 1.0], dtype=torch.float64))
    assert _slot_organs(seq) == [(1, 1), (21, 21), (22, 22), (23, 23), (24, 24)]


def test_fractions_are_not_compared_on_a_stem_that_grew_much() -> None:
    """Synthetic maize with 4 frames: internodes elongate 2x and more between frames, node ranks stay and a leaf's
    share of the stem moves onto its neighbour's; fractions compared there lose whole-sequence identities (seed 0:
    0.72), the growth gate keeps all."""
    maize = synthetic_plant("maize", 0, n_frames=4, T=24, dtype=torch.float64).sequence
    assert identity_accuracy(register_sequence(maize), maize.frames.label).sequence == 1.0
