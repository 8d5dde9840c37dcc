"""The four synthetic plant kinds: their developmental curves and how each draws a plant's organs.

Sizes come from the Pheno4D skeletons and the hand-corrected ``.mat`` trees, so that the methods
meet plants of realistic shape and size:

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
  azimuths (2/5 phyllotaxis, 144 degrees), leaving at 30-60 degrees from vertical. Shoots grow
  sympodially: they zig-zag by 15-35 degrees at nodes 4-9 mm apart, and the bud at a node breaks
  (into a secondary shoot 0.2-1x as long as its scaffold, or a spur of 6-25 mm) at a random time
  of one of the two flushes, so laterals appear between older ones. Apical dominance is weak: the
  top scaffold turns upright and overtakes the leader, which in 7 trees of 10 bends 20-45 degrees
  away above it. 4 layers of organs; nodes never move once laid down (wood). 100-165 nodes on the first
  day, 2,000-5,500 on the last; the tree spans 140-175 mm, then 500-700.

With ``variation=True`` (:func:`~torch4dtree.data.synthetic.synthetic_plant`; ``torch4dtree synth --vary``), plants
of a herbaceous kind differ as crops in one field do: each has a vigour (log-normal, 0.8-1.25 for two
plants in three) that paces its leaves (tomato and bean leaves per stem growth follow vigour, maize leaves its
square root roughly: 30 plants of a kind have 4-9 leaves on the main stem, a coefficient of variation of 0.14-0.17),
makes its side shoots likelier and gives them more leaves; tomato and bean side shoots grow on about 3 plants in 4.

In every frame of these plants (as in every frame of the Pheno4D skeletons, measured against
the hand-corrected trees) the longest root-to-leaf path leaves the stem for a leaf or a shoot,
and which organ it ends in changes between frames.

Organ traits follow identity: a profile along the axis shared by the kind, a plant-level offset
and small per-organ noise, so leaf k of one plant resembles leaf k of another (with independent
per-leaf draws, neighbouring leaves would differ as much as same-index ones and no shape metric
could tell organ identities apart across plants).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from .labels import SHOOT_OFFSET, STEM_LABEL
from .organ_curves import zigzag_side
from .plant_model import DEG, KindModel, Organ, PlantModel, wobble

__all__ = ["KINDS", "KIND_MODELS", "STRUCTURES"]

KINDS = ("tomato", "maize", "bean", "almond")  # a new kind goes at the end: indices seed the rng streams


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


# the settings shared by all plants of each kind
KIND_MODELS: dict[str, KindModel] = {
    "tomato": KindModel("tomato", _tomato_develop, node_drift=0.3, tau=1.5, droop_pow=1.6, node_spacing=1.35,
                         spur_rate=0.5),
    "maize": KindModel("maize", _maize_develop, node_drift=0.1, tau=3.0, droop_pow=2.0, node_spacing=1.15,
                        spur_rate=0.12, stack_share=0.5),
    "bean": KindModel("bean", _bean_develop, node_drift=0.25, tau=2.0, droop_pow=1.6, node_spacing=1.4,
                       spur_rate=0.3),
    # wood: internodes stop stretching once lignified (little drift), bends are stiff (low droop power)
    "almond": KindModel("almond", _almond_develop, node_drift=0.03, tau=4.0, droop_pow=1.3, node_spacing=1.4,
                         spur_rate=0.3),
}


# With ``vary`` (synthetic_plant's ``variation``), herbaceous plants of one kind differ as real crops do: a per-plant
# vigour (log-normal, sd VIGOUR_SD on the log scale, truncated at VIGOUR_CLIP sd) sets how fast leaves follow each
# other on the stem (leaves over the period ~ vigour), how likely each side shoot is (its probability x vigour) and
# how many leaves a side shoot makes.
VIGOUR_SD, VIGOUR_CLIP = 0.22, 2.0
# maize: leaf appearance is paced by thermal time more strictly than in dicots, so its leaf count follows vigour
# less (the exponent of vigour in its leaf rate)
MAIZE_LEAF_RATE_BY_VIGOUR = 0.6
SHOOT_LEAVES = 3.0  # leaves of a side shoot at vigour 1 (normal noise SHOOT_LEAVES_SD, at least 1, at most 5)
SHOOT_LEAVES_SD = 0.6


def _vigour(rng: np.random.Generator, vary: bool) -> float:
    """A herbaceous plant's vigour (1 typical; about 0.8-1.25 for two plants in three); 1 without drawing when not
    ``vary`` (so the plants of a seed stay those of the generator without variation)."""
    if not vary:
        return 1.0
    return math.exp(VIGOUR_SD * float(np.clip(rng.normal(), -VIGOUR_CLIP, VIGOUR_CLIP)))


def _shoot_leaves(rng: np.random.Generator, vigour: float, vary: bool) -> int:
    """How many leaves a side shoot of a plant of this vigour makes (``SHOOT_LEAVES`` without drawing when not
    ``vary``)."""
    if not vary:
        return int(SHOOT_LEAVES)
    return int(np.clip(round(SHOOT_LEAVES * vigour + rng.normal(0, SHOOT_LEAVES_SD)), 1, 5))


def _horizontal(rng: np.random.Generator, magnitude: float) -> np.ndarray:
    a = rng.uniform(0, 2 * math.pi)
    return magnitude * np.array([math.cos(a), math.sin(a)])


def _stem_wobble(rng: np.random.Generator, amplitude: float) -> np.ndarray:
    """``(3, 3)`` rows (amplitude, wavelength in mm, phase) of the stem's lateral wobble on one axis."""
    return np.stack([rng.normal(0, amplitude, 3), rng.uniform(50, 250, 3), rng.uniform(0, 2 * math.pi, 3)], 1)


