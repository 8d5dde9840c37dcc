"""Synthetic growing plants (tomato, maize, bean and almond 4D skeletons) with organ-level ground truth.

**What a plant is.** Every frame of a plant is a *skeleton graph*, as a skeletonised laser scan
gives it (Pheno4D, SPEC §6): nodes ``xyz (n, 3)`` (mm, z up, the root at the origin), parent
links ``parent (n,)`` (``-1`` for the root) and, as ground truth, the organ of every node
``organ (n,)`` (a branch point belongs to the parent organ). :attr:`SyntheticPlant.skeletons`
holds them; :attr:`SyntheticPlant.sequence` is derived from them by the package's reader path,
:func:`torch4dtree.trees.skeleton.skeleton_to_trees` (the hierarchy rule a user's SWC file goes
through; a branch's label is the most common organ among its own nodes). Organs are not
branches: when the rule runs the main branch up the stem into a leaf, that branch carries the
label of whichever organ has more of its nodes, the stem above the leaf becomes a side branch
labelled ``0``, and the next frame may pick another leaf. Nothing here protects the rule.

**Growth.** Every plant has a *biological clock* ``b = h(t)``, a monotone warp of its normalised
calendar time ``t in [0, 1]`` (``h(0) = 0``, ``h(1) = 1``); everything else is a deterministic
function of ``b`` whose form is shared by all plants of a kind, so the true temporal
correspondence between two plants is ``h_2^{-1} o h_1``. The stem's nominal length (its
*clock*, mm) is the kind's developmental curve ``D(b)``, scaled per plant by ``size``. An organ
on an axis (a leaf, or a side shoot from a leaf axil) starts growing when the axis clock ``C``
passes its onset ``G`` and then grows as ``max_len * (1 - exp(-(C - G) / width))``; a side
shoot is itself an axis whose clock is its nominal length. Where an organ sits on its axis
(arc length from the axis base) is ``softmin(C - depth, F + drift * (C - F))``: while young it
rides just ``depth`` below the axis apex (tomato and bean: the apical bud, a few mm; maize:
the still-rolled whorl, 15-25 mm), after reaching its node ``F`` it stays there while the
internodes below stretch a little (``drift``). Maize leaves also keep their order on the stem
(each collar above the older ones', as real collars stack up in the whorl): a young leaf sits at
least halfway from the previous leaf's place up to the stem's tip, never above its own node, so
the youngest leaf comes out near the top. Leaflets and lobes sit at a fixed fraction of
their parent and grow in proportion to the parent's length beyond a threshold. All lengths
and positions are non-decreasing in ``b``; an organ appears once it is ``min_length`` long, so
an organ present at one frame is present at all later frames.

**Kinds** (sizes from the Pheno4D skeletons and the hand-corrected ``.mat`` trees):

* ``tomato``: hypocotyl ~20 mm with two cotyledons at the top on the first day, a stem of about
  100-150 mm at the end; compound true leaves in spiral phyllotaxis (137.5 degrees) growing to
  ~200 mm, longer than the stem above their node (their node rides the apex while young), with
  2-3 pairs of leaflets and lobes on the basal leaflets; in about 4 plants out of 5, one or
  more vigorous basal side shoots from the axils of the lower leaves (mostly leaves 3 and 4)
  that grow leaves of their own and can outgrow the upper stem. The whole plant spans 35-55 mm
  on the first day and 230-320 mm on the last (Pheno4D: ~45 and ~230); 45-70 nodes on the
  first day, 1300-1800 on the last (Pheno4D: 35-61 and 1100-1550).
* ``maize``: a vertical stem (pseudostem and whorl) of ~28 mm growing to ~250 mm; two-ranked
  leaves alternating on opposite sides; a short first leaf, then leaves whose lengths and shapes
  are nearly equal from one node to the next (their positions along the stem tell them apart),
  arching, up to ~300 mm, far longer than the stem above them. 340-410 mm tall at the end;
  50-75 nodes on the first day, 950-1250 on the last (Pheno4D: 57-140 and 790-1040).
* ``bean``: hypocotyl and epicotyl ~35 mm bearing two opposite simple primary leaves, then
  alternate trifoliate leaves (petiole, two lateral leaflets at its tip, the terminal leaflet
  continuing it); in most plants, true side shoots from the axils of the primary and lower
  leaves bearing trifoliate leaves of their own: 4 layers of organs. 100-130 nodes on the first
  day, 1000-2000 on the last.
* ``almond``: a young almond tree over two flushes of growth (slow at the first, middle and
  last scans), wood only. A trunk (~160 mm at the first scan, ~560 at the last) leaning
  2-12 degrees; 3-5 scaffolds (sylleptic shoots) from buds at different heights (70-400 mm) and
  azimuths (2/5 phyllotaxis, 144 degrees), leaving at 30-60 degrees from vertical. Apical dominance
  is weak: the upper scaffolds are the most vigorous and curve upwards, the top one outgrows
  the trunk above it, and in half of the trees the leader itself arches 15-40 degrees away above
  the top scaffold. On each scaffold, secondary shoots break from buds every ~45 mm once it has
  grown past them, and spurs (short shoots, 6-25 mm: as long as skeletonisation spurs) appear on
  the older wood of scaffolds and shoots: 4 layers. Nodes never move once laid down (wood).
  100-135 nodes on the first day, 1200-2200 on the last; the tree spans 140-175 mm, then 500-650.

In every frame of these plants (as in every frame of the Pheno4D skeletons, measured against
the hand-corrected trees) the longest root-to-leaf path leaves the stem for a leaf or a shoot,
and which organ it ends in changes between frames.

**Skeletonisation noise**, per frame: every branch gets a smooth random bend (its tip moves by
about ``noise`` mm; lengths unchanged); nodes are spaced unevenly (mean ``node_spacing`` mm,
from ~0.45x to ~1.55x of it, with occasional gaps 2-3x as long); every node but the root is
jittered by ``jitter`` mm; and short spurs (0.5-8 mm, label :data:`SPUR_LABEL`) sprout from
random nodes at ``spurs`` times the kind's rate per 100 mm of skeleton (Pheno4D tomato ends
with ~50-60 tips). Leaves are not kept apart: large tomato leaves may cross or nearly touch.

**Ground-truth organ labels** (non-negative ints, written to the SWC type column). A label is a
path of base-100 digits, one per step from the stem (see :func:`label_parts`):

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

So a label means the same organ in every frame and in every plant of a kind, its parent organ is
``label // 100`` and its biological order (layer) is its number of digit pairs (see
:func:`label_layer`). Organ traits follow identity: a profile along the axis shared by the kind,
a plant-level offset and small per-organ noise, so leaf k of one plant resembles leaf k of
another.

Randomness: ``numpy.random.default_rng`` (PCG64) seeded from the plant seed (plant structure)
and from ``(seed, frame)`` (per-frame scanning noise), so a seed gives the same plant on any
machine. Node coordinates are rounded to 1e-4 mm, which SWC text holds exactly, so a written
frame reads back as the same skeleton (and the same trees).
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import torch
from torch import Tensor

from ..trees.growth import consistent_frames
from ..trees.skeleton import skeleton_to_trees
from ..trees.structures import DEFAULT_T, Trees, TreeSequence

KINDS = ("tomato", "maize", "bean", "almond")  # a new kind goes at the end: indices seed the rng streams
STEM_LABEL = 0
SPUR_LABEL = 99
SHOOT_OFFSET = 50  # a digit pair 50 + k names the side shoot from the axil of leaf k

_DEG = math.pi / 180.0
_SCALE = 10_000.0  # coordinates are integers / _SCALE mm: SWC's 6-decimal text holds them exactly


# ------------------------------------------------------------------------------------ labels
def label_parts(label: int) -> tuple[int, ...]:
    """Split a ground-truth label into its base-100 digit pairs: ``()`` stem, ``(k,)``, ``(k, j)``, ...

    E.g. ``305 -> (3, 5)`` (leaflet 5 of leaf 3), ``5302 -> (53, 2)`` (leaf 2 of the shoot from
    the axil of leaf 3), ``99 -> (99,)`` (a spur).
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
    """
    return -1 if label == SPUR_LABEL else len(label_parts(label))


def label_organ(label: int) -> str:
    """What a label names: ``"stem"``, ``"leaf"``, ``"leaflet"``, ``"lobe"``, ``"shoot"`` or ``"spur"``."""
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
    """The organ a labelled organ grows on (``label // 100``; the stem for a leaf or shoot on it)."""
    if label <= 0 or label == SPUR_LABEL:
        raise ValueError(f"label {label} has no parent organ")
    return label // 100


# ------------------------------------------------------------------------------ time warps
def sample_growth_warp(rng: np.random.Generator, grid_size: int = 101, strength: float = 1.0) -> tuple[
        np.ndarray, np.ndarray]:
    """A random smooth monotone warp ``h`` of ``[0, 1]`` with ``h(0) = 0``, ``h(1) = 1``.

    ``h`` is the normalised integral of a positive density ``exp(a (x - 1/2) + c sin(2 pi x + e))``:
    ``a > 0`` develops late, ``a < 0`` early. Returns ``(grid (G,), h (G,))``; between grid points
    ``h`` is linear (that piecewise-linear function IS the ground truth, see :func:`evaluate_warp`).
    """
    a = rng.uniform(-1.4, 1.4) * strength
    c = rng.uniform(-0.35, 0.35) * strength
    e = rng.uniform(0.0, 2 * math.pi)
    grid = np.linspace(0.0, 1.0, grid_size)
    fine = np.linspace(0.0, 1.0, 8 * (grid_size - 1) + 1)
    dens = np.exp(a * (fine - 0.5) + c * (np.sin(2 * math.pi * fine + e) - math.sin(e)))
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (dens[1:] + dens[:-1]))])
    h = np.interp(grid, fine, cum / cum[-1])
    h[0], h[-1] = 0.0, 1.0
    return grid, h


