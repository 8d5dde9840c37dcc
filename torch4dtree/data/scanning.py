"""Synthetic organ curves sampled as a skeleton graph with the noise of a skeletonised laser scan.

Methods meet skeletons, not clean curves, so each frame gets Pheno4D-like noise: nodes are
spaced unevenly (mean ``spacing`` mm, from ~0.45x to ~1.55x of it, with occasional gaps 2-3x as
long); every node but the root is jittered by ``jitter`` mm; and short spurs (0.5-8 mm, label
:data:`~.labels.SPUR_LABEL`) sprout from random nodes at a rate per 100 mm of skeleton (Pheno4D
tomato ends with ~50-60 tips). Leaves are not kept apart: large tomato leaves may cross or nearly
touch. Node coordinates are rounded to 1e-4 mm, which SWC text holds exactly, so a written frame
reads back as the same skeleton.
"""

from __future__ import annotations

import numpy as np

from .labels import SPUR_LABEL
from .organ_curves import at_arc
from .plant_model import PlantModel

__all__ = ["COORD_SCALE", "sample_skeleton"]

COORD_SCALE = 10_000.0  # coordinates are integers / COORD_SCALE mm: SWC's 6-decimal text holds them exactly
DIRECTION_FLOOR = 1e-12  # divisor floor of a direction's norm (a repeated node gives a zero direction)


def _node_arcs(rng: np.random.Generator, length: float, spacing: float, fixed: np.ndarray) -> np.ndarray:
    """Sorted arc lengths of an organ's own nodes: uneven steps ending at the tip, plus the ``fixed`` ones."""
    m = int(length / (0.45 * spacing)) + 2
    steps = spacing * rng.uniform(0.45, 1.55, m)
    steps[rng.uniform(size=m) < 0.03] *= rng.uniform(2.0, 3.0)  # scanning gaps
    arcs = np.cumsum(steps)
    arcs = arcs[arcs < length - 0.35 * spacing]
    if len(fixed):  # keep attachment nodes apart from the random ones
        k = np.searchsorted(fixed, arcs)
        gap = np.minimum(np.abs(arcs - fixed[np.clip(k - 1, 0, len(fixed) - 1)]),
                         np.abs(arcs - fixed[np.clip(k, 0, len(fixed) - 1)]))
        arcs = arcs[gap > 0.3]
    return np.unique(np.concatenate([arcs, fixed, [length]]))


def sample_skeleton(
    plant: PlantModel, curves: dict[int, np.ndarray], length: np.ndarray, pos: np.ndarray, rng: np.random.Generator,
    spacing: float, jitter: float, spurs: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sample the organ curves as a skeleton graph ``(xyz, parent, organ)`` with Pheno4D-like noise."""
    organs = plant.organs
    kids: dict[int, list[int]] = {i: [] for i in curves}
    for i in curves:
        if i:
            kids[organs[i].parent].append(i)
    xyz: list[np.ndarray] = [np.zeros((1, 3))]
    par: list[np.ndarray] = [np.array([-1])]
    lab: list[np.ndarray] = [np.array([organs[0].label])]
    count = 1
    base_node = {0: 0}  # organ -> the node its first own node hangs from (the root for the stem)
    for i in sorted(curves):
        fixed = np.unique(np.array([pos[c] for c in kids[i]], dtype=np.float64))
        arcs = _node_arcs(rng, float(length[i]), spacing, fixed)
        n = len(arcs)
        xyz.append(at_arc(curves[i], float(length[i]), arcs))
        chain = np.arange(count - 1, count + n - 1)
        chain[0] = base_node[i]
        par.append(chain)
        lab.append(np.full(n, organs[i].label))
        for c in kids[i]:  # children at one position (opposite leaves, a leaf and its axillary shoot) share a node
            base_node[c] = count + int(np.searchsorted(arcs, pos[c]))
        count += n
    points = np.concatenate(xyz)
    parent = np.concatenate(par)
    organ = np.concatenate(lab)
    points[1:] += rng.normal(0.0, jitter, (len(points) - 1, 3)) if jitter > 0 else 0.0
    points, parent, organ = _add_spurs(points, parent, organ, rng, spacing, spurs * plant.kind.spur_rate)
    return np.round(points * COORD_SCALE) / COORD_SCALE, parent, organ


def _add_spurs(
    xyz: np.ndarray, parent: np.ndarray, organ: np.ndarray, rng: np.random.Generator, spacing: float, rate: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Short straight side twigs (skeletonisation spurs) at random inner nodes, ``rate`` per 100 mm."""
    edges = np.linalg.norm(xyz[1:] - xyz[parent[1:]], axis=1)
    n_spurs = int(rng.poisson(rate * edges.sum() / 100.0)) if rate > 0 else 0
    if n_spurs == 0:
        return xyz, parent, organ
    inner = np.nonzero(np.bincount(parent[1:], minlength=len(xyz)) == 1)[0]
    inner = inner[inner > 0]
    if len(inner) == 0:
        return xyz, parent, organ
    at = rng.choice(inner, size=min(n_spurs, len(inner)), replace=False)
    new_xyz, new_par = [xyz], [parent]
    count = len(xyz)
    for v in at.tolist():
        along = xyz[v] - xyz[parent[v]]
        along /= max(float(np.linalg.norm(along)), DIRECTION_FLOOR)
        d = rng.normal(size=3)
        d -= 0.7 * (d @ along) * along  # mostly sideways, as spurs from a thick organ's surface
        d /= max(float(np.linalg.norm(d)), DIRECTION_FLOOR)
        size = min(0.5 + rng.gamma(1.5, 1.3), 8.0)
        m = max(int(round(size / spacing)), 1)
        steps = np.arange(1, m + 1)[:, None] * (size / m)
        new_xyz.append(xyz[v] + steps * d + rng.normal(0.0, 0.1, (m, 3)))
        new_par.append(np.concatenate([[v], np.arange(count, count + m - 1)]))
        count += m
    added = count - len(xyz)
    return np.concatenate(new_xyz), np.concatenate(new_par), np.concatenate([organ, np.full(added, SPUR_LABEL)])