def _stem(
    rng: np.random.Generator, size: tuple[float, float], lean_deg: tuple[float, float], wobble_amp: float,
) -> tuple[float, np.ndarray, np.ndarray, list[Organ], float]:
    """A plant's size factor, stem lean and lateral wobble, its organ list holding the stem, and the azimuth
    of its first organ, drawn in this order (the order fixes the plants a seed gives)."""
    scale = rng.uniform(*size)
    lean = _horizontal(rng, math.tan(rng.uniform(*lean_deg) * DEG))
    wob = np.stack([_stem_wobble(rng, wobble_amp) for _ in range(2)])
    organs = [Organ(label=STEM_LABEL, parent=-1, role="stem")]
    return scale, lean, wob, organs, rng.uniform(0, 2 * math.pi)


def _add_leaflets(
    rng: np.random.Generator, organs: list[Organ], leaf: int, pairs: Sequence[float], rate: float,
    threshold: float, step: float, lobes: float,
) -> None:
    """Leaflet pairs at fractions ``pairs`` of leaf ``organs[leaf]``; the basal pair gets lobes with prob. ``lobes``."""
    label = organs[leaf].label
    for p, u in enumerate(pairs, 1):
        u = u + rng.uniform(-0.03, 0.03)
        for side_i, side in ((1, 1.0), (2, -1.0)):
            leaflet = len(organs)
            organs.append(Organ(
                label=label * 100 + 2 * (p - 1) + side_i, parent=leaf, role="part", attach=u,
                rate=rate * rng.normal(1, 0.05), threshold=threshold + step * (p - 1) + rng.uniform(-3, 3),
                spread=(65 + rng.normal(0, 4)) * DEG, side=side, droop=(55 + rng.normal(0, 4)) * DEG,
                droop_max=60 * DEG, wobble_theta=wobble(rng, 0.06), wobble_phi=wobble(rng, 0.08),
            ))
            if p == 1 and rng.uniform() < lobes:
                for m, lside in ((1, 1.0), (2, -1.0)):
                    organs.append(Organ(
                        label=organs[leaflet].label * 100 + m, parent=leaflet, role="part",
                        attach=0.3 + rng.uniform(-0.04, 0.04), rate=0.35 + rng.normal(0, 0.015),
                        threshold=20.0 + rng.uniform(-3, 3), spread=(55 + rng.normal(0, 4)) * DEG, side=lside,
                        droop=30 * DEG, droop_max=40 * DEG, wobble_theta=wobble(rng, 0.05),
                        wobble_phi=wobble(rng, 0.05),
                    ))