def evaluate_warp(grid: Tensor | np.ndarray, values: Tensor | np.ndarray, x: Tensor | np.ndarray | float) -> Tensor:
    """Evaluate a warp given on a grid (piecewise linear) at ``x`` (any shape) -> same shape, float64."""
    g = np.asarray(torch.as_tensor(grid).double().cpu())
    v = np.asarray(torch.as_tensor(values).double().cpu())
    xs = np.asarray(torch.as_tensor(x).double().cpu())
    return torch.from_numpy(np.asarray(np.interp(xs, g, v), dtype=np.float64).reshape(xs.shape))


# ------------------------------------------------------------------------------ kind models
@dataclass(frozen=True)
class _KindModel:
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


def _tomato_develop(b: float) -> float:
    # hypocotyl ~22 mm at the first scan, stem ~120 mm at the last, growing faster and faster
    return 22.0 + 98.0 * (math.exp(1.5 * b) - 1.0) / (math.exp(1.5) - 1.0)


def _maize_develop(b: float) -> float:
    # pseudostem with whorl: ~28 mm at the first scan, ~250 mm at the last
    return 28.0 + 222.0 * (b + 0.5 * b * b) / 1.5


def _bean_develop(b: float) -> float:
    # hypocotyl + epicotyl ~38 mm at the first scan, ~240 mm at the last
    return 38.0 + 200.0 * (b + 0.3 * b * b) / 1.3


def _almond_develop(b: float) -> float:
    # trunk ~160 mm at the first scan, ~560 mm at the last, over two flushes: growth slows to 0.4x its mean
    # at b = 0, 1/2 and 1 (towards the dormant seasons) and is fastest (1.6x) mid-season
    return 160.0 + 400.0 * (b - 0.6 * math.sin(4 * math.pi * b) / (4 * math.pi))


_MODELS = {
    "tomato": _KindModel("tomato", _tomato_develop, node_drift=0.3, tau=1.5, droop_pow=1.6, node_spacing=1.35,
                         spur_rate=0.5),
    "maize": _KindModel("maize", _maize_develop, node_drift=0.1, tau=3.0, droop_pow=2.0, node_spacing=1.15,
                        spur_rate=0.12, stack_share=0.5),
    "bean": _KindModel("bean", _bean_develop, node_drift=0.25, tau=2.0, droop_pow=1.6, node_spacing=1.4,
                       spur_rate=0.3),
    # wood: internodes stop stretching once lignified (little drift), bends are stiff (low droop power)
    "almond": _KindModel("almond", _almond_develop, node_drift=0.03, tau=4.0, droop_pow=1.3, node_spacing=1.4,
                         spur_rate=0.3),
}


@dataclass
class _Organ:
    """One organ of a plant (fixed over time); its length and place at a time come from :func:`_state`."""

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


def _wobble(rng: np.random.Generator, amplitude: float) -> np.ndarray:
    """Coefficients of a smooth random function of ``u in [0, 1]`` that vanishes at 0 (``(3, 2)``)."""
    amp = rng.normal(0.0, amplitude, 3) / np.arange(1, 4)
    return np.stack([amp, rng.uniform(0, 2 * math.pi, 3)], 1)


@dataclass
class _PlantModel:
    """A plant's fixed structure: size, stem shape, organs (the stem first, parents before children)."""

    kind: _KindModel
    size: float
    stem_lean: np.ndarray  # (2,) horizontal lean of the stem direction
    stem_wobble: np.ndarray  # (2, 3, 3) per horizontal axis: (amplitude, wavelength mm, phase) x 3
    organs: list[_Organ]
    # almond: the leader bends away above arc length `bend_from` (nominal mm), its lateral slopes
    # ramping to `leader_bend (2,)` over `bend_ramp` mm; None: no bend (the herbaceous kinds)
    bend_from: float | None = None
    leader_bend: np.ndarray = field(default_factory=lambda: np.zeros(2))
    bend_ramp: float = 1.0


def _horizontal(rng: np.random.Generator, magnitude: float) -> np.ndarray:
    a = rng.uniform(0, 2 * math.pi)
    return magnitude * np.array([math.cos(a), math.sin(a)])


