"""How a synthetic plant grows: its fixed organs, and each organ's length and place at a biological time.

Everything is a deterministic function of the biological time ``b`` (see :mod:`.clock`) whose
form is shared by all plants of a kind, so development, not calendar time, decides what a plant
looks like. The stem's nominal length (its *clock*, mm) is the kind's developmental curve
``D(b)``, scaled per plant by ``size``. An organ on an axis (a leaf, or a side shoot from a leaf
axil) starts growing when the axis clock ``C`` passes its onset ``G`` and then grows as
``max_len * (1 - exp(-(C - G) / width))``; a side shoot is itself an axis whose clock is its
nominal length. Where an organ sits on its axis (arc length from the axis base) is
``softmin(C - depth, F + drift * (C - F))``: while young it rides just ``depth`` below the axis
apex (tomato and bean: the apical bud, a few mm; maize: the still-rolled whorl, 15-25 mm), after
reaching its node ``F`` it stays there while the internodes below stretch a little (``drift``).
Maize leaves also keep their order on the stem (each collar above the older ones', as real
collars stack up in the whorl): a young leaf sits at least halfway from the previous leaf's place
up to the stem's tip, never above its own node, so the youngest leaf comes out near the top.
Leaflets and lobes sit at a fixed fraction of their parent and grow in proportion to the parent's
length beyond a threshold. All lengths and positions are non-decreasing in ``b``, so an organ
present at one frame is present at all later frames.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

__all__ = ["DEG", "KindModel", "Organ", "PlantModel", "organ_state", "wobble"]

DEG = math.pi / 180.0


@dataclass(frozen=True)
class KindModel:
    """Settings shared by all plants of a kind (nominal sizes in mm; ``size`` scales them per plant)."""

    name: str
    develop: Callable[[float], float]  # D(b): nominal stem length at biological time b in [0, 1]
    node_drift: float  # share of later axis growth that happens below an organ's node
    tau: float  # smoothness (nominal mm) of the switch from riding the apex to staying at the node
    droop_pow: float
    node_spacing: float  # mean skeleton node spacing (mm), as in the kind's Pheno4D files
    spur_rate: float  # spurs per 100 mm of skeleton
    # > 0: organs on an axis keep their order (maize collars stack up in the whorl): a young organ sits at least
    # this share of the way from the previous organ's place on the axis up to the axis tip (never above its own
    # node: once settled, it is there); 0: no such constraint
    stack_share: float = 0.0


@dataclass
class Organ:
    """One organ of a plant (fixed over time); its length and place at a time come from :func:`organ_state`."""

    label: int
    parent: int  # index of the parent organ in the plant's list, -1 for the stem
    role: str  # "stem", "leaf" (lateral organ on an axis), "shoot" (lateral axis) or "part" (leaflet, lobe)
    onset: float = 0.0  # leaf / shoot: parent-axis clock (nominal mm) where it starts to grow
    node: float = 0.0  # leaf / shoot: the node F it settles at on the parent axis (nominal mm)
    depth: float = 0.0  # leaf / shoot: how far below the parent's apex it rides while young (nominal mm)
    max_len: float = 0.0  # leaf / shoot: asymptotic length (nominal mm)
    width: float = 1.0  # leaf / shoot: parent-clock growth (mm) to reach 63% of max_len
    attach: float = 0.0  # part: fraction of the parent's length where it sits
    rate: float = 0.0  # part: mm of own length per mm of parent length beyond `threshold`
    threshold: float = 0.0  # part: parent length (nominal mm) where it starts growing
    theta_young: float = 0.0  # leaf / shoot: inclination from vertical when small (rad)
    theta_mature: float = 0.0  # ... and when full grown
    phi: float = 0.0  # leaf / shoot: azimuth (rad)
    spread: float = 0.0  # part: angle from the parent's tangent (rad)
    side: float = 1.0  # part: +1 left, -1 right
    droop: float = 0.0  # bending (rad) from base to tip per 100 mm of length: > 0 down (gravity), < 0 up
    droop_max: float = 1.5  # cap on the size of that bending (rad)
    wobble_theta: np.ndarray = field(default_factory=lambda: np.zeros((3, 2)))  # (amplitude, phase) x 3
    wobble_phi: np.ndarray = field(default_factory=lambda: np.zeros((3, 2)))
    # shoot: sympodial growth, the axis turning alternately left and right by this angle (rad) at each of its nodes,
    # `internode` nominal mm apart (0: a smooth axis); a lateral at node k leaves on the side the axis turns from
    zigzag: float = 0.0
    internode: float = 0.0


def wobble(rng: np.random.Generator, amplitude: float) -> np.ndarray:
    """Coefficients of a smooth random function of ``u in [0, 1]`` that vanishes at 0 (``(3, 2)``)."""
    amp = rng.normal(0.0, amplitude, 3) / np.arange(1, 4)
    return np.stack([amp, rng.uniform(0, 2 * math.pi, 3)], 1)


@dataclass
class PlantModel:
    """A plant's fixed structure: size, stem shape, organs (the stem first, parents before children)."""

    kind: KindModel
    size: float
    stem_lean: np.ndarray  # (2,) horizontal lean of the stem direction
    stem_wobble: np.ndarray  # (2, 3, 3) per horizontal axis: (amplitude, wavelength mm, phase) x 3
    organs: list[Organ]
    # almond: the leader bends away above arc length `bend_from` (nominal mm), its lateral slopes
    # ramping to `leader_bend (2,)` over `bend_ramp` mm; None: no bend (the herbaceous kinds)
    bend_from: float | None = None
    leader_bend: np.ndarray = field(default_factory=lambda: np.zeros(2))
    bend_ramp: float = 1.0