def _shoot(rng: np.random.Generator, leaf: Organ, delay: float, max_len: float, width: float, theta: float,
           index: int) -> Organ:
    """The side shoot from the axil of ``leaf`` (organ index ``index``): same node, starts ``delay`` later."""
    return Organ(
        label=SHOOT_OFFSET + leaf.label, parent=index, role="shoot", onset=leaf.onset + delay, node=leaf.node,
        depth=leaf.depth, max_len=max_len, width=width, theta_young=theta - 5 * DEG, theta_mature=theta,
        phi=leaf.phi + rng.normal(0, 10 * DEG), droop=-(20 + rng.normal(0, 4)) * DEG, droop_max=30 * DEG,
        wobble_theta=wobble(rng, 0.05), wobble_phi=wobble(rng, 0.06),
    )


def _tomato_structure(rng: np.random.Generator, vary: bool = False) -> PlantModel:
    # traits follow identity (module doc)
    # phi0: azimuth of the first true leaf
    size, lean, wob, organs, phi0 = _stem(rng, (0.85, 1.15), (1.0, 8.0), 0.05)
    vigour = _vigour(rng, vary)
    incline = rng.normal(0.0, 3.0)  # plant-level offset of the leaf inclinations (deg)
    phi_c = phi0 - 0.5 * math.pi + rng.normal(0, 8 * DEG)  # cotyledons across the first true leaf
    cot_node = 19.0 + rng.uniform(-1.5, 1.5)
    for k, phi in ((1, phi_c), (2, phi_c + math.pi + rng.normal(0, 6 * DEG))):  # cotyledons, one node
        organs.append(Organ(
            label=k, parent=0, role="leaf", onset=0.0, node=cot_node, depth=1.5,
            max_len=52.0 * rng.normal(1, 0.05), width=30.0, theta_young=50 * DEG,
            theta_mature=(75 + incline + rng.normal(0, 3)) * DEG, phi=phi, droop=40 * DEG, droop_max=50 * DEG,
            wobble_theta=wobble(rng, 0.06), wobble_phi=wobble(rng, 0.08),
        ))
    leaves = {1: 1, 2: 2}
    internode = rng.uniform(18.0, 24.0) / vigour  # plant-specific plastochron (nominal mm of stem growth per leaf)
    k, G = 3, 24.0 + rng.uniform(-2, 2)
    while G < 118.0 and k < 50:
        leaves[k] = len(organs)
        organs.append(Organ(
            label=k, parent=0, role="leaf", onset=G, node=G + 8.0 + rng.uniform(-1, 1), depth=2.5,
            max_len=(200.0 + 40.0 * -math.expm1(-(k - 3) / 2.0)) * rng.normal(1, 0.04), width=45.0,
            theta_young=(30 + rng.normal(0, 2)) * DEG, theta_mature=(60 + incline + rng.normal(0, 3)) * DEG,
            phi=phi0 + (k - 3) * 137.5 * DEG + rng.normal(0, 8 * DEG),
            droop=(50 + rng.normal(0, 3)) * DEG, droop_max=80 * DEG,
            wobble_theta=wobble(rng, 0.08), wobble_phi=wobble(rng, 0.12),
        ))
        # the first true leaves carry two pairs of leaflets, later ones mostly three
        pairs = [0.36, 0.56, 0.73] if rng.uniform() < (0.15 if k < 6 else 0.85) else [0.4, 0.65]
        _add_leaflets(rng, organs, leaves[k], pairs, rate=0.3, threshold=40.0, step=30.0, lobes=0.8)
        k += 1
        G += internode + rng.uniform(-2, 2)
    # vigorous basal side shoots ("suckers") from the lower leaf axils; most plants have one or two
    for k, p in ((3, 0.5), (4, 0.4), (1, 0.12), (5, 0.15)):
        if rng.uniform() >= p * vigour or k not in leaves:
            continue
        leaf = organs[leaves[k]]
        shoot = len(organs)
        organs.append(_shoot(rng, leaf, delay=rng.uniform(30, 50), max_len=120.0 * rng.normal(1, 0.1),
                             width=45.0, theta=(40 + rng.normal(0, 4)) * DEG, index=0))
        phi_s = organs[shoot].phi
        g = 4.0 + rng.uniform(-1, 1)
        for i in range(1, _shoot_leaves(rng, vigour, vary) + 1):
            organs.append(Organ(
                label=organs[shoot].label * 100 + i, parent=shoot, role="leaf", onset=g, node=g + 6.0, depth=2.0,
                max_len=100.0 * (1 + 0.08 * (i - 1)) * rng.normal(1, 0.05), width=30.0,
                theta_young=(30 + rng.normal(0, 2)) * DEG, theta_mature=(58 + incline + rng.normal(0, 3)) * DEG,
                phi=phi_s + (0.5 if i % 2 else -0.5) * math.pi + rng.normal(0, 10 * DEG),
                droop=(50 + rng.normal(0, 3)) * DEG, droop_max=80 * DEG,
                wobble_theta=wobble(rng, 0.08), wobble_phi=wobble(rng, 0.12),
            ))
            _add_leaflets(rng, organs, len(organs) - 1, [0.4, 0.65], rate=0.3, threshold=35.0, step=25.0, lobes=0.0)
            g += 25.0 + rng.uniform(-2, 2)
    return PlantModel(KIND_MODELS["tomato"], size, lean, wob, organs)


