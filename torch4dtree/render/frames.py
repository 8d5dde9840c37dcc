"""Offscreen rendering of trees and 4D trees: tubes, pyrender frames, PNG / GIF / MP4, grids.

Pipeline: every branch becomes a tube (vectorised in numpy, one merged mesh per tree), a camera
is fitted once to **all** trees that will be shown together (a whole sequence, a whole grid) so
growth and differences stay visible, and pyrender draws the frames offscreen through EGL
(Mesa's software renderer ``llvmpipe`` serves when there is no GPU).

Public API::

    render_trees(trees, **options)            -> (n_trees, H, W, 3) uint8, one frame per tree
    render_sequence(seq, n_frames, **options) -> (n_frames, H, W, 3) uint8, a video over time
    render_grid(rows, row_labels, col_labels, title, video=False, **options)
                                              -> (H, W, 3) image (rows x time) or (n, H, W, 3) frames
    tree_meshes(trees, **options)             -> one trimesh.Trimesh per tree
    save_image(path, image) / save_video(path, frames, fps) / save_frames(folder, frames)

``options`` are the fields of :class:`RenderOptions` (``size``, ``view``, ``color``, ``radius``...).
``pyrender``, ``trimesh``, ``imageio`` and ``Pillow`` are imported lazily, so ``import torch4dtree``
never needs OpenGL.
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .options import (
    COLOR_MODES,
    GL_PACKAGES,
    IMAGE_SUFFIXES,
    LABEL_PALETTE,
    LAYER_COLORS,
    UNLABELLED_COLOR,
    VIDEO_SUFFIXES,
    RenderOptions,
    _options,
)

if TYPE_CHECKING:  # imported where used: importing the renderer must not import torch (fast CLI start)
    from ..trees.structures import Trees, TreeSequence


# ------------------------------------------------------------------------------------ geometry
def branch_colors(trees: Trees, color: str = "layer") -> np.ndarray:
    """``(N, 3)`` uint8 sRGB colour of every packed branch, by layer or by label."""
    if color == "layer":
        depth = trees.depth.cpu().numpy()
        return LAYER_COLORS[np.minimum(depth, len(LAYER_COLORS) - 1)]
    if color == "label":
        label = trees.label.cpu().numpy()
        out = LABEL_PALETTE[np.mod(label, len(LABEL_PALETTE))]
        out[label < 0] = UNLABELLED_COLOR
        return out
    raise ValueError(f"color must be one of {COLOR_MODES}, got {color!r}")


def _unit(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normalised vectors ``(..., 3)`` and their norms ``(...)``."""
    n = np.linalg.norm(v, axis=-1)
    return v / np.maximum(n, 1e-300)[..., None], n


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
    tang, tn = _unit(tang)
    for i in range(1, T):  # a stalled sample (repeated point) keeps the previous direction
        stalled = tn[:, i] < 1e-12
        tang[stalled, i] = tang[stalled, i - 1]
    axes = np.eye(3)
    normal = np.empty_like(points)
    n0 = np.cross(tang[:, 0], axes[np.argmin(np.abs(tang[:, 0]), axis=1)])
    normal[:, 0] = _unit(n0)[0]
    for i in range(1, T):
        t = tang[:, i]
        n = normal[:, i - 1] - (normal[:, i - 1] * t).sum(-1, keepdims=True) * t
        n, nn = _unit(n)
        bad = nn < 1e-6  # a turn of ~90 degrees between samples: restart from a fixed axis
        if bad.any():
            n[bad] = _unit(np.cross(t[bad], axes[np.argmin(np.abs(t[bad]), axis=1)]))[0]
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
class _Geometry:
    """One tree's merged tube mesh (``V`` vertices, ``F`` triangles)."""

    vertices: np.ndarray  # (V, 3) float32
    normals: np.ndarray  # (V, 3) float32
    colors: np.ndarray  # (V, 3) uint8 sRGB
    faces: np.ndarray  # (F, 3) uint32


