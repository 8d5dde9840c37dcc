"""Trees as tube meshes: every branch a tube, all branches of a batch built in one vectorised numpy pass.

One merged mesh per tree (not one per branch or per segment) keeps a frame to a single draw call,
which is what makes rendering a large plant fast.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .options import COLOR_MODES, LABEL_PALETTE, LAYER_COLORS, UNLABELLED_COLOR, RenderOptions

if TYPE_CHECKING:  # imported where used: importing the renderer must not import torch (fast CLI start)
    from ..trees.structures import Trees

__all__ = ["TreeGeometry", "branch_colors", "tree_geometry", "unit_vectors"]

NORM_FLOOR = 1e-300  # divisor floor of a normalisation: a zero vector stays zero instead of becoming NaN
STALLED = 1e-12  # a tangent shorter than this is a repeated point: it keeps the previous direction
LOST_NORMAL = 1e-6  # a carried normal shorter than this was lost in a ~90 degree turn: restart from an axis
NULL_LENGTH = 1e-9  # branches shorter than this share of the base radius are null branches, not drawn
RADIUS_FLOOR = 1e-12  # the base radius used for that test is at least this (a zero radius still drops nulls)


def branch_colors(trees: Trees, color: str = "layer") -> np.ndarray:
    """``(N, 3)`` uint8 sRGB colour of every packed branch, by layer or by label.

    Example:
        >>> import numpy as np
        >>> from torch4dtree import Trees
        >>> stem, leaf = np.array([[0.0, 0, 0], [0, 0, 10]]), np.array([[0.0, 0, 5], [4, 0, 8]])
        >>> trees = Trees.from_branches([[stem, leaf]], [[-1, 0]], T=8)
        >>> branch_colors(trees).tolist()  # red main branch, blue first layer
        [[214, 39, 40], [31, 94, 214]]
    """
    if color == "layer":
        depth = trees.depth.cpu().numpy()
        return LAYER_COLORS[np.minimum(depth, len(LAYER_COLORS) - 1)]
    if color == "label":
        label = trees.label.cpu().numpy()
        out = LABEL_PALETTE[np.mod(label, len(LABEL_PALETTE))]
        out[label < 0] = UNLABELLED_COLOR
        return out
    raise ValueError(f"color must be one of {COLOR_MODES}, got {color!r}")


def unit_vectors(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normalised vectors ``(..., 3)`` and their norms ``(...)`` (zero vectors stay zero)."""
    n = np.linalg.norm(v, axis=-1)
    return v / np.maximum(n, NORM_FLOOR)[..., None], n


