"""Synthetic growing plants (tomato-like and maize-like 4D trees) with ground truth.

The model, in one paragraph: every plant has a **biological clock** ``b = h(t)``, a monotone
warp of its normalised calendar time ``t in [0, 1]`` (``h(0) = 0``, ``h(1) = 1``); some plants
develop early, others late. Everything else is a deterministic function of ``b`` that has the
same form for all plants of a kind (only sizes, counts and geometry are plant-specific), so the
true temporal correspondence between two plants is ``h_2^{-1} o h_1``. The stem grows from its
apex: its length is ``L(b) = size * D(b)`` with ``D`` the kind's developmental curve (mm); leaf
``k`` appears at the apex once ``D`` passes its node height ``H_k`` and then grows along a
saturating curve. Leaflets (tomato) grow once their leaf is long enough, lobes once their
leaflet is. Lengths never decrease, so a branch present at one frame is present at all later
frames.

**Longest-path guarantee.** Skeleton files do not store the branch hierarchy: readers rebuild
it with the longest-path rule (SPEC §2). Every side branch is therefore kept shorter than
``margin`` (0.85) times the rest of its parent beyond the attachment point (a smooth minimum of
the branch's own growth curve and that cap), so at every frame the stem is the longest
root-to-leaf path and each branch's own continuation is the longest path from its base: writing
a plant to SWC and reading it back gives the same branches. A consequence, unlike real maize
skeletons (where the main path often runs into a leaf): the synthetic stem includes the
vertical, still-rolled whorl above the last collar, and upper leaves stay shorter than the stem
above them.

**Ground-truth labels** (non-negative ints, written to the SWC type column):

* ``0``: the main stem;
* ``k`` (1..99): the k-th leaf from the bottom. Tomato: 1 and 2 are the cotyledons (one node,
  opposite), 3, 4, ... the true leaves in spiral phyllotaxis (137.5 degrees). Maize: 1, 2, ...
  alternate on opposite sides;
* ``k * 100 + j`` (j = 1..99): leaflet ``j`` of leaf ``k`` (tomato): ``j = 2 p - 1`` / ``2 p`` for
  the left / right leaflet of pair ``p`` counted from the leaf's base (the terminal leaflet is
  the continuation of the rachis, part of the leaf itself);
* ``(k * 100 + j) * 100 + m`` (m = 1..99): lobe ``m`` of that leaflet (1 left, 2 right).

So the layer of a label follows from its size (see :func:`label_parts`), and a label means the
same organ in every frame and in every plant of the same kind.

Randomness: ``numpy.random.default_rng`` (PCG64) seeded from the plant seed (plant structure)
and from ``(seed, frame)`` (per-frame scanning noise), so a seed gives the same plant on any
machine. Noise is a smooth random bend of each branch, independent per frame: its tip moves by
about ``noise`` mm, its base stays (children stay attached) and its length is unchanged.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import torch
from torch import Tensor

from ..trees.structures import DEFAULT_T, Trees, TreeSequence

KINDS = ("tomato", "maize")

_DEG = math.pi / 180.0


# ------------------------------------------------------------------------------------ labels
def label_parts(label: int) -> tuple[int, ...]:
    """Split a ground-truth label into organ indices: ``()`` stem, ``(k,)`` leaf, ``(k, j)``, ``(k, j, m)``."""
    if label < 0:
        raise ValueError(f"labels are non-negative, got {label}")
    parts: list[int] = []
    while label > 0:
        parts.append(label % 100)
        label //= 100
    return tuple(reversed(parts))


def label_layer(label: int) -> int:
    """Layer of a ground-truth label: 0 stem, 1 leaf, 2 leaflet, 3 lobe."""
    return len(label_parts(label))


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
    node_drift: float  # share of later stem growth that happens below an existing node
    droop_pow: float


def _tomato_develop(b: float) -> float:
    # accelerating growth: about 45 mm on the first day, 230 mm on the last (Pheno4D tomato)
    return 45.0 + 185.0 * (math.exp(1.7 * b) - 1.0) / (math.exp(1.7) - 1.0)


def _maize_develop(b: float) -> float:
    # fast, slightly saturating growth: about 50 mm on the first day, 345 mm on the last
    return 50.0 + 295.0 * (1.0 - math.exp(-0.7 * b)) / (1.0 - math.exp(-0.7))


_MODELS = {
    "tomato": _KindModel("tomato", _tomato_develop, node_drift=0.15, droop_pow=1.6),
    "maize": _KindModel("maize", _maize_develop, node_drift=0.10, droop_pow=2.0),
}


@dataclass
class _Branch:
    """One organ of a plant (fixed over time); its length at a time comes from :func:`_lengths`."""

    label: int
    parent: int  # index in the plant's branch list, -1 for the stem
    attach: float  # leaf: nominal node height H (mm of D); leaflet / lobe: fraction of the parent's length
    max_len: float = 0.0  # leaf: asymptotic length (nominal mm)
    width: float = 1.0  # leaf: D-growth (mm) to reach 63% of max_len
    rate: float = 0.0  # leaflet / lobe: mm of own length per mm of parent length beyond `threshold`
    threshold: float = 0.0  # leaflet / lobe: parent length (nominal mm) where it starts growing
    theta_young: float = 0.0  # leaf: inclination from vertical when small (rad)
    theta_mature: float = 0.0  # ... and when full grown
    phi: float = 0.0  # leaf: azimuth (rad)
    spread: float = 0.0  # leaflet / lobe: angle from the parent's tangent (rad)
    side: float = 1.0  # leaflet / lobe: +1 left, -1 right
    droop: float = 0.0  # gravity bending from base to tip (rad) per 100 mm of length
    droop_max: float = 1.5  # cap on that bending (rad)
    wobble_theta: np.ndarray = field(default_factory=lambda: np.zeros((3, 2)))  # (amplitude, phase) x 3
    wobble_phi: np.ndarray = field(default_factory=lambda: np.zeros((3, 2)))


def _wobble(rng: np.random.Generator, amplitude: float) -> np.ndarray:
    """Coefficients of a smooth random function of ``u in [0, 1]`` that vanishes at 0 (``(3, 2)``)."""
    amp = rng.normal(0.0, amplitude, 3) / np.arange(1, 4)
    return np.stack([amp, rng.uniform(0, 2 * math.pi, 3)], 1)


def _eval_wobble(coef: np.ndarray, u: np.ndarray) -> np.ndarray:
    m = np.arange(1, 4)[:, None]
    return (coef[:, :1] * (np.sin(m * math.pi * u[None] + coef[:, 1:]) - np.sin(coef[:, 1:]))).sum(0)


@dataclass
class _PlantModel:
    """A plant's fixed structure: size, stem shape, branches (parents before children)."""

    kind: _KindModel
    size: float
    stem_lean: np.ndarray  # (2,) horizontal lean of the stem direction
    stem_wobble: np.ndarray  # (2, 3, 3) per horizontal axis: (amplitude, wavelength mm, phase) x 3
    branches: list[_Branch]