def _stem_wobble(rng: np.random.Generator, amplitude: float) -> np.ndarray:
    """``(3, 3)`` rows (amplitude, wavelength in mm, phase) of the stem's lateral wobble on one axis."""
    return np.stack([rng.normal(0, amplitude, 3), rng.uniform(50, 250, 3), rng.uniform(0, 2 * math.pi, 3)], 1)


def _add_leaflets(
    rng: np.random.Generator, organs: list[_Organ], leaf: int, pairs: Sequence[float], rate: float,
    threshold: float, step: float, lobes: float,
) -> None:
    """Leaflet pairs at fractions ``pairs`` of leaf ``organs[leaf]``; the basal pair gets lobes with prob. ``lobes``."""
    label = organs[leaf].label
    for p, u in enumerate(pairs, 1):
        u = u + rng.uniform(-0.03, 0.03)
        for side_i, side in ((1, 1.0), (2, -1.0)):
            leaflet = len(organs)
            organs.append(_Organ(
                label=label * 100 + 2 * (p - 1) + side_i, parent=leaf, role="part", attach=u,
                rate=rate * rng.normal(1, 0.05), threshold=threshold + step * (p - 1) + rng.uniform(-3, 3),
                spread=(65 + rng.normal(0, 4)) * _DEG, side=side, droop=(55 + rng.normal(0, 4)) * _DEG,
                droop_max=60 * _DEG, wobble_theta=_wobble(rng, 0.06), wobble_phi=_wobble(rng, 0.08),
            ))
            if p == 1 and rng.uniform() < lobes:
                for m, lside in ((1, 1.0), (2, -1.0)):
                    organs.append(_Organ(
                        label=organs[leaflet].label * 100 + m, parent=leaflet, role="part",
                        attach=0.3 + rng.uniform(-0.04, 0.04), rate=0.35 + rng.normal(0, 0.015),
                        threshold=20.0 + rng.uniform(-3, 3), spread=(55 + rng.normal(0, 4)) * _DEG, side=lside,
                        droop=30 * _DEG, droop_max=40 * _DEG, wobble_theta=_wobble(rng, 0.05),
                        wobble_phi=_wobble(rng, 0.05),
                    ))


def _shoot(rng: np.random.Generator, leaf: _Organ, delay: float, max_len: float, width: float, theta: float,
           index: int) -> _Organ:
    """The side shoot from the axil of ``leaf`` (organ index ``index``): same node, starts ``delay`` later."""
    return _Organ(
        label=SHOOT_OFFSET + leaf.label, parent=index, role="shoot", onset=leaf.onset + delay, node=leaf.node,
        depth=leaf.depth, max_len=max_len, width=width, theta_young=theta - 5 * _DEG, theta_mature=theta,
        phi=leaf.phi + rng.normal(0, 10 * _DEG), droop=-(20 + rng.normal(0, 4)) * _DEG, droop_max=30 * _DEG,
        wobble_theta=_wobble(rng, 0.05), wobble_phi=_wobble(rng, 0.06),
    )


def _tomato_structure(rng: np.random.Generator) -> _PlantModel:
    # With independent per-leaf draws neighbouring leaves differ as much as same-index ones and no shape
    # metric can tell organ identities apart across plants: traits follow identity (module doc).
    size = rng.uniform(0.85, 1.15)
    lean = _horizontal(rng, math.tan(rng.uniform(1.0, 8.0) * _DEG))
    wob = np.stack([_stem_wobble(rng, 0.05) for _ in range(2)])
    organs = [_Organ(label=STEM_LABEL, parent=-1, role="stem")]
    phi0 = rng.uniform(0, 2 * math.pi)  # azimuth of the first true leaf
    incline = rng.normal(0.0, 3.0)  # plant-level offset of the leaf inclinations (deg)
    phi_c = phi0 - 0.5 * math.pi + rng.normal(0, 8 * _DEG)  # cotyledons across the first true leaf
    cot_node = 19.0 + rng.uniform(-1.5, 1.5)
    for k, phi in ((1, phi_c), (2, phi_c + math.pi + rng.normal(0, 6 * _DEG))):  # cotyledons, one node
        organs.append(_Organ(
            label=k, parent=0, role="leaf", onset=0.0, node=cot_node, depth=1.5,
            max_len=52.0 * rng.normal(1, 0.05), width=30.0, theta_young=50 * _DEG,
            theta_mature=(75 + incline + rng.normal(0, 3)) * _DEG, phi=phi, droop=40 * _DEG, droop_max=50 * _DEG,
            wobble_theta=_wobble(rng, 0.06), wobble_phi=_wobble(rng, 0.08),
        ))
    leaves = {1: 1, 2: 2}
    internode = rng.uniform(18.0, 24.0)  # plant-specific plastochron (nominal mm of stem growth per leaf)
    k, G = 3, 24.0 + rng.uniform(-2, 2)
    while G < 118.0 and k < 50:
        leaves[k] = len(organs)
        organs.append(_Organ(
            label=k, parent=0, role="leaf", onset=G, node=G + 8.0 + rng.uniform(-1, 1), depth=2.5,
            max_len=(200.0 + 40.0 * -math.expm1(-(k - 3) / 2.0)) * rng.normal(1, 0.04), width=45.0,
            theta_young=(30 + rng.normal(0, 2)) * _DEG, theta_mature=(60 + incline + rng.normal(0, 3)) * _DEG,
            phi=phi0 + (k - 3) * 137.5 * _DEG + rng.normal(0, 8 * _DEG),
            droop=(50 + rng.normal(0, 3)) * _DEG, droop_max=80 * _DEG,
            wobble_theta=_wobble(rng, 0.08), wobble_phi=_wobble(rng, 0.12),
        ))
        # the first true leaves carry two pairs of leaflets, later ones mostly three
        pairs = [0.36, 0.56, 0.73] if rng.uniform() < (0.15 if k < 6 else 0.85) else [0.4, 0.65]
        _add_leaflets(rng, organs, leaves[k], pairs, rate=0.3, threshold=40.0, step=30.0, lobes=0.8)
        k += 1
        G += internode + rng.uniform(-2, 2)
    # vigorous basal side shoots ("suckers") from the lower leaf axils; most plants have one or two
    for k, p in ((3, 0.5), (4, 0.4), (1, 0.12), (5, 0.15)):
        if rng.uniform() >= p or k not in leaves:
            continue
        leaf = organs[leaves[k]]
        shoot = len(organs)
        organs.append(_shoot(rng, leaf, delay=rng.uniform(30, 50), max_len=120.0 * rng.normal(1, 0.1),
                             width=45.0, theta=(40 + rng.normal(0, 4)) * _DEG, index=0))
        phi_s = organs[shoot].phi
        g = 4.0 + rng.uniform(-1, 1)
        for i in range(1, 4):
            organs.append(_Organ(
                label=organs[shoot].label * 100 + i, parent=shoot, role="leaf", onset=g, node=g + 6.0, depth=2.0,
                max_len=100.0 * (1 + 0.08 * (i - 1)) * rng.normal(1, 0.05), width=30.0,
                theta_young=(30 + rng.normal(0, 2)) * _DEG, theta_mature=(58 + incline + rng.normal(0, 3)) * _DEG,
                phi=phi_s + (0.5 if i % 2 else -0.5) * math.pi + rng.normal(0, 10 * _DEG),
                droop=(50 + rng.normal(0, 3)) * _DEG, droop_max=80 * _DEG,
                wobble_theta=_wobble(rng, 0.08), wobble_phi=_wobble(rng, 0.12),
            ))
            _add_leaflets(rng, organs, len(organs) - 1, [0.4, 0.65], rate=0.3, threshold=35.0, step=25.0, lobes=0.0)
            g += 25.0 + rng.uniform(-2, 2)
    return _PlantModel(_MODELS["tomato"], size, lean, wob, organs)


