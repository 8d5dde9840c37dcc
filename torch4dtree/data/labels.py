"""Ground-truth organ labels of the synthetic plants: non-negative ints, one path of base-100 digit pairs.

A label is written to the SWC type column of every skeleton node, so it must be a small
non-negative int that means the same organ in every frame and in every plant of a kind. One
digit pair per step from the stem (see :func:`label_parts`):

* ``0``: the main stem;
* ``k`` (1..49): the k-th leaf from the bottom of the stem. Tomato: 1 and 2 are the cotyledons
  (one node, opposite), 3, 4, ... the true leaves. Maize: 1, 2, ... alternating on opposite
  sides. Bean: 1 and 2 the opposite primary leaves, 3, 4, ... the trifoliate leaves (1 is the primary leaf a
  quarter turn clockwise, seen from above, from leaf 3: leaf 3 sits 56-111 degrees anticlockwise of leaf 1 in
  20 of 20 plants, so a rotation about the vertical cannot swap the names; before leaf 3 appears, at the first
  frame of every plant, nothing tells 1 from 2 across plants, and cross-plant scores use later frames). Almond:
  none;
* ``50 + k`` (51..98): the side shoot from the axil of leaf ``k`` (same node as that leaf). Almond:
  the ``k``-th scaffold from the bottom of the trunk (its leaf is gone);
* ``P * 100 + i`` with ``P`` a shoot label and ``i`` (1..49): the i-th leaf of that shoot;
* ``P * 100 + 50 + j`` with ``P`` a shoot label: almond, the ``j``-th lateral (secondary shoot
  or spur, a short shoot) from the base of shoot ``P``;
* ``L * 100 + j`` with ``L`` a leaf label and ``j`` (1..49): leaflet ``j`` of that leaf:
  ``j = 2 p - 1`` / ``2 p`` for the left / right leaflet of pair ``p`` from the leaf's base
  (the terminal leaflet is the continuation of the rachis, part of the leaf itself);
* ``(L * 100 + j) * 100 + m`` (m = 1, 2): lobe ``m`` (left, right) of that leaflet (tomato);
* :data:`SPUR_LABEL` (99): a skeletonisation spur, not an organ (ignore it in scores).

So an organ's parent organ is ``label // 100`` and its biological order (layer) is its number of
digit pairs (see :func:`label_layer`).
"""

from __future__ import annotations

__all__ = ["SHOOT_OFFSET", "SPUR_LABEL", "STEM_LABEL", "label_layer", "label_organ", "label_parts", "parent_label"]

STEM_LABEL = 0
SPUR_LABEL = 99
SHOOT_OFFSET = 50  # a digit pair 50 + k names the side shoot from the axil of leaf k


def label_parts(label: int) -> tuple[int, ...]:
    """Split a ground-truth label into its base-100 digit pairs: ``()`` stem, ``(k,)``, ``(k, j)``, ...

    E.g. ``305 -> (3, 5)`` (leaflet 5 of leaf 3), ``5302 -> (53, 2)`` (leaf 2 of the shoot from
    the axil of leaf 3), ``99 -> (99,)`` (a spur).

    Example:
        >>> label_parts(0), label_parts(305), label_parts(5302)
        ((), (3, 5), (53, 2))
    """
    if label < 0:
        raise ValueError(f"labels are non-negative, got {label}")
    parts: list[int] = []
    while label > 0:
        parts.append(label % 100)
        label //= 100
    return tuple(reversed(parts))


def label_layer(label: int) -> int:
    """Biological order of an organ: 0 stem; 1 leaf or side shoot on the stem; 2 leaflet, or leaf of a
    side shoot; 3 lobe, or leaflet of a shoot's leaf; ... ``-1`` for :data:`SPUR_LABEL` (not an organ).

    It is the organ's depth in the plant's true organ hierarchy, not the depth of a branch in a
    tree derived from the skeleton (the hierarchy rule may put a leaf on the main branch).

    Example:
        >>> [label_layer(x) for x in (0, 3, 305, 30501, SPUR_LABEL)]
        [0, 1, 2, 3, -1]
    """
    return -1 if label == SPUR_LABEL else len(label_parts(label))


def label_organ(label: int) -> str:
    """What a label names: ``"stem"``, ``"leaf"``, ``"leaflet"``, ``"lobe"``, ``"shoot"`` or ``"spur"``.

    Example:
        >>> [label_organ(x) for x in (0, 3, 305, 30501, 53, 5302, 99)]
        ['stem', 'leaf', 'leaflet', 'lobe', 'shoot', 'leaf', 'spur']
    """
    if label == SPUR_LABEL:
        return "spur"
    parts = label_parts(label)
    if not parts:
        return "stem"
    if parts[-1] > SHOOT_OFFSET:
        return "shoot"
    since_axis = len(parts) - max((i + 1 for i, p in enumerate(parts) if p > SHOOT_OFFSET), default=0)
    return ("leaf", "leaflet", "lobe")[min(since_axis, 3) - 1]


def parent_label(label: int) -> int:
    """The organ a labelled organ grows on (``label // 100``; the stem for a leaf or shoot on it).

    Example:
        >>> parent_label(305), parent_label(3)
        (3, 0)
    """
    if label <= 0 or label == SPUR_LABEL:
        raise ValueError(f"label {label} has no parent organ")
    return label // 100