def _tomato_structure(rng: np.random.Generator) -> _PlantModel:
    # Organ traits follow the organ's identity: a profile along the stem shared by the kind, a plant-level
    # offset and small per-organ noise, so leaf k of one plant resembles leaf k of another (as nodes of one
    # cultivar do). With independent per-leaf draws (the first version) neighbouring leaves differed as much
    # as same-index ones, and no shape metric could tell organ identities apart across plants.
    size = rng.uniform(0.85, 1.15)
    lean = _horizontal(rng, math.tan(rng.uniform(1.0, 6.0) * _DEG))
    wob = np.stack([_stem_wobble(rng, 0.05) for _ in range(2)])
    branches: list[_Branch] = []
    phi0 = rng.uniform(0, 2 * math.pi)  # azimuth of the first true leaf
    incline = rng.normal(0.0, 3.0)  # plant-level offset of the leaf inclinations (deg)
    phi_c = phi0 - 0.5 * math.pi + rng.normal(0, 8 * _DEG)  # cotyledons across the first true leaf
    for k, phi in ((1, phi_c), (2, phi_c + math.pi + rng.normal(0, 6 * _DEG))):  # cotyledons, one node
        branches.append(_Branch(
            label=k, parent=-1, attach=20.0 + rng.uniform(-2, 2), max_len=28.0 + rng.normal(0, 1.5), width=15.0,
            theta_young=45 * _DEG, theta_mature=(72 + incline + rng.normal(0, 3)) * _DEG, phi=phi,
            droop=40 * _DEG, droop_max=50 * _DEG,
            wobble_theta=_wobble(rng, 0.06), wobble_phi=_wobble(rng, 0.08),
        ))
    internode = rng.uniform(14.0, 19.0)  # plant-specific spacing of the true leaves along the stem
    k, H = 3, 30.0 + rng.uniform(0, 4)
    while H < 222.0 and k < 100:
        leaf = len(branches)
        branches.append(_Branch(
            label=k, parent=-1, attach=H, max_len=(135.0 + 45.0 * -math.expm1(-(k - 3) / 3.0)) * rng.normal(1, 0.04),
            width=60.0, theta_young=(30 + rng.normal(0, 2)) * _DEG,
            theta_mature=(57 + incline + rng.normal(0, 3)) * _DEG,
            phi=phi0 + (k - 3) * 137.5 * _DEG + rng.normal(0, 8 * _DEG),
            droop=(55 + rng.normal(0, 3)) * _DEG, droop_max=85 * _DEG,
            wobble_theta=_wobble(rng, 0.08), wobble_phi=_wobble(rng, 0.12),
        ))
        # the first true leaves carry two pairs of leaflets, later ones mostly three
        pairs = [0.36, 0.56, 0.73] if rng.uniform() < (0.15 if k < 6 else 0.85) else [0.4, 0.65]
        for p, u in enumerate(pairs, 1):
            u = u + rng.uniform(-0.03, 0.03)
            for side_i, side in ((1, 1.0), (2, -1.0)):
                j = 2 * (p - 1) + side_i
                leaflet = len(branches)
                branches.append(_Branch(
                    label=k * 100 + j, parent=leaf, attach=u, rate=0.37 + rng.normal(0, 0.02),
                    threshold=40.0 + 30.0 * (p - 1) + rng.uniform(-3, 3),
                    spread=(65 + rng.normal(0, 4)) * _DEG, side=side,
                    droop=(55 + rng.normal(0, 4)) * _DEG, droop_max=60 * _DEG,
                    wobble_theta=_wobble(rng, 0.06), wobble_phi=_wobble(rng, 0.08),
                ))
                if p == 1 and rng.uniform() < 0.8:  # the big basal leaflets carry a pair of lobes
                    for m, lside in ((1, 1.0), (2, -1.0)):
                        branches.append(_Branch(
                            label=(k * 100 + j) * 100 + m, parent=leaflet, attach=0.3 + rng.uniform(-0.04, 0.04),
                            rate=0.35 + rng.normal(0, 0.015), threshold=20.0 + rng.uniform(-3, 3),
                            spread=(55 + rng.normal(0, 4)) * _DEG, side=lside,
                            droop=30 * _DEG, droop_max=40 * _DEG,
                            wobble_theta=_wobble(rng, 0.05), wobble_phi=_wobble(rng, 0.05),
                        ))
        k += 1
        H += internode + rng.uniform(-2, 2)
    return _PlantModel(_MODELS["tomato"], size, lean, wob, branches)