def _maize_structure(rng: np.random.Generator, vary: bool = False) -> PlantModel:
    size, lean, wob, organs, phi0 = _stem(rng, (0.88, 1.12), (0.5, 3.0), 0.02)
    vigour = _vigour(rng, vary)
    incline = rng.normal(0.0, 3.0)  # plant-level offsets: adjacent leaves of one plant are near copies
    droop = rng.uniform(48, 58)
    whorl = rng.uniform(15.0, 25.0)  # the rolled leaves above the youngest leaf's divergence
    # plant-specific: nominal stem growth between two leaves
    interval = rng.uniform(40.0, 52.0) / vigour ** MAIZE_LEAF_RATE_BY_VIGOUR
    # the short first leaf is already out at the first scan
    organs.append(Organ(
        label=1, parent=0, role="leaf", onset=-40.0, node=14.0 + rng.uniform(-2, 2), depth=5.0,
        max_len=32.0 * rng.normal(1, 0.06), width=25.0, theta_young=20 * DEG,
        theta_mature=(40 + incline) * DEG, phi=phi0, droop=70 * DEG, droop_max=60 * DEG,
        wobble_theta=wobble(rng, 0.05), wobble_phi=wobble(rng, 0.08),
    ))
    k, G = 2, 16.0 + rng.uniform(-3, 3)
    while G < 225.0 and k < 50:
        # lengths rise over the first leaves, then stay nearly equal from node to node
        max_len = 110.0 + 195.0 * (1.0 - math.exp(-(k - 2) / 0.9)) + 2.0 * (k - 2)
        organs.append(Organ(
            label=k, parent=0, role="leaf", onset=G, node=G + 55.0 + rng.uniform(-3, 3), depth=whorl,
            max_len=max_len * rng.normal(1, 0.025), width=70.0,
            theta_young=(8 + rng.normal(0, 1)) * DEG, theta_mature=(24 + incline + rng.normal(0, 1.5)) * DEG,
            phi=phi0 + (k - 1) * math.pi + rng.normal(0, 8 * DEG),
            droop=(droop + rng.normal(0, 2)) * DEG, droop_max=(115 + rng.normal(0, 3)) * DEG,
            wobble_theta=wobble(rng, 0.04), wobble_phi=wobble(rng, 0.08),
        ))
        k += 1
        G += interval + rng.uniform(-4, 4)
    return PlantModel(KIND_MODELS["maize"], size, lean, wob, organs)


