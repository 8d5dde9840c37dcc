"""Identities of a woody tree's spurs between two snapshots (``register_trees`` with ordered matching), and of organs
along growing axes in sequence mode (``register_sequence``'s positions)."""

from __future__ import annotations

import numpy as np
import torch

from torch4dtree import Trees, TreeSequence
from torch4dtree.data import synthetic_plant
from torch4dtree.settings import ORDER_TOL
from torch4dtree.temporal import identity_accuracy, register_sequence
from torch4dtree.trees import register_trees

SCAFFOLD_DIR = np.array([np.sin(np.radians(50)), 0.0, np.cos(np.radians(50))])  # leaves the trunk at 50 degrees


def _spur_dir(azimuth_deg: float) -> np.ndarray:
    """A unit direction perpendicular to the scaffold, ``azimuth_deg`` about it."""
    u = np.cross(SCAFFOLD_DIR, [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(SCAFFOLD_DIR, u)
    a = np.radians(azimuth_deg)
    return np.cos(a) * u + np.sin(a) * v


def _tree(azimuths: list[float]) -> Trees:
    """A 100 mm trunk, an 80 mm scaffold at its middle, 10 mm spurs at 0.2, 0.4, 0.6, 0.8 of the scaffold."""
    t = np.linspace(0.0, 1.0, 40)[:, None]
    trunk = t * np.array([0.0, 0.0, 100.0])
    base = np.array([0.0, 0.0, 40.0])
    scaffold = base + t * 80.0 * SCAFFOLD_DIR
    spurs = [base + 80.0 * s * SCAFFOLD_DIR + t * 10.0 * _spur_dir(az)
             for s, az in zip((0.2, 0.4, 0.6, 0.8), azimuths)]
    return Trees.from_branches([[trunk, scaffold, *spurs]], [[-1, 0, 1, 1, 1, 1]], T=32, dtype=torch.float64,
                               labels=[[1, 2, 3, 4, 5, 6]])


def test_spurs_that_turn_keep_their_places() -> None:
    """Spurs 4 and 5 exchange directions between the snapshots (60 degrees apart, each turns by 60 degrees): matched by
    shape they swap places along the scaffold, 16 mm apart; order-keeping matching keeps every spur
    with itself (a simulator's young tree turns spurs like this, docs/experiments.md)."""
    earlier = _tree([0.0, 120.0, 180.0, 300.0])
    later = _tree([0.0, 180.0, 120.0, 300.0])
    free = register_trees(later, earlier)  # the default: any matching
    assert (3, 4) in free.matches and (4, 3) in free.matches  # the case is a real one: any matching swaps them
    reg = register_trees(later, earlier, order_tol=ORDER_TOL)
    assert reg.matches == [(k, k) for k in range(6)]


def _grown_scaffold(length: float, spurs_at: list[float]) -> Trees:
    """A 100 mm trunk, a scaffold of ``length`` mm at its middle, identical 10 mm spurs at arc lengths ``spurs_at``
    (mm from the scaffold's base), each pointing the same way."""
    t = np.linspace(0.0, 1.0, 40)[:, None]
    trunk = t * np.array([0.0, 0.0, 100.0])
    base = np.array([0.0, 0.0, 40.0])
    scaffold = base + t * length * SCAFFOLD_DIR
    spurs = [base + a * SCAFFOLD_DIR + t * 10.0 * _spur_dir(90.0) for a in spurs_at]
    labels = [1, 2, *(3 + int(a) for a in spurs_at)]  # a spur's organ: its place on the scaffold
    return Trees.from_branches([[trunk, scaffold, *spurs]], [[-1, 0, *[1] * len(spurs_at)]], T=32,
                               dtype=torch.float64, labels=[labels])


def test_spurs_keep_their_arc_length_as_the_scaffold_grows() -> None:
    """A scaffold grows at its tip from 100 to 150 mm: its spurs stay 40 and 60 mm from its base and a new one
    appears at 90 mm. Compared as fractions of the scaffold (0.4, 0.6 against 0.27, 0.4, 0.6; ``"rank"`` below the
    main branch) every spur takes the place of the one above it; compared by arc length in the earlier scaffold's
    units (``"arclength"``) each keeps its own."""
    earlier = _grown_scaffold(100.0, [40.0, 60.0])
    later = _grown_scaffold(150.0, [40.0, 60.0, 90.0])
    lm, lr = later.label.tolist(), earlier.label.tolist()

    def organs(positions: str) -> list[tuple[int, int]]:
        return sorted((lm[a], lr[b]) for a, b in register_trees(later, earlier, positions=positions).matches)

    assert (93, 63) in organs("rank")  # the case is a real one: fractions shift the spurs by one place
    assert organs("arclength") == [(1, 1), (2, 2), (43, 43), (63, 63)]


def _stem_plant(stem: float, organs: list[tuple[float, float, float, int]]) -> Trees:
    """A vertical stem ``stem`` mm long carrying straight organs ``(arc length from the base, length, azimuth in
    degrees, label)`` that leave it at 60 degrees."""
    t = np.linspace(0.0, 1.0, 40)[:, None]
    branches = [t * np.array([0.0, 0.0, stem])]
    for arc, length, azimuth, _ in organs:
        a, tilt = np.radians(azimuth), np.radians(60.0)
        direction = np.array([np.sin(tilt) * np.cos(a), np.sin(tilt) * np.sin(a), np.cos(tilt)])
        branches.append(np.array([0.0, 0.0, arc]) + t * length * direction)
    return Trees.from_branches([branches], [[-1] + [0] * len(organs)], T=32, dtype=torch.float64,
                               labels=[[1] + [o[3] for o in organs]])


def _slot_organs(seq: TreeSequence, positions: str | None = None) -> list[tuple[int | None, ...]]:
    """Every slot of ``register_sequence(seq)`` as its organ label in each frame (``None`` where absent)."""
    aligned = register_sequence(seq, **({"positions": positions} if positions else {}))
    ident = aligned.identity.tolist()
    counts = seq.frames.num_branches.tolist()
    labels = seq.frames.label.tolist()
    starts = np.concatenate([[0], np.cumsum(counts)]).tolist()
    return sorted((tuple(None if ident[j][k] < 0 else labels[starts[j] + ident[j][k]] for j in range(len(counts)))
                   for k in range(len(ident[0]))), key=str)


def test_sequence_positions_keep_organs_on_elongating_stems_and_apically_growing_axes() -> None:
    """``register_sequence``'s default positions keep identities both where internodes elongate between sparse
    frames (synthetic maize, 4 frames: node ranks stay, arc lengths from the base do not) and where an axis grows at
    its tip while a bud low on it becomes a shoot (arc lengths stay, the node ranks of every organ above the bud
    shift by one)."""
    maize = synthetic_plant("maize", 4, n_frames=4, T=24, dtype=torch.float64).sequence
    assert identity_accuracy(register_sequence(maize, positions="arclength"), maize.frames.label).sequence < 0.9
    assert identity_accuracy(register_sequence(maize), maize.frames.label).sequence == 1.0
    earlier = _stem_plant(100.0, [(10.0, 1.0, 90.0, 21), (30.0, 20.0, 0.0, 22), (50.0, 20.0, 120.0, 23),
                                  (70.0, 20.0, 240.0, 24)])
    later = _stem_plant(150.0, [(110.0, 20.0, 120.0, 26), (90.0, 20.0, 0.0, 25), (70.0, 20.0, 240.0, 24),
                                (50.0, 20.0, 120.0, 23), (30.0, 20.0, 0.0, 22), (10.0, 20.0, 90.0, 21)])  # the
    # organs listed top-down: the index order (a registration's fallback) is not the answer
    axis = TreeSequence(Trees.cat([earlier, later]), torch.tensor([0.0, 1.0], dtype=torch.float64))
    assert (22, 21) in _slot_organs(axis, "rank")  # the case is a real one: ranks shift the shoots by one
    assert _slot_organs(axis) == [(1, 1), (21, 21), (22, 22), (23, 23), (24, 24), (None, 25), (None, 26)]


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