def _maize_structure(rng: np.random.Generator) -> _PlantModel:
    size = rng.uniform(0.88, 1.12)
    lean = _horizontal(rng, math.tan(rng.uniform(0.5, 3.0) * _DEG))
    wob = np.stack([_stem_wobble(rng, 0.02) for _ in range(2)])
    branches: list[_Branch] = []
    phi0 = rng.uniform(0, 2 * math.pi)
    internode = rng.uniform(60.0, 80.0)  # plant-specific: how fast new leaves follow each other
    k, H = 1, 8.0 + rng.uniform(0, 6)
    while H < 330.0 and k < 100:
        branches.append(_Branch(
            label=k, parent=-1, attach=H, max_len=rng.uniform(280, 330), width=110.0,
            theta_young=rng.uniform(8, 15) * _DEG, theta_mature=rng.uniform(18, 32) * _DEG,
            phi=phi0 + (k - 1) * math.pi + rng.normal(0, 12 * _DEG),
            droop=rng.uniform(45, 60) * _DEG, droop_max=rng.uniform(105, 125) * _DEG,
            wobble_theta=_wobble(rng, 0.05), wobble_phi=_wobble(rng, 0.10),
        ))
        k += 1
        H += internode + rng.uniform(-5, 5)
    return _PlantModel(_MODELS["maize"], size, lean, wob, branches)


def _horizontal(rng: np.random.Generator, magnitude: float) -> np.ndarray:
    a = rng.uniform(0, 2 * math.pi)
    return magnitude * np.array([math.cos(a), math.sin(a)])


def _stem_wobble(rng: np.random.Generator, amplitude: float) -> np.ndarray:
    """``(3, 3)`` rows (amplitude, wavelength in mm, phase) of the stem's lateral wobble on one axis."""
    return np.stack([rng.normal(0, amplitude, 3), rng.uniform(50, 250, 3), rng.uniform(0, 2 * math.pi, 3)], 1)


