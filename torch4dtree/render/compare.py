"""Generated and real 4D trees side by side at the same ages, one camera and one scale: the picture in which a
reader judges whether generated plants look like real ones.

Every plant is shown at the same normalised ages (``(t - t_first) / (t_last - t_first)``), each cell captioned with
the plant's own time; each plant is moved so that the root of its first frame is at the origin (one shift for all of
its frames, so its growth and size are kept), one camera frames every cell, and a scale bar gives the length of a
round number of data units. Layout ``"rows"``: one row per plant, one column per age (a fit report);
``"columns"``: one column per plant, one row per age (a compact README figure of a mid-growth and a final frame).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from .camera import prepare_camera
from .frames import fit_size, format_time
from .geometry import tree_geometry
from .gl import draw_frames
from .options import RenderOptions, resolve_options
from .text import CAPTION_INK, WHITE, compose, label_strip, line_height, load_font

if TYPE_CHECKING:  # imported where used: importing the renderer must not import torch (fast CLI start)
    from ..trees.structures import Trees, TreeSequence

__all__ = ["COMPARISON_LAYOUTS", "SCALE_BAR_SHARE", "nearest_frames", "render_comparison", "round_length",
           "scale_bar"]

COMPARISON_LAYOUTS = ("rows", "columns")
SCALE_BAR_SHARE = 0.3  # the scale bar is the round length nearest below this share of a cell's width


def nearest_frames(times: Sequence[float], ages: Sequence[float]) -> list[int]:
    """For each normalised age in ``[0, 1]``, the index of the frame of ``times`` (increasing) nearest to it; a frame
    may serve two ages (a plant scanned less often), so every column keeps its age.

    Example:
        >>> nearest_frames([0.0, 2.0, 10.0], [0.0, 0.5, 1.0])
        [0, 1, 2]
        >>> nearest_frames([5.0], [0.0, 1.0])
        [0, 0]
    """
    t = np.asarray(times, dtype=float)
    span = t[-1] - t[0]
    u = (t - t[0]) / span if span > 0 else np.zeros_like(t)
    return [int(np.abs(u - a).argmin()) for a in ages]


def round_length(x: float) -> float:
    """The largest 1, 2 or 5 times a power of ten not above ``x > 0`` (a scale bar's length).

    Example:
        >>> round_length(73.0), round_length(0.31)
        (50.0, 0.2)
    """
    mag = 10.0 ** math.floor(math.log10(x))
    return max(m * mag for m in (1.0, 2.0, 5.0) if m * mag <= x * (1 + 1e-12))


def _format_length(x: float, unit: str) -> str:
    text = f"{x:.0f}" if x >= 1 else f"{x:.3g}"
    return f"{text} {unit}".strip()


def scale_bar(image: np.ndarray, length_px: float, label: str) -> np.ndarray:
    """``image (H, W, 3)`` with a white strip below holding a horizontal bar of ``length_px`` pixels at the left and
    its ``label`` after it.

    Example:
        >>> scale_bar(np.full((40, 200, 3), 255, np.uint8), 50, "10 mm").shape[0] > 40
        True
    """
    from PIL import Image, ImageDraw

    W = image.shape[1]
    px = max(11, min(22, W // 70))
    font = load_font(px)
    lh = line_height(font)
    strip = Image.new("RGB", (W, lh + px), WHITE)
    draw = ImageDraw.Draw(strip)
    thick = max(2, px // 5)
    y = px // 2 + lh // 2
    draw.rectangle([px, y - thick // 2, px + round(length_px), y + thick // 2], fill=CAPTION_INK)
    draw.text((2 * px + round(length_px), px // 2), label, fill=CAPTION_INK, font=font)
    return np.concatenate([image, np.asarray(strip)], axis=0)


def _rooted(seq: TreeSequence, which: list[int]) -> Trees:
    """The frames ``which`` of ``seq`` moved so that the root of its first frame is at the origin."""
    frames = seq.frames
    shown = frames[which]
    return shown.translate(-frames.points[0, 0].expand(shown.num_trees, -1))


def render_comparison(
    generated: Sequence[TreeSequence],
    real: Sequence[TreeSequence],
    ages: Sequence[float] = (0.0, 0.25, 0.5, 0.75, 1.0),
    title: str | None = None,
    layout: str = "rows",
    unit: str = "",
    cell: int = 256,
    options: RenderOptions | None = None,
    **overrides: Any,
) -> np.ndarray:
    """Generated plants then real plants at the same normalised ``ages``, one camera and one scale (module doc).

    Args:
        generated / real: 4D trees (at least one in all); labelled ``generated 1..`` and ``real: <name>``.
        ages: normalised ages shown (each plant's nearest frame, captioned with its time).
        title: lines above the grid; layout: ``"rows"`` or ``"columns"`` (:data:`COMPARISON_LAYOUTS`).
        unit: the data's length unit for the scale bar (e.g. ``"mm"``).
        cell: pixels of a cell's longer side (the cells are shaped like the plants: :func:`.frames.fit_size`).
        options / overrides: :class:`RenderOptions` fields (``view``, ``color``...; ``size`` is set from ``cell``).

    Returns:
        ``(H, W, 3)`` uint8 image: the grid, then a strip with the scale bar (its length at the scene's centre depth).

    Example:
        >>> from torch4dtree.data import synthetic_plant
        >>> real = synthetic_plant("tomato", seed=0, n_frames=3, T=8).sequence
        >>> fake = synthetic_plant("tomato", seed=1, n_frames=3, T=8).sequence
        >>> render_comparison([fake], [real], ages=(0.5, 1.0), cell=64).ndim
        3
    """
    if layout not in COMPARISON_LAYOUTS:
        raise ValueError(f"layout must be one of {COMPARISON_LAYOUTS}, got {layout!r}")
    plants = [*generated, *real]
    if not plants or not ages:
        raise ValueError("render_comparison needs at least one plant and one age")
    names = [f"generated {i + 1}" for i in range(len(generated))] + [f"real: {s.name}" for s in real]
    picks = [nearest_frames(s.times.detach().cpu().double().tolist(), ages) for s in plants]
    batches = [_rooted(s, w) for s, w in zip(plants, picks)]
    opts = resolve_options(options, overrides)
    opts = replace(opts, size=fit_size(batches, cell, options=opts))
    n = len(ages)
    framing, r0, rmin = prepare_camera(batches, n, opts)
    framing = replace(framing, poses=framing.poses[:n])
    cells = []
    for seq, w, b in zip(plants, picks, batches):
        frames = draw_frames(tree_geometry(b, opts, r0, rmin), list(range(n)), framing, opts)
        times = seq.times.detach().cpu().double().numpy()[w]
        cells.append(np.concatenate([label_strip(f[None], format_time(float(t))) for f, t in zip(frames, times)]))
    grid = np.stack(cells)  # (plants, ages, H, W, 3)
    age_labels = [f"age {a:.2g}" for a in ages]
    if layout == "rows":
        image = compose(grid, names, age_labels, title)
    else:
        image = compose(grid.transpose(1, 0, 2, 3, 4), age_labels, names, title)
    W = opts.wh[0]
    bar = round_length(SCALE_BAR_SHARE * W * framing.pixel)
    return scale_bar(image, bar / framing.pixel, _format_length(bar, unit))