def _softmin(x: float, y: float, tau: float) -> float:
    """A smooth minimum, never above ``min(x, y)`` and increasing in both."""
    lo = min(x, y)
    return lo - tau * math.log1p(math.exp(-abs(x - y) / tau))


def organ_state(plant: PlantModel, b: float) -> tuple[np.ndarray, np.ndarray]:
    """Per organ, its length and its position (arc length on its parent, mm) at biological time ``b``.

    Every length and position is non-decreasing in ``b`` (module doc); a leaf or shoot sits strictly
    below its parent axis's tip.
    """
    kind, size = plant.kind, plant.size
    n = len(plant.organs)
    clock = np.zeros(n)  # axes: nominal length (mm), the clock of the organs on them
    length = np.zeros(n)
    pos = np.zeros(n)
    previous: dict[int, int] = {}  # axis -> its last organ so far that has started growing (stack_share)
    for i, o in enumerate(plant.organs):
        if o.role == "stem":
            clock[i] = kind.develop(b)
            length[i] = size * clock[i]
        elif o.role == "part":
            R = length[o.parent]
            pos[i] = o.attach * R
            length[i] = o.rate * max(R - size * o.threshold, 0.0)
        else:
            C = clock[o.parent]
            if C <= o.onset or length[o.parent] <= 0:
                continue
            grown = o.max_len * -math.expm1(-(C - o.onset) / o.width)
            if o.role == "shoot":
                clock[i] = grown
            length[i] = size * grown
            riding = C - o.depth  # young: just below the apex
            settled = o.node + kind.node_drift * (C - o.node)  # at its node, which the internodes below lift
            pos[i] = size * max(_softmin(riding, settled, kind.tau), 0.05 * C)
            if kind.stack_share > 0:
                older = previous.get(o.parent)
                if older is not None:  # between the older organ's place and the tip, never above the own node
                    # (a node above the older one's: the order is strict); min / max of non-decreasing terms
                    # below the tip keep the position non-decreasing and below the tip
                    stacked = pos[older] + kind.stack_share * (length[o.parent] - pos[older])
                    pos[i] = max(pos[i], min(stacked, size * settled))
                previous[o.parent] = i
    return length, pos