_STRUCTURES = {"tomato": _tomato_structure, "maize": _maize_structure}


# ------------------------------------------------------------------------- growth in time
def _softmin(x: float, y: float, tau: float) -> float:
    """A smooth minimum, never above ``min(x, y)`` and non-decreasing in both."""
    lo = min(x, y)
    return lo - tau * math.log1p(math.exp(-abs(x - y) / tau))


def _lengths(plant: _PlantModel, b: float, margin: float) -> tuple[float, np.ndarray, np.ndarray]:
    """Stem length, and per branch its length and attachment arc length (mm) at biological time ``b``.

    Every length is non-decreasing in ``b``. Side branches are capped at ``margin`` times the
    rest of their parent beyond the attachment (the longest-path guarantee of the module doc).
    """
    D = plant.kind.develop(b)
    L = plant.size * D
    tau = 1.0 * plant.size
    n = len(plant.branches)
    length = np.zeros(n)
    at = np.zeros(n)
    for i, br in enumerate(plant.branches):
        if br.parent < 0:  # a leaf on the stem
            if D <= br.attach:
                continue
            at[i] = plant.size * (br.attach + plant.kind.node_drift * (D - br.attach))
            want = plant.size * br.max_len * -math.expm1(-(D - br.attach) / br.width)
            length[i] = max(_softmin(want, margin * (L - at[i]), tau), 0.0)
        else:
            R = length[br.parent]
            at[i] = br.attach * R
            want = br.rate * max(R - plant.size * br.threshold, 0.0)
            length[i] = max(_softmin(want, margin * (1.0 - br.attach) * R, tau), 0.0) if want > 0 else 0.0
    return L, length, at


# ------------------------------------------------------------------------------- geometry
def _directions(theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], -1)


def _polyline(start: np.ndarray, dirs: np.ndarray, length: float) -> np.ndarray:
    """Integrate unit directions at segment midpoints ``(n-1, 3)`` into a polyline of exactly ``length``."""
    steps = dirs * (length / len(dirs))
    return start + np.concatenate([np.zeros((1, 3)), np.cumsum(steps, 0)])


def _stem_points(plant: _PlantModel, L: float, jitter: np.ndarray, step: float = 1.0) -> np.ndarray:
    """The stem up to arc length ``L``: its shape is fixed in absolute arc length, so it only extends.

    ``jitter (2, 3, 2)``: this frame's noise on the two lateral slopes (see :func:`_angle_noise`).
    """
    n = max(int(math.ceil(L / step)), 8)
    a = (np.arange(n) + 0.5) * (L / n)  # segment midpoints (mm from the root)
    w = plant.stem_wobble
    lateral = [
        plant.stem_lean[ax] + (w[ax, :, :1] * np.sin(2 * math.pi * a[None] / w[ax, :, 1:2] + w[ax, :, 2:])).sum(0)
        + _eval_wobble(jitter[ax], a / L)
        for ax in range(2)
    ]
    d = np.stack([lateral[0], lateral[1], np.ones(n)], -1)
    return _polyline(np.zeros(3), d / np.linalg.norm(d, axis=-1, keepdims=True), L)


def _point_and_tangent(poly: np.ndarray, frac: float) -> tuple[np.ndarray, np.ndarray]:
    """Point at arc-length fraction ``frac`` of a polyline ``(n, 3)`` and the unit tangent there."""
    seg = np.diff(poly, axis=0)
    seg_len = np.linalg.norm(seg, axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg_len)])
    target = frac * cum[-1]
    k = int(np.clip(np.searchsorted(cum, target, side="right") - 1, 0, len(seg) - 1))
    w = (target - cum[k]) / seg_len[k] if seg_len[k] > 0 else 0.0
    return poly[k] + w * seg[k], seg[k] / max(seg_len[k], 1e-12)