def _maize_structure(rng: np.random.Generator) -> _PlantModel:
    size = rng.uniform(0.88, 1.12)
    lean = _horizontal(rng, math.tan(rng.uniform(0.5, 3.0) * _DEG))
    wob = np.stack([_stem_wobble(rng, 0.02) for _ in range(2)])
    organs = [_Organ(label=STEM_LABEL, parent=-1, role="stem")]
    phi0 = rng.uniform(0, 2 * math.pi)
    incline = rng.normal(0.0, 3.0)  # plant-level offsets: adjacent leaves of one plant are near copies
    droop = rng.uniform(48, 58)
    whorl = rng.uniform(15.0, 25.0)  # the rolled leaves above the youngest leaf's divergence
    interval = rng.uniform(40.0, 52.0)  # plant-specific: nominal stem growth between two leaves
    # the short first leaf is already out at the first scan
    organs.append(_Organ(
        label=1, parent=0, role="leaf", onset=-40.0, node=14.0 + rng.uniform(-2, 2), depth=5.0,
        max_len=32.0 * rng.normal(1, 0.06), width=25.0, theta_young=20 * _DEG,
        theta_mature=(40 + incline) * _DEG, phi=phi0, droop=70 * _DEG, droop_max=60 * _DEG,
        wobble_theta=_wobble(rng, 0.05), wobble_phi=_wobble(rng, 0.08),
    ))
    k, G = 2, 16.0 + rng.uniform(-3, 3)
    while G < 225.0 and k < 50:
        # lengths rise over the first leaves, then stay nearly equal from node to node
        max_len = 110.0 + 195.0 * (1.0 - math.exp(-(k - 2) / 0.9)) + 2.0 * (k - 2)
        organs.append(_Organ(
            label=k, parent=0, role="leaf", onset=G, node=G + 55.0 + rng.uniform(-3, 3), depth=whorl,
            max_len=max_len * rng.normal(1, 0.025), width=70.0,
            theta_young=(8 + rng.normal(0, 1)) * _DEG, theta_mature=(24 + incline + rng.normal(0, 1.5)) * _DEG,
            phi=phi0 + (k - 1) * math.pi + rng.normal(0, 8 * _DEG),
            droop=(droop + rng.normal(0, 2)) * _DEG, droop_max=(115 + rng.normal(0, 3)) * _DEG,
            wobble_theta=_wobble(rng, 0.04), wobble_phi=_wobble(rng, 0.08),
        ))
        k += 1
        G += interval + rng.uniform(-4, 4)
    return _PlantModel(_MODELS["maize"], size, lean, wob, organs)


def _bean_structure(rng: np.random.Generator) -> _PlantModel:
    size = rng.uniform(0.88, 1.12)
    lean = _horizontal(rng, math.tan(rng.uniform(1.0, 6.0) * _DEG))
    wob = np.stack([_stem_wobble(rng, 0.04) for _ in range(2)])
    organs = [_Organ(label=STEM_LABEL, parent=-1, role="stem")]
    phi0 = rng.uniform(0, 2 * math.pi)  # azimuth of the first primary leaf
    incline = rng.normal(0.0, 3.0)
    node1 = 32.0 + rng.uniform(-2, 2)
    leaves = {}
    for k in (1, 2):  # the two simple primary leaves, opposite at one node
        leaves[k] = len(organs)
        organs.append(_Organ(
            label=k, parent=0, role="leaf", onset=0.0, node=node1, depth=3.0, max_len=105.0 * rng.normal(1, 0.05),
            width=45.0, theta_young=35 * _DEG, theta_mature=(60 + incline + rng.normal(0, 3)) * _DEG,
            phi=phi0 + (k - 1) * math.pi + rng.normal(0, 6 * _DEG), droop=(45 + rng.normal(0, 3)) * _DEG,
            droop_max=70 * _DEG, wobble_theta=_wobble(rng, 0.06), wobble_phi=_wobble(rng, 0.08),
        ))
    interval = rng.uniform(40.0, 48.0)
    k, G = 3, 40.0 + rng.uniform(-3, 3)
    while G < 228.0 and k < 50:  # alternate trifoliate leaves, across the primary pair
        leaves[k] = len(organs)
        organs.append(_Organ(
            label=k, parent=0, role="leaf", onset=G, node=G + 10.0 + rng.uniform(-1, 1), depth=3.0,
            max_len=(150.0 + 15.0 * -math.expm1(-(k - 3) / 2.0)) * rng.normal(1, 0.04), width=55.0,
            theta_young=(25 + rng.normal(0, 2)) * _DEG, theta_mature=(50 + incline + rng.normal(0, 3)) * _DEG,
            phi=phi0 + 0.5 * math.pi + (k - 3) * math.pi + rng.normal(0, 12 * _DEG),
            droop=(55 + rng.normal(0, 3)) * _DEG, droop_max=85 * _DEG,
            wobble_theta=_wobble(rng, 0.07), wobble_phi=_wobble(rng, 0.10),
        ))
        _add_leaflets(rng, organs, leaves[k], [0.5], rate=0.45, threshold=25.0, step=0.0, lobes=0.0)
        k += 1
        G += interval + rng.uniform(-3, 3)
    # true side shoots from the axils of the primary and lower trifoliate leaves
    for k, p, delay in ((1, 0.45, (80, 110)), (2, 0.45, (80, 110)), (3, 0.35, (50, 75)), (4, 0.2, (50, 75))):
        if rng.uniform() >= p or k not in leaves:
            continue
        shoot = len(organs)
        organs.append(_shoot(rng, organs[leaves[k]], delay=rng.uniform(*delay), max_len=115.0 * rng.normal(1, 0.12),
                             width=60.0, theta=(48 + rng.normal(0, 4)) * _DEG, index=0))
        phi_s = organs[shoot].phi
        g = 5.0 + rng.uniform(-1, 1)
        for i in range(1, 4):
            organs.append(_Organ(
                label=organs[shoot].label * 100 + i, parent=shoot, role="leaf", onset=g, node=g + 8.0, depth=3.0,
                max_len=100.0 * rng.normal(1, 0.05), width=40.0,
                theta_young=(25 + rng.normal(0, 2)) * _DEG, theta_mature=(50 + incline + rng.normal(0, 3)) * _DEG,
                phi=phi_s + (0.5 if i % 2 else -0.5) * math.pi + rng.normal(0, 12 * _DEG),
                droop=(55 + rng.normal(0, 3)) * _DEG, droop_max=85 * _DEG,
                wobble_theta=_wobble(rng, 0.07), wobble_phi=_wobble(rng, 0.10),
            ))
            _add_leaflets(rng, organs, len(organs) - 1, [0.5], rate=0.43, threshold=25.0, step=0.0, lobes=0.0)
            g += 30.0 + rng.uniform(-3, 3)
    return _PlantModel(_MODELS["bean"], size, lean, wob, organs)