def _bean_structure(rng: np.random.Generator, vary: bool = False) -> PlantModel:
    # phi0: azimuth of the first primary leaf
    size, lean, wob, organs, phi0 = _stem(rng, (0.88, 1.12), (1.0, 6.0), 0.04)
    vigour = _vigour(rng, vary)
    incline = rng.normal(0.0, 3.0)
    node1 = 32.0 + rng.uniform(-2, 2)
    leaves = {}
    for k in (1, 2):  # the two simple primary leaves, opposite at one node
        leaves[k] = len(organs)
        organs.append(Organ(
            label=k, parent=0, role="leaf", onset=0.0, node=node1, depth=3.0, max_len=105.0 * rng.normal(1, 0.05),
            width=45.0, theta_young=35 * DEG, theta_mature=(60 + incline + rng.normal(0, 3)) * DEG,
            phi=phi0 + (k - 1) * math.pi + rng.normal(0, 6 * DEG), droop=(45 + rng.normal(0, 3)) * DEG,
            droop_max=70 * DEG, wobble_theta=wobble(rng, 0.06), wobble_phi=wobble(rng, 0.08),
        ))
    interval = rng.uniform(40.0, 48.0) / vigour
    k, G = 3, 40.0 + rng.uniform(-3, 3)
    while G < 228.0 and k < 50:  # alternate trifoliate leaves, across the primary pair
        leaves[k] = len(organs)
        organs.append(Organ(
            label=k, parent=0, role="leaf", onset=G, node=G + 10.0 + rng.uniform(-1, 1), depth=3.0,
            max_len=(150.0 + 15.0 * -math.expm1(-(k - 3) / 2.0)) * rng.normal(1, 0.04), width=55.0,
            theta_young=(25 + rng.normal(0, 2)) * DEG, theta_mature=(50 + incline + rng.normal(0, 3)) * DEG,
            phi=phi0 + 0.5 * math.pi + (k - 3) * math.pi + rng.normal(0, 12 * DEG),
            droop=(55 + rng.normal(0, 3)) * DEG, droop_max=85 * DEG,
            wobble_theta=wobble(rng, 0.07), wobble_phi=wobble(rng, 0.10),
        ))
        _add_leaflets(rng, organs, leaves[k], [0.5], rate=0.45, threshold=25.0, step=0.0, lobes=0.0)
        k += 1
        G += interval + rng.uniform(-3, 3)
    # true side shoots from the axils of the primary and lower trifoliate leaves
    for k, p, delay in ((1, 0.45, (80, 110)), (2, 0.45, (80, 110)), (3, 0.35, (50, 75)), (4, 0.2, (50, 75))):
        if rng.uniform() >= p * vigour or k not in leaves:
            continue
        shoot = len(organs)
        organs.append(_shoot(rng, organs[leaves[k]], delay=rng.uniform(*delay), max_len=115.0 * rng.normal(1, 0.12),
                             width=60.0, theta=(48 + rng.normal(0, 4)) * DEG, index=0))
        phi_s = organs[shoot].phi
        g = 5.0 + rng.uniform(-1, 1)
        for i in range(1, _shoot_leaves(rng, vigour, vary) + 1):
            organs.append(Organ(
                label=organs[shoot].label * 100 + i, parent=shoot, role="leaf", onset=g, node=g + 8.0, depth=3.0,
                max_len=100.0 * rng.normal(1, 0.05), width=40.0,
                theta_young=(25 + rng.normal(0, 2)) * DEG, theta_mature=(50 + incline + rng.normal(0, 3)) * DEG,
                phi=phi_s + (0.5 if i % 2 else -0.5) * math.pi + rng.normal(0, 12 * DEG),
                droop=(55 + rng.normal(0, 3)) * DEG, droop_max=85 * DEG,
                wobble_theta=wobble(rng, 0.07), wobble_phi=wobble(rng, 0.10),
            ))
            _add_leaflets(rng, organs, len(organs) - 1, [0.5], rate=0.43, threshold=25.0, step=0.0, lobes=0.0)
            g += 30.0 + rng.uniform(-3, 3)
    return PlantModel(KIND_MODELS["bean"], size, lean, wob, organs)