def _branch_points(
    br: _Branch, start: np.ndarray, base_dir: np.ndarray, length: float, maturity: float, droop_pow: float,
    jitter: np.ndarray,
) -> np.ndarray:
    """A side branch: start direction (spherical angles), gravity droop growing with length, smooth wobble.

    ``jitter (2, 3, 2)``: this frame's noise on the inclination and azimuth (see :func:`_angle_noise`).
    """
    n = int(np.clip(math.ceil(length / 1.0), 8, 200))
    u = (np.arange(n) + 0.5) / n
    theta0 = math.acos(float(np.clip(base_dir[2], -1.0, 1.0)))
    phi0 = math.atan2(float(base_dir[1]), float(base_dir[0]))
    droop = min(br.droop * length / 100.0, br.droop_max) * (0.5 + 0.5 * maturity)
    theta = theta0 + droop * u**droop_pow + _eval_wobble(br.wobble_theta, u) + _eval_wobble(jitter[0], u)
    theta = np.clip(theta, 0.02, math.pi - 0.2)
    phi = phi0 + _eval_wobble(br.wobble_phi, u) + _eval_wobble(jitter[1], u)
    return _polyline(start, _directions(theta, phi), length)


def _lateral_direction(tangent: np.ndarray, spread: float, side: float) -> np.ndarray:
    """Direction at ``spread`` from a parent's tangent, to its left (+1) or right (-1), slightly down."""
    horiz = np.cross(tangent, np.array([0.0, 0.0, 1.0]))
    if np.linalg.norm(horiz) < 1e-6:  # vertical parent: any horizontal direction
        horiz = np.array([1.0, 0.0, 0.0])
    horiz /= np.linalg.norm(horiz)
    d = math.cos(spread) * tangent + math.sin(spread) * side * horiz - np.array([0.0, 0.0, 0.15])
    return d / np.linalg.norm(d)


def _angle_noise(rng: np.random.Generator, sigma: float, length: float) -> np.ndarray:
    """Per-frame noise as ``(2, 3, 2)`` smooth random perturbations of a branch's two direction angles.

    Bending the direction (instead of moving points) keeps every branch's length exact, so the
    longest-path margin holds whatever the noise; the tip moves by about ``sigma`` mm, the base
    not at all (children stay attached). Tiny organs bend at most ~0.15 rad.
    """
    amp = min(sigma / max(length, 1e-9), 0.15) if sigma > 0 else 0.0
    return np.stack([_wobble(rng, amp), _wobble(rng, amp)])


def _frame(
    plant: _PlantModel, b: float, rng: np.random.Generator, noise: float, margin: float, min_length: float,
) -> tuple[list[np.ndarray], list[int], list[int]]:
    """Polylines, parent indices and labels of the plant at biological time ``b`` (present branches only)."""
    L, length, at = _lengths(plant, b, margin)
    stem = _stem_points(plant, L, _angle_noise(rng, noise, L))
    polys: list[np.ndarray] = [stem]
    parents: list[int] = [-1]
    labels: list[int] = [0]
    where: dict[int, int] = {}  # branch index -> position in the output lists
    for i, br in enumerate(plant.branches):
        if length[i] < min_length or (br.parent >= 0 and br.parent not in where):
            continue
        if br.parent < 0:
            parent_poly, frac = stem, at[i] / L
            maturity = min(length[i] / (plant.size * br.max_len), 1.0)
            theta = br.theta_young + (br.theta_mature - br.theta_young) * maturity
            base_dir = _directions(np.array(theta), np.array(br.phi))
        else:
            parent_poly = polys[where[br.parent]]
            frac, maturity = br.attach, 1.0
        start, tangent = _point_and_tangent(parent_poly, frac)
        if br.parent >= 0:
            base_dir = _lateral_direction(tangent, br.spread, br.side)
        jitter = _angle_noise(rng, noise, float(length[i]))
        pts = _branch_points(br, start, base_dir, float(length[i]), maturity, plant.kind.droop_pow, jitter)
        where[i] = len(polys)
        polys.append(pts)
        parents.append(0 if br.parent < 0 else where[br.parent])
        labels.append(br.label)
    return polys, parents, labels


# ------------------------------------------------------------------------------------ API
@dataclass(frozen=True, eq=False)
class SyntheticPlant:
    """A synthetic 4D plant and its ground truth.

    Attributes:
        sequence: the 4D tree; ``sequence.frames.label`` holds the branch identities (module doc).
        kind: ``"tomato"`` or ``"maize"``.
        seed: the seed that regenerates this plant alone (``synthetic_plant(kind, seed, ...)``).
        growth_grid: ``(G,)`` normalised calendar times ``linspace(0, 1, G)``.
        growth_warp: ``(G,)`` the biological clock ``h`` on ``growth_grid`` (monotone, ``h(0)=0``,
            ``h(1)=1``, linear in between).
        bio_times: ``(n_frames,)`` ``h`` at the frames' normalised times.
        settings: the generation settings (JSON-serialisable).
        name: e.g. ``"tomato_03"`` in a dataset.
    """

    sequence: TreeSequence
    kind: str
    seed: int
    growth_grid: Tensor
    growth_warp: Tensor
    bio_times: Tensor
    settings: dict
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
        """Per frame, the sorted branch labels present."""
        f = self.sequence.frames
        ptr = f.ptr.tolist()
        lab = f.label.tolist()
        return [sorted(lab[a:b]) for a, b in zip(ptr[:-1], ptr[1:])]


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


