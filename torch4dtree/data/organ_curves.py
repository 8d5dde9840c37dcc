"""Synthetic organs as dense 3D polylines at one biological time, with this frame's smooth random bends.

A polyline is uniform in arc length, so a point at a given arc length (an attachment, a skeleton
node) is a cheap interpolation. Bends change directions, not points, so every organ keeps its
exact length and its children stay attached.
"""

from __future__ import annotations

import math

import numpy as np

from .plant_model import Organ, PlantModel, organ_state

__all__ = ["at_arc", "organ_curves", "zigzag_nodes", "zigzag_side"]

LOST_DIRECTION = 1e-6  # a vertical parent has no horizontal direction: any will do
LENGTH_FLOOR = 1e-9  # divisor floor of an organ length (a zero-length organ gets the largest bend)
MAX_SEGMENTS = 2000  # segments of a sympodial shoot's polyline (~1 mm each)
TANGENT_FLOOR = 1e-12  # divisor floor of a segment length (a repeated point gives a zero tangent)


def _directions(theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], -1)


def _polyline(start: np.ndarray, dirs: np.ndarray, length: float) -> np.ndarray:
    """Integrate unit directions at segment midpoints ``(n-1, 3)`` into a polyline of exactly ``length``.

    Its points are uniform in arc length (see :func:`at_arc`).
    """
    steps = dirs * (length / len(dirs))
    return start + np.concatenate([np.zeros((1, 3)), np.cumsum(steps, 0)])


def at_arc(poly: np.ndarray, length: float, arc: np.ndarray) -> np.ndarray:
    """Points at arc lengths ``arc (m,)`` of a polyline with uniform segments of total ``length``."""
    x = np.clip(np.asarray(arc, dtype=np.float64) / length, 0.0, 1.0) * (len(poly) - 1)
    lo = np.minimum(np.floor(x).astype(np.int64), len(poly) - 2)
    w = (x - lo)[:, None]
    return poly[lo] + w * (poly[lo + 1] - poly[lo])


def _tangent_at(poly: np.ndarray, length: float, arc: float) -> np.ndarray:
    k = int(np.clip(arc / length * (len(poly) - 1), 0, len(poly) - 2))
    d = poly[k + 1] - poly[k]
    return d / max(float(np.linalg.norm(d)), TANGENT_FLOOR)


