"""Branch identities against organ truth, with the wrong matches named by cause (docs/method.md §7).

A registration matches branches of a moving tree to branches of a reference tree; every branch carries its majority
organ (:attr:`~torch4dtree.Trees.label`, from skeletons whose every node names its organ). Precision and recall are
those of :func:`torch4dtree.data.identity_scores` (as :mod:`.hierarchy` scores them). This module says, in
addition, *why* a matched pair holds two different organs, from each branch's **composition**: the share of its
length lying on each organ of the skeleton it was read from (:func:`branch_composition`).

Every wrong pair ``(i, j)`` (moving branch ``i`` of organ ``a``, reference branch ``j`` of organ ``b != a``, both
valid) gets the first of these causes that applies (:data:`CAUSES`):

* ``inherited``: the two branches' parent branches are matched to each other and hold different organs: the error
  follows from the parents' one (a branch whose continuation changed takes its children along), counted there.
* ``spur``: one of the two branches is shorter than :data:`SPUR_SHARE` of its tree's main branch: a stub (a young
  organ, or a piece the hierarchy cut off an organ) matched where its organ is not.
* ``apex_chain``: the two branches share an organ but not their majority one: branch ``i`` holds at least
  :data:`SHARE_MIN` of its length on organ ``b``, or branch ``j`` on organ ``a``. One of them ran on from an organ
  into another at that organ's apex (or at a branch point where it took the younger organ), and the younger part
  outweighs the older one in one snapshot but not in the other.
* ``split``: organ ``a`` is cut into several branches of the moving tree, or ``b`` of the reference (at least two
  branches each holding :data:`SHARE_MIN` of the organ's length in that tree), and this piece was matched to
  another organ.
* ``swap``: two whole organs each matched to the other: another matched pair holds organ ``b`` in the moving tree
  and ``a`` in the reference.
* ``other``: a whole organ matched to a different whole organ, not in return.

On the recall side, an organ present in both trees but never matched to itself is ``mismatched`` (some branch of it
was matched to another organ) or ``unmatched`` (its branches were left out of the correspondence).
"""

from __future__ import annotations

from collections import Counter, defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np
from torch import Tensor

from ..data.truth import DEFAULT_IGNORE, IdentityScores, identity_scores
from ..trees.structures import Trees

__all__ = ["CAUSES", "SHARE_MIN", "SPUR_SHARE", "ErrorCauses", "branch_composition", "branch_lengths",
           "error_causes", "score_pair", "sequence_matches", "sum_causes"]

CAUSES = ("inherited", "spur", "apex_chain", "split", "swap", "other")
SPUR_SHARE = 0.05  # a branch shorter than this share of its tree's main branch is a stub
SHARE_MIN = 0.1  # a share of a branch's (or an organ's) length below this is ignored: the branch point's neighbourhood


@dataclass
class ErrorCauses:
    """Wrong matched pairs by cause (module doc) and organs missed by recall.

    Attributes:
        counts: ``{cause: wrong pairs}`` over :data:`CAUSES`.
        mismatched: organs common to both trees never matched to themselves, some branch matched elsewhere.
        unmatched: such organs whose branches were all left unmatched.
        pairs: ``[(moving branch, reference branch, cause), ...]`` the wrong pairs.
    """

    counts: dict[str, int] = field(default_factory=lambda: dict.fromkeys(CAUSES, 0))
    mismatched: int = 0
    unmatched: int = 0
    pairs: list[tuple[int, int, str]] = field(default_factory=list)

    def to_dict(self) -> dict[str, int]:
        """Plain counts (JSON): the causes, ``mismatched``, ``unmatched``.

        Example:
            >>> ErrorCauses(unmatched=1).to_dict()["unmatched"]
            1
        """
        return {**self.counts, "mismatched": self.mismatched, "unmatched": self.unmatched}


def branch_lengths(tree: Trees) -> np.ndarray:
    """``(N,)`` arc length of every branch of a single tree (its resampled polyline).

    Example:
        >>> stem = np.array([[0.0, 0, 0], [0, 0, 10]])
        >>> branch_lengths(Trees.from_branches([[stem, stem[:, [2, 1, 0]] / 2]], [[-1, 0]], T=8)).tolist()
        [10.0, 5.0]
    """
    pts = tree.points.detach().double().cpu().numpy()
    return np.linalg.norm(pts[:, 1:] - pts[:, :-1], axis=-1).sum(-1)