def synthetic_plant(
    kind: str = "tomato",
    seed: int = 0,
    n_frames: int = 10,
    times: Sequence[float] | Tensor | np.ndarray | None = None,
    T: int = DEFAULT_T,
    noise: float = 0.5,
    warp_strength: float = 1.0,
    min_length: float = 2.0,
    margin: float = 0.85,
    grid_size: int = 101,
    dtype: torch.dtype = torch.float32,
    name: str = "",
) -> SyntheticPlant:
    """Generate one synthetic growing plant with ground truth.

    Args:
        kind: ``"tomato"`` (stem, spiral leaves with leaflet pairs and lobes: up to 4 layers) or
            ``"maize"`` (stem and long arching leaves on alternate sides: 2 layers).
        seed: any non-negative int; the same seed gives the same plant.
        n_frames: number of frames when ``times`` is not given.
        times: ``(n_frames,)`` strictly increasing acquisition times (any unit); default:
            irregular days from the seed (:func:`default_times`). The first and last map to
            normalised times 0 and 1.
        T: points per branch.
        noise: size (mm) of the smooth per-frame random bend of each branch (tip displacement); 0 for none.
        warp_strength: how far the growth clock departs from the identity (0: ``h(t) = t``).
        min_length: a branch appears in a frame once it is at least this long (mm).
        margin: side branches stay below this fraction of the rest of their parent (longest-path rule).
        grid_size: points of the growth-warp grid.
        dtype: dtype of the points.
        name: the sequence name.

    Returns:
        a :class:`SyntheticPlant`. Units are mm, z up, the root at the origin.
    """
    if kind not in KINDS:
        raise ValueError(f"unknown plant kind {kind!r}; expected one of {', '.join(KINDS)}")
    if seed < 0:
        raise ValueError(f"seed must be non-negative, got {seed}")
    if not 0.0 < margin < 1.0:
        raise ValueError(f"margin must lie in (0, 1), got {margin}")
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
    branches, parents, labels = [], [], []
    for j, b in enumerate(bio):
        polys, par, lab = _frame(model, float(b), np.random.default_rng([seed, kid, 3, j]), noise, margin, min_length)
        branches.append(polys)
        parents.append(par)
        labels.append(lab)
    name = name or f"{kind}_seed{seed}"
    frames = Trees.from_branches(branches, parents, T=T, labels=labels, dtype=dtype,
                                 names=[f"{name} frame {j}" for j in range(len(t))])
    sequence = TreeSequence(frames, torch.tensor(t, dtype=dtype), name)
    settings = {"n_frames": len(t), "T": T, "noise": noise, "warp_strength": warp_strength,
                "min_length": min_length, "margin": margin, "grid_size": grid_size}
    return SyntheticPlant(
        sequence, kind, int(seed), torch.from_numpy(grid), torch.from_numpy(h), torch.from_numpy(bio), settings, name,
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
    **kwargs: object,
) -> list[SyntheticPlant]:
    """Several plants of one kind (their labels name the same organs).

    Plant ``i`` is ``synthetic_plant(kind, plant_seed(seed, i), ...)`` named ``f"{kind}_{i:02d}"``.
    With ``shared_times`` (default) and no ``times``, all plants are scanned on the same irregular
    days drawn from ``seed`` (as in Pheno4D); otherwise each plant draws its own.
    Other keyword arguments go to :func:`synthetic_plant`.
    """
    if plants < 1:
        raise ValueError(f"plants must be at least 1, got {plants}")
    if times is None and shared_times:
        times = default_times(np.random.default_rng([seed, 99]), n_frames)
    out = []
    for i in range(plants):
        p = synthetic_plant(kind, plant_seed(seed, i), n_frames=n_frames, times=times, name=f"{kind}_{i:02d}",
                            **kwargs)  # type: ignore[arg-type]
        out.append(replace(p, settings={**p.settings, "dataset_seed": seed, "index": i}))
    return out