def _tree_geometry(trees: Trees, opts: RenderOptions, base_radius: float, min_radius: float) -> list[_Geometry]:
    """One merged tube mesh per tree; all branches of all trees are built in one vectorised pass."""
    pts = trees.points.detach().cpu().double().numpy()  # (N, T, 3)
    N, T, _ = pts.shape
    K = opts.sides
    depth = trees.depth.cpu().numpy()
    colors = branch_colors(trees, opts.color)
    tree_of = trees.tree_index.cpu().numpy()
    seg = np.linalg.norm(np.diff(pts, axis=1), axis=-1)
    keep = seg.sum(1) > 1e-9 * max(base_radius, 1e-12)  # null branches (zero length) are not drawn
    pts, depth, colors, tree_of = pts[keep], depth[keep], colors[keep], tree_of[keep]
    n = len(pts)
    out: list[_Geometry] = []
    if n:
        normal, binormal = _tube_frames(pts)
        # radius: thinner per layer, tapering along the branch, never under min_radius
        s = np.concatenate([np.zeros((n, 1)), np.cumsum(np.linalg.norm(np.diff(pts, axis=1), axis=-1), 1)], 1)
        s /= np.maximum(s[:, -1:], 1e-300)
        r = base_radius * opts.thinning ** depth[:, None] * (1.0 - opts.taper * s)
        r = np.maximum(r, min_radius)  # (n, T)
        theta = 2 * np.pi * np.arange(K) / K
        radial = (np.cos(theta)[None, None, :, None] * normal[:, :, None]
                  + np.sin(theta)[None, None, :, None] * binormal[:, :, None])  # (n, T, K, 3)
        ring = pts[:, :, None] + r[:, :, None, None] * radial
        tang = _unit(pts[:, -1] - pts[:, -2])[0]
        tang0 = _unit(pts[:, 1] - pts[:, 0])[0]
        verts = np.concatenate([ring.reshape(n, T * K, 3), pts[:, :1], pts[:, -1:]], 1)  # (n, Vb, 3)
        norms = np.concatenate([radial.reshape(n, T * K, 3), -tang0[:, None], tang[:, None]], 1)
        Vb = T * K + 2
        template = _tube_template(T, K)
    bounds = np.searchsorted(tree_of, np.arange(trees.num_trees + 1)) if n else np.zeros(trees.num_trees + 1, int)
    for t in range(trees.num_trees):
        a, b = int(bounds[t]), int(bounds[t + 1])
        if b == a:  # nothing to draw (every branch null)
            out.append(_Geometry(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32),
                                 np.zeros((0, 3), np.uint8), np.zeros((0, 3), np.uint32)))
            continue
        faces = template[None] + (np.arange(b - a) * Vb)[:, None, None]
        out.append(_Geometry(
            verts[a:b].reshape(-1, 3).astype(np.float32),
            norms[a:b].reshape(-1, 3).astype(np.float32),
            np.repeat(colors[a:b], Vb, axis=0),
            faces.reshape(-1, 3).astype(np.uint32),
        ))
    return out


# -------------------------------------------------------------------------------------- camera
@dataclass
class _Framing:
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


def _camera_axes(azimuth: float, elevation: float, up: int) -> np.ndarray:
    """``(3, 3)`` rows = camera right, up and backward axes in world coordinates (degrees in)."""
    u = np.eye(3)[up]
    h1, h2 = np.eye(3)[(up + 1) % 3], np.eye(3)[(up + 2) % 3]
    a, e = math.radians(azimuth), math.radians(elevation)
    back = math.cos(e) * (math.sin(a) * h1 - math.cos(a) * h2) + math.sin(e) * u
    right = math.cos(a) * h1 + math.sin(a) * h2
    return np.stack([right, np.cross(back, right), back])


def _frame_azimuths(opts: RenderOptions, n: int) -> list[float]:
    """Camera azimuth of each of ``n`` frames (turning only for ``orbit``)."""
    base = {"front": 0.0, "side": 90.0, "top": 0.0, "orbit": 0.0}[opts.view] + opts.azimuth
    if opts.view != "orbit":
        return [base] * n
    return [base + 360.0 * opts.turns * k / max(n, 1) for k in range(n)]


def _fit_camera(points: np.ndarray, azimuths: Sequence[float], opts: RenderOptions) -> _Framing:
    """A perspective camera that keeps every point (plus tube radius) inside the frame at every azimuth.

    Args:
        points: ``(P, 3)`` all branch points of everything that will be shown.
        azimuths: one camera azimuth (degrees) per frame; a single fixed target and distance
            serve all of them, so nothing jumps between frames.
    """
    lo, hi = points.min(0), points.max(0)
    scale = float(max((hi - lo).max(), 1e-9))
    center = (lo + hi) / 2
    pad = opts.radius * scale  # the thickest tube's radius
    W, H = opts.wh
    aspect = W / H
    ty = math.tan(math.radians(opts.yfov) / 2) * (1 - 2 * opts.margin)
    tx = ty * aspect
    elevation = 90.0 if opts.view == "top" else opts.elevation
    rel = points - center
    axes = [_camera_axes(a, elevation, opts.up) for a in azimuths]
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
    znear = max(D - radius, 1e-3 * D) * 0.9
    zfar = (D + radius) * 1.1
    pixel = 2 * D * math.tan(math.radians(opts.yfov) / 2) / H
    return _Framing(poses, math.radians(opts.yfov), aspect, znear, zfar, pixel, scale, D - 0.3 * radius, D + radius)


def _all_points(batches: Sequence[Trees]) -> np.ndarray:
    """``(P, 3)`` every branch point of every batch (the extent to frame)."""
    pts = [b.points.detach().cpu().double().numpy().reshape(-1, b.dim) for b in batches]
    out = np.concatenate(pts)
    if out.shape[1] != 3:
        from ..trees.structures import TreeError

        raise TreeError(f"only 3D trees can be rendered, got dimension {out.shape[1]}")
    return out


# ------------------------------------------------------------------------------------ renderer
_RENDERER: Any = None


def _gl_error(err: BaseException) -> RuntimeError:
    return RuntimeError(
        f"offscreen OpenGL (EGL) rendering is unavailable: {type(err).__name__}: {err}. "
        f"Install the system libraries (Debian/Ubuntu: `apt-get install -y {GL_PACKAGES}`, or run "
        f".ci/system-packages.sh); with a GPU driver, its EGL vendor library works too. "
        f"PYOPENGL_PLATFORM={os.environ.get('PYOPENGL_PLATFORM')!r}."
    )