def _eval_wobbles(coef: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Several :func:`wobble` functions ``coef (k, 3, 2)`` at once at ``u (n,)`` -> ``(k, n)``."""
    amp, phase = coef[..., 0, None], coef[..., 1, None]
    arg = (np.arange(1, 4)[:, None] * math.pi) * u[None]  # (3, n)
    return (amp * (np.sin(arg[None] + phase) - np.sin(phase))).sum(1)


def _stem_points(plant: PlantModel, L: float, jitter: np.ndarray, step: float = 1.0) -> np.ndarray:
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
    o: Organ, start: np.ndarray, base_dir: np.ndarray, length: float, maturity: float, droop_pow: float,
    jitter: np.ndarray, size: float = 1.0, drift: float = 0.0,
) -> np.ndarray:
    """A lateral organ: start direction (spherical angles), droop growing with length, smooth wobble, and a
    sympodial shoot's turns at its nodes (``size``: the plant's size factor, ``drift``: the kind's node drift).

    ``jitter (2, 3, 2)``: this frame's noise on the inclination and azimuth (see :func:`_frame_noise`).
    """
    # ~1 mm segments (a sympodial shoot's internodes need them all), at most 200 on a smooth organ
    n = int(np.clip(math.ceil(length / 1.0), 8, MAX_SEGMENTS if o.zigzag > 0 else 200))
    u = (np.arange(n) + 0.5) / n
    theta0 = math.acos(min(max(float(base_dir[2]), -1.0), 1.0))
    phi0 = math.atan2(float(base_dir[1]), float(base_dir[0]))
    bend = math.copysign(min(abs(o.droop) * length / 100.0, o.droop_max), o.droop) * (0.5 + 0.5 * maturity)
    w = _eval_wobbles(np.concatenate([o.wobble_theta[None], o.wobble_phi[None], jitter]), u)
    theta = np.clip(theta0 + bend * u**droop_pow + w[0] + w[2], 0.02, math.pi - 0.2)
    phi = phi0 + w[1] + w[3]
    dirs = _directions(theta, phi)
    if o.zigzag > 0 and o.internode > 0:
        dirs = _zigzag(dirs, u * length, zigzag_nodes(o, length, size, drift), o.zigzag)
    return _polyline(start, dirs, length)


def zigzag_nodes(o: Organ, length: float, size: float, drift: float) -> np.ndarray:
    """Arc lengths (mm) of the nodes of a sympodial shoot of ``length`` mm: nominal ``k * internode`` (k >= 1),
    lifted by the stretch of the internodes below them as the shoot grows (``drift``, as :func:`organ_state` places
    the laterals there)."""
    if o.internode <= 0:
        return np.zeros(0)
    clock = length / size  # a shoot's clock is its nominal length
    nominal = o.internode * np.arange(1, int(clock / o.internode) + 1)
    return size * (nominal + drift * (clock - nominal))


def zigzag_side(k: int | np.ndarray) -> float | np.ndarray:
    """The side (+1 / -1: towards a smaller / larger azimuth) a sympodial axis turns to above its ``k``-th node."""
    return 1.0 - 2.0 * (k % 2)


def _zigzag(dirs: np.ndarray, arc: np.ndarray, nodes: np.ndarray, angle: float) -> np.ndarray:
    """Turn unit directions ``(n, 3)`` at arc lengths ``arc (n,)`` alternately sideways at every node ``(k,)``: by
    ``+-angle / 2`` about the shoot's course, so consecutive internodes meet at ``angle``."""
    k = np.searchsorted(nodes, arc, side="right")  # nodes passed
    side = zigzag_side(k)
    h = np.stack([dirs[:, 1], -dirs[:, 0], np.zeros(len(dirs))], -1)  # dirs x up: azimuth - 90 degrees
    norm = np.linalg.norm(h, axis=-1, keepdims=True)
    h = np.where(norm > LOST_DIRECTION, h / np.maximum(norm, LOST_DIRECTION), np.array([1.0, 0.0, 0.0]))
    turned = dirs + (side * math.tan(angle / 2))[:, None] * h
    return turned / np.linalg.norm(turned, axis=-1, keepdims=True)


def _lateral_direction(tangent: np.ndarray, spread: float, side: float) -> np.ndarray:
    """Direction at ``spread`` from a parent's tangent, to its left (+1) or right (-1), slightly down."""
    tx, ty, tz = (float(v) for v in tangent)
    hx, hy = ty, -tx  # tangent x (0, 0, 1)
    norm = math.hypot(hx, hy)
    hx, hy = (hx / norm, hy / norm) if norm > LOST_DIRECTION else (1.0, 0.0)
    c, s = math.cos(spread), math.sin(spread) * side
    d = np.array([c * tx + s * hx, c * ty + s * hy, c * tz - 0.15])
    return d / math.sqrt(float(d @ d))


def _frame_noise(rng: np.random.Generator, sigma: float, lengths: np.ndarray) -> np.ndarray:
    """This frame's smooth random bends of every organ: ``(n_organs, 2, 3, 2)`` :func:`wobble` coefficients
    of the perturbations of its two direction angles (the stem: of its two lateral slopes).

    Bending the direction (instead of moving points) keeps every organ's length exact; the tip
    moves by about ``sigma`` mm, the base not at all (children stay attached). Tiny organs bend at
    most ~0.15 rad.
    """
    n = len(lengths)
    amp = np.minimum(sigma / np.maximum(lengths, LENGTH_FLOOR), 0.15) if sigma > 0 else np.zeros(n)
    coef = np.empty((n, 2, 3, 2))
    coef[..., 0] = rng.normal(0.0, 1.0, (n, 2, 3)) * amp[:, None, None] / np.arange(1, 4)
    coef[..., 1] = rng.uniform(0, 2 * math.pi, (n, 2, 3))
    return coef


def organ_curves(
    plant: PlantModel, b: float, rng: np.random.Generator, noise: float, min_length: float,
) -> tuple[dict[int, np.ndarray], np.ndarray, np.ndarray]:
    """Dense polylines (uniform in arc length) of the organs present at ``b``, with all lengths and positions."""
    length, pos = organ_state(plant, b)
    bends = _frame_noise(rng, noise, length)
    curves: dict[int, np.ndarray] = {0: _stem_points(plant, float(length[0]), bends[0])}
    for i, o in enumerate(plant.organs):
        if i == 0 or length[i] < min_length or o.parent not in curves:
            continue
        par = o.parent
        start = at_arc(curves[par], float(length[par]), np.array([pos[i]]))[0]
        if o.role == "part":
            base_dir = _lateral_direction(_tangent_at(curves[par], float(length[par]), float(pos[i])), o.spread, o.side)
            maturity = 1.0
        else:
            maturity = min(length[i] / (plant.size * o.max_len), 1.0)
            theta = o.theta_young + (o.theta_mature - o.theta_young) * maturity
            base_dir = _directions(np.array(theta), np.array(o.phi))
        curves[i] = _organ_points(o, start, base_dir, float(length[i]), maturity, plant.kind.droop_pow, bends[i],
                                  plant.size, plant.kind.node_drift)
    return curves, length, pos