def branch_composition(tree: Trees, xyz: np.ndarray, parent: np.ndarray, node_label: np.ndarray,
                       chunk: int = 4096) -> list[dict[int, float]]:
    """Per branch of a single tree read from a skeleton, the share of its length on each organ.

    Each resampled point but the first (the branch point, on the parent) takes the organ of the nearest skeleton
    edge (an edge belongs to its child node's organ); the points of a branch are evenly spaced in arc length, so
    their shares are length shares. Works whatever hierarchy built the branches (a branch lies on the skeleton).

    Args:
        tree: one tree, ``(N, T, d)`` points in the skeleton's coordinates.
        xyz / parent / node_label: the skeleton, ``(n, d)``, ``(n,)`` (``-1`` at the root), ``(n,)`` organs.
        chunk: points per block of the distance computation (memory).

    Returns:
        ``[{organ: share}, ...]`` per branch, shares summing to 1.

    Example (a stem of organ 1 with organ 2 continuing it at its apex):
        >>> xyz = np.array([[0.0, 0, 0], [0, 0, 10], [0, 0, 15]])
        >>> tree = Trees.from_branches([[xyz]], [[-1]], T=16)
        >>> comp = branch_composition(tree, xyz, np.array([-1, 0, 1]), np.array([1, 1, 2]))
        >>> {k: round(v, 2) for k, v in comp[0].items()}
        {1: 0.67, 2: 0.33}
    """
    xyz, parent = np.asarray(xyz, dtype=np.float64), np.asarray(parent, dtype=np.int64)
    child = np.nonzero(parent >= 0)[0]
    a, b = xyz[parent[child]], xyz[child]
    ab = b - a
    den = np.maximum((ab * ab).sum(-1), np.finfo(np.float64).tiny)
    edge_label = np.asarray(node_label)[child]
    pts = tree.points.detach().double().cpu().numpy()[:, 1:]
    n_br, m = pts.shape[:2]
    flat = pts.reshape(-1, pts.shape[-1])
    nearest = np.empty(len(flat), dtype=np.int64)
    for s in range(0, len(flat), chunk):
        p = flat[s:s + chunk]
        t = np.clip(((p[:, None, :] - a[None]) * ab[None]).sum(-1) / den[None], 0.0, 1.0)
        d = ((a[None] + t[..., None] * ab[None] - p[:, None, :]) ** 2).sum(-1)
        nearest[s:s + chunk] = d.argmin(1)
    labels = edge_label[nearest].reshape(n_br, m)
    return [{int(k): v / m for k, v in Counter(row.tolist()).items()} for row in labels]


def error_causes(matches: Sequence[tuple[int, int]], labels_moving: Sequence[int], labels_reference: Sequence[int],
                 comp_moving: Sequence[dict[int, float]], comp_reference: Sequence[dict[int, float]],
                 len_moving: Sequence[float], len_reference: Sequence[float],
                 parents_moving: Sequence[int] | None = None, parents_reference: Sequence[int] | None = None,
                 ignore: Iterable[int] = DEFAULT_IGNORE) -> ErrorCauses:
    """Name the cause of every wrong matched pair of one registration (module doc).

    Args:
        matches: ``[(moving branch, reference branch), ...]``.
        labels_moving / labels_reference: every branch's majority organ.
        comp_moving / comp_reference: every branch's composition (:func:`branch_composition`).
        len_moving / len_reference: every branch's length; branch 0 is the main branch.
        parents_moving / parents_reference: every branch's parent branch (``-1`` for the main one); ``None``: no
            ``inherited`` cause.
        ignore: labels that are not organs (spurs of the synthetic generator, unknown).

    Example (organs 3 and 4 swapped; organ 5 cut into branches 3 and 4 of the moving tree, branch 4 matched to 6):
        >>> lm, lr = [1, 3, 4, 5, 5], [1, 3, 4, 5, 6]
        >>> comp = lambda labels: [{x: 1.0} for x in labels]
        >>> e = error_causes([(0, 0), (1, 2), (2, 1), (3, 3), (4, 4)], lm, lr, comp(lm), comp(lr),
        ...                  [10.0, 5, 5, 3, 3], [10.0, 5, 5, 3, 3])
        >>> e.pairs
        [(1, 2, 'swap'), (2, 1, 'swap'), (4, 4, 'split')]
    """
    lm, lr = [int(x) for x in labels_moving], [int(x) for x in labels_reference]
    skip = {int(x) for x in ignore}
    out = ErrorCauses()
    organ_pieces_m, organ_pieces_r = _pieces(comp_moving, len_moving), _pieces(comp_reference, len_reference)
    valid = [(i, j) for i, j in matches if lm[i] not in skip and lr[j] not in skip]
    pair_organs = {(lm[i], lr[j]) for i, j in valid}
    spur_m, spur_r = SPUR_SHARE * float(len_moving[0]), SPUR_SHARE * float(len_reference[0])
    partner = dict(matches)
    for i, j in valid:
        a, b = lm[i], lr[j]
        if a == b:
            continue
        pi = -1 if parents_moving is None else int(parents_moving[i])
        pj = -1 if parents_reference is None else int(parents_reference[j])
        if pi >= 0 and pj >= 0 and partner.get(pi) == pj and lm[pi] != lr[pj]:
            cause = "inherited"
        elif float(len_moving[i]) < spur_m or float(len_reference[j]) < spur_r:
            cause = "spur"
        elif comp_moving[i].get(b, 0.0) >= SHARE_MIN or comp_reference[j].get(a, 0.0) >= SHARE_MIN:
            cause = "apex_chain"
        elif organ_pieces_m.get(a, 0) >= 2 or organ_pieces_r.get(b, 0) >= 2:
            cause = "split"
        elif (b, a) in pair_organs:
            cause = "swap"
        else:
            cause = "other"
        out.counts[cause] += 1
        out.pairs.append((i, j, cause))
    right = {a for a, b in pair_organs if a == b}
    matched_m = {lm[i] for i, _ in valid}
    for organ in (set(lm) & set(lr)) - skip - right:
        if organ in matched_m or organ in {lr[j] for _, j in valid}:
            out.mismatched += 1
        else:
            out.unmatched += 1
    return out