def _pyrender() -> Any:
    """Import pyrender on EGL, turning a missing package or GL library into a clear error."""
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")  # before OpenGL is first imported
    if "pyglet" not in sys.modules and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        # pyrender imports pyglet's window code; without a display use its EGL backend, not X11's
        os.environ.setdefault("PYGLET_HEADLESS", "true")
    try:
        import pyrender
    except ModuleNotFoundError as e:
        if e.name and e.name.split(".")[0] in ("pyrender", "trimesh", "OpenGL", "pyglet"):
            raise ModuleNotFoundError(
                f"rendering needs the 'render' extra: pip install 'torch4dtree[render]' ({e})", name=e.name
            ) from e
        raise
    except Exception as e:  # ImportError('Unable to load EGL library'), OSError, AttributeError...
        raise _gl_error(e) from e
    return pyrender


def _renderer(W: int, H: int) -> Any:
    """The process-wide offscreen renderer (creating an EGL context per frame is slow)."""
    global _RENDERER
    pyrender = _pyrender()
    if _RENDERER is None:
        try:
            _RENDERER = pyrender.OffscreenRenderer(W, H)
        except Exception as e:
            raise _gl_error(e) from e
        import atexit

        atexit.register(close_renderer)
    _RENDERER.viewport_width, _RENDERER.viewport_height = W, H
    return _RENDERER


def close_renderer() -> None:
    """Release the offscreen GL context (it is re-created on the next render)."""
    global _RENDERER
    if _RENDERER is not None:
        try:
            _RENDERER.delete()
        except Exception:  # noqa: S110 - tearing down a dead context at exit is best effort
            pass
        _RENDERER = None


def _look_pose(direction: Sequence[float]) -> np.ndarray:
    """``(4, 4)`` pose whose -z axis points along ``direction`` (light travel, camera frame)."""
    z = -_unit(np.asarray(direction, float))[0]
    x = np.cross([0.0, 1.0, 0.0], z) if abs(z[1]) < 0.99 else np.cross([1.0, 0.0, 0.0], z)
    x = _unit(x)[0]
    pose = np.eye(4)
    pose[:3, :3] = np.stack([x, np.cross(z, x), z], 1)
    return pose


def _srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """pyrender multiplies vertex colours into linear light and gamma-encodes the result."""
    c = c.astype(np.float32) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)


def _fog(color: np.ndarray, depth: np.ndarray, framing: _Framing, amount: float) -> np.ndarray:
    """Fade ``(H, W, 3)`` pixels towards white with their depth ``(H, W)`` (0 = background)."""
    if amount <= 0:
        return color
    t = np.clip((depth - framing.near) / max(framing.far - framing.near, 1e-12), 0.0, 1.0) * amount
    t[depth <= 0] = 0.0
    return (color + t[..., None] * (255.0 - color)).round().astype(np.uint8)


def _render_frames(geoms: list[_Geometry], which: Sequence[int], framing: _Framing, opts: RenderOptions) -> np.ndarray:
    """``(len(which), H, W, 3)`` uint8: frame ``k`` shows ``geoms[which[k]]`` from ``framing.poses[k]``."""
    pyrender = _pyrender()
    W, H = opts.wh
    renderer = _renderer(W, H)
    scene = pyrender.Scene(bg_color=[1.0, 1.0, 1.0, 1.0], ambient_light=[0.18, 0.18, 0.18])
    camera = pyrender.PerspectiveCamera(yfov=framing.yfov, aspectRatio=framing.aspect,
                                        znear=framing.znear, zfar=framing.zfar)
    cam_node = scene.add(camera, pose=framing.poses[0])
    # lights ride with the camera, so an orbit keeps the same modelling: key upper-left, fill right, rim behind
    for direction, intensity in (((0.6, -0.7, -0.8), 3.0), ((-0.9, 0.2, -0.5), 0.6), ((0.0, -0.4, 1.0), 1.0)):
        scene.add(pyrender.DirectionalLight(color=np.ones(3), intensity=intensity),
                  pose=_look_pose(direction), parent_node=cam_node)
    material = pyrender.MetallicRoughnessMaterial(baseColorFactor=[1.0, 1.0, 1.0, 1.0], metallicFactor=0.0,
                                                  roughnessFactor=0.5)
    meshes: dict[int, Any] = {}
    out = np.empty((len(which), H, W, 3), np.uint8)
    last: tuple[int, int] | None = None
    for k, (g, pose) in enumerate(zip(which, framing.poses)):
        if last is not None and last[0] == g and np.array_equal(framing.poses[last[1]], pose):
            out[k] = out[k - 1]  # the same tree from the same place: reuse the pixels
            continue
        geom = geoms[g]
        node = None
        if len(geom.faces):
            if g not in meshes:
                colors = np.concatenate([_srgb_to_linear(geom.colors), np.ones((len(geom.colors), 1), np.float32)], 1)
                prim = pyrender.Primitive(positions=geom.vertices, normals=geom.normals, color_0=colors,
                                          indices=geom.faces, material=material, mode=4)  # 4 = GL_TRIANGLES
                meshes[g] = pyrender.Mesh([prim])
            node = scene.add(meshes[g])
        scene.set_pose(cam_node, pose)
        try:
            color, depth = renderer.render(scene)
        except Exception as e:
            raise _gl_error(e) from e
        out[k] = _fog(color[..., :3], depth, framing, opts.fog)
        if node is not None:
            scene.remove_node(node)
        last = (g, k)
    return out