ALMOND_FLUSHES = ((0.08, 0.42), (0.55, 0.9))  # biological times of the two flushes in which buds break
ALMOND_MAX_LATERALS = 48  # lateral labels 51..98 on one shoot


def _almond_clock(axes: Sequence[Organ], b: float) -> float:
    """The clock (nominal length, mm) at biological time ``b`` of the last of a chain of shoots ``axes`` (the trunk's
    scaffold first), each growing on its parent's clock as :func:`~.plant_model.organ_state` grows them."""
    c = _almond_develop(b)
    for o in axes:
        c = o.max_len * -math.expm1(-(c - o.onset) / o.width) if c > o.onset else 0.0
    return c


def _almond_buds(rng: np.random.Generator, axes: Sequence[Organ], internode: float, p_shoot: float,
                 p_spur: float) -> list[tuple[int, float, str]]:
    """The buds that break on the last shoot of ``axes`` before the last scan: ``(node k, onset, "shoot" | "spur")``,
    one bud per node ``k * internode``, breaking at a random time of one of the two flushes (or once the node is
    laid down and 8 mm overgrown, if later); ``onset`` is in the shoot's clock."""
    end = _almond_clock(axes, 1.0)
    out = []
    for k in range(1, int(end / internode) + 1):
        u = rng.uniform()
        what = "shoot" if u < p_shoot else "spur" if u < p_shoot + p_spur else ""
        flush = ALMOND_FLUSHES[int(rng.integers(0, 2))]
        onset = max(k * internode + 8.0, _almond_clock(axes, rng.uniform(*flush)))
        if what and onset < end - 2.0:
            out.append((k, onset, what))
    return out[:ALMOND_MAX_LATERALS]