def _almond_structure(rng: np.random.Generator) -> _PlantModel:
    # A young almond tree over two flushes, wood only. Apical dominance is weak: scaffolds near the top are the
    # most vigorous and outgrow the leader above them, which in about half of the trees arches away.
    size = rng.uniform(0.88, 1.12)
    lean = _horizontal(rng, math.tan(rng.uniform(2.0, 12.0) * _DEG))  # trunks lean (wind, no stake)
    wob = np.stack([_stem_wobble(rng, 0.05) for _ in range(2)])
    organs = [_Organ(label=STEM_LABEL, parent=-1, role="stem")]
    phi0 = rng.uniform(0, 2 * math.pi)
    n_scaffolds = int(rng.integers(3, 6))
    lo, hi = 70.0, 400.0  # trunk heights (nominal mm) of the scaffolds' buds, one per slot at random within it
    nodes = lo + (hi - lo) * (np.arange(n_scaffolds) + rng.uniform(0.15, 0.85, n_scaffolds)) / n_scaffolds
    end_clock = _almond_develop(1.0)
    for k, F in enumerate(nodes.tolist(), 1):
        rel = (F - lo) / (hi - lo)  # 0 at the bottom, 1 at the top: acrotony, the upper ones grow most
        theta = rng.uniform(30.0, 60.0) * _DEG
        scaffold = len(organs)
        onset = F + 30.0 + rng.uniform(-5, 5)
        organs.append(_Organ(
            label=SHOOT_OFFSET + k, parent=0, role="shoot", onset=onset, node=F, depth=30.0,
            max_len=(230.0 + 170.0 * rel) * rng.normal(1, 0.12), width=160.0 * rng.normal(1, 0.1),
            theta_young=theta - 12 * _DEG, theta_mature=theta,
            phi=phi0 + (k - 1) * 144.0 * _DEG + rng.normal(0, 20 * _DEG),  # 2/5 phyllotaxis
            droop=(rng.uniform(-30, -10) if rel > 0.5 else rng.uniform(-10, 15)) * _DEG, droop_max=35 * _DEG,
            wobble_theta=_wobble(rng, 0.08), wobble_phi=_wobble(rng, 0.10),
        ))
        sc = organs[scaffold]
        sc_end = sc.max_len * -math.expm1(-(end_clock - onset) / sc.width)  # its clock at the last scan
        # laterals on the scaffold: secondary shoots from buds every ~45 mm that break once the scaffold has
        # grown 40 mm beyond them, and spurs (short shoots) on the older wood; numbered from the scaffold's base
        laterals: list[tuple[float, str]] = []
        F2 = 30.0 + rng.uniform(-10, 10)
        while F2 + 40.0 < sc_end:
            if rng.uniform() < 0.5:
                laterals.append((F2, "shoot"))
            F2 += 45.0 + rng.uniform(-10, 10)
        for _ in range(int(rng.poisson(3.0))):
            laterals.append((rng.uniform(15.0, max(0.7 * sc_end, 20.0)), "spur"))
        laterals.sort()
        side = 1.0 if rng.uniform() < 0.5 else -1.0
        for j, (F2, what) in enumerate(laterals[:48], 1):
            if what == "spur":
                organs.append(_spur(rng, sc.label * 100 + SHOOT_OFFSET + j, scaffold, F2, delay=150.0))
                continue
            side = -side
            shoot = len(organs)
            organs.append(_Organ(
                label=sc.label * 100 + SHOOT_OFFSET + j, parent=scaffold, role="shoot", onset=F2 + 40.0,
                node=F2, depth=35.0, max_len=rng.uniform(60.0, 140.0), width=90.0 * rng.normal(1, 0.1),
                theta_young=rng.uniform(30, 45) * _DEG, theta_mature=rng.uniform(45, 70) * _DEG,
                phi=sc.phi + side * rng.uniform(40, 80) * _DEG, droop=rng.uniform(-15, 15) * _DEG,
                droop_max=25 * _DEG, wobble_theta=_wobble(rng, 0.08), wobble_phi=_wobble(rng, 0.10),
            ))
            sec = organs[shoot]
            spurs = np.sort(rng.uniform(10.0, max(0.6 * sec.max_len, 15.0), int(rng.integers(0, 3))))
            for m, F3 in enumerate(spurs.tolist(), 1):
                organs.append(_spur(rng, sec.label * 100 + SHOOT_OFFSET + m, shoot, F3, delay=60.0))
    if rng.uniform() < 0.5:  # a weak leader arching away above the top scaffold
        bend_from = float(nodes[-1]) + rng.uniform(0.0, 40.0)
        return _PlantModel(_MODELS["almond"], size, lean, wob, organs, bend_from=bend_from,
                           leader_bend=_horizontal(rng, math.tan(rng.uniform(15.0, 40.0) * _DEG)),
                           bend_ramp=rng.uniform(60.0, 120.0))
    return _PlantModel(_MODELS["almond"], size, lean, wob, organs)


def _spur(rng: np.random.Generator, label: int, parent: int, node: float, delay: float) -> _Organ:
    """A spur (a short shoot on older wood) at ``node``: it breaks once its axis has grown ~``delay`` mm past it."""
    return _Organ(
        label=label, parent=parent, role="shoot", onset=node + delay + rng.uniform(-20, 20), node=node, depth=40.0,
        max_len=rng.uniform(6.0, 25.0), width=20.0, theta_young=rng.uniform(50, 100) * _DEG,
        theta_mature=rng.uniform(50, 100) * _DEG, phi=rng.uniform(0, 2 * math.pi), droop=0.0,
        wobble_theta=_wobble(rng, 0.03), wobble_phi=_wobble(rng, 0.03),
    )


_STRUCTURES = {"tomato": _tomato_structure, "maize": _maize_structure, "bean": _bean_structure,
               "almond": _almond_structure}


# ------------------------------------------------------------------------- growth in time
def _softmin(x: float, y: float, tau: float) -> float:
    """A smooth minimum, never above ``min(x, y)`` and increasing in both."""
    lo = min(x, y)
    return lo - tau * math.log1p(math.exp(-abs(x - y) / tau))


def _state(plant: _PlantModel, b: float) -> tuple[np.ndarray, np.ndarray]:
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