def _prepare(batches: Sequence[Trees], n_views: int, opts: RenderOptions) -> tuple[_Framing, float, float]:
    """Camera for everything in ``batches`` and the tube radii (base, minimum) in world units."""
    framing = _fit_camera(_all_points(batches), _frame_azimuths(opts, n_views), opts)
    return framing, opts.radius * framing.scale, opts.min_pixels * framing.pixel


# ---------------------------------------------------------------------------------- public API
def tree_meshes(trees: Trees, options: RenderOptions | None = None, **overrides: Any) -> list[Any]:
    """One ``trimesh.Trimesh`` per tree (tubes coloured by layer or label), e.g. to export as .ply / .glb.

    Radii are relative to the bounding box of the whole batch, as in the renders.
    """
    import trimesh

    opts = _options(options, overrides)
    pts = _all_points([trees])
    scale = float(max(np.ptp(pts, axis=0).max(), 1e-9))
    out = []
    for g in _tree_geometry(trees, opts, opts.radius * scale, 0.0):
        rgba = np.concatenate([g.colors, np.full((len(g.colors), 1), 255, np.uint8)], 1)
        out.append(trimesh.Trimesh(g.vertices, g.faces, vertex_normals=g.normals, vertex_colors=rgba, process=False))
    return out


def render_trees(trees: Trees, options: RenderOptions | None = None, **overrides: Any) -> np.ndarray:
    """Render every tree of a batch as one frame, with one camera framing them all.

    Args:
        trees: a batch of ``n`` 3D trees (e.g. the frames of a sequence, or a geodesic path).
        options / overrides: :class:`RenderOptions` fields (``size``, ``view``, ``color``...).

    Returns:
        ``(n, H, W, 3)`` uint8 RGB frames on a white background.
    """
    opts = _options(options, overrides)
    n = trees.num_trees
    framing, r0, rmin = _prepare([trees], n, opts)
    geoms = _tree_geometry(trees, opts, r0, rmin)
    return _render_frames(geoms, list(range(n)), framing, opts)


def _time_index(times: np.ndarray, n: int) -> list[int]:
    """For ``n`` evenly spaced video times over ``[times[0], times[-1]]``, the last frame already acquired."""
    if len(times) == 1 or n == 1:
        return [len(times) - 1] * n if n == 1 else [0] * n
    u = np.linspace(times[0], times[-1], n)
    tol = 1e-9 * (times[-1] - times[0])
    return np.clip(np.searchsorted(times, u + tol, side="right") - 1, 0, len(times) - 1).tolist()


def format_time(t: float) -> str:
    """A time for a label: whole numbers as such, others with one decimal (``"t = 66.5"``)."""
    return f"t = {t:.0f}" if abs(t - round(t)) < 1e-6 else f"t = {t:.1f}"


def _video_times(times: np.ndarray, n: int) -> np.ndarray:
    """``n`` evenly spaced times over ``[times[0], times[-1]]``."""
    return np.linspace(times[0], times[-1], n) if n > 1 else times[-1:].copy()


def render_sequence(
    seq: TreeSequence,
    n_frames: int | None = None,
    options: RenderOptions | None = None,
    caption: bool = False,
    interpolate: bool = False,
    **overrides: Any,
) -> np.ndarray:
    """Render a 4D tree as a video with a fixed camera framing the whole sequence.

    Args:
        seq: the 4D tree.
        n_frames: video frames (default: one per acquired frame). Video frame ``k`` is at time
            ``t_0 + k (t_n - t_0) / (n_frames - 1)``, so irregular acquisition spacing stays visible;
            ``orbit`` turns the camera smoothly over all frames.
        caption: write the sequence name and the frame's time in the top-left corner.
        interpolate: show, between two scans, the geodesic between them at the elapsed fraction of
            time (:func:`~torch4dtree.render.interpolate.interpolate_sequence`, one tree registration
            per pair of scans); otherwise the latest scan acquired by then.

    Returns:
        ``(n_frames, H, W, 3)`` uint8.
    """
    opts = _options(options, overrides)
    n = len(seq) if n_frames is None else int(n_frames)
    if n < 1:
        raise ValueError(f"n_frames must be >= 1, got {n}")
    times = seq.times.detach().cpu().double().numpy()
    if interpolate and len(seq) > 1:
        from .interpolate import interpolate_sequence

        shown = times if n_frames is None else _video_times(times, n)
        trees, which = interpolate_sequence(seq, shown), list(range(n))
    else:
        which = list(range(n)) if n_frames is None else _time_index(times, n)
        trees, shown = seq.frames, times[which]
    framing, r0, rmin = _prepare([trees], n, opts)
    frames = _render_frames(_tree_geometry(trees, opts, r0, rmin), which, framing, opts)
    if caption:
        name = f"{seq.name}  " if seq.name else ""
        frames = np.stack([_draw_caption(f, f"{name}{format_time(t)}") for f, t in zip(frames, shown)])
    return frames


