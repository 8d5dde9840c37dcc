"""Offscreen rendering of trees and 4D trees: frames of a batch, videos of a sequence, grids, meshes.

Pipeline: every branch becomes a tube (:mod:`.geometry`), a camera is fitted once to **all** trees
that will be shown together (:mod:`.camera`: a whole sequence, a whole grid) so growth and
differences stay visible, pyrender draws the frames offscreen through EGL (:mod:`.gl`), labels
and titles are set with Pillow (:mod:`.text`), and :mod:`.save` writes PNG / GIF / MP4 files.

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
from collections.abc import Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from .camera import MIN_EXTENT, all_points, camera_axes, frame_azimuths, prepare_camera, view_elevation
from .geometry import branch_colors, tree_geometry
from .gl import close_renderer, draw_frames
from .options import (
    COLOR_MODES,
    GL_PACKAGES,
    IMAGE_SUFFIXES,
    LABEL_PALETTE,
    LAYER_COLORS,
    UNLABELLED_COLOR,
    VIDEO_SUFFIXES,
    RenderOptions,
    resolve_options,
)
from .save import pad_even, save_frames, save_image, save_video
from .text import TEXT_INK, compose, draw_caption, label_strip

if TYPE_CHECKING:  # imported where used: importing the renderer must not import torch (fast CLI start)
    from ..trees.structures import Trees, TreeSequence

__all__ = [
    "COLOR_MODES", "GL_PACKAGES", "IMAGE_SUFFIXES", "LABEL_PALETTE", "LAYER_COLORS", "TEXT_INK", "UNLABELLED_COLOR",
    "VIDEO_SUFFIXES", "RenderOptions", "branch_colors", "close_renderer", "fit_size", "format_time", "render_grid",
    "render_sequence", "render_trees", "save_frames", "save_image", "save_video", "time_index", "tree_meshes",
]

SAME_TIME = 1e-9  # a video time within this share of the time span after a scan shows that scan (rounding)
WHOLE_TIME = 1e-6  # a time this close to a whole number is labelled as that number
ASPECT_FLOOR = 1e-12  # a flat projection (a single straight branch seen end-on) still has a finite aspect ratio

def tree_meshes(trees: Trees, options: RenderOptions | None = None, **overrides: Any) -> list[Any]:
    """One ``trimesh.Trimesh`` per tree (tubes coloured by layer or label), e.g. to export as .ply / .glb.

    Radii are relative to the bounding box of the whole batch, as in the renders.

    Example:
        >>> import numpy as np
        >>> from torch4dtree import Trees
        >>> stem, leaf = np.array([[0.0, 0, 0], [0, 0, 10]]), np.array([[0.0, 0, 5], [4, 0, 8]])
        >>> trees = Trees.from_branches([[stem, leaf]], [[-1, 0]], T=8)
        >>> mesh = tree_meshes(trees, sides=6)[0]
        >>> len(mesh.faces) > 0
        True
    """
    import trimesh

    opts = resolve_options(options, overrides)
    pts = all_points([trees])
    scale = float(max(np.ptp(pts, axis=0).max(), MIN_EXTENT))
    out = []
    for g in tree_geometry(trees, opts, opts.radius * scale, 0.0):
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

    Example (offscreen through EGL: set ``PYOPENGL_PLATFORM=egl`` where there is no display):
        >>> import numpy as np
        >>> from torch4dtree import Trees
        >>> stem, leaf = np.array([[0.0, 0, 0], [0, 0, 10]]), np.array([[0.0, 0, 5], [4, 0, 8]])
        >>> trees = Trees.from_branches([[stem, leaf]], [[-1, 0]], T=8)
        >>> render_trees(trees, size=64).shape
        (1, 64, 64, 3)
    """
    opts = resolve_options(options, overrides)
    n = trees.num_trees
    framing, r0, rmin = prepare_camera([trees], n, opts)
    geoms = tree_geometry(trees, opts, r0, rmin)
    return draw_frames(geoms, list(range(n)), framing, opts)