def _pieces(comp: Sequence[dict[int, float]], lengths: Sequence[float]) -> dict[int, int]:
    """Per organ, the branches holding at least :data:`SHARE_MIN` of the organ's length in the tree."""
    per: dict[int, list[float]] = defaultdict(list)
    for c, length in zip(comp, lengths):
        for organ, share in c.items():
            per[organ].append(share * float(length))
    return {o: sum(x >= SHARE_MIN * sum(v) for x in v) for o, v in per.items()}


def score_pair(matches: Sequence[tuple[int, int]], moving: Trees, reference: Trees,
               skeleton_moving: tuple[np.ndarray, np.ndarray, np.ndarray],
               skeleton_reference: tuple[np.ndarray, np.ndarray, np.ndarray]) -> tuple[IdentityScores, ErrorCauses]:
    """Identity scores (:func:`~torch4dtree.data.identity_scores`, from the trees' labels) and error causes of
    one registration's matches; ``skeleton_*``: ``(xyz, parent, node_label)`` each tree was read from.

    Example (a stem, organ 1, and a leaf, organ 3, matched to themselves):
        >>> xyz, parent, organ = np.array([[0.0, 0, 0], [0, 0, 5], [0, 0, 10], [4, 0, 5]]), [-1, 0, 1, 1], [1, 1, 1, 3]
        >>> tree = Trees.from_branches([[xyz[:3], xyz[[1, 3]]]], [[-1, 0]], T=8, labels=[[1, 3]])
        >>> scores, causes = score_pair([(0, 0), (1, 1)], tree, tree, (xyz, parent, organ), (xyz, parent, organ))
        >>> scores.precision, scores.recall, causes.pairs
        (1.0, 1.0, [])
    """
    lm, lr = moving.label.tolist(), reference.label.tolist()
    scores = identity_scores(matches, lm, lr)
    causes = error_causes(matches, lm, lr, branch_composition(moving, *skeleton_moving),
                          branch_composition(reference, *skeleton_reference), branch_lengths(moving).tolist(),
                          branch_lengths(reference).tolist(), moving.parent.tolist(), reference.parent.tolist())
    return scores, causes


def sequence_matches(identity: Tensor, j: int) -> list[tuple[int, int]]:
    """The matches of frame ``j`` onto frame ``j + 1`` in a within-sequence identity table ``(n, S)``
    (:attr:`~torch4dtree.temporal.AlignedSequence.identity`): two branches share a slot exactly when the
    registration matched them.

    Example:
        >>> import torch
        >>> sequence_matches(torch.tensor([[0, 1, -1], [0, 2, 1]]), 0)
        [(0, 0), (1, 2)]
    """
    a, b = identity[j].tolist(), identity[j + 1].tolist()
    return [(x, y) for x, y in zip(a, b) if x >= 0 and y >= 0]


def sum_causes(items: Iterable[ErrorCauses]) -> dict[str, int]:
    """Counts of several registrations added up (:meth:`ErrorCauses.to_dict`).

    Example:
        >>> sum_causes([ErrorCauses(mismatched=1), ErrorCauses(unmatched=2)])["unmatched"]
        2
    """
    total = Counter()  # type: Counter[str]
    for e in items:
        total.update(e.to_dict())
    return {k: int(total.get(k, 0)) for k in (*CAUSES, "mismatched", "unmatched")}