def _as_batch(row: TreeSequence | Trees) -> tuple[Trees, np.ndarray]:
    """A grid row as a batch of trees and normalised times in ``[0, 1]``."""
    from ..trees.structures import Trees, TreeSequence

    if isinstance(row, TreeSequence):
        return row.frames, row.normalized_times().detach().cpu().double().numpy()
    if isinstance(row, Trees):
        n = row.num_trees
        return row, (np.linspace(0, 1, n) if n > 1 else np.zeros(1))
    raise TypeError(f"grid rows must be TreeSequence or Trees, got {type(row).__name__}")


def _interpolated_row(row: TreeSequence | Trees, n: int) -> tuple[Trees, list[int]]:
    """``n`` trees of a row at evenly spaced times: geodesics between scans for a sequence, else the latest."""
    from ..trees.structures import TreeSequence

    if isinstance(row, TreeSequence) and len(row) > 1:
        from .interpolate import interpolate_sequence

        return interpolate_sequence(row, _video_times(row.times.detach().cpu().double().numpy(), n)), list(range(n))
    batch, t = _as_batch(row)
    return batch, _time_index(t, n)


def render_grid(
    rows: Sequence[TreeSequence | Trees],
    row_labels: Sequence[str] | None = None,
    col_labels: Sequence[str] | None = None,
    title: str | None = None,
    video: bool = False,
    n_cols: int | None = None,
    n_frames: int | None = None,
    share_camera: bool = True,
    options: RenderOptions | None = None,
    frame_labels: Sequence[str] | None = None,
    interpolate: bool = False,
    wrap: int | None = None,
    **overrides: Any,
) -> np.ndarray:
    """Several trees / 4D trees side by side (geodesics, modes of variation, samples), one shared camera.

    With ``share_camera`` (default) every cell uses one camera and one tube radius, so sizes
    compare across rows; ``share_camera=False`` frames each row on its own (still fixed over time).

    Image (``video=False``): one row per input, one column per time; ``n_cols`` samples every row
    at that many evenly spaced normalised times (default: each row's frames in order, short rows
    padded with white). ``col_labels`` go above the columns, ``row_labels`` left of the rows. ``wrap``
    lays a single row out over several, at most ``wrap`` cells wide, each cell under its column label.

    Video (``video=True``): one cell per input laid out ``n_cols`` cells wide (default: up to 4),
    each cell animating its row over ``n_frames`` video frames (default: the longest row's length)
    by normalised time; ``row_labels`` caption the cells, ``frame_labels`` (one per video frame, e.g.
    its time) are written under the title of every frame, and ``interpolate`` shows sequences between
    their scans by geodesics (see :func:`render_sequence`). Titles may hold several lines (``\\n``);
    they are set smaller, then wrapped, to fit the width.

    Returns:
        ``(H, W, 3)`` uint8 image, or ``(n_frames, H, W, 3)`` uint8 frames.
    """
    if not rows:
        raise ValueError("render_grid needs at least one row")
    if row_labels is not None and len(row_labels) != len(rows):
        raise ValueError(f"{len(row_labels)} row labels for {len(rows)} rows")
    opts = _options(options, overrides)
    batches = [_as_batch(r) for r in rows]
    longest = max(b.num_trees for b, _ in batches)
    if video:
        n = n_frames or longest
        if interpolate:
            batches, which = map(list, zip(*(_interpolated_row(r, n) for r in rows)))
            batches = [(b, None) for b in batches]
        else:
            which = [_time_index(t, n) for _, t in batches]
    elif n_cols is not None:
        n = n_cols
        which = [_time_index(t, n) for _, t in batches]
    else:
        n = longest
        which = [list(range(b.num_trees)) for b, _ in batches]
    if col_labels is not None and not video and len(col_labels) != n:
        raise ValueError(f"{len(col_labels)} column labels for {n} columns")
    if frame_labels is not None and (not video or len(frame_labels) != n):
        raise ValueError(f"frame_labels need video=True and one label per frame ({n}), got {len(frame_labels)}")
    if share_camera:
        shared = _prepare([b for b, _ in batches], n, opts)
    W, H = opts.wh
    cells = []  # per row, (n, H, W, 3)
    for (b, _), w in zip(batches, which):
        framing, r0, rmin = shared if share_camera else _prepare([b], n, opts)
        frames = _render_frames(_tree_geometry(b, opts, r0, rmin), w, replace(framing, poses=framing.poses[:len(w)]),
                                opts)
        if len(w) < n:  # a short row: blank cells
            frames = np.concatenate([frames, np.full((n - len(w), H, W, 3), 255, np.uint8)])
        cells.append(frames)
    if not video:
        if wrap is not None and len(cells) == 1 and n > wrap:
            c = cells[0]
            if col_labels is not None:
                c = np.concatenate([_label_strip(c[k:k + 1], str(col_labels[k])) for k in range(n)])
            R = -(-n // wrap)
            c = np.concatenate([c, np.full((R * wrap - n, *c.shape[1:]), 255, np.uint8)])
            return _compose(c.reshape(R, wrap, *c.shape[1:]), None, None, title)
        return _compose(np.stack(cells), row_labels, col_labels, title)
    per_row = n_cols or min(len(rows), 4)
    n_grid_rows = -(-len(rows) // per_row)
    if row_labels is not None:  # a label strip above each cell, not over the plant
        cells = [_label_strip(c, str(lab)) for c, lab in zip(cells, row_labels)]
        H = cells[0].shape[1]
    blank = np.full((n, H, W, 3), 255, np.uint8)
    cells += [blank] * (n_grid_rows * per_row - len(cells))
    tiles = np.stack(cells).reshape(n_grid_rows, per_row, n, H, W, 3)
    frames = tiles.transpose(2, 0, 3, 1, 4, 5).reshape(n, n_grid_rows * H, per_row * W, 3)
    if title or frame_labels is not None:
        subs = [None] * n if frame_labels is None else list(frame_labels)
        frames = np.stack([_compose(f[None, None], None, None, title, sub) for f, sub in zip(frames, subs)])
    return _even(frames)


def fit_size(rows: Sequence[TreeSequence | Trees], longest: int = 512, share_camera: bool = True,
             options: RenderOptions | None = None, max_aspect: float = 2.5, **overrides: Any) -> tuple[int, int]:
    """A panel size ``(W, H)`` shaped like the trees as the camera sees them, so that they fill it.

    The aspect ratio is that of the projected bounding box of every point of ``rows`` (of each row on
    its own and then their geometric mean with ``share_camera=False``) over all camera azimuths of the
    view, clamped to ``[1 / max_aspect, max_aspect]``; the longer side is ``longest`` pixels (sides even).
    """
    opts = _options(options, overrides)
    batches = [_as_batch(r)[0] for r in rows]
    groups = [batches] if share_camera else [[b] for b in batches]
    elevation = 90.0 if opts.view == "top" else opts.elevation
    axes = [_camera_axes(a, elevation, opts.up) for a in _frame_azimuths(opts, 36 if opts.view == "orbit" else 1)]
    logs = []
    for g in groups:
        pts = _all_points(g)
        rel = pts - (pts.min(0) + pts.max(0)) / 2
        q = np.stack([rel @ R.T for R in axes])  # (views, P, 3) camera coordinates
        wx = float(np.ptp(q[..., 0], axis=1).max())
        wy = float(np.ptp(q[..., 1], axis=1).max())
        logs.append(math.log(max(wx, 1e-12) / max(wy, 1e-12)))
    aspect = min(max(math.exp(sum(logs) / len(logs)), 1 / max_aspect), max_aspect)
    w, h = (longest, longest / aspect) if aspect >= 1 else (longest * aspect, longest)
    return 2 * max(4, round(w / 2)), 2 * max(4, round(h / 2))


# ------------------------------------------------------------------------------------ 2D layout
TEXT_INK = (30, 30, 30)


def _font(px: int) -> Any:
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=px)  # Pillow >= 10.1 ships a scalable font
    except (TypeError, OSError):
        return ImageFont.load_default()


def _text_width(text: str, font: Any) -> int:
    from PIL import Image, ImageDraw

    x0, _, x1, _ = ImageDraw.Draw(Image.new("RGB", (1, 1))).textbbox((0, 0), text, font=font)
    return x1 - x0


def _line_height(font: Any) -> int:
    """Height of a line of ``font`` whatever its letters (so that layouts do not change with the text)."""
    try:
        ascent, descent = font.getmetrics()
        return int(ascent + descent)
    except AttributeError:  # Pillow's old bitmap font
        from PIL import Image, ImageDraw

        _, y0, _, y1 = ImageDraw.Draw(Image.new("RGB", (1, 1))).textbbox((0, 0), "Agy|", font=font)
        return y1 - y0


def _shorten(text: str, width: int, font: Any) -> str:
    """``text`` cut in the middle with an ellipsis until it fits ``width`` pixels."""
    if _text_width(text, font) <= width:
        return text
    keep = len(text)
    while keep > 1:
        keep -= 1
        cut = text[: (keep + 1) // 2] + "\u2026" + text[len(text) - keep // 2:]
        if _text_width(cut, font) <= width:
            return cut
    return "\u2026"


def _fit_text(text: str, width: int, px: int, min_px: int) -> tuple[list[str], Any]:
    """Lines of ``text`` (split at newlines) and a font of at most ``px`` pixels with which each fits ``width``:
    the font shrinks down to ``min_px``, then lines are wrapped at spaces, then cut in the middle."""
    lines = text.split("\n")
    size = px
    while size > min_px and max(_text_width(ln, _font(size)) for ln in lines) > width:
        size -= 1
    font = _font(size)
    out: list[str] = []
    for ln in lines:
        cur = ""
        for word in ln.split(" "):
            cand = f"{cur} {word}" if cur else word
            if cur and _text_width(cand, font) > width:
                out.append(cur)
                cur = word
            else:
                cur = cand
        out.append(cur)
    return [_shorten(ln, width, font) for ln in out], font


def _text_px(H: int, W: int) -> int:
    """Font size in pixels for the labels of ``H x W`` cells (readable, not dominating)."""
    return max(11, min(32, max(H, W) // 14))


def _label_strip(frames: np.ndarray, text: str) -> np.ndarray:
    """``(n, H, W, 3)`` frames with a white strip on top holding ``text``, centred (shrunk or cut to fit)
    -> ``(n, H + h, W, 3)``."""
    from PIL import Image, ImageDraw

    n, H, W, _ = frames.shape
    px = _text_px(H, W)
    lines, font = _fit_text(text, W - px // 2, px, max(8, px * 2 // 3))
    h = _line_height(font) + px // 2
    strip = Image.new("RGB", (W, h), (255, 255, 255))
    ImageDraw.Draw(strip).text(((W - _text_width(lines[0], font)) // 2, px // 4), lines[0], fill=TEXT_INK, font=font)
    top = np.broadcast_to(np.asarray(strip), (n, h, W, 3))
    return np.concatenate([top, frames], axis=1)


def _draw_caption(frame: np.ndarray, text: str) -> np.ndarray:
    """The frame with ``text`` in its top-left corner (shrunk or cut to fit the frame's width)."""
    from PIL import Image, ImageDraw

    img = Image.fromarray(frame)
    px = max(10, min(28, frame.shape[0] // 18))
    lines, font = _fit_text(text, frame.shape[1] - px, px, max(8, px * 2 // 3))
    ImageDraw.Draw(img).text((px // 2, px // 3), lines[0], fill=(40, 40, 40), font=font)
    return np.asarray(img)


def _compose(
    cells: np.ndarray, row_labels: Sequence[str] | None, col_labels: Sequence[str] | None, title: str | None,
    subtitle: str | None = None,
) -> np.ndarray:
    """Tile ``cells (R, C, H, W, 3)`` into one image with a title (any lines, fitted to the width), a
    subtitle line (e.g. a video frame's time), column labels and row labels."""
    from PIL import Image, ImageDraw

    R, C, H, W, _ = cells.shape
    px = _text_px(H, W)
    font = _font(px)
    pad = px // 2
    left = max((_text_width(str(t), font) for t in row_labels), default=0) + 2 * pad if row_labels else 0
    full = left + C * W
    title_lines, title_font = _fit_text(title, full - 2 * pad, int(px * 1.3), px * 2 // 3) if title else ([], font)
    sub_lines, sub_font = _fit_text(subtitle, full - 2 * pad, px, px * 2 // 3) if subtitle is not None else ([], font)
    col_texts, col_font = [], font
    if col_labels:
        col_texts = [str(c) for c in col_labels]
        size = px
        while size > max(8, px // 2) and max(_text_width(c, _font(size)) for c in col_texts) > W - pad:
            size -= 1
        col_font = _font(size)
        col_texts = [_shorten(c, W - pad, col_font) for c in col_texts]
    lh_title, lh_sub, lh_col = _line_height(title_font), _line_height(sub_font), _line_height(col_font)
    top_title = len(title_lines) * lh_title + (pad if title_lines else 0)
    top_sub = len(sub_lines) * lh_sub + (pad // 2 if sub_lines else 0)
    top_cols = lh_col + pad if col_labels else 0
    top = (top_title + top_sub + top_cols + pad) if (title_lines or sub_lines or col_labels) else 0
    img = Image.new("RGB", (full, top + R * H), (255, 255, 255))
    img.paste(Image.fromarray(cells.transpose(0, 2, 1, 3, 4).reshape(R * H, C * W, 3)), (left, top))
    draw = ImageDraw.Draw(img)
    y = pad
    for ln, f, lh in [(t, title_font, lh_title) for t in title_lines] + [(t, sub_font, lh_sub) for t in sub_lines]:
        draw.text(((full - _text_width(ln, f)) // 2, y), ln, fill=TEXT_INK, font=f)
        y += lh
    for c, lab in enumerate(col_texts):
        draw.text((left + c * W + (W - _text_width(lab, col_font)) // 2, top - top_cols), lab, fill=TEXT_INK,
                  font=col_font)
    if row_labels:
        for r, lab in enumerate(row_labels):
            draw.text((pad, top + r * H + (H - _line_height(font)) // 2), str(lab), fill=TEXT_INK, font=font)
    return np.asarray(img)


def _even(frames: np.ndarray) -> np.ndarray:
    """Pad ``(..., H, W, 3)`` with white to even ``H`` and ``W`` (H.264 with yuv420p needs it)."""
    H, W = frames.shape[-3:-1]
    ph, pw = H % 2, W % 2
    if not (ph or pw):
        return frames
    widths = [(0, 0)] * (frames.ndim - 3) + [(0, ph), (0, pw), (0, 0)]
    return np.pad(frames, widths, constant_values=255)


# ---------------------------------------------------------------------------------------- files
def _check_frames(frames: np.ndarray, what: str) -> np.ndarray:
    arr = np.asarray(frames)
    if arr.dtype != np.uint8 or arr.shape[-1] not in (3, 4):
        raise ValueError(f"{what} must be uint8 RGB(A) with shape (..., H, W, 3), got {arr.dtype} {arr.shape}")
    return arr


def save_image(path: str | Path, image: np.ndarray, overwrite: bool = False) -> Path:
    """Write one ``(H, W, 3)`` uint8 image (format from the suffix: .png, .jpg); never replaces a file unless asked."""
    import imageio.v3 as iio

    path = Path(path)
    img = _check_frames(image, "image")
    if img.ndim == 4 and len(img) == 1:
        img = img[0]
    if img.ndim != 3:
        raise ValueError(f"save_image takes one (H, W, 3) image, got {img.shape}; use save_video or save_frames")
    suffix = path.suffix.lower()
    if suffix not in IMAGE_SUFFIXES:
        raise ValueError(f"{path}: image files must end in {', '.join(IMAGE_SUFFIXES)}")
    if path.exists() and not overwrite:  # fail before encoding
        raise FileExistsError(f"{path} exists; pass overwrite=True (--overwrite) to replace it")
    data = iio.imwrite("<bytes>", img, extension=suffix)
    from ..io.files import write_bytes_safely  # here: importing torch4dtree.io imports torch

    return write_bytes_safely(path, data, overwrite)


def save_frames(folder: str | Path, frames: np.ndarray, overwrite: bool = False, prefix: str = "frame") -> list[Path]:
    """Write ``(n, H, W, 3)`` frames as ``folder/<prefix>_0000.png`` ...; refuses to replace any existing file."""
    arr = _check_frames(frames, "frames")
    folder = Path(folder)
    paths = [folder / f"{prefix}_{k:04d}.png" for k in range(len(arr))]
    clash = [p for p in paths if p.exists()]
    if clash and not overwrite:
        raise FileExistsError(f"{clash[0]} exists; pass overwrite=True (--overwrite) to replace it")
    return [save_image(p, f, overwrite) for p, f in zip(paths, arr)]


def _gif_bytes(frames: np.ndarray, fps: float) -> bytes:
    """A looping GIF of ``(n, H, W, 3)`` frames, one GIF frame per input frame.

    Pillow's animated-GIF writer merges identical consecutive frames (a held time point), which
    would change the frame count, so the frames are written one by one with their own palettes.
    """
    from PIL import GifImagePlugin, Image

    ms = 1000.0 / fps
    ims = [Image.fromarray(f).quantize(colors=256, dither=Image.Dither.NONE) for f in frames]
    out = bytearray()
    for chunk in GifImagePlugin.getheader(ims[0], None, {"loop": 0, "duration": ms})[0]:
        out += chunk
    for k, im in enumerate(ims):
        # GIF delays are in centiseconds: spread the rounding so the total duration stays right
        delay = 10 * (round((k + 1) * ms / 10) - round(k * ms / 10))
        for chunk in GifImagePlugin.getdata(im, duration=delay, include_color_table=True):
            out += chunk
    out += b";"
    return bytes(out)


def save_video(path: str | Path, frames: np.ndarray, fps: float = 4.0, overwrite: bool = False) -> Path:
    """Write ``(n, H, W, 3)`` uint8 frames as a GIF (looping) or an MP4 (H.264, yuv420p).

    The format comes from the suffix. MP4 uses imageio-ffmpeg's bundled ffmpeg; odd sizes are
    padded with white to even ones. Never replaces an existing file unless ``overwrite``.
    """
    path = Path(path)
    arr = _check_frames(frames, "frames")
    if arr.ndim == 3:
        arr = arr[None]
    if arr.ndim != 4 or len(arr) == 0:
        raise ValueError(f"save_video takes (n >= 1, H, W, 3) frames, got {arr.shape}")
    arr = np.ascontiguousarray(arr[..., :3])
    if fps <= 0:
        raise ValueError(f"fps must be positive, got {fps}")
    suffix = path.suffix.lower()
    if suffix not in VIDEO_SUFFIXES:
        raise ValueError(f"{path}: video files must end in {', '.join(VIDEO_SUFFIXES)} (use save_frames for PNGs)")
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists; pass overwrite=True (--overwrite) to replace it")
    from ..io.files import publish_file, temporary_path, write_bytes_safely  # here: torch4dtree.io imports torch

    if suffix == ".gif":
        return write_bytes_safely(path, _gif_bytes(arr, fps), overwrite)
    import imageio_ffmpeg

    arr = _even(arr)
    n, H, W, _ = arr.shape
    tmp = temporary_path(path)
    try:
        writer = imageio_ffmpeg.write_frames(
            str(tmp), (W, H), fps=fps, codec="libx264", pix_fmt_in="rgb24", pix_fmt_out="yuv420p",
            macro_block_size=1, quality=None, ffmpeg_log_level="error",
            output_params=["-crf", "18", "-preset", "veryfast", "-movflags", "+faststart"],
        )
        try:
            writer.send(None)
            for f in arr:
                writer.send(f.tobytes())
            writer.close()
        except (OSError, RuntimeError) as e:  # ffmpeg's messages name the hidden temporary file
            raise type(e)(f"{path}: cannot encode the video: {str(e).replace(str(tmp), str(path))}") from None
        publish_file(tmp, path, overwrite)
    finally:
        tmp.unlink(missing_ok=True)
    return path