# ------------------------------------------------------------------------------- geometry
def _directions(theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], -1)


def _polyline(start: np.ndarray, dirs: np.ndarray, length: float) -> np.ndarray:
    """Integrate unit directions at segment midpoints ``(n-1, 3)`` into a polyline of exactly ``length``.

    Its points are uniform in arc length (see :func:`_at_arc`).
    """
    steps = dirs * (length / len(dirs))
    return start + np.concatenate([np.zeros((1, 3)), np.cumsum(steps, 0)])


def _at_arc(poly: np.ndarray, length: float, arc: np.ndarray) -> np.ndarray:
    """Points at arc lengths ``arc (m,)`` of a polyline with uniform segments of total ``length``."""
    x = np.clip(np.asarray(arc, dtype=np.float64) / length, 0.0, 1.0) * (len(poly) - 1)
    lo = np.minimum(np.floor(x).astype(np.int64), len(poly) - 2)
    w = (x - lo)[:, None]
    return poly[lo] + w * (poly[lo + 1] - poly[lo])


def _tangent_at(poly: np.ndarray, length: float, arc: float) -> np.ndarray:
    k = int(np.clip(arc / length * (len(poly) - 1), 0, len(poly) - 2))
    d = poly[k + 1] - poly[k]
    return d / max(float(np.linalg.norm(d)), 1e-12)