def _almond_structure(rng: np.random.Generator, vary: bool = False) -> PlantModel:
    # A young almond tree over two flushes, wood only: sympodial shoots that zig-zag at nodes a few mm apart, buds
    # breaking at random over both flushes into laterals as long as the leader, and a weak leader that bends and is
    # overtaken by the upright top scaffold.
    size, lean, wob, organs, phi0 = _stem(rng, (0.88, 1.12), (2.0, 12.0), 0.05)  # trunks lean (wind, no stake)
    internode = rng.uniform(4.0, 9.0)  # nominal mm between the nodes of a shoot
    n_scaffolds = int(rng.integers(3, 6))
    lo, hi = 70.0, 400.0  # trunk heights (nominal mm) of the scaffolds' buds, one per slot at random within it
    nodes = lo + (hi - lo) * (np.arange(n_scaffolds) + rng.uniform(0.15, 0.85, n_scaffolds)) / n_scaffolds
    for k, F in enumerate(nodes.tolist(), 1):
        rel = (F - lo) / (hi - lo)  # 0 at the bottom, 1 at the top: acrotony, the upper ones grow most
        top = k == n_scaffolds
        theta = rng.uniform(25.0, 40.0) * DEG if top else rng.uniform(30.0, 60.0) * DEG
        scaffold = len(organs)
        organs.append(Organ(
            label=SHOOT_OFFSET + k, parent=0, role="shoot", onset=F + 30.0 + rng.uniform(-5, 5), node=F, depth=30.0,
            max_len=(230.0 + 170.0 * rel) * rng.normal(1, 0.12) * (1.3 if top else 1.0),
            width=160.0 * rng.normal(1, 0.1), theta_young=theta - 12 * DEG, theta_mature=theta,
            phi=phi0 + (k - 1) * 144.0 * DEG + rng.normal(0, 20 * DEG),  # 2/5 phyllotaxis
            # the top scaffold turns upright and takes over from the leader
            droop=(rng.uniform(-40, -25) if top else rng.uniform(-30, -10) if rel > 0.5 else rng.uniform(-10, 15))
            * DEG, droop_max=(40 if top else 35) * DEG,
            wobble_theta=wobble(rng, 0.08), wobble_phi=wobble(rng, 0.10),
            zigzag=rng.uniform(15.0, 35.0) * DEG, internode=internode,
        ))
        sc = organs[scaffold]
        # laterals on the scaffold, numbered from its base: secondary shoots up to as long as the scaffold, spurs
        for j, (node, onset, what) in enumerate(_almond_buds(rng, [sc], internode, 0.12, 0.1), 1):
            label = sc.label * 100 + SHOOT_OFFSET + j
            if what == "spur":
                organs.append(_spur(rng, label, scaffold, node * internode, onset))
                continue
            shoot = len(organs)
            organs.append(Organ(
                label=label, parent=scaffold, role="shoot", onset=onset, node=node * internode, depth=35.0,
                max_len=sc.max_len * rng.uniform(0.2, 1.0), width=90.0 * rng.normal(1, 0.1),
                theta_young=rng.uniform(30, 45) * DEG, theta_mature=rng.uniform(40, 70) * DEG,
                # it leaves on the side the scaffold turns away from above that node
                phi=sc.phi + float(zigzag_side(node)) * rng.uniform(40, 80) * DEG, droop=rng.uniform(-25, 15) * DEG,
                droop_max=25 * DEG, wobble_theta=wobble(rng, 0.08), wobble_phi=wobble(rng, 0.10),
                zigzag=rng.uniform(15.0, 35.0) * DEG, internode=internode,
            ))
            sec = organs[shoot]
            for m, (node2, onset2, _) in enumerate(_almond_buds(rng, [sc, sec], internode, 0.0, 0.08), 1):
                organs.append(_spur(rng, sec.label * 100 + SHOOT_OFFSET + m, shoot, node2 * internode, onset2))
    if rng.uniform() < 0.7:  # a weak leader arching away above the top scaffold
        bend_from = float(nodes[-1]) + rng.uniform(0.0, 40.0)
        return PlantModel(KIND_MODELS["almond"], size, lean, wob, organs, bend_from=bend_from,
                           leader_bend=_horizontal(rng, math.tan(rng.uniform(20.0, 45.0) * DEG)),
                           bend_ramp=rng.uniform(60.0, 120.0))
    return PlantModel(KIND_MODELS["almond"], size, lean, wob, organs)


def _spur(rng: np.random.Generator, label: int, parent: int, node: float, onset: float) -> Organ:
    """A spur (a short shoot on older wood) at ``node`` that starts growing at its parent's clock ``onset``."""
    return Organ(
        label=label, parent=parent, role="shoot", onset=onset, node=node, depth=40.0,
        max_len=rng.uniform(6.0, 25.0), width=20.0, theta_young=rng.uniform(50, 100) * DEG,
        theta_mature=rng.uniform(50, 100) * DEG, phi=rng.uniform(0, 2 * math.pi), droop=0.0,
        wobble_theta=wobble(rng, 0.03), wobble_phi=wobble(rng, 0.03),
    )


# kind -> draws one plant's organs from an rng (and whether plants vary in vigour: herbaceous kinds only)
STRUCTURES: dict[str, Callable[[np.random.Generator, bool], PlantModel]] = {
    "tomato": _tomato_structure, "maize": _maize_structure, "bean": _bean_structure, "almond": _almond_structure,
}