def _tube_frames(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation-minimising normal and binormal ``(N, T, 3)`` along polylines ``(N, T, 3)``.

    The normal is carried from point to point by projection on the next normal plane
    (vectorised over branches, a loop over the ``T`` samples), so tubes do not twist.
    """
    N, T, _ = points.shape
    tang = np.empty_like(points)
    tang[:, 1:-1] = points[:, 2:] - points[:, :-2]  # central differences are smoother than one-sided
    tang[:, 0] = points[:, 1] - points[:, 0]
    tang[:, -1] = points[:, -1] - points[:, -2]
    tang, tn = unit_vectors(tang)
    for i in range(1, T):  # a stalled sample (repeated point) keeps the previous direction
        stalled = tn[:, i] < STALLED
        tang[stalled, i] = tang[stalled, i - 1]
    axes = np.eye(3)
    normal = np.empty_like(points)
    n0 = np.cross(tang[:, 0], axes[np.argmin(np.abs(tang[:, 0]), axis=1)])
    normal[:, 0] = unit_vectors(n0)[0]
    for i in range(1, T):
        t = tang[:, i]
        n = normal[:, i - 1] - (normal[:, i - 1] * t).sum(-1, keepdims=True) * t
        n, nn = unit_vectors(n)
        bad = nn < LOST_NORMAL
        if bad.any():
            n[bad] = unit_vectors(np.cross(t[bad], axes[np.argmin(np.abs(t[bad]), axis=1)]))[0]
        normal[:, i] = n
    return normal, np.cross(tang, normal)


def _tube_template(T: int, K: int) -> np.ndarray:
    """``(F, 3)`` triangle indices of one tube: ``T`` rings of ``K`` vertices, then two cap centres."""
    i, k = np.meshgrid(np.arange(T - 1), np.arange(K), indexing="ij")
    a = i * K + k
    b = i * K + (k + 1) % K
    c = (i + 1) * K + k
    d = (i + 1) * K + (k + 1) % K
    side = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([b, d, c], -1).reshape(-1, 3)])
    ring = np.arange(K)
    start, end = T * K, T * K + 1
    cap0 = np.stack([np.full(K, start), (ring + 1) % K, ring], -1)  # wound to face backwards
    cap1 = np.stack([np.full(K, end), (T - 1) * K + ring, (T - 1) * K + (ring + 1) % K], -1)
    return np.concatenate([side, cap0, cap1]).astype(np.int64)


@dataclass
class TreeGeometry:
    """One tree's merged tube mesh (``V`` vertices, ``F`` triangles)."""

    vertices: np.ndarray  # (V, 3) float32
    normals: np.ndarray  # (V, 3) float32
    colors: np.ndarray  # (V, 3) uint8 sRGB
    faces: np.ndarray  # (F, 3) uint32


def tree_geometry(trees: Trees, opts: RenderOptions, base_radius: float, min_radius: float) -> list[TreeGeometry]:
    """One merged tube mesh per tree of ``trees`` (world units: radii ``base_radius``, at least ``min_radius``).

    A tube is thinner per layer (``opts.thinning``) and tapers along its branch (``opts.taper``);
    null branches (zero length) are left out, a tree of null branches gives an empty mesh.
    """
    pts = trees.points.detach().cpu().double().numpy()  # (N, T, 3)
    N, T, _ = pts.shape
    K = opts.sides
    depth = trees.depth.cpu().numpy()
    colors = branch_colors(trees, opts.color)
    tree_of = trees.tree_index.cpu().numpy()
    seg = np.linalg.norm(np.diff(pts, axis=1), axis=-1)
    keep = seg.sum(1) > NULL_LENGTH * max(base_radius, RADIUS_FLOOR)
    pts, depth, colors, tree_of = pts[keep], depth[keep], colors[keep], tree_of[keep]
    n = len(pts)
    out: list[TreeGeometry] = []
    if n:
        normal, binormal = _tube_frames(pts)
        s = np.concatenate([np.zeros((n, 1)), np.cumsum(np.linalg.norm(np.diff(pts, axis=1), axis=-1), 1)], 1)
        s /= np.maximum(s[:, -1:], NORM_FLOOR)
        r = base_radius * opts.thinning ** depth[:, None] * (1.0 - opts.taper * s)
        r = np.maximum(r, min_radius)  # (n, T)
        theta = 2 * np.pi * np.arange(K) / K
        radial = (np.cos(theta)[None, None, :, None] * normal[:, :, None]
                  + np.sin(theta)[None, None, :, None] * binormal[:, :, None])  # (n, T, K, 3)
        ring = pts[:, :, None] + r[:, :, None, None] * radial
        tang = unit_vectors(pts[:, -1] - pts[:, -2])[0]
        tang0 = unit_vectors(pts[:, 1] - pts[:, 0])[0]
        verts = np.concatenate([ring.reshape(n, T * K, 3), pts[:, :1], pts[:, -1:]], 1)  # (n, Vb, 3)
        norms = np.concatenate([radial.reshape(n, T * K, 3), -tang0[:, None], tang[:, None]], 1)
        Vb = T * K + 2
        template = _tube_template(T, K)
    bounds = np.searchsorted(tree_of, np.arange(trees.num_trees + 1)) if n else np.zeros(trees.num_trees + 1, int)
    for t in range(trees.num_trees):
        a, b = int(bounds[t]), int(bounds[t + 1])
        if b == a:  # nothing to draw (every branch null)
            out.append(TreeGeometry(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32),
                                    np.zeros((0, 3), np.uint8), np.zeros((0, 3), np.uint32)))
            continue
        faces = template[None] + (np.arange(b - a) * Vb)[:, None, None]
        out.append(TreeGeometry(
            verts[a:b].reshape(-1, 3).astype(np.float32),
            norms[a:b].reshape(-1, 3).astype(np.float32),
            np.repeat(colors[a:b], Vb, axis=0),
            faces.reshape(-1, 3).astype(np.uint32),
        ))
    return out