def time_index(times: np.ndarray, n: int) -> list[int]:
    """For ``n`` evenly spaced video times over ``[times[0], times[-1]]``, the index of the last frame acquired.

    Example:
        >>> time_index(np.array([0.0, 1.0, 4.0]), 5)  # video times 0, 1, 2, 3, 4
        [0, 1, 1, 1, 2]
    """
    if len(times) == 1 or n == 1:
        return [len(times) - 1] * n if n == 1 else [0] * n
    u = np.linspace(times[0], times[-1], n)
    tol = SAME_TIME * (times[-1] - times[0])
    return np.clip(np.searchsorted(times, u + tol, side="right") - 1, 0, len(times) - 1).tolist()


def format_time(t: float) -> str:
    """A time for a label: whole numbers as such, others with one decimal.

    Example:
        >>> format_time(12.0), format_time(66.54)
        ('t = 12', 't = 66.5')
    """
    return f"t = {t:.0f}" if abs(t - round(t)) < WHOLE_TIME else f"t = {t:.1f}"


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

    Example:
        >>> from torch4dtree.data import synthetic_plant
        >>> seq = synthetic_plant("tomato", seed=0, n_frames=2, T=8).sequence
        >>> render_sequence(seq, n_frames=3, size=(64, 48)).shape
        (3, 48, 64, 3)
    """
    opts = resolve_options(options, overrides)
    n = len(seq) if n_frames is None else int(n_frames)
    if n < 1:
        raise ValueError(f"n_frames must be >= 1, got {n}")
    times = seq.times.detach().cpu().double().numpy()
    if interpolate and len(seq) > 1:
        from .interpolate import interpolate_sequence

        shown = times if n_frames is None else _video_times(times, n)
        trees, which = interpolate_sequence(seq, shown), list(range(n))
    else:
        which = list(range(n)) if n_frames is None else time_index(times, n)
        trees, shown = seq.frames, times[which]
    framing, r0, rmin = prepare_camera([trees], n, opts)
    frames = draw_frames(tree_geometry(trees, opts, r0, rmin), which, framing, opts)
    if caption:
        name = f"{seq.name}  " if seq.name else ""
        frames = np.stack([draw_caption(f, f"{name}{format_time(t)}") for f, t in zip(frames, shown)])
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
    return batch, time_index(t, n)


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

    Example:
        >>> from torch4dtree.data import synthetic_plant
        >>> seq = synthetic_plant("tomato", seed=0, n_frames=2, T=8).sequence
        >>> image = render_grid([seq, seq.frames], row_labels=["sequence", "frames"], title="two rows", size=48)
        >>> image.ndim, image.shape[1] >= 2 * 48
        (3, True)
    """
    if not rows:
        raise ValueError("render_grid needs at least one row")
    if row_labels is not None and len(row_labels) != len(rows):
        raise ValueError(f"{len(row_labels)} row labels for {len(rows)} rows")
    opts = resolve_options(options, overrides)
    batches = [_as_batch(r) for r in rows]
    longest = max(b.num_trees for b, _ in batches)
    if video:
        n = n_frames or longest
        if interpolate:
            batches, which = map(list, zip(*(_interpolated_row(r, n) for r in rows)))
            batches = [(b, None) for b in batches]
        else:
            which = [time_index(t, n) for _, t in batches]
    elif n_cols is not None:
        n = n_cols
        which = [time_index(t, n) for _, t in batches]
    else:
        n = longest
        which = [list(range(b.num_trees)) for b, _ in batches]
    if col_labels is not None and not video and len(col_labels) != n:
        raise ValueError(f"{len(col_labels)} column labels for {n} columns")
    if frame_labels is not None and (not video or len(frame_labels) != n):
        raise ValueError(f"frame_labels need video=True and one label per frame ({n}), got {len(frame_labels)}")
    if share_camera:
        shared = prepare_camera([b for b, _ in batches], n, opts)
    W, H = opts.wh
    cells = []  # per row, (n, H, W, 3)
    for (b, _), w in zip(batches, which):
        framing, r0, rmin = shared if share_camera else prepare_camera([b], n, opts)
        frames = draw_frames(tree_geometry(b, opts, r0, rmin), w, replace(framing, poses=framing.poses[:len(w)]),
                                opts)
        if len(w) < n:  # a short row: blank cells
            frames = np.concatenate([frames, np.full((n - len(w), H, W, 3), 255, np.uint8)])
        cells.append(frames)
    if not video:
        if wrap is not None and len(cells) == 1 and n > wrap:
            c = cells[0]
            if col_labels is not None:
                c = np.concatenate([label_strip(c[k:k + 1], str(col_labels[k])) for k in range(n)])
            R = -(-n // wrap)
            c = np.concatenate([c, np.full((R * wrap - n, *c.shape[1:]), 255, np.uint8)])
            return compose(c.reshape(R, wrap, *c.shape[1:]), None, None, title)
        return compose(np.stack(cells), row_labels, col_labels, title)
    per_row = n_cols or min(len(rows), 4)
    n_grid_rows = -(-len(rows) // per_row)
    if row_labels is not None:  # a label strip above each cell, not over the plant
        cells = [label_strip(c, str(lab)) for c, lab in zip(cells, row_labels)]
        H = cells[0].shape[1]
    blank = np.full((n, H, W, 3), 255, np.uint8)
    cells += [blank] * (n_grid_rows * per_row - len(cells))
    tiles = np.stack(cells).reshape(n_grid_rows, per_row, n, H, W, 3)
    frames = tiles.transpose(2, 0, 3, 1, 4, 5).reshape(n, n_grid_rows * H, per_row * W, 3)
    if title or frame_labels is not None:
        subs = [None] * n if frame_labels is None else list(frame_labels)
        frames = np.stack([compose(f[None, None], None, None, title, sub) for f, sub in zip(frames, subs)])
    return pad_even(frames)


def fit_size(rows: Sequence[TreeSequence | Trees], longest: int = 512, share_camera: bool = True,
             options: RenderOptions | None = None, max_aspect: float = 2.5, **overrides: Any) -> tuple[int, int]:
    """A panel size ``(W, H)`` shaped like the trees as the camera sees them, so that they fill it.

    The aspect ratio is that of the projected bounding box of every point of ``rows`` (of each row on
    its own and then their geometric mean with ``share_camera=False``) over all camera azimuths of the
    view, clamped to ``[1 / max_aspect, max_aspect]``; the longer side is ``longest`` pixels (sides even).

    Example (a tall plant gets a tall panel):
        >>> import numpy as np
        >>> from torch4dtree import Trees
        >>> stem, leaf = np.array([[0.0, 0, 0], [0, 0, 10]]), np.array([[0.0, 0, 5], [4, 0, 8]])
        >>> trees = Trees.from_branches([[stem, leaf]], [[-1, 0]], T=8)
        >>> fit_size([trees], longest=64)
        (26, 64)
    """
    opts = resolve_options(options, overrides)
    batches = [_as_batch(r)[0] for r in rows]
    groups = [batches] if share_camera else [[b] for b in batches]
    elevation = view_elevation(opts)
    axes = [camera_axes(a, elevation, opts.up) for a in frame_azimuths(opts, 36 if opts.view == "orbit" else 1)]
    logs = []
    for g in groups:
        pts = all_points(g)
        rel = pts - (pts.min(0) + pts.max(0)) / 2
        q = np.stack([rel @ R.T for R in axes])  # (views, P, 3) camera coordinates
        wx = float(np.ptp(q[..., 0], axis=1).max())
        wy = float(np.ptp(q[..., 1], axis=1).max())
        logs.append(math.log(max(wx, ASPECT_FLOOR) / max(wy, ASPECT_FLOOR)))
    aspect = min(max(math.exp(sum(logs) / len(logs)), 1 / max_aspect), max_aspect)
    w, h = (longest, longest / aspect) if aspect >= 1 else (longest * aspect, longest)
    return 2 * max(4, round(w / 2)), 2 * max(4, round(h / 2))
