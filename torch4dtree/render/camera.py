"""The camera: one perspective framing fitted to everything that is shown together.

A sequence, a grid or an orbit is framed once, over all its trees and all camera azimuths, so
that growth and differences stay visible and nothing jumps between frames.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .options import RenderOptions

if TYPE_CHECKING:  # imported where used: importing the renderer must not import torch (fast CLI start)
    from ..trees.structures import Trees

__all__ = ["Framing", "all_points", "camera_axes", "fit_camera", "frame_azimuths", "prepare_camera", "view_elevation"]

MIN_EXTENT = 1e-9  # a scene of one point still gets a positive size
NEAR_SHARE = 1e-3  # the near clipping plane stays at least this share of the camera distance in front
VIEW_AZIMUTH = {"front": 0.0, "side": 90.0, "top": 0.0, "orbit": 0.0}  # degrees about the up axis
TOP_ELEVATION = 90.0  # the ``top`` view looks straight down the up axis


@dataclass
class Framing:
    """A camera fitted to a set of points: one pose per frame, fixed intrinsics."""

    poses: list[np.ndarray]  # (4, 4) camera-to-world, camera looks along its -z
    yfov: float  # radians
    aspect: float
    znear: float
    zfar: float
    pixel: float  # world size of one pixel at the scene's centre depth
    scale: float  # largest side of the scene's bounding box
    near: float  # depth range of the fog: none in front of ``near``, full at ``far``
    far: float


def camera_axes(azimuth: float, elevation: float, up: int) -> np.ndarray:
    """``(3, 3)`` rows = camera right, up and backward axes in world coordinates (angles in degrees)."""
    u = np.eye(3)[up]
    h1, h2 = np.eye(3)[(up + 1) % 3], np.eye(3)[(up + 2) % 3]
    a, e = math.radians(azimuth), math.radians(elevation)
    back = math.cos(e) * (math.sin(a) * h1 - math.cos(a) * h2) + math.sin(e) * u
    right = math.cos(a) * h1 + math.sin(a) * h2
    return np.stack([right, np.cross(back, right), back])


def view_elevation(opts: RenderOptions) -> float:
    """The camera elevation in degrees of ``opts.view``."""
    return TOP_ELEVATION if opts.view == "top" else opts.elevation


def frame_azimuths(opts: RenderOptions, n: int) -> list[float]:
    """Camera azimuth in degrees of each of ``n`` frames (turning only for the ``orbit`` view)."""
    base = VIEW_AZIMUTH[opts.view] + opts.azimuth
    if opts.view != "orbit":
        return [base] * n
    return [base + 360.0 * opts.turns * k / max(n, 1) for k in range(n)]


def fit_camera(points: np.ndarray, azimuths: Sequence[float], opts: RenderOptions) -> Framing:
    """A perspective camera that keeps every point (plus tube radius) inside the frame at every azimuth.

    Args:
        points: ``(P, 3)`` all branch points of everything that will be shown.
        azimuths: one camera azimuth (degrees) per frame; a single fixed target and distance
            serve all of them, so nothing jumps between frames.
        opts: the view, field of view, margin, size and tube radius.
    """
    lo, hi = points.min(0), points.max(0)
    scale = float(max((hi - lo).max(), MIN_EXTENT))
    center = (lo + hi) / 2
    pad = opts.radius * scale  # the thickest tube's radius
    W, H = opts.wh
    aspect = W / H
    ty = math.tan(math.radians(opts.yfov) / 2) * (1 - 2 * opts.margin)
    tx = ty * aspect
    elevation = view_elevation(opts)
    rel = points - center
    axes = [camera_axes(a, elevation, opts.up) for a in azimuths]
    unique = {round(a % 360.0, 9): R for a, R in zip(azimuths, axes)}
    cams = [rel @ R.T for R in unique.values()]  # (P, 3) camera-frame coordinates per distinct azimuth

    def distance(ox: float, oy: float) -> float:
        # smallest D with |x - ox| / (D - z) <= tx and |y - oy| / (D - z) <= ty for every point and azimuth
        return max(float(np.max(q[:, 2] + pad + np.maximum((np.abs(q[:, 0] - ox) + pad) / tx,
                                                             (np.abs(q[:, 1] - oy) + pad) / ty))) for q in cams)

    # centre the projected extent: shifting the camera sideways is linear, iterate a few times
    ox = 0.0 if opts.view == "orbit" else float((cams[0][:, 0].min() + cams[0][:, 0].max()) / 2)
    oy = float(np.mean([(q[:, 1].min() + q[:, 1].max()) / 2 for q in cams]))
    for _ in range(4):
        D = distance(ox, oy)
        depth = D - np.concatenate([q[:, 2] for q in cams])
        u = (np.concatenate([q[:, 0] for q in cams]) - ox) / depth
        v = (np.concatenate([q[:, 1] for q in cams]) - oy) / depth
        if opts.view != "orbit":
            ox += float((u.min() + u.max()) / 2 * D)
        oy += float((v.min() + v.max()) / 2 * D)
    D = distance(ox, oy)
    poses = []
    for R in axes:
        pose = np.eye(4)
        pose[:3, :3] = R.T
        pose[:3, 3] = center + ox * R[0] + oy * R[1] + D * R[2]
        poses.append(pose)
    radius = float(np.linalg.norm(hi - lo)) / 2 + pad
    znear = max(D - radius, NEAR_SHARE * D) * 0.9
    zfar = (D + radius) * 1.1
    pixel = 2 * D * math.tan(math.radians(opts.yfov) / 2) / H
    return Framing(poses, math.radians(opts.yfov), aspect, znear, zfar, pixel, scale, D - 0.3 * radius, D + radius)


def all_points(batches: Sequence[Trees]) -> np.ndarray:
    """``(P, 3)`` every branch point of every batch (the extent to frame); only 3D trees can be rendered."""
    pts = [b.points.detach().cpu().double().numpy().reshape(-1, b.dim) for b in batches]
    out = np.concatenate(pts)
    if out.shape[1] != 3:
        from ..trees.structures import TreeError

        raise TreeError(f"only 3D trees can be rendered, got dimension {out.shape[1]}")
    return out


def prepare_camera(batches: Sequence[Trees], n_views: int, opts: RenderOptions) -> tuple[Framing, float, float]:
    """The camera for everything in ``batches`` over ``n_views`` frames, and the tube radii (base, minimum)
    in world units: radii follow the scene's size and the pixel size, so thin branches stay visible."""
    framing = fit_camera(all_points(batches), frame_azimuths(opts, n_views), opts)
    return framing, opts.radius * framing.scale, opts.min_pixels * framing.pixel