def _eval_wobbles(coef: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Several :func:`_wobble` functions ``coef (k, 3, 2)`` at once at ``u (n,)`` -> ``(k, n)``."""
    amp, phase = coef[..., 0, None], coef[..., 1, None]
    arg = (np.arange(1, 4)[:, None] * math.pi) * u[None]  # (3, n)
    return (amp * (np.sin(arg[None] + phase) - np.sin(phase))).sum(1)


def _stem_points(plant: _PlantModel, L: float, jitter: np.ndarray, step: float = 1.0) -> np.ndarray:
    """The stem up to arc length ``L``: its shape is fixed in absolute arc length, so it only extends.

    ``jitter (2, 3, 2)``: this frame's noise on the two lateral slopes (see :func:`_frame_noise`).
    """
    n = max(int(math.ceil(L / step)), 8)
    a = (np.arange(n) + 0.5) * (L / n)  # segment midpoints (mm from the root)
    w = plant.stem_wobble
    noise = _eval_wobbles(jitter, a / L)
    lateral = [
        plant.stem_lean[ax] + (w[ax, :, :1] * np.sin(2 * math.pi * a[None] / w[ax, :, 1:2] + w[ax, :, 2:])).sum(0)
        + noise[ax]
        for ax in range(2)
    ]
    if plant.bend_from is not None:  # a weak leader arching over (fixed in arc length: the stem still only extends)
        start = plant.size * plant.bend_from
        ramp = np.clip((a - start) / (plant.size * plant.bend_ramp), 0.0, 1.0)
        ramp = ramp * ramp * (3 - 2 * ramp)
        lateral = [lateral[ax] + plant.leader_bend[ax] * ramp for ax in range(2)]
    d = np.stack([lateral[0], lateral[1], np.ones(n)], -1)
    return _polyline(np.zeros(3), d / np.linalg.norm(d, axis=-1, keepdims=True), L)


def _organ_points(
    o: _Organ, start: np.ndarray, base_dir: np.ndarray, length: float, maturity: float, droop_pow: float,
    jitter: np.ndarray,
) -> np.ndarray:
    """A lateral organ: start direction (spherical angles), droop growing with length, smooth wobble.

    ``jitter (2, 3, 2)``: this frame's noise on the inclination and azimuth (see :func:`_frame_noise`).
    """
    n = int(np.clip(math.ceil(length / 1.0), 8, 200))
    u = (np.arange(n) + 0.5) / n
    theta0 = math.acos(min(max(float(base_dir[2]), -1.0), 1.0))
    phi0 = math.atan2(float(base_dir[1]), float(base_dir[0]))
    bend = math.copysign(min(abs(o.droop) * length / 100.0, o.droop_max), o.droop) * (0.5 + 0.5 * maturity)
    w = _eval_wobbles(np.concatenate([o.wobble_theta[None], o.wobble_phi[None], jitter]), u)
    theta = np.clip(theta0 + bend * u**droop_pow + w[0] + w[2], 0.02, math.pi - 0.2)
    phi = phi0 + w[1] + w[3]
    return _polyline(start, _directions(theta, phi), length)


def _lateral_direction(tangent: np.ndarray, spread: float, side: float) -> np.ndarray:
    """Direction at ``spread`` from a parent's tangent, to its left (+1) or right (-1), slightly down."""
    tx, ty, tz = (float(v) for v in tangent)
    hx, hy = ty, -tx  # tangent x (0, 0, 1)
    norm = math.hypot(hx, hy)
    hx, hy = (hx / norm, hy / norm) if norm > 1e-6 else (1.0, 0.0)  # vertical parent: any horizontal direction
    c, s = math.cos(spread), math.sin(spread) * side
    d = np.array([c * tx + s * hx, c * ty + s * hy, c * tz - 0.15])
    return d / math.sqrt(float(d @ d))


def _frame_noise(rng: np.random.Generator, sigma: float, lengths: np.ndarray) -> np.ndarray:
    """This frame's smooth random bends of every organ: ``(n_organs, 2, 3, 2)`` :func:`_wobble` coefficients
    of the perturbations of its two direction angles (the stem: of its two lateral slopes).

    Bending the direction (instead of moving points) keeps every organ's length exact; the tip
    moves by about ``sigma`` mm, the base not at all (children stay attached). Tiny organs bend at
    most ~0.15 rad.
    """
    n = len(lengths)
    amp = np.minimum(sigma / np.maximum(lengths, 1e-9), 0.15) if sigma > 0 else np.zeros(n)
    coef = np.empty((n, 2, 3, 2))
    coef[..., 0] = rng.normal(0.0, 1.0, (n, 2, 3)) * amp[:, None, None] / np.arange(1, 4)
    coef[..., 1] = rng.uniform(0, 2 * math.pi, (n, 2, 3))
    return coef


def _organ_curves(
    plant: _PlantModel, b: float, rng: np.random.Generator, noise: float, min_length: float,
) -> tuple[dict[int, np.ndarray], np.ndarray, np.ndarray]:
    """Dense polylines (uniform in arc length) of the organs present at ``b``, with all lengths and positions."""
    length, pos = _state(plant, b)
    bends = _frame_noise(rng, noise, length)
    curves: dict[int, np.ndarray] = {0: _stem_points(plant, float(length[0]), bends[0])}
    for i, o in enumerate(plant.organs):
        if i == 0 or length[i] < min_length or o.parent not in curves:
            continue
        par = o.parent
        start = _at_arc(curves[par], float(length[par]), np.array([pos[i]]))[0]
        if o.role == "part":
            base_dir = _lateral_direction(_tangent_at(curves[par], float(length[par]), float(pos[i])), o.spread, o.side)
            maturity = 1.0
        else:
            maturity = min(length[i] / (plant.size * o.max_len), 1.0)
            theta = o.theta_young + (o.theta_mature - o.theta_young) * maturity
            base_dir = _directions(np.array(theta), np.array(o.phi))
        curves[i] = _organ_points(o, start, base_dir, float(length[i]), maturity, plant.kind.droop_pow, bends[i])
    return curves, length, pos


# ------------------------------------------------------------------------------- skeleton
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


def _skeleton(
    plant: _PlantModel, curves: dict[int, np.ndarray], length: np.ndarray, pos: np.ndarray, rng: np.random.Generator,
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
        xyz.append(_at_arc(curves[i], float(length[i]), arcs))
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
    return np.round(points * _SCALE) / _SCALE, parent, organ


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
        along /= max(float(np.linalg.norm(along)), 1e-12)
        d = rng.normal(size=3)
        d -= 0.7 * (d @ along) * along  # mostly sideways, as spurs from a thick organ's surface
        d /= max(float(np.linalg.norm(d)), 1e-12)
        size = min(0.5 + rng.gamma(1.5, 1.3), 8.0)
        m = max(int(round(size / spacing)), 1)
        steps = np.arange(1, m + 1)[:, None] * (size / m)
        new_xyz.append(xyz[v] + steps * d + rng.normal(0.0, 0.1, (m, 3)))
        new_par.append(np.concatenate([[v], np.arange(count, count + m - 1)]))
        count += m
    added = count - len(xyz)
    return np.concatenate(new_xyz), np.concatenate(new_par), np.concatenate([organ, np.full(added, SPUR_LABEL)])


# ------------------------------------------------------------------------------------ API
Skeleton = tuple[np.ndarray, np.ndarray, np.ndarray]


@dataclass(frozen=True, eq=False)
class SyntheticPlant:
    """A synthetic 4D plant and its ground truth.

    Attributes:
        sequence: the 4D tree derived from :attr:`skeletons` by
            :func:`~torch4dtree.trees.skeleton.skeleton_to_trees` (with the plant's ``hierarchy_kwargs``);
            ``sequence.frames.label`` is each branch's majority organ (module doc).
        kind: ``"tomato"``, ``"maize"``, ``"bean"`` or ``"almond"``.
        seed: the seed that regenerates this plant alone (``synthetic_plant(kind, seed, ...)``).
        growth_grid: ``(G,)`` normalised calendar times ``linspace(0, 1, G)``.
        growth_warp: ``(G,)`` the biological clock ``h`` on ``growth_grid`` (monotone, ``h(0)=0``,
            ``h(1)=1``, linear in between).
        bio_times: ``(n_frames,)`` ``h`` at the frames' normalised times.
        settings: the generation settings (JSON-serialisable).
        skeletons: per frame ``(xyz (n, 3) float64 mm, parent (n,) int64 with -1 at the root (node 0),
            organ (n,) int64 labels)``; a branch point carries its parent organ's label.
        name: e.g. ``"tomato_03"`` in a dataset.
    """

    sequence: TreeSequence
    kind: str
    seed: int
    growth_grid: Tensor
    growth_warp: Tensor
    bio_times: Tensor
    settings: dict
    skeletons: list[Skeleton] = field(default_factory=list)
    name: str = ""

    def warp(self, t: Tensor | np.ndarray | float) -> Tensor:
        """The biological clock ``h`` at normalised calendar times ``t`` (float64, same shape)."""
        return evaluate_warp(self.growth_grid, self.growth_warp, t)

    @property
    def times(self) -> Tensor:
        """``(n_frames,)`` frame times (calendar, e.g. days)."""
        return self.sequence.times

    def warp_inverse(self, y: Tensor | np.ndarray | float) -> Tensor:
        """``h^{-1}``: the normalised calendar time at which the plant reaches biological time ``y``."""
        return evaluate_warp(self.growth_warp, self.growth_grid, y)

    def labels_per_frame(self) -> list[list[int]]:
        """Per frame, the sorted labels of the derived trees' branches (a label may repeat or be missing)."""
        f = self.sequence.frames
        ptr = f.ptr.tolist()
        lab = f.label.tolist()
        return [sorted(lab[a:b]) for a, b in zip(ptr[:-1], ptr[1:])]

    def organs_per_frame(self) -> list[list[int]]:
        """Per frame, the sorted organ labels present in the skeleton (spurs left out)."""
        return [sorted(set(organ.tolist()) - {SPUR_LABEL}) for _, _, organ in self.skeletons]

    def organ_lengths(self) -> list[dict[int, float]]:
        """Per frame, each organ's length along the skeleton (mm; the edges ending in its nodes, spurs left out)."""
        out = []
        for xyz, parent, organ in self.skeletons:
            edge = np.linalg.norm(xyz[1:] - xyz[parent[1:]], axis=1)
            sums: Counter[int] = Counter()
            for lab, e in zip(organ[1:].tolist(), edge.tolist()):
                sums[lab] += e
            sums.pop(SPUR_LABEL, None)
            out.append({lab: sums.get(lab, 0.0) for lab in sorted(set(organ.tolist()) - {SPUR_LABEL})})
        return out


def relative_warp(a: SyntheticPlant, b: SyntheticPlant, t: Tensor | np.ndarray | float) -> Tensor:
    """The true time warp between two plants: ``xi(t) = h_b^{-1}(h_a(t))`` (float64, shape of ``t``).

    Plant ``b`` at normalised time ``xi(t)`` is as developed as plant ``a`` at ``t``, so a temporal
    registration that matches ``b``'s trajectory at ``xi(t)`` to ``a``'s at ``t`` should recover it.
    """
    return b.warp_inverse(a.warp(t))


def default_times(rng: np.random.Generator, n_frames: int) -> np.ndarray:
    """Irregular acquisition days (gaps of 1 to 3 days, mostly 2, as in Pheno4D), starting at day 0."""
    gaps = rng.choice([1.0, 2.0, 2.0, 2.0, 3.0], size=max(n_frames - 1, 0))
    return np.concatenate([[0.0], np.cumsum(gaps)])


def _json_safe(value: object) -> object:
    return value if isinstance(value, (str, int, float, bool, type(None))) else repr(value)


def synthetic_plant(
    kind: str = "tomato",
    seed: int = 0,
    n_frames: int = 10,
    times: Sequence[float] | Tensor | np.ndarray | None = None,
    T: int = DEFAULT_T,
    noise: float = 0.5,
    warp_strength: float = 1.0,
    min_length: float = 2.0,
    grid_size: int = 101,
    dtype: torch.dtype = torch.float32,
    name: str = "",
    node_spacing: float | None = None,
    jitter: float = 0.15,
    spurs: float = 1.0,
    hierarchy_kwargs: dict | None = None,
    joint_hierarchy: bool = True,
) -> SyntheticPlant:
    """Generate one synthetic growing plant: per-frame skeletons with organ labels, and the trees derived from them.

    Args:
        kind: ``"tomato"`` (stem, cotyledons, compound leaves with leaflets and lobes, basal side
            shoots), ``"maize"`` (stem and whorl, two-ranked arching leaves), ``"bean"`` (primary
            leaves, trifoliate leaves, side shoots with leaves of their own) or ``"almond"`` (a young
            tree's wood: trunk, scaffolds, secondary shoots, spurs); see the module doc.
        seed: any non-negative int; the same seed gives the same plant.
        n_frames: number of frames when ``times`` is not given.
        times: ``(n_frames,)`` strictly increasing acquisition times (any unit); default:
            irregular days from the seed (:func:`default_times`). The first and last map to
            normalised times 0 and 1.
        T: points per branch of the derived trees.
        noise: size (mm) of the smooth per-frame random bend of each branch (tip displacement); 0 for none.
        warp_strength: how far the growth clock departs from the identity (0: ``h(t) = t``).
        min_length: an organ appears in a frame once it is at least this long (mm).
        grid_size: points of the growth-warp grid.
        dtype: dtype of the derived trees' points.
        name: the sequence name.
        node_spacing: mean distance (mm) between skeleton nodes; default the kind's (1.15-1.4).
        jitter: standard deviation (mm) of the per-node position noise; 0 for none.
        spurs: multiplier of the kind's rate of skeletonisation spurs; 0 for none.
        hierarchy_kwargs: keyword arguments of :func:`~torch4dtree.trees.skeleton.skeleton_to_trees` (the
            hierarchy rule and its settings) used to derive :attr:`SyntheticPlant.sequence`.
        joint_hierarchy: choose each frame's main branch to agree with the next frame's
            (:func:`~torch4dtree.trees.growth.consistent_frames`), as :func:`~torch4dtree.io.read_sequence` does
            with the written SWC files by default; ``False``: the rule on each frame alone.

    The longest-path guarantee of earlier versions (side branches capped below ``margin`` times the
    rest of their parent, so the longest-path rule always found the stem) is gone, and with it the
    ``margin`` argument: organs grow as real ones do and the derived hierarchy is whatever the rule makes.

    Returns:
        a :class:`SyntheticPlant`. Units are mm, z up, the root at the origin.
    """
    if kind not in KINDS:
        raise ValueError(f"unknown plant kind {kind!r}; expected one of {', '.join(KINDS)}")
    if seed < 0:
        raise ValueError(f"seed must be non-negative, got {seed}")
    model_kind = _MODELS[kind]
    spacing = model_kind.node_spacing if node_spacing is None else float(node_spacing)
    if not 0.1 <= spacing <= 20.0:
        raise ValueError(f"node_spacing must lie in [0.1, 20] mm, got {spacing}")
    if jitter < 0 or spurs < 0 or noise < 0:
        raise ValueError(f"noise, jitter and spurs must be non-negative, got {noise}, {jitter}, {spurs}")
    kid = KINDS.index(kind)  # different kinds with one seed get unrelated draws
    rng = np.random.default_rng([seed, kid, 0])
    model = _STRUCTURES[kind](rng)
    if times is None:
        if n_frames < 2:
            raise ValueError(f"a synthetic plant needs at least 2 frames, got n_frames={n_frames}")
        t = default_times(np.random.default_rng([seed, kid, 1]), n_frames)
    else:
        t = np.asarray(torch.as_tensor(times).double().cpu()).reshape(-1)
        if len(t) < 2 or not np.all(np.diff(t) > 0) or not np.isfinite(t).all():
            raise ValueError(f"times must be at least 2 finite, strictly increasing values, got {t.tolist()}")
    grid, h = sample_growth_warp(np.random.default_rng([seed, kid, 2]), grid_size, warp_strength)
    tn = (t - t[0]) / (t[-1] - t[0])
    bio = np.interp(tn, grid, h)
    name = name or f"{kind}_seed{seed}"
    skeletons: list[Skeleton] = []
    for j, b in enumerate(bio):
        frame_rng = np.random.default_rng([seed, kid, 3, j])
        curves, length, pos = _organ_curves(model, float(b), frame_rng, noise, min_length)
        sk = _skeleton(model, curves, length, pos, frame_rng, spacing, jitter, spurs)
        skeletons.append(sk)
    names = [f"{name} frame {j}" for j in range(len(bio))]
    if joint_hierarchy:
        trees = consistent_frames(skeletons, T=T, names=names, dtype=dtype, **(hierarchy_kwargs or {}))
    else:
        trees = [skeleton_to_trees(sk[0], sk[1], T=T, node_labels=sk[2], dtype=dtype, where=where,
                                   **(hierarchy_kwargs or {})) for sk, where in zip(skeletons, names)]
    sequence = TreeSequence(Trees.cat(trees), torch.tensor(t, dtype=dtype), name)
    settings = {"n_frames": len(t), "T": T, "noise": noise, "warp_strength": warp_strength,
                "min_length": min_length, "grid_size": grid_size, "node_spacing": spacing, "jitter": jitter,
                "spurs": spurs}
    if not joint_hierarchy:
        settings["joint_hierarchy"] = False
    if hierarchy_kwargs:
        settings["hierarchy_kwargs"] = {k: _json_safe(v) for k, v in hierarchy_kwargs.items()}
    return SyntheticPlant(
        sequence, kind, int(seed), torch.from_numpy(grid), torch.from_numpy(h), torch.from_numpy(bio), settings,
        skeletons, name,
    )


def plant_seed(seed: int, index: int) -> int:
    """The seed of plant ``index`` of a dataset drawn with ``seed`` (a 32-bit int)."""
    return int(np.random.SeedSequence([seed, index]).generate_state(1)[0])


def synthetic_dataset(
    kind: str = "tomato",
    plants: int = 7,
    seed: int = 0,
    n_frames: int = 10,
    times: Sequence[float] | Tensor | np.ndarray | None = None,
    shared_times: bool = True,
    hierarchy_kwargs: dict | None = None,
    **kwargs: object,
) -> list[SyntheticPlant]:
    """Several plants of one kind (their labels name the same organs).

    Plant ``i`` is ``synthetic_plant(kind, plant_seed(seed, i), ...)`` named ``f"{kind}_{i:02d}"``.
    With ``shared_times`` (default) and no ``times``, all plants are scanned on the same irregular
    days drawn from ``seed`` (as in Pheno4D); otherwise each plant draws its own.
    ``hierarchy_kwargs`` and other keyword arguments go to :func:`synthetic_plant`.
    """
    if plants < 1:
        raise ValueError(f"plants must be at least 1, got {plants}")
    if times is None and shared_times:
        times = default_times(np.random.default_rng([seed, 99]), n_frames)
    out = []
    for i in range(plants):
        p = synthetic_plant(kind, plant_seed(seed, i), n_frames=n_frames, times=times, name=f"{kind}_{i:02d}",
                            hierarchy_kwargs=hierarchy_kwargs, **kwargs)  # type: ignore[arg-type]
        out.append(replace(p, settings={**p.settings, "dataset_seed": seed, "index": i}))
    return out
